//! The summary of an approach run: one [`ApproachRow`] per distance, with and without the
//! survey.

use std::path::{Path, PathBuf};

use super::frames::FrameRow;
use epd_io::csv::num;

use super::scenario::{ApproachScenario, Feature};
use crate::output::CsvFile;

/// The columns of `approach.csv`.
pub const APPROACH_COLUMNS: [&str; 10] = [
    "distance_m",
    "segmented",
    "n_frames",
    "n_found",
    "dmean_bias_mm",
    "dmean_range_mm",
    "straight_until_err_max_mm",
    "bend_radius_err_max_pct",
    "straight_until_cover95",
    "bend_radius_cover95",
];

/// One row of `approach.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct ApproachRow {
    /// Distance (m).
    pub distance_m: f64,
    /// With the survey.
    pub segmented: bool,
    /// Frames.
    pub n_frames: usize,
    /// Frames whose survey found the feature (`bend_ahead` or `tee_ahead` as the
    /// scenario's kind).
    pub n_found: usize,
    /// Mean of the mean-diameter errors with a result (mm).
    pub dmean_bias_mm: f64,
    /// Their max − min (mm).
    pub dmean_range_mm: f64,
    /// Largest |error| of `straight_until_m` (mm).
    pub straight_until_err_max_mm: f64,
    /// Largest |error| of the bend radius (%).
    pub bend_radius_err_max_pct: f64,
    /// Share of the frames with a `straight_until_m` and its 1-σ whose ±1.96σ holds the
    /// truth (`cover95`).
    pub straight_until_cover95: f64,
    /// The same for the bend radius.
    pub bend_radius_cover95: f64,
}

/// The share of the (error, 1-σ) pairs with both finite whose |error| ≤ 1.96·σ; NaN
/// without any.
pub fn cover95(pairs: impl Iterator<Item = (f64, f64)>) -> f64 {
    let (mut n, mut held) = (0usize, 0usize);
    for (e, sd) in pairs.filter(|(e, sd)| e.is_finite() && sd.is_finite()) {
        n += 1;
        held += usize::from(e.abs() <= 1.959_963_984_540_054 * sd);
    }
    if n == 0 {
        f64::NAN
    } else {
        held as f64 / n as f64
    }
}

pub(super) fn summarise(s: &ApproachScenario, rows: &[FrameRow]) -> Vec<ApproachRow> {
    let found = match s.feature {
        Feature::Elbow { .. } => "bend_ahead",
        Feature::Tee { .. } => "tee_ahead",
    };
    let mut out = Vec::new();
    for &d in &s.distances_m {
        for segmented in [false, true] {
            let r: Vec<&FrameRow> = rows
                .iter()
                .filter(|r| r.distance_m == d && r.segmented == segmented)
                .collect();
            let e: Vec<f64> = r
                .iter()
                .map(|r| r.dmean_err_mm)
                .filter(|v| v.is_finite())
                .collect();
            let max_abs = |f: fn(&FrameRow) -> f64| {
                r.iter()
                    .map(|x| f(x).abs())
                    .filter(|v| v.is_finite())
                    .fold(f64::NAN, f64::max)
            };
            let (lo, hi) = e
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            out.push(ApproachRow {
                distance_m: d,
                segmented,
                n_frames: r.len(),
                n_found: r.iter().filter(|r| r.geometry == found).count(),
                dmean_bias_mm: if e.is_empty() {
                    f64::NAN
                } else {
                    e.iter().sum::<f64>() / e.len() as f64
                },
                dmean_range_mm: if e.is_empty() { f64::NAN } else { hi - lo },
                straight_until_err_max_mm: max_abs(|r| r.straight_until_err_mm),
                bend_radius_err_max_pct: max_abs(|r| r.bend_radius_err_pct),
                straight_until_cover95: cover95(
                    r.iter()
                        .map(|r| (r.straight_until_err_mm, r.sigma_straight_until_mm)),
                ),
                bend_radius_cover95: cover95(r.iter().map(|r| {
                    (
                        r.bend_radius_err_pct / 100.0 * r.bend_radius_mm
                            / (1.0 + r.bend_radius_err_pct / 100.0),
                        r.sigma_bend_radius_mm,
                    )
                })),
            });
        }
    }
    out
}

