//! Diagnostics on standard error that never stop a program: `eprintln!` panics when
//! standard error is a pipe whose reader has gone ("failed printing to stderr: Broken
//! pipe", exit 101), which would lose the outputs and the exit code of the run that
//! printed it. `line` (and the [`stderr_line!`](crate::stderr_line) macro over it)
//! writes the line and ignores a failure: a diagnostic nobody can read is dropped, the
//! run goes on and exits with its own code.

use std::io::Write;

/// Write `args` and a newline to standard error in one locked write; any error (a closed
/// pipe, a full disk) is ignored.
pub fn line(args: std::fmt::Arguments<'_>) {
    let mut text = args.to_string();
    text.push('\n');
    let _ = std::io::stderr().lock().write_all(text.as_bytes());
}

/// `eprintln!` that ignores a closed or failing standard error ([`diag::line`](crate::diag::line)).
#[macro_export]
macro_rules! stderr_line {
    ($($arg:tt)*) => {
        $crate::diag::line(::std::format_args!($($arg)*))
    };
}
