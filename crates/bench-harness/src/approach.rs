//! `[approach]` scenarios: the sensor approaching an elbow or a tee (issue 12). For each
//! distance from the sensor to the straight section's end, frames from the paper's
//! random poses in a pipeline (`tof_sim::Pipeline`), each estimated by ML-EPD with the
//! Cauchy loss on every point (`segmented = false`) and by the survey
//! (`epd_core::segment::survey`, `segmented = true`), scored against the pipeline's
//! ground truth.
//!
//! ```toml
//! name = "elbow_approach"
//! seed = 12
//! [approach]
//! kind = "elbow"                # or "tee"
//! distances_m = [6.0, 3.0, 2.0, 1.0, 0.5, 0.3]
//! frames = 6
//! sigma_m = 0.03                # range noise along the rays
//! nominal_od_in = 20.0
//! wall_mm = 12.0
//! ovality = 0.02
//! bend_radius_d = 1.5           # elbow: centreline radius in nominal diameters
//! bend_angle_deg = 90.0
//! direction_deg = 40.0          # the turn (or branch) toward this PCS angle
//! branch_diameter_mm = 300.0    # tee
//! ```
//!
//! Files: `frames.csv` (one row per distance × frame × segmented: `distance_m, frame,
//! segmented, geometry, dmean_err_mm, straight_until_m, straight_until_err_mm,
//! bend_radius_mm, bend_radius_err_pct, direction_err_deg`), `approach.csv` (one row
//! per distance × segmented: `distance_m, segmented, n_frames, n_found, dmean_bias_mm,
//! dmean_range_mm, straight_until_err_max_mm, bend_radius_err_max_pct`), `approach.png`,
//! `scenario.toml`, `metadata.json`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use epd_core::segment::{SegmentOptions, clock_angle_deg, survey};
use epd_core::{EstimateOptions, Loss, Method, Params, estimate};
use rayon::prelude::*;
use serde::Deserialize;
use tof_sim::{
    FrameSeed, MeshResolution, Noise, Pipe, Pipeline, PoseRanges, Scene, Segment, Sensor,
    Subsample, simulate,
};

use crate::output::{StagedFiles, create_new, finish, write_new, write_run, wrote};
use crate::scenario::ScenarioError;

mod figures;

