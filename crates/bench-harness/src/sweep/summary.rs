//! The statistics of a sweep: one [`SummaryRow`] per setting, method and quantity, as
//! `summary.csv` holds them, and the file read back ([`read_summary`]).

use std::path::Path;

use anyhow::Context;

use super::record::TrialRecord;
use super::rows::QUANTITIES;
use crate::stats::Stats;

/// One row of `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct SummaryRow {
    /// The swept value as written in the scenario.
    pub sweep_value: String,
    /// Method name.
    pub method: String,
    /// Quantity name (dmax, …, time_ms).
    pub quantity: String,
    /// Its unit.
    pub unit: String,
    /// Statistics over the converged trials.
    pub stats: Stats,
    /// Trials that did not converge (or failed).
    pub n_failed: usize,
    /// √(mean over trials of the CRB variance): the physical limit of `stats.std`.
    pub crb_std: Option<f64>,
    /// Fraction of the converged trials whose |error| ≤ 1.96·(reported 1-σ): the
    /// coverage of the nominal 95 % interval (parameters only; trials without a
    /// reported 1-σ, e.g. an undetermined roll, count as not covered).
    pub coverage95: Option<f64>,
}

/// The rows of a `summary.csv` as written by a run (columns by name; an empty cell is a
/// missing value). Every number there is in shortest round-trip decimal, so the rows read
/// back equal the run's, bit for bit: the figures drawn from them are the run's.
pub fn read_summary(path: &Path) -> anyhow::Result<Vec<SummaryRow>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| anyhow::anyhow!("{}: empty", path.display()))?
        .split(',')
        .collect();
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        let cells: std::collections::HashMap<&str, &str> =
            header.iter().copied().zip(line.split(',')).collect();
        let at = || format!("{} line {}", path.display(), i + 2);
        let text = |k: &str| -> anyhow::Result<String> {
            cells
                .get(k)
                .map(|v| (*v).to_string())
                .ok_or_else(|| anyhow::anyhow!("{}: no column `{k}`", at()))
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

/// Summarise the trials of one setting (every one of them, in trial order).
pub(crate) fn summarise(
    value: &str,
    methods: &[epd_core::Method],
    trials: &[TrialRecord],
) -> Vec<SummaryRow> {
    let mut rows = Vec::new();
    for (mi, m) in methods.iter().enumerate() {
        let results: Vec<_> = trials.iter().map(|t| (&t.methods[mi], t)).collect();
        let ok: Vec<_> = results.iter().filter(|(r, _)| r.ok()).collect();
        let n_failed = results.len() - ok.len();
        for q in &QUANTITIES {
            let v: Vec<f64> = ok
                .iter()
                .filter_map(|(r, _)| r.errors.as_ref().map(q.error))
                .collect();
            let crb_std = q.param.and_then(|i| {
                let vars: Vec<f64> = trials
                    .iter()
                    .filter_map(|t| t.crb[i])
                    .map(|s| (s * q.scale).powi(2))
                    .collect();
                (!vars.is_empty()).then(|| (vars.iter().sum::<f64>() / vars.len() as f64).sqrt())
            });
            let coverage95 = q.param.filter(|_| !ok.is_empty()).map(|i| {
                let covered = ok
                    .iter()
                    .filter(|(r, _)| {
                        let (Some(e), Some(s)) = (r.errors.as_ref(), r.sigma[i]) else {
                            return false;
                        };
                        ((q.error)(e)).abs() <= 1.96 * s * q.scale
                    })
                    .count();
                covered as f64 / ok.len() as f64
            });
            rows.push(SummaryRow {
                sweep_value: value.into(),
                method: m.name().into(),
                quantity: q.name.into(),
                unit: q.unit.into(),
                stats: Stats::of(&v),
                n_failed,
                crb_std,
                coverage95,
            });
        }
        let times: Vec<f64> = results
            .iter()
            .filter(|(r, _)| r.estimate.is_some())
            .map(|(r, _)| r.time_ms)
            .collect();
        rows.push(SummaryRow {
            sweep_value: value.into(),
            method: m.name().into(),
            quantity: "time_ms".into(),
            unit: "ms".into(),
            stats: Stats::of(&times),
            n_failed,
            crb_std: None,
            coverage95: None,
        });
    }
    rows
}
