//! `bench-harness SCENARIO.toml [--out DIR] [--trials N] [--threads N] [-q]`: run a
//! scenario.
//!
//! Exit codes: 0 done; 1 the run failed, or a trial could not be made at all (status
//! `error` in `trials.csv`; estimates that did not converge are results, counted in
//! `n_failed`); 2 the scenario, the arguments or the output folder are wrong (nothing is
//! written then);
//! 130 interrupted (SIGINT or SIGTERM: nothing is written, the previous results stay).

use std::num::NonZeroUsize;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::Ordering;

use bench_harness::run::{INTERRUPTED, Interrupted, OutputRefused, default_output};
use bench_harness::{RunOptions, Scenario, run};
use clap::Parser;

/// Run a scenario of simulated ToF frames through the EPD estimators: trials.csv,
/// summary.csv, metadata.json and PNG plots in one folder, replaced as a whole.
#[derive(Parser, Debug)]
#[command(name = "bench-harness", version)]
struct Cli {
    /// The scenario file (TOML); `-` reads it from standard input.
    #[arg(value_name = "SCENARIO")]
    scenario: PathBuf,
    /// Output folder (default: target/results/<name>/ of the workspace, ignored by git).
    #[arg(short = 'o', long, alias = "output", value_name = "DIR")]
    out: Option<PathBuf>,
    /// Trials per setting, overriding the scenario's (at most 1 000 000).
    #[arg(long, value_name = "N")]
    trials: Option<NonZeroUsize>,
    /// Worker threads (default: all cores).
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
    if let Some(t) = trials.filter(|&t| t > bench_harness::scenario::MAX_TRIALS) {
        eprintln!(
            "error: --trials {t}: at most {}",
            bench_harness::scenario::MAX_TRIALS
        );
        return ExitCode::from(2);
    }
    let loaded = if cli.scenario.as_os_str() == "-" {
        match std::io::read_to_string(std::io::stdin().lock()) {
            Ok(text) => Scenario::parse(std::path::Path::new("<stdin>"), &text),
            Err(e) => {
                eprintln!("error: cannot read the scenario from standard input: {e}");
                return ExitCode::from(2);
            }
        }
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
        Err(e) if e.downcast_ref::<OutputRefused>().is_some() => {
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
