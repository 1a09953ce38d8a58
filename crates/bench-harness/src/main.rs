//! `bench-harness SCENARIO.toml [--out DIR] [--trials N] [--threads N] [--shard K/N] [-q]`:
//! run a scenario, or the K-th of N parts of it;
//! `bench-harness merge D_1 … D_N --out M [-q]`: merge the N parts into one run.
//!
//! Exit codes: 0 done; 1 the run failed, or a trial could not be made at all (status
//! `error` in `trials.csv`; estimates that did not converge are results, counted in
//! `n_failed`); 2 the scenario, the arguments or the output folder are wrong (nothing is
//! written then);
//! 130 interrupted (SIGINT or SIGTERM: nothing is written, the previous results stay).
//! `merge` exits 2 when the folders are not the N shards of one run (nothing is written).

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::Ordering;

use bench_harness::approach::ApproachScenario;
use bench_harness::calibration_transfer::TransferScenario;
use bench_harness::experiment::{Experiment, Kind, Refused, Request};
use bench_harness::output::{INTERRUPTED, Interrupted, OutputRefused};
use bench_harness::pipeline::PipelineScenario;
use bench_harness::scenario::read_source;
use bench_harness::sweep::merge::{MergeError, MergeOptions, merge};
use bench_harness::sweep::trial_errors_note;
use bench_harness::{Scenario, ScenarioError};
use clap::{Parser, Subcommand};
use epd_frame::shard::ShardSpec;

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
  2    bad arguments, scenario (a limit passed) or output folder: nothing is written;
       for merge also: the folders are not the N shards of one run
  130  interrupted (SIGINT, SIGTERM): nothing is written, the previous run stays

Sharding (one machine is not enough):
  bench-harness SCENARIO --shard K/N --out D_K    (K = 1 … N, anywhere, any order)
  bench-harness merge D_1 … D_N --out M           (M/trials.csv, M/summary.csv, plots)
Trial g = setting index × trials + trial runs in shard (g mod N) + 1, with the seeds of
the unsharded run: the merged trials.csv and summary.csv equal one unsharded run's,
timings (time_ms) aside. Pipeline scenarios ([pipeline]) cannot be sharded.";

/// Run a scenario of simulated ToF frames through the EPD estimators: trials.csv,
/// summary.csv, metadata.json and PNG plots in one folder, replaced as a whole.
#[derive(Parser, Debug)]
#[command(
    name = "bench-harness",
    version,
    after_help = AFTER_HELP,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true,
    disable_help_subcommand = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// The scenario file (TOML); `-` reads it from standard input.
    #[arg(value_name = "SCENARIO", required = true)]
    scenario: Option<PathBuf>,
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
    /// Run only the K-th of N parts (1 ≤ K ≤ N): the trials g = setting index × trials +
    /// trial with g mod N = K − 1, seeded as in the unsharded run. Writes trials.csv (this
    /// part's rows), shard.json and shard-trials.jsonl (exact values) for `merge`; no
    /// summary or plots. Default --out: target/results/<name>-shard-K-of-N/.
    #[arg(long, value_name = "K/N")]
    shard: Option<ShardSpec>,
    /// No progress bar and no summary line: only errors on stderr.
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Merge the N shard folders of one run (`--shard K/N`) into one run's folder.
    ///
    /// The folders may come in any order. The merged folder holds trials.csv,
    /// summary.csv, scenario.toml, metadata.json and the plots, equal to an unsharded
    /// run's apart from timings. Refused (exit 2, nothing written): shards of different
    /// scenarios, seeds, --trials or code (or another binary than the merge's), a shard
    /// missing or given twice, different N.
    Merge(MergeArgs),
}

#[derive(clap::Args, Debug)]
struct MergeArgs {
    /// The shard folders D_1 … D_N, in any order.
    #[arg(value_name = "DIR", required = true)]
    dirs: Vec<PathBuf>,
    /// The merged run's folder (replaced as a whole, like a run's).
    #[arg(short = 'o', long, alias = "output", value_name = "M")]
    out: PathBuf,
    /// No summary line: only errors on stderr.
    #[arg(short, long)]
    quiet: bool,
}

/// Set up the worker threads and the interrupt handler; `Err` is the exit code.
fn start_workers(threads: Option<NonZeroUsize>) -> Result<(), ExitCode> {
    if let Some(n) = threads.filter(|n| n.get() > MAX_THREADS) {
        epd_io::stderr_line!("error: --threads {n}: at most {MAX_THREADS}");
        return Err(ExitCode::from(2));
    }
    if let Some(n) = threads
        && let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n.get())
            .build_global()
    {
        epd_io::stderr_line!("error: cannot start {n} worker threads: {e}");
        return Err(ExitCode::FAILURE);
    }
    // SIGINT and SIGTERM stop the run at the next batch of trials; the staging folder
    // is removed on the way out.
    if let Err(e) = ctrlc::set_handler(|| INTERRUPTED.store(true, Ordering::SeqCst)) {
        epd_io::stderr_line!("warning: no interrupt handler: {e}");
    }
    Ok(())
}

