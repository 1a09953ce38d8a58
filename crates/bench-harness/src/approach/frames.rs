//! One frame of an approach run scored twice: ML-EPD (Cauchy) on every point, and the
//! survey (`epd_core::segment::survey`) with its straight section, its end and the bend.

use std::path::{Path, PathBuf};

use epd_core::segment::{SegmentOptions, clock_angle_deg, survey};
use epd_core::{EstimateOptions, Loss, Method, Params, estimate};
use epd_frame::config::DEFAULT_LOSS_SCALE_M;
use epd_io::csv::num;
use tof_sim::{FrameSeed, MeshResolution, Noise, PoseRanges, Scene, Sensor, Subsample, simulate};

use super::scenario::{ApproachScenario, Feature};
use crate::output::CsvFile;

/// One frame's scores, with or without segmentation.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRow {
    /// Distance to the straight section's end (m).
    pub distance_m: f64,
    /// Frame index.
    pub frame: usize,
    /// By the survey (`true`) or one fit on every point.
    pub segmented: bool,
    /// The survey's verdict (`straight` for the plain fit).
    pub geometry: &'static str,
    /// Mean-diameter error (mm); NaN when withheld (in_bend), failed, or (by the survey)
    /// not `converged`, as `epd estimate` gives no result for such a frame.
    pub dmean_err_mm: f64,
    /// The reported end of the straight section (m), NaN when none.
    pub straight_until_m: f64,
    /// Its error (mm), NaN when none.
    pub straight_until_err_mm: f64,
    /// Bend radius (mm), NaN when none.
    pub bend_radius_mm: f64,
    /// Its error (%), NaN when none.
    pub bend_radius_err_pct: f64,
    /// Clock-angle error of the bend's or branch's direction (deg), NaN when none.
    pub direction_err_deg: f64,
    /// The 1-σ of `straight_until_m` the survey reports (mm), NaN when none.
    pub sigma_straight_until_mm: f64,
    /// The 1-σ of the bend radius the survey reports (mm), NaN when none.
    pub sigma_bend_radius_mm: f64,
    /// The survey's departure evidence (`epd_core::segment::Survey::evidence`), NaN for
    /// the plain fit.
    pub geometry_evidence: f64,
}

pub(super) fn frame_rows(
    s: &ApproachScenario,
    di: usize,
    k: usize,
) -> anyhow::Result<[FrameRow; 2]> {
    let distance = s.distances_m[di];
    let p = s.pipeline(distance);
    let mut truth = PoseRanges::default().sample(&s.pipe, s.seed, (di * s.frames + k) as u64)?;
    truth.d_max = p.d_max;
    truth.d_min = p.d_min;
    let scene = Scene::pipeline(&truth, &p, &MeshResolution::default())?;
    let noise = if s.sigma_m > 0.0 {
        Noise::range(s.sigma_m)
    } else {
        Noise::none()
    };
    let seed = FrameSeed {
        seed: s.seed,
        trial: k as u64,
        sweep_index: di as u64,
    };
    let f = simulate(&Sensor::helios2(), &scene, &noise, Subsample::All, seed)?;
    let options =
        EstimateOptions::default().with_loss(Loss::from_name("cauchy", DEFAULT_LOSS_SCALE_M)?)?;
    let err = |e: &Params| 0.5e3 * ((e.d_max + e.d_min) - (truth.d_max + truth.d_min));
    let want_until = p.straight_until().unwrap_or(f64::NAN);
    let want_clock = clock_angle_deg(&truth, s.direction);
    let nan = f64::NAN;
    let plain = estimate(&f.measured, Method::MlEpd, &options)
        .map(|e| err(&e.params))
        .unwrap_or(nan);
    let plain_row = FrameRow {
        distance_m: distance,
        frame: k,
        segmented: false,
        geometry: "straight",
        dmean_err_mm: plain,
        straight_until_m: nan,
        straight_until_err_mm: nan,
        bend_radius_mm: nan,
        bend_radius_err_pct: nan,
        direction_err_deg: nan,
        sigma_straight_until_mm: nan,
        sigma_bend_radius_mm: nan,
        geometry_evidence: nan,
    };
    let sv = survey(
        &f.measured,
        Method::MlEpd,
        &options,
        &SegmentOptions::default(),
    )?;
    let seg = &sv.segmentation;
    let until = seg.straight_until.unwrap_or(nan);
    let (radius, radius_err) = match (sv.bend, s.feature) {
        (Some(b), Feature::Elbow { radius, .. }) => (
            b.geometry.radius * 1e3,
            100.0 * (b.geometry.radius / radius - 1.0),
        ),
        (Some(b), _) => (b.geometry.radius * 1e3, nan),
        _ => (nan, nan),
    };
    let direction = sv
        .bend
        .map(|b| b.geometry.direction)
        .or(seg.direction)
        .map(|d| clock_angle_deg(&seg.straight.params, d));
    let direction_err = direction
        .map(|c| ((c - want_clock + 180.0).rem_euclid(360.0) - 180.0).abs())
        .unwrap_or(nan);
    let seg_row = FrameRow {
        distance_m: distance,
        frame: k,
        segmented: true,
        geometry: seg.layout.name(),
        dmean_err_mm: if seg.straight_withheld || !seg.straight.status.is_converged() {
            nan
        } else {
            err(&seg.straight.params)
        },
        straight_until_m: until,
        straight_until_err_mm: (until - want_until) * 1e3,
        bend_radius_mm: radius,
        bend_radius_err_pct: radius_err,
        direction_err_deg: direction_err,
        sigma_straight_until_mm: sv.straight_until_sigma.map_or(nan, |v| v * 1e3),
        sigma_bend_radius_mm: sv.bend.map_or(nan, |b| b.radius_sigma * 1e3),
        geometry_evidence: sv.evidence,
    };
    Ok([plain_row, seg_row])
}

/// The columns of `frames.csv`.
pub const FRAME_COLUMNS: [&str; 13] = [
    "distance_m",
    "frame",
    "segmented",
    "geometry",
    "dmean_err_mm",
    "straight_until_m",
    "straight_until_err_mm",
    "bend_radius_mm",
    "bend_radius_err_pct",
    "direction_err_deg",
    "sigma_straight_until_mm",
    "sigma_bend_radius_mm",
    "geometry_evidence",
];

/// `frames.csv`: one row per frame and fit ([`FRAME_COLUMNS`]).
pub(super) fn write_frames_csv(dir: &Path, rows: &[FrameRow]) -> anyhow::Result<PathBuf> {
    CsvFile::write_all(
        &dir.join("frames.csv"),
        &FRAME_COLUMNS,
        rows.iter().map(frame_row),
    )
}

/// The row of `frames.csv` of `r` ([`FRAME_COLUMNS`]).
fn frame_row(r: &FrameRow) -> [String; FRAME_COLUMNS.len()] {
    [
        num(r.distance_m),
        r.frame.to_string(),
        r.segmented.to_string(),
        r.geometry.to_string(),
        num(r.dmean_err_mm),
        num(r.straight_until_m),
        num(r.straight_until_err_mm),
        num(r.bend_radius_mm),
        num(r.bend_radius_err_pct),
        num(r.direction_err_deg),
        num(r.sigma_straight_until_mm),
        num(r.sigma_bend_radius_mm),
        num(r.geometry_evidence),
    ]
}