/// `approach.csv`: one row per distance and fit ([`APPROACH_COLUMNS`]).
pub(super) fn write_approach_csv(dir: &Path, summary: &[ApproachRow]) -> anyhow::Result<PathBuf> {
    CsvFile::write_all(
        &dir.join("approach.csv"),
        &APPROACH_COLUMNS,
        summary.iter().map(approach_row),
    )
}

/// The row of `approach.csv` of `r` ([`APPROACH_COLUMNS`]).
fn approach_row(r: &ApproachRow) -> [String; APPROACH_COLUMNS.len()] {
    [
        num(r.distance_m),
        r.segmented.to_string(),
        r.n_frames.to_string(),
        r.n_found.to_string(),
        num(r.dmean_bias_mm),
        num(r.dmean_range_mm),
        num(r.straight_until_err_max_mm),
        num(r.bend_radius_err_max_pct),
        num(r.straight_until_cover95),
        num(r.bend_radius_cover95),
    ]
}

/// The columns of `confusion.csv`.
pub const CONFUSION_COLUMNS: [&str; 4] = ["true_scene", "distance_m", "geometry", "count"];

/// One row of `confusion.csv`: of a distance's frames, how many the survey read as
/// `geometry`.
#[derive(Clone, Debug, PartialEq)]
pub struct ConfusionRow {
    /// What lies ahead: the scenario's kind (`elbow` or `tee`).
    pub true_scene: &'static str,
    /// Distance to the straight section's end (m).
    pub distance_m: f64,
    /// The geometry reported.
    pub geometry: &'static str,
    /// Frames read so.
    pub count: usize,
}

/// The survey's readings by distance: for each distance every geometry the survey can
/// report (`straight`, `bend_ahead`, `tee_ahead`, `in_bend`, then any other it reported),
/// with the number of frames read as it (zeros included, so each distance's counts sum
/// to its frames). Only the survey's rows (`segmented`) count.
pub fn confusion(s: &ApproachScenario, rows: &[FrameRow]) -> Vec<ConfusionRow> {
    use epd_core::segment::Layout;
    let true_scene = match s.feature {
        Feature::Elbow { .. } => "elbow",
        Feature::Tee { .. } => "tee",
    };
    let mut names: Vec<&'static str> = [
        Layout::Straight,
        Layout::BendAhead,
        Layout::TeeAhead,
        Layout::InBend,
    ]
    .map(Layout::name)
    .to_vec();
    for r in rows.iter().filter(|r| r.segmented) {
        if !names.contains(&r.geometry) {
            names.push(r.geometry);
        }
    }
    let mut out = Vec::new();
    for &d in &s.distances_m {
        for &g in &names {
            let count = rows
                .iter()
                .filter(|r| r.segmented && r.distance_m == d && r.geometry == g)
                .count();
            out.push(ConfusionRow {
                true_scene,
                distance_m: d,
                geometry: g,
                count,
            });
        }
    }
    out
}

/// `confusion.csv`: one row per distance and geometry ([`CONFUSION_COLUMNS`]).
pub(super) fn write_confusion_csv(dir: &Path, rows: &[ConfusionRow]) -> anyhow::Result<PathBuf> {
    CsvFile::write_all(
        &dir.join("confusion.csv"),
        &CONFUSION_COLUMNS,
        rows.iter().map(|r| {
            [
                r.true_scene.to_string(),
                num(r.distance_m),
                r.geometry.to_string(),
                r.count.to_string(),
            ]
        }),
    )
}
