//! `epd`: pipe diameters and sensor pose from point-cloud files.
//!
//! ```text
//! epd estimate FILE… [--method ml-epd|ru-epd|c-epd] [--min-range M] [--max-range M]
//!                    [--format text|json|csv] [--nominal-od-in X] [--loss cauchy|huber|none]
//!                    [--loss-scale M] [--units m|mm] [--frame sensor|optical]
//!                    [--input-format F] [--calibration LUT.json [--unweighted]]
//!                    [-o FILE] [--threads N] [--shard K/N] [-q]
//! epd calibrate FILE… --known-id-mm D [--known-dmin-mm D2] --out LUT.json
//!               [--min-range M] [--max-range M] [--range-bins N] [--intensity-bins N]
//!               [--min-count N] [--passes N] [--units m|mm] [--frame sensor|optical] [--threads N] [-q]
//! epd simulate --out DIR [--frames K] [--seed S] [--sigma M] [--od-in X] [--ovality O]
//!              [--wall-mm T] [--points N] [--outliers F] [--noise range|isotropic]
//!              [--ply binary|ascii] [--precision f64|f32]
//! ```
//! Exit codes: 0 all files estimated, 1 a file failed or its fit did not converge to a
//! result consistent with its points (the others are still reported), 2 wrong arguments.
//! `calibrate` exits 1 when a frame was skipped (the table is written from the others)
//! or none could be used (no table written).

mod args;
mod calibrate;
mod estimate;
mod simulate;

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use indicatif::ProgressBar;

use crate::args::{Cli, Command};

/// A usage error found after parsing (exit code 2).
#[derive(Debug)]
struct Usage(String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for Usage {}

pub(crate) fn usage(msg: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(Usage(msg.into()))
}

/// Refuse an output path that exists but is not a regular file or a link (a device, a
/// pipe, a folder: the atomic write would replace it), or that names one of the inputs.
pub(crate) fn check_output_path(out: &Path, inputs: &[PathBuf], flag: &str) -> anyhow::Result<()> {
    let shown = out.display();
    // A link is replaced, never followed (a planted link cannot redirect the write).
    match std::fs::symlink_metadata(out) {
        Ok(m) if !m.file_type().is_file() && !m.file_type().is_symlink() => {
            return Err(usage(format!(
                "{flag} {shown}: exists and is not a regular file (a device, pipe or folder); \
                 the result replaces the file at that path, so name a new or regular file"
            )));
        }
        _ => {}
    }
    if let Ok(o) = out.canonicalize() {
        for i in inputs {
            if i.canonicalize().is_ok_and(|c| c == o) {
                return Err(usage(format!(
                    "{flag} {shown}: is also an input file; it would be overwritten"
                )));
            }
        }
    }
    Ok(())
}

/// Start rayon's global pool with `threads` workers (unset: one per core).
pub(crate) fn start_threads(threads: Option<NonZeroUsize>) -> anyhow::Result<()> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n.get())
            .build_global()
            .context("cannot start the worker threads")?;
    }
    Ok(())
}

/// A progress bar over `n` files on standard error, hidden with `--quiet`.
pub(crate) fn progress(quiet: bool, n: usize) -> ProgressBar {
    if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(n as u64)
    }
}

fn main() -> ExitCode {
    epd_frame::keep_freed_memory();
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        // Help and version exit 0, usage errors 2 (clap's codes); a closed stdout while
        // printing help is ignored.
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    let result = match &cli.command {
        Command::Estimate(a) => estimate::run_estimate(a),
        Command::Calibrate(a) => calibrate::run_calibrate(a),
        Command::Simulate(a) => simulate::run_simulate(a),
    };
    match result {
        Ok(code) => code,
        Err(e) if e.downcast_ref::<Usage>().is_some() => {
            eprintln!("error: {e}\n\nFor more information, try '--help'.");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