/// Whether a scenario text is an approach run (it has an `[approach]` table).
pub fn is_approach(source: &str) -> bool {
    toml::from_str::<toml::Table>(source).is_ok_and(|t| t.contains_key("approach"))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    name: String,
    #[serde(default)]
    seed: u64,
    approach: Keys,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Keys {
    kind: String,
    distances_m: Vec<f64>,
    frames: usize,
    sigma_m: f64,
    #[serde(default = "crate::defaults::nominal_od_in")]
    nominal_od_in: f64,
    #[serde(default = "crate::defaults::wall_mm")]
    wall_mm: f64,
    #[serde(default = "crate::defaults::ovality")]
    ovality: f64,
    #[serde(default = "crate::defaults::bend_radius_d")]
    bend_radius_d: f64,
    #[serde(default = "crate::defaults::bend_angle_deg")]
    bend_angle_deg: f64,
    #[serde(default = "forty")]
    direction_deg: f64,
    #[serde(default = "three_hundred")]
    branch_diameter_mm: f64,
}

fn forty() -> f64 {
    40.0
}
fn three_hundred() -> f64 {
    300.0
}

impl Keys {
    /// The feature ahead, checked against `pipe`; else (key, message).
    fn feature(&self, pipe: &Pipe) -> Result<Feature, (&'static str, String)> {
        match self.kind.as_str() {
            "elbow" => {
                let radius = self.bend_radius_d * pipe.outer_diameter();
                if !(radius > 0.6 * pipe.d_max() && radius.is_finite()) {
                    return Err((
                        "approach.bend_radius_d",
                        format!(
                            "{}: the bend radius must exceed the tube's",
                            self.bend_radius_d
                        ),
                    ));
                }
                if !(self.bend_angle_deg > 0.0 && self.bend_angle_deg <= 180.0) {
                    return Err((
                        "approach.bend_angle_deg",
                        format!("{}: must lie in (0, 180]", self.bend_angle_deg),
                    ));
                }
                Ok(Feature::Elbow {
                    radius,
                    angle: self.bend_angle_deg.to_radians(),
                })
            }
            "tee" => {
                let d = self.branch_diameter_mm * 1e-3;
                if !(d > 0.0 && d <= pipe.d_min()) {
                    return Err((
                        "approach.branch_diameter_mm",
                        format!(
                            "{}: must be > 0 and at most the pipe's",
                            self.branch_diameter_mm
                        ),
                    ));
                }
                Ok(Feature::Tee { branch_diameter: d })
            }
            other => Err(("approach.kind", format!("`{other}`: expected elbow or tee"))),
        }
    }

    /// The run's size and noise: distances in (0, 20] m, 1 to 1000 frames, σ ≤ 0.2 m.
    fn check_run(&self) -> Result<(), (&'static str, String)> {
        if self.distances_m.is_empty() || self.distances_m.iter().any(|d| !(*d > 0.0 && *d <= 20.0))
        {
            return Err((
                "approach.distances_m",
                format!("{:?}: one or more distances in (0, 20] m", self.distances_m),
            ));
        }
        if !(1..=1000).contains(&self.frames) {
            return Err((
                "approach.frames",
                format!("{}: must lie in [1, 1000]", self.frames),
            ));
        }
        if !(self.sigma_m >= 0.0 && self.sigma_m <= 0.2) {
            return Err((
                "approach.sigma_m",
                format!("{}: must lie in [0, 0.2] m", self.sigma_m),
            ));
        }
        Ok(())
    }
}

/// What the sensor approaches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Feature {
    /// A bend of centreline radius `radius` (m) and `angle` (rad).
    Elbow {
        /// Centreline radius (m).
        radius: f64,
        /// Bend angle (rad).
        angle: f64,
    },
    /// A tee whose branch has this diameter (m).
    Tee {
        /// Branch diameter (m).
        branch_diameter: f64,
    },
}

/// A checked approach scenario.
#[derive(Clone, Debug)]
pub struct ApproachScenario {
    /// `name`: the default output folder's name.
    pub name: String,
    /// `seed`.
    pub seed: u64,
    /// The feature ahead.
    pub feature: Feature,
    /// Distances from the sensor to the straight section's end (m).
    pub distances_m: Vec<f64>,
    /// Frames per distance.
    pub frames: usize,
    /// Range noise σ (m).
    pub sigma_m: f64,
    /// The straight pipe.
    pub pipe: Pipe,
    /// The turn's (or branch's) direction in the PCS (rad).
    pub direction: f64,
    /// The file's text.
    pub source: String,
}

impl ApproachScenario {
    /// Check an approach scenario given as text (`path` names it in errors).
    pub fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        let invalid = |key: &str, message: String| ScenarioError::Invalid {
            path: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        let f: File = toml::from_str(source).map_err(|e| ScenarioError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let k = f.approach;
        let pipe = Pipe {
            nominal_od_in: k.nominal_od_in,
            wall_thickness: k.wall_mm * 1e-3,
            ovality: k.ovality,
        };
        pipe.validate()
            .map_err(|e| invalid("approach.nominal_od_in/wall_mm/ovality", e.to_string()))?;
        let feature = k.feature(&pipe).map_err(|(key, m)| invalid(key, m))?;
        k.check_run().map_err(|(key, m)| invalid(key, m))?;
        Ok(Self {
            name: f.name,
            seed: f.seed,
            feature,
            distances_m: k.distances_m,
            frames: k.frames,
            sigma_m: k.sigma_m,
            pipe,
            direction: k.direction_deg.to_radians(),
            source: source.to_string(),
        })
    }

    /// The pipeline whose straight section ends `distance` ahead of the sensor.
    pub fn pipeline(&self, distance: f64) -> Pipeline {
        let (d_max, d_min) = (self.pipe.d_max(), self.pipe.d_min());
        match self.feature {
            Feature::Elbow { radius, angle } => Pipeline::with_one_bend(
                d_max,
                d_min,
                -1.0,
                distance,
                Segment::Bend {
                    radius,
                    angle,
                    direction: self.direction,
                },
                6.0,
            ),
            Feature::Tee { branch_diameter } => {
                // The opening's near edge at `distance`: a tee of length 2·b centred
                // b/2 + radius past it.
                let len = 2.0 * branch_diameter;
                let first = 1.0 + distance - (0.5 * len - 0.5 * branch_diameter);
                Pipeline {
                    d_max,
                    d_min,
                    bend_diameter: None,
                    start_x: -1.0,
                    segments: vec![
                        Segment::Straight { length: first },
                        Segment::Tee {
                            length: len,
                            branch_diameter,
                            direction: self.direction,
                        },
                        Segment::Straight { length: 6.0 },
                    ],
                }
            }
        }
    }
}

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
    /// Mean-diameter error (mm); NaN when withheld (in_bend) or failed.
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
}

