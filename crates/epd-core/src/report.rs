//! An estimate as named fields in the units of reports (mm, degrees): one list of keys
//! ([`ESTIMATE_KEYS`]) shared by every front end (the `estimate` example, the `epd`
//! tool's JSON, CSV and text, the Python package). Data only: the encodings (JSON, CSV)
//! live in the `epd-io` crate.

use crate::estimate::Estimate;

/// A value of a report field.
#[derive(Clone, Debug, PartialEq)]
pub enum Field {
    /// A number (mm, degrees, ms or a count, as the key says).
    Num(f64),
    /// A whole number.
    Int(u64),
    /// A whole number that may be negative (a ROS header stamp in ns).
    Int64(i64),
    /// Text.
    Text(String),
    /// A flag.
    Bool(bool),
    /// No value (e.g. the 1-σ of an undetermined roll).
    Null,
}

const MM: f64 = 1e3;
const DEG: f64 = 180.0 / std::f64::consts::PI;

/// The keys of [`estimate_fields`], in order: the solver's account, then β (eq. 2) in mm
/// and degrees, then the 1-σ of each parameter, then what an inspection engineer reads:
/// the mean diameter and the ovality (in % of the mean diameter) with their 1-σ.
pub const ESTIMATE_KEYS: [&str; 25] = [
    "method",
    "status",
    "status_reason",
    "iterations",
    "n_points",
    "n_dropped",
    "d_max_mm",
    "d_min_mm",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
    "dy_mm",
    "dz_mm",
    "roll_determined",
    "sigma_d_max_mm",
    "sigma_d_min_mm",
    "sigma_roll_deg",
    "sigma_pitch_deg",
    "sigma_yaw_deg",
    "sigma_dy_mm",
    "sigma_dz_mm",
    "d_mean_mm",
    "sigma_d_mean_mm",
    "ovality_pct",
    "sigma_ovality_pct",
];

/// The index in [`ESTIMATE_KEYS`] of the first result (`d_max_mm`): from there on the
/// values (diameters, pose, `roll_determined`, the 1-σ) mean something only when the
/// estimate converged.
pub const FIRST_RESULT_KEY: usize = 6;

/// The fields of an estimate, keyed by [`ESTIMATE_KEYS`] in that order.
pub fn estimate_fields(est: &Estimate) -> Vec<(&'static str, Field)> {
    let p = est.params;
    let num = |v: f64| {
        if v.is_finite() {
            Field::Num(v)
        } else {
            Field::Null
        }
    };
    let sig = |i: usize, s: f64| est.sigma[i].map_or(Field::Null, |v| num(v * s));
    let values = [
        Field::Text(est.method.name().into()),
        Field::Text(est.status.name().into()),
        Field::Text(est.status.reason()),
        Field::Int(est.iterations as u64),
        Field::Int(est.n_points as u64),
        Field::Int(est.n_dropped as u64),
        num(p.d_max * MM),
        num(p.d_min * MM),
        num(p.roll * DEG),
        num(p.pitch * DEG),
        num(p.yaw * DEG),
        num(p.dy * MM),
        num(p.dz * MM),
        Field::Bool(est.roll_determined),
        sig(0, MM),
        sig(1, MM),
        sig(2, DEG),
        sig(3, DEG),
        sig(4, DEG),
        sig(5, MM),
        sig(6, MM),
        num(est.d_mean() * MM),
        est.sigma_d_mean().map_or(Field::Null, |v| num(v * MM)),
        num(est.ovality() * 100.0),
        est.sigma_ovality().map_or(Field::Null, |v| num(v * 100.0)),
    ];
    ESTIMATE_KEYS.into_iter().zip(values).collect()
}
