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

use bench_harness::pipeline::{PipelineScenario, is_pipeline, run_pipeline};
use bench_harness::run::{INTERRUPTED, Interrupted, OutputRefused, default_output};
use bench_harness::scenario::MAX_SCENARIO_BYTES;
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

/// The scenario's text, at most [`MAX_SCENARIO_BYTES`] of it.
fn read_scenario(path: &Path, reader: impl std::io::Read) -> Result<String, ScenarioError> {
    use std::io::Read;
    let mut source = String::new();
    reader
        .take(MAX_SCENARIO_BYTES + 1)
        .read_to_string(&mut source)
        .map_err(|source| ScenarioError::Read {
            path: path.to_path_buf(),
            source,
        })?;
    if source.len() as u64 > MAX_SCENARIO_BYTES {
        return Err(ScenarioError::TooLarge {
            path: path.to_path_buf(),
        });
    }
    Ok(source)
}

/// Set up the worker threads and the interrupt handler; `Err` is the exit code.
fn start_workers(threads: Option<NonZeroUsize>) -> Result<(), ExitCode> {
    if let Some(n) = threads.filter(|n| n.get() > MAX_THREADS) {
        eprintln!("error: --threads {n}: at most {MAX_THREADS}");
        return Err(ExitCode::from(2));
    }
    if let Some(n) = threads
        && let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n.get())
            .build_global()
    {
        eprintln!("error: cannot start {n} worker threads: {e}");
        return Err(ExitCode::FAILURE);
    }
    // SIGINT and SIGTERM stop the run at the next batch of trials; the staging folder
    // is removed on the way out.
    if let Err(e) = ctrlc::set_handler(|| INTERRUPTED.store(true, Ordering::SeqCst)) {
        eprintln!("warning: no interrupt handler: {e}");
    }
    Ok(())
}

/// Print why a run failed and give its exit code: 2 for a refused output folder or
/// scenario (nothing written), 130 when interrupted, 1 otherwise.
fn failed(e: &anyhow::Error, name: &str) -> ExitCode {
    if e.downcast_ref::<OutputRefused>().is_some() || e.downcast_ref::<ScenarioError>().is_some() {
        eprintln!("error: {e}");
        ExitCode::from(2)
    } else if e.downcast_ref::<Interrupted>().is_some() {
        eprintln!("{name}: {e}");
        ExitCode::from(130)
    } else {
        eprintln!("error: {e:#}");
        ExitCode::FAILURE
    }
}

/// A pipeline run (a scenario with a `[pipeline]` table).
fn run_pipeline_main(cli: &Cli, path: &Path, text: &str) -> ExitCode {
    let scenario = match PipelineScenario::parse(path, text) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    if cli.trials.is_some() {
        eprintln!(
            "error: --trials does not apply to a pipeline run (set pipeline.frames_per_section)"
        );
        return ExitCode::from(2);
    }
    if let Err(code) = start_workers(cli.threads) {
        return code;
    }
    let out = cli
        .out
        .clone()
        .unwrap_or_else(|| default_output(&scenario.name));
    match run_pipeline(&scenario, &out, !cli.quiet) {
        Ok(report) => {
            if !cli.quiet {
                eprintln!(
                    "{}: {} sections × {} frames in {:.1} s → {}",
                    scenario.name,
                    scenario.sections.len(),
                    scenario.frames_per_section,
                    report.wall_time_s,
                    out.display()
                );
            }
            if report.errors > 0 {
                eprintln!(
                    "{} estimates returned an error (status `error` in profile.csv)",
                    report.errors
                );
                return ExitCode::FAILURE;
            }
            ExitCode::SUCCESS
        }
        Err(e) => failed(&e, &scenario.name),
    }
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
    let path = if cli.scenario.as_os_str() == "-" {
        PathBuf::from("<stdin>")
    } else {
        cli.scenario.clone()
    };
    let text = if cli.scenario.as_os_str() == "-" {
        read_scenario(&path, std::io::stdin().lock())
    } else {
        std::fs::File::open(&path)
            .map_err(|source| ScenarioError::Read {
                path: path.clone(),
                source,
            })
            .and_then(|f| read_scenario(&path, f))
    };
    let text = match text {
        Ok(t) => t,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    if is_pipeline(&text) {
        return run_pipeline_main(&cli, &path, &text);
    }
    let scenario = match Scenario::parse(&path, &text) {
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
    if let Err(code) = start_workers(cli.threads) {
        return code;
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
        Err(e) => failed(&e, &scenario.name),
    }
}