/// Print why a run failed and give its exit code: 2 for a refused output folder,
/// scenario or set of shards (nothing written), 130 when interrupted, 1 otherwise.
fn failed(e: &anyhow::Error, name: &str) -> ExitCode {
    if e.downcast_ref::<OutputRefused>().is_some()
        || e.downcast_ref::<ScenarioError>().is_some()
        || e.downcast_ref::<Refused>().is_some()
        || e.downcast_ref::<MergeError>().is_some()
    {
        epd_io::stderr_line!("error: {e}");
        ExitCode::from(2)
    } else if e.downcast_ref::<Interrupted>().is_some() {
        epd_io::stderr_line!("{name}: {e}");
        ExitCode::from(130)
    } else {
        epd_io::stderr_line!("error: {e:#}");
        ExitCode::FAILURE
    }
}

/// Run the scenario `text` (read from `path`) as experiment `E`: parse and check it,
/// check what the command line asks of it, start the workers, run it into `--out` (or its
/// default folder) and say what ran; the exit code.
fn run_scenario<E: Experiment>(cli: &Cli, path: &Path, text: &str) -> ExitCode {
    let experiment = match E::parse(path, text) {
        Ok(e) => e,
        Err(e) => {
            epd_io::stderr_line!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let request = Request {
        trials: cli.trials.map(NonZeroUsize::get),
        shard: cli.shard,
        progress: !cli.quiet,
    };
    if let Err(e) = experiment.check(&request) {
        epd_io::stderr_line!("error: {e}");
        return ExitCode::from(2);
    }
    if let Err(code) = start_workers(cli.threads) {
        return code;
    }
    let out = cli
        .out
        .clone()
        .unwrap_or_else(|| experiment.default_output(&request));
    match experiment.run(&out, &request) {
        Ok(done) => {
            if !cli.quiet {
                epd_io::stderr_line!(
                    "{} in {:.1} s → {}",
                    done.what,
                    done.wall_time_s,
                    out.display()
                );
            }
            errors_exit(done.errors)
        }
        Err(e) => failed(&e, experiment.name()),
    }
}

/// `bench-harness merge D_1 … D_N --out M`.
fn merge_main(a: &MergeArgs) -> ExitCode {
    if let Err(code) = start_workers(None) {
        return code;
    }
    match merge(&a.dirs, &MergeOptions { out: a.out.clone() }) {
        Ok(report) => {
            if !a.quiet {
                epd_io::stderr_line!(
                    "merged {} shards in {:.2} s → {}",
                    a.dirs.len(),
                    report.wall_time_s,
                    a.out.display()
                );
            }
            errors_exit(trial_errors_note(report.trial_errors))
        }
        Err(e) => failed(&e, "merge"),
    }
}

/// The exit code of a finished run or merge: 1, saying why, when trials or estimates
/// could not be made (`errors`).
fn errors_exit(errors: Option<String>) -> ExitCode {
    match errors {
        Some(note) => {
            epd_io::stderr_line!("{note}");
            ExitCode::FAILURE
        }
        None => ExitCode::SUCCESS,
    }
}

/// The scenario's name in messages (`<stdin>` for `-`) and its text; `Err` the exit code.
fn scenario_text(arg: &Path) -> Result<(PathBuf, String), ExitCode> {
    let path = if arg.as_os_str() == "-" {
        PathBuf::from("<stdin>")
    } else {
        arg.to_path_buf()
    };
    let text = if arg.as_os_str() == "-" {
        read_source(&path, std::io::stdin().lock())
    } else {
        // A regular file only: opening a FIFO would wait for a writer.
        epd_io::read::open_regular(&path)
            .map_err(|e| ScenarioError::Read {
                path: path.clone(),
                source: std::io::Error::other(e),
            })
            .and_then(|(f, _)| read_source(&path, f))
    };
    match text {
        Ok(t) => Ok((path, t)),
        Err(e) => {
            epd_io::stderr_line!("error: {e}");
            Err(ExitCode::from(2))
        }
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
    if let Some(Command::Merge(a)) = &cli.command {
        return merge_main(a);
    }
    let Some(scenario_arg) = cli.scenario.clone() else {
        // clap requires SCENARIO without a subcommand; kept as an error, not a panic.
        epd_io::stderr_line!("error: the scenario file is missing: bench-harness SCENARIO.toml");
        return ExitCode::from(2);
    };
    let (path, text) = match scenario_text(&scenario_arg) {
        Ok(t) => t,
        Err(code) => return code,
    };
    match Kind::of(&text) {
        Kind::Sweep => run_scenario::<Scenario>(&cli, &path, &text),
        Kind::Pipeline => run_scenario::<PipelineScenario>(&cli, &path, &text),
        Kind::Approach => run_scenario::<ApproachScenario>(&cli, &path, &text),
        Kind::CalibrationTransfer => run_scenario::<TransferScenario>(&cli, &path, &text),
    }
}
