//! Redraw the figures of a sweep run from its own files, without running it again:
//!
//! ```sh
//! cargo run -p bench-harness --example replot -- results/sigma_sweep [more folders…]
//! ```
//!
//! Reads `scenario.toml` and `summary.csv` of each folder and rewrites its six PNGs
//! (`diameter_error.png`, `dmean_error.png`, `pose_error.png`, `time.png`,
//! `std_vs_crb.png`, `coverage.png`) with the current plotting code; nothing else in the folder changes,
//! so committed results keep their numbers and timings when only the figures change. The
//! figures equal a fresh run's for the same summary: `summary.csv` holds every number in
//! shortest round-trip decimal, so it reads back to the same `f64`s.
//!
//! Exit codes: 0 done, 1 a folder could not be read or written, 2 wrong arguments.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use bench_harness::Scenario;
use bench_harness::sweep::figures::plot_all;
use bench_harness::sweep::summary::read_summary;

use clap::Parser;

/// Redraw the PNGs of sweep runs from their `scenario.toml` and `summary.csv`.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// Output folders of sweep runs (`results/<name>`).
    #[arg(required = true)]
    dirs: Vec<PathBuf>,
}

fn replot(dir: &Path) -> anyhow::Result<()> {
    let scenario = Scenario::load(&dir.join("scenario.toml"))?;
    let summary = read_summary(&dir.join("summary.csv"))?;
    if summary.is_empty() {
        bail!("{}: summary.csv has no rows", dir.display());
    }
    for png in plot_all(&scenario, &summary)? {
        let path = dir.join(&png.name);
        std::fs::write(&path, &png.bytes)
            .with_context(|| format!("cannot write {}", path.display()))?;
        println!("{}", path.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = match Args::try_parse() {
        Ok(a) => a,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    for dir in &args.dirs {
        if let Err(e) = replot(dir) {
            eprintln!("error: {e:#}");
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}