fn frame_rows(s: &ApproachScenario, di: usize, k: usize) -> anyhow::Result<[FrameRow; 2]> {
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
    let options = EstimateOptions::default().with_loss(Loss::from_name("cauchy", 0.05)?)?;
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
        dmean_err_mm: if seg.straight_withheld {
            nan
        } else {
            err(&seg.straight.params)
        },
        straight_until_m: until,
        straight_until_err_mm: (until - want_until) * 1e3,
        bend_radius_mm: radius,
        bend_radius_err_pct: radius_err,
        direction_err_deg: direction_err,
    };
    Ok([plain_row, seg_row])
}

/// The columns of `frames.csv`.
pub const FRAME_COLUMNS: [&str; 10] = [
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
];

/// The columns of `approach.csv`.
pub const APPROACH_COLUMNS: [&str; 8] = [
    "distance_m",
    "segmented",
    "n_frames",
    "n_found",
    "dmean_bias_mm",
    "dmean_range_mm",
    "straight_until_err_max_mm",
    "bend_radius_err_max_pct",
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
}

fn summarise(s: &ApproachScenario, rows: &[FrameRow]) -> Vec<ApproachRow> {
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
            });
        }
    }
    out
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        String::new()
    }
}

/// What an approach run wrote.
#[derive(Debug)]
pub struct ApproachReport {
    /// The files, in the output folder.
    pub files: Vec<PathBuf>,
    /// The summary rows.
    pub rows: Vec<ApproachRow>,
    /// Wall time (s).
    pub wall_time_s: f64,
}

impl StagedFiles for ApproachReport {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }
}

/// Run the scenario into `out` (replaced whole when the run succeeds).
pub fn run_approach(
    s: &ApproachScenario,
    out: &Path,
    progress: bool,
) -> anyhow::Result<ApproachReport> {
    write_run(out, |dir| stage(s, dir, progress))
}

/// `frames.csv`: one row per frame and fit ([`FRAME_COLUMNS`]).
fn write_frames_csv(dir: &Path, rows: &[FrameRow]) -> anyhow::Result<PathBuf> {
    let frames_path = dir.join("frames.csv");
    let mut w = create_new(&frames_path)?;
    writeln!(w, "{}", epd_io::csv::line(FRAME_COLUMNS)).map_err(wrote(&frames_path))?;
    for r in rows {
        let row = [
            r.distance_m.to_string(),
            r.frame.to_string(),
            r.segmented.to_string(),
            r.geometry.to_string(),
            num(r.dmean_err_mm),
            num(r.straight_until_m),
            num(r.straight_until_err_mm),
            num(r.bend_radius_mm),
            num(r.bend_radius_err_pct),
            num(r.direction_err_deg),
        ];
        writeln!(w, "{}", epd_io::csv::line(row)).map_err(wrote(&frames_path))?;
    }
    finish(w, &frames_path)
}

