//! What a pipeline run writes besides the figures: `profile.csv` and `sections.csv` (their
//! columns and rows), `depth_table.json` and `metadata.json`, and the per-frame values the
//! figures draw.

use std::path::{Path, PathBuf};

use epd_frame::table::CalibrationTable;
use epd_io::csv::num;

use super::PipelineScenario;
use super::rows::{ProfileRow, RunTables};
use super::summary::SectionRow;
use crate::output::CsvFile;
use crate::provenance::Metadata;

/// `profile.csv` columns (the first eleven are the interface; the rest add the truth, the
/// Cramér–Rao bound of the heteroscedastic model, and the geometry ahead: the survey's
/// verdict as `epd estimate` reports it, and the route's truth; last, the bend radius as
/// fitted, also where `epd estimate` withholds it, and the fraction of the bend's points
/// the depth table observed, `epd_frame::scene::bend_table_coverage`).
pub const PROFILE_COLUMNS: &[&str] = &[
    "section",
    "frame",
    "distance_m",
    "method",
    "calibrated",
    "status",
    "d_max_mm",
    "d_min_mm",
    "d_mean_mm",
    "ovality_pct",
    "wall_mm",
    "d_max_true_mm",
    "d_min_true_mm",
    "n_points",
    "crb_d_max_mm",
    "crb_d_min_mm",
    "geometry",
    "straight_until_m",
    "bend_radius_mm",
    "geometry_true",
    "straight_until_true_m",
    "bend_radius_fit_mm",
    "bend_table_coverage",
];

/// `sections.csv` columns (the first eleven are the interface).
pub const SECTION_COLUMNS: &[&str] = &[
    "section",
    "method",
    "calibrated",
    "n_frames",
    "wall_true_mm",
    "wall_est_mm",
    "wall_ci95_mm",
    "dmean_bias_mm",
    "dmean_range_mm",
    "dmax_bias_mm",
    "dmin_bias_mm",
    "n_failed",
    "dmax_range_mm",
    "dmin_range_mm",
    "dmax_std_mm",
    "dmin_std_mm",
    "dmean_std_mm",
    "crb_dmax_mm",
    "crb_dmin_mm",
];

/// `profile.csv` in `dir`: one row per frame, method and calibration
/// ([`PROFILE_COLUMNS`]), in the order of `rows`.
pub(super) fn write_profile(
    dir: &Path,
    s: &PipelineScenario,
    rows: &[ProfileRow],
) -> anyhow::Result<PathBuf> {
    CsvFile::write_all(
        &dir.join("profile.csv"),
        PROFILE_COLUMNS,
        rows.iter().map(|r| profile_row(s, r)),
    )
}

/// `sections.csv` in `dir`: one row per section, method and calibration
/// ([`SECTION_COLUMNS`]).
pub(super) fn write_sections(dir: &Path, sections: &[SectionRow]) -> anyhow::Result<PathBuf> {
    CsvFile::write_all(
        &dir.join("sections.csv"),
        SECTION_COLUMNS,
        sections.iter().map(section_row),
    )
}

/// The row of `profile.csv` of `r` ([`PROFILE_COLUMNS`]).
fn profile_row(s: &PipelineScenario, r: &ProfileRow) -> [String; 23] {
    let id = r.pipe.inner_diameter();
    let od = r.pipe.outer_diameter();
    let opt = |v: Option<f64>| v.map_or(String::new(), num);
    let (dmax, dmin, dmean, ovality, wall) = match r.d {
        Some((a, b)) => (
            Some(a * 1e3),
            Some(b * 1e3),
            Some(0.5 * (a + b) * 1e3),
            Some(100.0 * (a - b) / id),
            Some((od - 0.5 * (a + b)) / 2.0 * 1e3),
        ),
        None => (None, None, None, None, None),
    };
    let g = &r.geometry;
    [
        s.place_name(r.section),
        r.frame.to_string(),
        num(r.distance_m),
        r.method.to_string(),
        r.calibrated.to_string(),
        r.status.name().to_string(),
        opt(dmax),
        opt(dmin),
        opt(dmean),
        opt(ovality),
        opt(wall),
        num(r.truth.0 * 1e3),
        num(r.truth.1 * 1e3),
        r.n_points.to_string(),
        opt(r.crb.0.map(|v| v * 1e3)),
        opt(r.crb.1.map(|v| v * 1e3)),
        g.found.to_string(),
        opt(g.straight_until),
        opt(g.bend_radius_mm),
        g.truth.geometry.to_string(),
        opt(g.truth.straight_until_m),
        opt(g.bend_radius_fit_mm),
        opt(g.bend_table_coverage),
    ]
}

/// The row of `sections.csv` of `r` ([`SECTION_COLUMNS`]).
fn section_row(r: &SectionRow) -> [String; 19] {
    [
        r.section.clone(),
        r.method.to_string(),
        r.calibrated.to_string(),
        r.n_frames.to_string(),
        num(r.wall_true_mm),
        num(r.wall_est_mm),
        num(r.wall_ci95_mm),
        num(r.dmean.mean),
        num(r.dmean.range),
        num(r.dmax.mean),
        num(r.dmin.mean),
        r.n_failed.to_string(),
        num(r.dmax.range),
        num(r.dmin.range),
        num(r.dmax.std),
        num(r.dmin.std),
        num(r.dmean.std),
        num(r.crb.0),
        num(r.crb.1),
    ]
}

/// A pipeline run's `metadata.json`: what every run records ([`Metadata::new`]), the
/// machine, the scenario's file and the depth table's fill (`filled` bins from `n_obs`
/// points).
pub(super) fn metadata(
    s: &PipelineScenario,
    wall_time_s: f64,
    filled: usize,
    n_obs: usize,
) -> Metadata {
    Metadata::new(&s.name, s.seed, wall_time_s)
        .with_cpu()
        .with("kind", "pipeline")
        .with("scenario_file", s.path.display().to_string())
        .with(
            "depth_table",
            serde_json::json!({ "bins_filled": filled, "observations": n_obs }),
        )
}

/// The depth table in the file format of `epd calibrate` (`epd estimate --calibration`
/// reads it).
pub(super) fn table_file(t: &RunTables, n_obs: usize, s: &PipelineScenario) -> CalibrationTable {
    let known = (s.rig.d_max(), s.rig.d_min());
    CalibrationTable {
        table: t.plain.clone(),
        known,
        frames: s.rig_frames,
        n_observations: n_obs as u64,
        incidence: t.incidence.clone(),
        rigs: if t.incidence.is_some() {
            vec![(known, s.rig_frames)]
        } else {
            Vec::new()
        },
        spans: t.incidence.as_ref().map(|_| t.spans),
    }
}
