//! The rows of a sweep's CSV files: `trials.csv` (one per trial and method) and
//! `summary.csv` (one per setting, method and quantity), their columns and the quantities
//! summarised.

use epd_core::ParamErrors;
use epd_io::csv::num;

use super::record::{MethodRecord, TrialRecord};
use super::summary::SummaryRow;
use crate::output::CsvFile;

/// A summarised quantity: its name in `summary.csv`, unit, the error it reads (in that
/// unit) and the index of its parameter in β for the Cramér–Rao bound.
pub struct Quantity {
    /// Name in the `quantity` column.
    pub name: &'static str,
    /// Unit in the `unit` column.
    pub unit: &'static str,
    /// The error in that unit.
    pub error: fn(&ParamErrors) -> f64,
    /// β index of the parameter (for the CRB), if it is one.
    pub param: Option<usize>,
    /// m or rad → the unit.
    pub scale: f64,
}

const MM: f64 = 1e3;
const DEG: f64 = 180.0 / std::f64::consts::PI;

/// The error quantities of `summary.csv` (time_ms is summarised apart).
pub const QUANTITIES: [Quantity; 8] = [
    Quantity {
        name: "dmax",
        unit: "mm",
        error: |e| e.d_max * MM,
        param: Some(0),
        scale: MM,
    },
    Quantity {
        name: "dmin",
        unit: "mm",
        error: |e| e.d_min * MM,
        param: Some(1),
        scale: MM,
    },
    Quantity {
        name: "dmean",
        unit: "mm",
        error: |e| e.d_mean * MM,
        param: None,
        scale: MM,
    },
    Quantity {
        name: "roll",
        unit: "deg",
        error: |e| e.roll * DEG,
        param: Some(2),
        scale: DEG,
    },
    Quantity {
        name: "pitch",
        unit: "deg",
        error: |e| e.pitch * DEG,
        param: Some(3),
        scale: DEG,
    },
    Quantity {
        name: "yaw",
        unit: "deg",
        error: |e| e.yaw * DEG,
        param: Some(4),
        scale: DEG,
    },
    Quantity {
        name: "dy",
        unit: "mm",
        error: |e| e.dy * MM,
        param: Some(5),
        scale: MM,
    },
    Quantity {
        name: "dz",
        unit: "mm",
        error: |e| e.dz * MM,
        param: Some(6),
        scale: MM,
    },
];

/// `trials.csv` columns: the error columns README lists first, then the truth and
/// estimate in full, the reported 1-σ, the Cramér–Rao 1-σ, the geometry the frame library
/// reported (empty unless the scenario sets `geometry = true`) and the solver's message.
pub const TRIAL_COLUMNS: &[&str] = &[
    "sweep_variable",
    "sweep_value",
    "trial",
    "method",
    "n_points",
    "status",
    "iterations",
    "time_ms",
    "dmax_true_mm",
    "dmin_true_mm",
    "dmax_est_mm",
    "dmin_est_mm",
    "err_dmax_mm",
    "err_dmin_mm",
    "err_dmean_mm",
    "err_roll_deg",
    "err_pitch_deg",
    "err_yaw_deg",
    "err_dy_mm",
    "err_dz_mm",
    "roll_true_deg",
    "pitch_true_deg",
    "yaw_true_deg",
    "dy_true_mm",
    "dz_true_mm",
    "roll_est_deg",
    "pitch_est_deg",
    "yaw_est_deg",
    "dy_est_mm",
    "dz_est_mm",
    "sigma_dmax_mm",
    "sigma_dmin_mm",
    "sigma_roll_deg",
    "sigma_pitch_deg",
    "sigma_yaw_deg",
    "sigma_dy_mm",
    "sigma_dz_mm",
    "crb_dmax_mm",
    "crb_dmin_mm",
    "crb_roll_deg",
    "crb_pitch_deg",
    "crb_yaw_deg",
    "crb_dy_mm",
    "crb_dz_mm",
    "geometry",
    "message",
];