/// `approach.csv`: one row per distance and fit ([`APPROACH_COLUMNS`]).
fn write_approach_csv(dir: &Path, summary: &[ApproachRow]) -> anyhow::Result<PathBuf> {
    let path = dir.join("approach.csv");
    let mut w = create_new(&path)?;
    writeln!(w, "{}", epd_io::csv::line(APPROACH_COLUMNS)).map_err(wrote(&path))?;
    for r in summary {
        let row = [
            r.distance_m.to_string(),
            r.segmented.to_string(),
            r.n_frames.to_string(),
            r.n_found.to_string(),
            num(r.dmean_bias_mm),
            num(r.dmean_range_mm),
            num(r.straight_until_err_max_mm),
            num(r.bend_radius_err_max_pct),
        ];
        writeln!(w, "{}", epd_io::csv::line(row)).map_err(wrote(&path))?;
    }
    finish(w, &path)
}

fn stage(s: &ApproachScenario, dir: &Path, progress: bool) -> anyhow::Result<ApproachReport> {
    let start = Instant::now();
    let mut rows = Vec::new();
    for di in 0..s.distances_m.len() {
        if progress {
            eprintln!(
                "{}: {} m ahead, {} frames",
                s.name, s.distances_m[di], s.frames
            );
        }
        let done: Vec<anyhow::Result<[FrameRow; 2]>> = (0..s.frames)
            .into_par_iter()
            .with_max_len(1)
            .map(|k| frame_rows(s, di, k))
            .collect();
        for d in done {
            rows.extend(d.with_context(|| format!("{} m ahead", s.distances_m[di]))?);
        }
    }
    let mut files = vec![write_frames_csv(dir, &rows)?];
    let summary = summarise(s, &rows);
    files.push(write_approach_csv(dir, &summary)?);
    files.push(write_new(&dir.join("scenario.toml"), s.source.as_bytes())?);
    let png = figures::plot_approach(s, &rows)?;
    files.push(write_new(&dir.join(&png.name), &png.bytes)?);
    let (git_commit, git_dirty) = crate::provenance::git_provenance();
    let wall_time_s = start.elapsed().as_secs_f64();
    let meta = serde_json::json!({
        "scenario": s.name,
        "kind": "approach",
        "seed": s.seed,
        "crate_version": env!("CARGO_PKG_VERSION"),
        "git_commit": git_commit,
        "git_dirty": git_dirty,
        "threads": rayon::current_num_threads(),
        "wall_time_s": wall_time_s,
        "profile": if cfg!(debug_assertions) { "dev" } else { "release" },
    });
    files.push(write_new(
        &dir.join("metadata.json"),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?);
    Ok(ApproachReport {
        files,
        rows: summary,
        wall_time_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const OK: &str = "name = \"a\"\n[approach]\nkind = \"elbow\"\ndistances_m = [1.0]\nframes = 1\nsigma_m = 0.0\n";

    #[test]
    fn parses_and_refuses_with_the_key() {
        let p = Path::new("a.toml");
        assert!(is_approach(OK));
        let s = ApproachScenario::parse(p, OK).unwrap();
        assert!(matches!(s.feature, Feature::Elbow { .. }));
        assert_eq!(s.pipeline(1.0).straight_until(), Some(1.0));
        for (bad, key) in [
            (OK.replace("elbow", "wye"), "approach.kind"),
            (OK.replace("[1.0]", "[]"), "approach.distances_m"),
            (OK.replace("frames = 1", "frames = 0"), "approach.frames"),
            (
                OK.replace("sigma_m = 0.0", "sigma_m = -1.0"),
                "approach.sigma_m",
            ),
        ] {
            let e = ApproachScenario::parse(p, &bad).unwrap_err().to_string();
            assert!(e.contains(key), "{e}");
        }
        let tee = OK.replace("elbow", "tee");
        let s = ApproachScenario::parse(p, &tee).unwrap();
        let want = s.pipeline(0.7).straight_until().unwrap();
        assert!((want - 0.7).abs() < 1e-12, "{want}");
    }
}
