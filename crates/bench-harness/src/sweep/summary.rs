//! The statistics of a sweep: one [`SummaryRow`] per setting, method and quantity, as
//! `summary.csv` holds them, and the file read back ([`read_summary`]).

use std::path::Path;

use anyhow::Context;

use epd_core::errors_at_roll;

use super::record::TrialRecord;
use super::rows::QUANTITIES;
use crate::stats::{FalseAlarms, Stats};

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
    /// reported 1-σ, e.g. an undetermined roll, count as not covered). Where the roll is
    /// undetermined, the pose's errors are taken at the reported roll
    /// ([`epd_core::symmetry::errors_at_roll`]), where its 1-σ are.
    pub coverage95: Option<f64>,
    /// With `geometry = true`: the frames whose geometry was reported and how many were
    /// read as anything but `straight` (the same on every row of a setting and method);
    /// `None` when the scenario does not survey the geometry.
    pub false_alarms: Option<FalseAlarms>,
}

/// The rows of a `summary.csv` as written by a run (columns by name; an empty cell is a
/// missing value). Every number there is in shortest round-trip decimal, so the rows read
/// back equal the run's, bit for bit: the figures drawn from them are the run's.
pub fn read_summary(path: &Path) -> anyhow::Result<Vec<SummaryRow>> {
    // A regular file only: opening a FIFO would wait for a writer.
    let text = epd_io::read::open_regular(path)
        .map_err(anyhow::Error::msg)
        .and_then(|(mut f, _)| {
            let mut text = String::new();
            std::io::Read::read_to_string(&mut f, &mut text)?;
            Ok(text)
        })
        .with_context(|| format!("cannot read {}", path.display()))?;
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
            false_alarms: match (opt("geometry_frames")?, opt("false_alarms")?) {
                (Some(n), Some(k)) => Some(FalseAlarms::of(k as usize, n as usize)),
                _ => None,
            },
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
        let false_alarms = false_alarms(results.iter().map(|(r, _)| *r));
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
                    .filter(|(r, t)| {
                        let (Some(e), Some(s)) = (r.errors.as_ref(), r.sigma[i]) else {
                            return false;
                        };
                        // An undetermined roll (no 1-σ): the pose's 1-σ are those at the
                        // reported roll, and so are its errors.
                        let at_roll = r.sigma[2]
                            .is_none()
                            .then(|| r.estimate.map(|est| errors_at_roll(&est, &t.truth)))
                            .flatten();
                        ((q.error)(at_roll.as_ref().unwrap_or(e))).abs() <= 1.96 * s * q.scale
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
                false_alarms,
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
            false_alarms,
        });
    }
    rows
}

/// The false alarms of one method over a setting's `records`: of the frames whose
/// geometry was reported, those read as anything but `straight`; `None` when no record
/// carries a geometry (the scenario does not survey it).
pub fn false_alarms<'a>(
    records: impl IntoIterator<Item = &'a super::record::MethodRecord>,
) -> Option<FalseAlarms> {
    let alarms: Vec<bool> = records
        .into_iter()
        .filter_map(super::record::MethodRecord::false_alarm)
        .collect();
    (!alarms.is_empty())
        .then(|| FalseAlarms::of(alarms.iter().filter(|&&a| a).count(), alarms.len()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sweep::record::MethodRecord;
    use crate::sweep::rows::{SUMMARY_COLUMNS, summary_row};
    use epd_core::{FitOutcome, Method, N_PARAMS, ParamErrors, Params};

    fn record(geometry: Option<&str>, withheld: bool) -> TrialRecord {
        let errors = ParamErrors {
            d_max: 1e-4,
            d_min: -1e-4,
            d_mean: 0.0,
            roll: 0.0,
            pitch: 0.0,
            yaw: 0.0,
            dy: 0.0,
            dz: 0.0,
        };
        let params = Params::from_array([0.5, 0.49, 0.0, 0.0, 0.0, 0.0, 0.0]);
        TrialRecord {
            setting: 0,
            trial: 0,
            n_points: 1000,
            truth: params,
            crb: [None; N_PARAMS],
            error: None,
            methods: vec![MethodRecord {
                method: Method::MlEpd,
                status: geometry.map(|_| FitOutcome::Converged),
                message: String::new(),
                iterations: 3,
                time_ms: 1.0,
                estimate: geometry.map(|_| params),
                sigma: [Some(1e-3); N_PARAMS],
                errors: geometry.map(|_| errors),
                geometry: geometry.map(String::from),
                straight_withheld: withheld,
            }],
        }
    }

    #[test]
    fn false_alarms_are_counted_from_the_records() {
        // 7 straight, 2 tees ahead, 1 in a bend (withheld), 1 without an estimate.
        let mut trials: Vec<TrialRecord> =
            (0..7).map(|_| record(Some("straight"), false)).collect();
        trials.push(record(Some("tee_ahead"), false));
        trials.push(record(Some("tee_ahead"), false));
        trials.push(record(Some("in_bend"), true));
        trials.push(record(None, false));
        let rows = summarise("v", &[Method::MlEpd], &trials);
        assert_eq!(rows.len(), QUANTITIES.len() + 1);
        let want = FalseAlarms::of(3, 10);
        for r in &rows {
            assert_eq!(r.false_alarms, Some(want), "{}", r.quantity);
            // The withheld frame and the one without an estimate do not count.
            assert_eq!(
                (r.stats.n, r.n_failed),
                (if r.quantity == "time_ms" { 10 } else { 9 }, 2)
            );
        }
        assert!((want.rate - 0.3).abs() < 1e-15);
        assert!((want.se - (0.3f64 * 0.7 / 10.0).sqrt()).abs() < 1e-15);
        assert!(want.upper95 > 0.3 && want.upper95 < 1.0);
        let cells = summary_row("pipe+noise", &rows[0]);
        let cell = |name: &str| {
            let i = SUMMARY_COLUMNS.iter().position(|c| *c == name).unwrap();
            cells[i].clone()
        };
        assert_eq!(cell("geometry_frames"), "10");
        assert_eq!(cell("false_alarms"), "3");
        assert_eq!(cell("false_alarm_rate").parse::<f64>().unwrap(), want.rate);
        assert_eq!(cell("false_alarm_se").parse::<f64>().unwrap(), want.se);
        assert_eq!(
            cell("false_alarm_upper95").parse::<f64>().unwrap(),
            want.upper95
        );
        // Without a surveyed geometry: no count, empty cells.
        let plain: Vec<TrialRecord> = (0..3)
            .map(|_| {
                let mut t = record(Some("straight"), false);
                t.methods[0].geometry = None;
                t
            })
            .collect();
        let rows = summarise("v", &[Method::MlEpd], &plain);
        assert!(rows.iter().all(|r| r.false_alarms.is_none()));
        let cells = summary_row("x", &rows[0]);
        assert!(
            cells[SUMMARY_COLUMNS.len() - 5..]
                .iter()
                .all(String::is_empty)
        );
    }
}
