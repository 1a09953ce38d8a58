//! `bench-harness SCENARIO.toml [--out DIR] [--trials N] [--threads N] [-q]`: run a
//! scenario.
//!
//! Exit codes: 0 done; 1 the run failed, or a trial could not be made at all (status
//! `error` in `trials.csv`; estimates that did not converge are results, counted in
//! `n_failed`); 2 the scenario, the arguments or the output folder are wrong (nothing is
//! written then);
//! 130 interrupted (SIGINT or SIGTERM: nothing is written, the previous results stay).

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::Ordering;

use bench_harness::run::{INTERRUPTED, Interrupted, OutputRefused, default_output};
use bench_harness::{RunOptions, Scenario, ScenarioError, run};
use clap::Parser;

/// Most worker threads (`--threads`).
const MAX_THREADS: usize = 1024;

/// The end of `--help`: the output folder and the exit codes.
const AFTER_HELP: &str = "\
The output folder is replaced as a whole: the run is written into a new hidden folder
beside it (.run-XXXXXX) that takes its place only once every file is written. It must
be new, empty, or hold a previous run (nothing but bench-harness's files); anything
else is refused.

Exit codes:
  0    done; estimates that did not converge (e.g. C-EPD `implausible` at high tilt)
       are results: rows with their status in trials.csv, counted in n_failed
  1    the run failed (an I/O error, naming the file: nothing is written, the
       previous run stays), or a trial could not be made at all (status `error` in
       trials.csv: the frame or an estimate returned an error; the run is written)
  2    bad arguments, scenario (a limit passed) or output folder: nothing is written
  130  interrupted (SIGINT, SIGTERM): nothing is written, the previous run stays";

/// Run a scenario of simulated ToF frames through the EPD estimators: trials.csv,
/// summary.csv, metadata.json and PNG plots in one folder, replaced as a whole.
#[derive(Parser, Debug)]
#[command(name = "bench-harness", version, after_help = AFTER_HELP)]
struct Cli {
    /// The scenario file (TOML); `-` reads it from standard input.
    #[arg(value_name = "SCENARIO")]
    scenario: PathBuf,
    /// Output folder (default: target/results/<name>/ of the workspace, ignored by git).
    #[arg(short = 'o', long, alias = "output", value_name = "DIR")]
    out: Option<PathBuf>,
    /// Trials per setting, overriding the scenario's (at most 1 000 000, and at most 10^8
    /// estimates: trials × swept values × methods).
    #[arg(long, value_name = "N")]
    trials: Option<NonZeroUsize>,
    /// Worker threads, 1 ≤ N ≤ 1024 (default: all cores); the results do not depend on it.
    #[arg(long, value_name = "N")]
    threads: Option<NonZeroUsize>,
    /// No progress bar and no summary line: only errors on stderr.
    #[arg(short, long)]
    quiet: bool,
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    let trials = cli.trials.map(NonZeroUsize::get);
    let loaded = if cli.scenario.as_os_str() == "-" {
        Scenario::from_reader(Path::new("<stdin>"), std::io::stdin().lock())
    } else {
        Scenario::load(&cli.scenario)
    };
    let scenario = match loaded {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    if let Some(t) = trials
        && let Err(e) = scenario.check_trials("--trials", t)
    {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    if let Some(n) = cli.threads.filter(|n| n.get() > MAX_THREADS) {
        eprintln!("error: --threads {n}: at most {MAX_THREADS}");
        return ExitCode::from(2);
    }
    if let Some(n) = cli.threads
        && let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n.get())
            .build_global()
    {
        eprintln!("error: cannot start {n} worker threads: {e}");
        return ExitCode::FAILURE;
    }
    // SIGINT and SIGTERM stop the run at the next batch of trials; the staging folder
    // is removed on the way out.
    if let Err(e) = ctrlc::set_handler(|| INTERRUPTED.store(true, Ordering::SeqCst)) {
        eprintln!("warning: no interrupt handler: {e}");
    }
    let out = cli.out.unwrap_or_else(|| default_output(&scenario.name));
    let options = RunOptions {
        out: out.clone(),
        trials,
        progress: !cli.quiet,
    };
    match run(&scenario, &options) {
        Ok(report) => {
            if !cli.quiet {
                eprintln!(
                    "{}: {} settings × {} trials in {:.1} s → {}",
                    scenario.name,
                    scenario.sweeps.len(),
                    trials.unwrap_or(scenario.trials),
                    report.wall_time_s,
                    out.display()
                );
            }
            if report.trial_errors > 0 {
                eprintln!(
                    "{} trials or estimates could not be made (status `error` in trials.csv)",
                    report.trial_errors
                );
                return ExitCode::FAILURE;
            }
            ExitCode::SUCCESS
        }
        Err(e)
            if e.downcast_ref::<OutputRefused>().is_some()
                || e.downcast_ref::<ScenarioError>().is_some() =>
        {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
        Err(e) if e.downcast_ref::<Interrupted>().is_some() => {
            eprintln!("{}: {e}", scenario.name);
            ExitCode::from(130)
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
