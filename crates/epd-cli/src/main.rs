//! `epd`: pipe diameters and sensor pose from point-cloud files.
//!
//! ```text
//! epd estimate FILE… [--method ml-epd|ru-epd|c-epd] [--min-range M] [--max-range M]
//!                    [--format text|json|csv] [--nominal-od-in X] [--loss cauchy|huber|none]
//!                    [--loss-scale M] [--units m|mm] [--frame sensor|optical|body|flu]
//!                    [--input-format F] [--calibration LUT.json [--unweighted]] [--topic T]
//!                    [-o FILE] [--threads N] [--shard K/N] [-q] [--export-fit OUT.ply]
//! epd calibrate FILE… --known-id-mm D [--known-dmin-mm D2] --out LUT.json
//!               [--min-range M] [--max-range M] [--range-bins N] [--intensity-bins N]
//!               [--min-count N] [--passes N] [--units m|mm] [--frame sensor|optical] [--threads N] [-q]
//! epd topics BAG…
//! epd profile RUN.mcap|FILE… --out DIR [--topic T] [--odometry-topic TOPIC | --speed M_PER_S]
//!             [--shard K/N] [fit options as for estimate] [--threads N] [-q]
//! epd view FILE --out frame.png [--limit-mm L] [fit options as for estimate]
//! epd simulate --out DIR [--frames K] [--seed S] [--sigma M] [--od-in X] [--ovality O]
//!              [--wall-mm T] [--points N] [--outliers F] [--noise range|isotropic]
//!              [--ply binary|ascii] [--precision f64|f32]
//! ```
//! Exit codes: 0 all files estimated, 1 a file failed or its fit did not converge to a
//! result consistent with its points (the others are still reported), 2 wrong arguments.
//! `calibrate` exits 1 when a frame was skipped (the table is written from the others)
//! or none could be used (no table written).
//!
//! Streams and signals: a standard output or error that is closed (or a pipe whose reader
//! went away) changes no exit code and loses no output file: results are written before
//! any diagnostic, and diagnostics that cannot be written are dropped
//! (`epd_io::stderr_line!`). SIGINT, SIGTERM and SIGHUP remove the temporary file of an
//! output being written (`.epd-output-XXXXXX`, `.epd-io-XXXXXX`) and then end the process
//! as the signal would have (a previous output at that path is untouched); a signal that
//! was ignored when `epd` started (`nohup`) stays ignored. Temporary files of a process
//! killed outright (SIGKILL) are removed by the next output in that folder
//! (`epd_io::atomic`).

mod args;
mod calibrate;
mod estimate;
mod profile;
mod simulate;
mod stream;
mod topics;
mod view;

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use epd_io::stderr_line;
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

/// Refuse an output path that cannot be one (a folder, a block device, a socket, or a
/// link to one: `epd_io::atomic::output_kind`), or that names one of the inputs. A new
/// path, a regular file or a link to one is replaced whole; a character device or a pipe
/// (`/dev/null`, `/dev/stdout`) is written through.
pub(crate) fn check_output_path(out: &Path, inputs: &[PathBuf], flag: &str) -> anyhow::Result<()> {
    let shown = epd_io::name::shown(out);
    let kind =
        epd_io::atomic::output_kind(out).map_err(|why| usage(format!("{flag} {shown}: {why}")))?;
    if kind == epd_io::atomic::OutputKind::Through {
        return Ok(());
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

/// On SIGINT, SIGTERM and SIGHUP (each unless ignored at start): remove the temporary
/// files of the outputs being written, then end as the signal would
/// (`epd_io::atomic::remove_pending_temporaries`). The handler runs on its own thread
/// (signal-hook's iterator), so it may take locks and remove files. A handled signal
/// that the parent left blocked (a mask is inherited through `exec`) is unblocked here,
/// before any other thread starts (threads inherit the mask): blocked, it would stay
/// pending and the process could not be stopped by it. An ignored signal is the user's
/// choice (`nohup`) and stays ignored; a blocked one is rarely meant for the program.
#[cfg(unix)]
fn remove_temporaries_on_signals() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let ignored = |sig: libc::c_int| {
        // SAFETY: a query only (no new action); `old` is written by the call.
        unsafe {
            let mut old: libc::sigaction = std::mem::zeroed();
            libc::sigaction(sig, std::ptr::null(), &mut old) == 0
                && old.sa_sigaction == libc::SIG_IGN
        }
    };
    let wanted: Vec<libc::c_int> = [SIGINT, SIGTERM, SIGHUP]
        .into_iter()
        .filter(|&s| !ignored(s))
        .collect();
    // SAFETY: sigemptyset/sigaddset fill a local set; pthread_sigmask changes only this
    // thread's mask (no other thread runs yet).
    unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        for &s in &wanted {
            libc::sigaddset(&mut set, s);
        }
        libc::pthread_sigmask(libc::SIG_UNBLOCK, &set, std::ptr::null_mut());
    }
    let Ok(mut signals) = signal_hook::iterator::Signals::new(&wanted) else {
        stderr_line!("warning: no signal handler: an interrupted -o may leave a temporary file");
        return;
    };
    let spawned = std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            if let Some(sig) = signals.forever().next() {
                epd_io::atomic::remove_pending_temporaries();
                let _ = signal_hook::low_level::emulate_default_handler(sig);
                // Not reached for these signals (their default ends the process).
                std::process::exit(128 + sig);
            }
        });
    if spawned.is_err() {
        stderr_line!("warning: no signal handler: an interrupted -o may leave a temporary file");
    }
}

#[cfg(not(unix))]
fn remove_temporaries_on_signals() {}

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
    remove_temporaries_on_signals();
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
        Command::Topics(a) => topics::run_topics(a),
        Command::Profile(a) => profile::run_profile(a),
        Command::View(a) => view::run_view(a),
    };
    match result {
        Ok(code) => code,
        // Names in messages are data: their control characters are escaped.
        Err(e) if e.downcast_ref::<Usage>().is_some() => {
            let e = e.to_string();
            let e = epd_io::name::escape_controls(&e);
            stderr_line!("error: {e}\n\nFor more information, try '--help'.");
            ExitCode::from(2)
        }
        Err(e) => {
            let e = format!("{e:#}");
            stderr_line!("error: {}", epd_io::name::escape_controls(&e));
            ExitCode::FAILURE
        }
    }
}
