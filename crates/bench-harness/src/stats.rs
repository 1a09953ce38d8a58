//! Statistics over the trials of one setting (README, Conventions): bias, spread, error range.

use std::path::Path;

use anyhow::Context;

/// Summary statistics of a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stats {
    /// Number of values.
    pub n: usize,
    /// Mean (the bias, for errors).
    pub mean: f64,
    /// Sample standard deviation (n − 1); 0 for one value.
    pub std: f64,
    /// √(mean of squares).
    pub rmse: f64,
    /// Median.
    pub median: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// max − min (the paper's error range).
    pub range: f64,
}

impl Stats {
    /// Statistics of `v`; all NaN when `v` is empty.
    pub fn of(v: &[f64]) -> Self {
        let n = v.len();
        if n == 0 {
            let nan = f64::NAN;
            return Self {
                n,
                mean: nan,
                std: nan,
                rmse: nan,
                median: nan,
                min: nan,
                max: nan,
                range: nan,
            };
        }
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = if n > 1 {
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64
        } else {
            0.0
        };
        let rmse = (v.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            s[n / 2]
        } else {
            0.5 * (s[n / 2 - 1] + s[n / 2])
        };
        Self {
            n,
            mean,
            std: var.sqrt(),
            rmse,
            median,
            min: s[0],
            max: s[n - 1],
            range: s[n - 1] - s[0],
        }
    }

    /// The standard error of the mean, std/√n.
    pub fn sem(&self) -> f64 {
        self.std / (self.n as f64).sqrt()
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_sample() {
        let s = Stats::of(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(s.n, 4);
        assert_eq!(s.mean, 2.5);
        assert!((s.std - (5.0f64 / 3.0).sqrt()).abs() < 1e-15);
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert_eq!((s.median, s.min, s.max, s.range), (2.5, 1.0, 4.0, 3.0));
        assert_eq!(Stats::of(&[5.0, 1.0, 3.0]).median, 3.0);
        assert!(Stats::of(&[]).mean.is_nan());
        assert_eq!(Stats::of(&[2.0]).std, 0.0);
    }
}
