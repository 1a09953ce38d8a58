//! `bench-harness SCENARIO.toml [--out DIR] [--trials N]`: run a scenario.
//!
//! Exit codes: 0 done, 1 the run failed, 2 the scenario or the arguments are wrong
//! (nothing is written then).

use std::path::PathBuf;
use std::process::ExitCode;

use bench_harness::{RunOptions, Scenario, run};

const USAGE: &str = "usage: bench-harness SCENARIO.toml [--out DIR] [--trials N]";

struct Args {
    scenario: PathBuf,
    out: Option<PathBuf>,
    trials: Option<usize>,
}

fn parse_args() -> Result<Args, String> {
    let mut scenario = None;
    let mut out = None;
    let mut trials = None;
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        match a.as_str() {
            "--out" => out = Some(PathBuf::from(it.next().ok_or("--out needs a folder")?)),
            "--trials" => {
                let v = it.next().ok_or("--trials needs a number")?;
                let n: usize = v
                    .parse()
                    .map_err(|_| format!("--trials {v}: not a whole number"))?;
                if n == 0 {
                    return Err("--trials must be at least 1".into());
                }
                trials = Some(n);
            }
            "-h" | "--help" => return Err(String::new()),
            s if s.starts_with('-') => return Err(format!("unknown option `{s}`")),
            s => {
                if scenario.replace(PathBuf::from(s)).is_some() {
                    return Err("give exactly one scenario file".into());
                }
            }
        }
    }
    Ok(Args {
        scenario: scenario.ok_or("no scenario file given")?,
        out,
        trials,
    })
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) if e.is_empty() => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("error: {e}\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    let scenario = match Scenario::load(&args.scenario) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let out = args
        .out
        .unwrap_or_else(|| PathBuf::from("results").join(&scenario.name));
    let options = RunOptions {
        out: out.clone(),
        trials: args.trials,
        progress: true,
    };
    match run(&scenario, &options) {
        Ok(report) => {
            eprintln!(
                "{}: {} settings × {} trials in {:.1} s → {}",
                scenario.name,
                scenario.sweeps.len(),
                args.trials.unwrap_or(scenario.trials),
                report.wall_time_s,
                out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
