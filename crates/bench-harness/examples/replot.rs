//! Redraw the figures of a sweep run from its own files, without running it again:
//!
//! ```sh
//! cargo run -p bench-harness --example replot -- results/sigma_sweep [more folders…]
//! ```
//!
//! Reads `scenario.toml` and `summary.csv` of each folder and rewrites its five PNGs
//! (`diameter_error.png`, `dmean_error.png`, `pose_error.png`, `time.png`,
//! `std_vs_crb.png`) with the current plotting code; nothing else in the folder changes,
//! so committed results keep their numbers and timings when only the figures change. The
//! figures equal a fresh run's for the same summary: `summary.csv` holds every number in
//! shortest round-trip decimal, so it reads back to the same `f64`s.
//!
//! Exit codes: 0 done, 1 a folder could not be read or written, 2 wrong arguments.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, anyhow, bail};
use bench_harness::stats::{Stats, SummaryRow};
use bench_harness::{Scenario, plots};
use clap::Parser;

/// Redraw the PNGs of sweep runs from their `scenario.toml` and `summary.csv`.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// Output folders of sweep runs (`results/<name>`).
    #[arg(required = true)]
    dirs: Vec<PathBuf>,
}

/// The rows of a `summary.csv` (columns by name; an empty cell is a missing value).
fn read_summary(path: &Path) -> anyhow::Result<Vec<SummaryRow>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| anyhow!("{}: empty", path.display()))?
        .split(',')
        .collect();
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        let cells: HashMap<&str, &str> = header.iter().copied().zip(line.split(',')).collect();
        let at = || format!("{} line {}", path.display(), i + 2);
        let text = |k: &str| -> anyhow::Result<String> {
            cells
                .get(k)
                .map(|v| (*v).to_string())
                .ok_or_else(|| anyhow!("{}: no column `{k}`", at()))
        };
        let opt = |k: &str| -> anyhow::Result<Option<f64>> {
            match cells.get(k).copied() {
                None | Some("") => Ok(None),
                Some(v) => v
                    .parse()
                    .map(Some)
                    .with_context(|| format!("{}: `{k}` = {v:?} is not a number", at())),
            }
        };
        let num = |k: &str| -> anyhow::Result<f64> { Ok(opt(k)?.unwrap_or(f64::NAN)) };
        let count = |k: &str| -> anyhow::Result<usize> {
            let v = text(k)?;
            v.parse()
                .with_context(|| format!("{}: `{k}` = {v:?} is not a count", at()))
        };
        rows.push(SummaryRow {
            sweep_value: text("sweep_value")?,
            method: text("method")?,
            quantity: text("quantity")?,
            unit: text("unit")?,
            stats: Stats {
                n: count("n")?,
                mean: num("mean")?,
                std: num("std")?,
                rmse: num("rmse")?,
                median: num("median")?,
                min: num("min")?,
                max: num("max")?,
                range: num("range")?,
            },
            n_failed: count("n_failed")?,
            crb_std: opt("crb_std")?,
            coverage95: opt("coverage95")?,
        });
    }
    Ok(rows)
}

fn replot(dir: &Path) -> anyhow::Result<()> {
    let scenario = Scenario::load(&dir.join("scenario.toml"))?;
    let summary = read_summary(&dir.join("summary.csv"))?;
    if summary.is_empty() {
        bail!("{}: summary.csv has no rows", dir.display());
    }
    for png in plots::plot_all(&scenario, &summary)? {
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