/// `summary.csv` columns.
pub const SUMMARY_COLUMNS: &[&str] = &[
    "sweep_variable",
    "sweep_value",
    "method",
    "quantity",
    "unit",
    "n",
    "n_failed",
    "mean",
    "std",
    "rmse",
    "median",
    "min",
    "max",
    "range",
    "sem",
    "crb_std",
    "coverage95",
    "geometry_frames",
    "false_alarms",
    "false_alarm_rate",
    "false_alarm_se",
    "false_alarm_upper95",
];

/// `v` × `scale` as CSV text, empty when there is no value.
fn opt(v: Option<f64>, scale: f64) -> String {
    v.map_or(String::new(), |x| num(x * scale))
}

/// Write the rows of trial `t` to `trials.csv` ([`TRIAL_COLUMNS`]), one per method, in
/// the scenario's order; `variable` and `value` are the setting's swept key and value.
pub(crate) fn write_trial_rows(
    csv: &mut CsvFile,
    variable: &str,
    value: &str,
    t: &TrialRecord,
) -> anyhow::Result<()> {
    for m in &t.methods {
        csv.row(trial_row(variable, value, t, m))?;
    }
    Ok(())
}

/// The row of `trials.csv` of method `m` in trial `t` ([`TRIAL_COLUMNS`]).
fn trial_row(variable: &str, value: &str, t: &TrialRecord, m: &MethodRecord) -> Vec<String> {
    let tr = &t.truth;
    let e = m.errors.as_ref();
    let est = m.estimate.as_ref();
    let mut f: Vec<String> = vec![
        variable.to_string(),
        value.to_string(),
        t.trial.to_string(),
        m.method.name().into(),
        t.n_points.to_string(),
        m.status_name().to_string(),
        m.iterations.to_string(),
        num(m.time_ms),
        num(tr.d_max * MM),
        num(tr.d_min * MM),
        est.map_or(String::new(), |p| num(p.d_max * MM)),
        est.map_or(String::new(), |p| num(p.d_min * MM)),
    ];
    for q in &QUANTITIES {
        f.push(e.map_or(String::new(), |e| num((q.error)(e))));
    }
    for v in [
        tr.roll * DEG,
        tr.pitch * DEG,
        tr.yaw * DEG,
        tr.dy * MM,
        tr.dz * MM,
    ] {
        f.push(num(v));
    }
    for (i, s) in [(2, DEG), (3, DEG), (4, DEG), (5, MM), (6, MM)] {
        f.push(est.map_or(String::new(), |p| num(p.to_array()[i] * s)));
    }
    let scales = [MM, MM, DEG, DEG, DEG, MM, MM];
    for i in 0..7 {
        f.push(opt(m.sigma[i], scales[i]));
    }
    for i in 0..7 {
        f.push(opt(t.crb[i], scales[i]));
    }
    f.push(m.geometry.clone().unwrap_or_default());
    f.push(m.message.clone());
    f
}

/// The row of `summary.csv` of `r` ([`SUMMARY_COLUMNS`]); `variable` is the swept key.
pub(crate) fn summary_row(variable: &str, r: &SummaryRow) -> [String; 22] {
    let s = &r.stats;
    let fa = r.false_alarms.as_ref();
    let fa_num = |v: fn(&crate::stats::FalseAlarms) -> f64| fa.map_or(String::new(), |f| num(v(f)));
    [
        variable.to_string(),
        r.sweep_value.clone(),
        r.method.clone(),
        r.quantity.clone(),
        r.unit.clone(),
        s.n.to_string(),
        r.n_failed.to_string(),
        num(s.mean),
        num(s.std),
        num(s.rmse),
        num(s.median),
        num(s.min),
        num(s.max),
        num(s.range),
        num(s.sem()),
        r.crb_std.map_or(String::new(), num),
        r.coverage95.map_or(String::new(), num),
        fa.map_or(String::new(), |f| f.frames.to_string()),
        fa.map_or(String::new(), |f| f.count.to_string()),
        fa_num(|f| f.rate),
        fa_num(|f| f.se),
        fa_num(|f| f.upper95),
    ]
}
