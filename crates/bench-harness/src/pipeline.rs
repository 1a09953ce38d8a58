//! A pipeline run: the paper's experiment (§4.2, Figs. 9–12) with a simulated Helios2.
//!
//! A robot drives along a pipeline; its odometer gives the distance x, and its pose in
//! the pipe drifts smoothly with x (roll creeping, the offsets and the tilt wandering on
//! periods of metres) instead of being drawn afresh per frame. Each straight section is
//! a pipe of nominal outer diameter and wall thickness; the camera is the realistic ToF
//! model of `tof_sim::physics` (amplitude-dependent noise, invalid pixels, wiggling,
//! amplitude offset, multipath). Before the run, frames recorded in a calibration rig
//! (a pipe of known diameter, not one of the sections) give a depth table
//! ([`epd_core::DepthTable`]). Every section frame is then estimated by every method on
//! the points whose model range lies in the gate, without and with the table.
//!
//! `ml-epd-w` is ML-EPD with each range residual weighted by 1/σᵢ² (heteroscedastic
//! maximum likelihood): σᵢ from the sensor model's amplitude law without the table
//! (the camera's σ(A) known), from the table's spread at the point's range and
//! intensity with it.
//!
//! Files: `profile.csv` (one row per frame × method × calibrated: a caliper tool's pipe
//! tally), `sections.csv` (one row per section × method × calibrated), `depth_table.json`,
//! and the figures `diameters.png` (Fig. 11), `section_errors.png` (Fig. 12),
//! `profile.png` and `weights.png`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::Context;
use epd_core::FitOutcome;
use epd_core::calibration::{CalibrationFrame, CalibrationSettings};
use epd_core::{
    DepthTable, EstimateOptions, Loss, LossScale, Method, Params, cramer_rao_bound_weighted,
    estimate, estimate_weighted,
};
use epd_frame::input::ranges;
use epd_frame::scene::FrameScene;
use epd_frame::table::CalibrationTable;
use epd_io::csv::num;
use rand::RngExt;
use rayon::prelude::*;
use serde::Deserialize;
use tof_sim::noise::{Stream, stream};
use tof_sim::{
    Frame, FrameSeed, MeshResolution, Noise, PartKind, Pipe, Scene, Segment, Sensor, Subsample,
    ToFPhysics, WallModel, simulate,
};

use crate::output::{
    INTERRUPTED, Interrupted, StagedFiles, create_new, finish, write_new, write_run, wrote,
};
use crate::route::{Fitting, FittingKind, Route, TruthAhead, local_mesh};
use crate::scenario::{KeyError, ScenarioError, check_name, key_err};

mod figures;

/// The estimators of a pipeline run, by their names in the CSV files.
pub const METHODS: [&str; 4] = ["c-epd", "ru-epd", "ml-epd", "ml-epd-w"];

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

/// One straight section as written in the scenario.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SectionFile {
    name: String,
    #[serde(default = "crate::defaults::nominal_od_in")]
    nominal_od_in: f64,
    wall_mm: f64,
    #[serde(default)]
    ovality: f64,
    /// Odometer distance of the first frame (m).
    start_m: f64,
}

/// A fitting between sections as written (`[[pipeline.fitting]]`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FittingFile {
    /// `tee` or `elbow`.
    kind: String,
    /// Odometer distance where it begins (m).
    at_m: f64,
    /// Tee: the branch's inner diameter (mm).
    branch_diameter_mm: Option<f64>,
    /// Elbow: centreline radius in pipe diameters (default 1.5, long radius).
    bend_radius_d: Option<f64>,
    /// Elbow: angle (degrees, default 90).
    angle_deg: Option<f64>,
    /// Toward (0, cos φ, sin φ) of the incoming straight's PCS (degrees).
    #[serde(default)]
    direction_deg: f64,
}

/// The calibration rig as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    nominal_od_in: f64,
    wall_mm: f64,
    #[serde(default = "twenty_frames")]
    frames: usize,
    #[serde(default = "thirty")]
    range_bins: usize,
    #[serde(default = "twelve")]
    intensity_bins: usize,
    /// Amplitude of the sensor's offset from the rig's axis (mm): off the axis the rig
    /// shows each range at more incidence angles, hence intensities.
    #[serde(default = "sixty")]
    offset_mm: f64,
    /// Passes of the alternating pose/table refinement.
    #[serde(default = "three")]
    passes: usize,
}

/// The pose drift along the distance, as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DriftFile {
    #[serde(default)]
    roll_deg_per_m: f64,
    #[serde(default)]
    tilt_deg: f64,
    #[serde(default = "five")]
    tilt_period_m: f64,
    #[serde(default)]
    offset_mm: f64,
    #[serde(default = "seven")]
    offset_period_m: f64,
}

/// Changes to the sensor preset's error model (`tof_sim::ToFPhysics` fields).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SensorModelFile {
    reflectivity: Option<f64>,
    sigma_ref_m: Option<f64>,
    ambient: Option<f64>,
    wiggle_amplitude_m: Option<f64>,
    amplitude_offset_m_per_ln: Option<f64>,
    multipath_ratio: Option<f64>,
    multipath_extra_path_m: Option<f64>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PipelineFile {
    #[serde(default = "fifty")]
    frames_per_section: usize,
    #[serde(default = "spacing")]
    frame_spacing_m: f64,
    #[serde(default = "gate")]
    range_gate_m: [f64; 2],
    #[serde(default = "helios2")]
    sensor: String,
    #[serde(default)]
    sensor_model: SensorModelFile,
    section: Vec<SectionFile>,
    rig: RigFile,
    drift: DriftFile,
    #[serde(default)]
    fitting: Vec<FittingFile>,
    /// Mesh cells around the pipe for frames that see a fitting.
    #[serde(default = "five_twelve")]
    mesh_segments: usize,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    name: String,
    #[serde(default = "crate::defaults::seed")]
    seed: u64,
    pipeline: PipelineFile,
}

fn twenty_frames() -> usize {
    20
}
fn thirty() -> usize {
    30
}
fn twelve() -> usize {
    12
}
fn three() -> usize {
    3
}
fn sixty() -> f64 {
    60.0
}
fn five() -> f64 {
    5.0
}
fn seven() -> f64 {
    7.0
}
fn fifty() -> usize {
    50
}
fn spacing() -> f64 {
    0.2
}
fn gate() -> [f64; 2] {
    [0.5, 2.0]
}
fn helios2() -> String {
    "helios2".into()
}
fn five_twelve() -> usize {
    512
}

/// A straight section, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct Section {
    /// Its name in the CSV files.
    pub name: String,
    /// The pipe.
    pub pipe: Pipe,
    /// Odometer distance of the first frame (m).
    pub start_m: f64,
}

/// The smooth pose along the distance x (m): roll = roll₀ + k·x; pitch, yaw = T·sin, T·cos
/// of 2πx/P_T (different phases and a 1.3 × longer yaw period); δy, δz = A·sin of
/// 2πx/P_A (δz on a 0.77 × shorter period); the phases drawn from the seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drift {
    /// Roll rate (rad/m).
    pub roll_per_m: f64,
    /// Tilt amplitude T (rad).
    pub tilt: f64,
    /// Tilt period P_T (m).
    pub tilt_period_m: f64,
    /// Offset amplitude A (m).
    pub offset: f64,
    /// Offset period P_A (m).
    pub offset_period_m: f64,
}

impl Drift {
    /// The pose at distance x in `pipe`, phases from (seed, `leg`).
    pub fn pose(&self, pipe: &Pipe, seed: u64, leg: u64, x: f64) -> Params {
        let mut rng = stream(seed, leg, 0, Stream::Pose, 0);
        let tau = std::f64::consts::TAU;
        let ph: [f64; 5] = std::array::from_fn(|_| rng.random_range(0.0..tau));
        let roll = epd_core::params::wrap_pi(ph[0] + self.roll_per_m * x);
        Params {
            d_max: pipe.d_max(),
            d_min: pipe.d_min(),
            roll,
            pitch: self.tilt * (tau * x / self.tilt_period_m + ph[1]).sin(),
            yaw: self.tilt * (tau * x / (1.3 * self.tilt_period_m) + ph[2]).cos(),
            dy: self.offset * (tau * x / self.offset_period_m + ph[3]).sin(),
            dz: self.offset * (tau * x / (0.77 * self.offset_period_m) + ph[4]).sin(),
        }
    }
}

/// A checked pipeline scenario.
#[derive(Clone, Debug)]
pub struct PipelineScenario {
    /// `name`: the default output folder's name.
    pub name: String,
    /// `seed`.
    pub seed: u64,
    /// Frames per section.
    pub frames_per_section: usize,
    /// Odometer distance between frames (m).
    pub frame_spacing_m: f64,
    /// The estimators' gate on the model range (m).
    pub range_gate: (f64, f64),
    /// The camera.
    pub sensor: Sensor,
    /// Its error model.
    pub physics: ToFPhysics,
    /// The straight sections, in driving order.
    pub sections: Vec<Section>,
    /// The calibration rig's pipe (known diameter).
    pub rig: Pipe,
    /// Calibration frames.
    pub rig_frames: usize,
    /// Table bins (range, intensity).
    pub table_bins: (usize, usize),
    /// Passes of the calibration's alternating refinement.
    pub calibration_passes: usize,
    /// The pose along the distance.
    pub drift: Drift,
    /// The pose along the rig (the drift with the rig's offset amplitude).
    pub rig_drift: Drift,
    /// Tees and elbows along the odometer, between the sections.
    pub route: Route,
    /// How frames that see a fitting are meshed.
    pub mesh: MeshResolution,
    /// The file's text.
    pub source: String,
    /// The file.
    pub path: PathBuf,
}

/// Whether a scenario text is a pipeline run (it has a `[pipeline]` table).
pub fn is_pipeline(source: &str) -> bool {
    toml::from_str::<toml::Table>(source).is_ok_and(|t| t.contains_key("pipeline"))
}

/// The fittings as a [`Route`], checked: kinds and sizes, in driving order without
/// overlaps, each between two sections' frames (the sections are straight pipe), each
/// tee's branch no wider than the narrower neighbouring section. Errors name the key.
fn parse_route(
    files: &[FittingFile],
    sections: &[Section],
    frames: usize,
    spacing: f64,
) -> Result<Route, KeyError> {
    let span = |s: &Section| (s.start_m, s.start_m + (frames as f64 - 1.0) * spacing);
    if !files.is_empty() && sections.windows(2).any(|w| span(&w[0]).1 >= w[1].start_m) {
        return Err(key_err(
            "pipeline.section",
            "with fittings, the sections must follow each other along the odometer without \
             overlapping frames"
                .into(),
        ));
    }
    let mut route = Route::default();
    for (k, f) in files.iter().enumerate() {
        let bad =
            |field: &str, m: String| Err(key_err(&format!("pipeline.fitting[{k}].{field}"), m));
        if !f.at_m.is_finite() {
            return bad("at_m", format!("= {}: must be finite", f.at_m));
        }
        if !f.direction_deg.is_finite() {
            return bad("direction_deg", "must be finite".into());
        }
        let (a, b) = f
            .neighbours(sections)
            .map_err(|m| key_err(&format!("pipeline.fitting[{k}].at_m"), m))?;
        let fitting = Fitting {
            kind: f.kind(k, a, b)?,
            at_m: f.at_m,
            direction: f.direction_deg.to_radians(),
        };
        if fitting.at_m <= span(a).1 || fitting.end_m() >= b.start_m {
            return bad(
                "at_m",
                format!(
                    "= {}: the fitting ({:.2} m long) must lie between section {}'s last frame \
                     ({:.2} m) and section {}'s first ({:.2} m)",
                    f.at_m,
                    fitting.length(),
                    a.name,
                    span(a).1,
                    b.name,
                    b.start_m
                ),
            );
        }
        if let Some(prev) = route.fittings.last()
            && prev.end_m() > fitting.at_m
        {
            return bad(
                "at_m",
                format!(
                    "= {}: overlaps the fitting before it (ends at {:.3} m); list them in driving order",
                    f.at_m,
                    prev.end_m()
                ),
            );
        }
        route.fittings.push(fitting);
    }
    Ok(route)
}

impl FittingFile {
    /// The sections around the fitting (at a finite `at_m`): the last one starting
    /// before it and the next; else what is wrong with `at_m`.
    fn neighbours<'a>(
        &self,
        sections: &'a [Section],
    ) -> Result<(&'a Section, &'a Section), String> {
        let Some(before) = sections.iter().rposition(|s| s.start_m < self.at_m) else {
            return Err(format!(
                "= {}: must lie after the first section's frames",
                self.at_m
            ));
        };
        match sections.get(before + 1) {
            Some(after) => Ok((&sections[before], after)),
            None => Err(format!("= {}: must lie before the last section", self.at_m)),
        }
    }

    /// The fitting `k`'s kind and size in SI units, checked against the sections `a`
    /// before and `b` after it: a tee's branch (mm → m) no wider than the narrower minor
    /// diameter; an elbow's radius (pipe diameters → m, D = `a`'s mean diameter) and
    /// angle (degrees → rad).
    fn kind(&self, k: usize, a: &Section, b: &Section) -> Result<FittingKind, KeyError> {
        let bad =
            |field: &str, m: String| Err(key_err(&format!("pipeline.fitting[{k}].{field}"), m));
        match self.kind.as_str() {
            "tee" => {
                if self.bend_radius_d.is_some() || self.angle_deg.is_some() {
                    return bad(
                        "kind",
                        "= \"tee\" takes branch_diameter_mm, not bend_radius_d or angle_deg".into(),
                    );
                }
                let Some(bd) = self.branch_diameter_mm else {
                    return bad(
                        "branch_diameter_mm",
                        "a tee needs its branch's inner diameter".into(),
                    );
                };
                let d_min = a.pipe.d_min().min(b.pipe.d_min());
                if !(bd > 0.0 && bd * 1e-3 <= d_min) {
                    return bad(
                        "branch_diameter_mm",
                        format!(
                            "= {bd}: must lie in (0, {:.1}] (the main pipe's minor diameter)",
                            d_min * 1e3
                        ),
                    );
                }
                Ok(FittingKind::Tee {
                    branch_diameter: bd * 1e-3,
                })
            }
            "elbow" => {
                if self.branch_diameter_mm.is_some() {
                    return bad(
                        "kind",
                        "= \"elbow\" takes bend_radius_d and angle_deg, not branch_diameter_mm"
                            .into(),
                    );
                }
                let rd = self
                    .bend_radius_d
                    .unwrap_or_else(crate::defaults::bend_radius_d);
                let angle = self
                    .angle_deg
                    .unwrap_or_else(crate::defaults::bend_angle_deg);
                if !(0.75..=50.0).contains(&rd) {
                    return bad(
                        "bend_radius_d",
                        format!("= {rd}: must lie in [0.75, 50] pipe diameters"),
                    );
                }
                if !(angle > 0.0 && angle <= 180.0) {
                    return bad("angle_deg", format!("= {angle}: must lie in (0, 180]"));
                }
                let d = 0.5 * (a.pipe.d_max() + a.pipe.d_min());
                Ok(FittingKind::Elbow {
                    radius: rd * d,
                    angle: angle.to_radians(),
                })
            }
            other => bad(
                "kind",
                format!("= \"{other}\": must be \"tee\" or \"elbow\""),
            ),
        }
    }
}

/// A checked pipe from file units (mm → m); errors name `key`.
fn pipe_of(key: &str, nominal_od_in: f64, wall_mm: f64, ovality: f64) -> Result<Pipe, KeyError> {
    let pipe = Pipe {
        nominal_od_in,
        wall_thickness: wall_mm * 1e-3,
        ovality,
    };
    pipe.validate()
        .map(|_| pipe)
        .map_err(|e| key_err(key, e.to_string()))
}

impl PipelineFile {
    /// The frames along each section and the gate: `frames_per_section` in [1, 10000], a
    /// spacing > 0, 0 ≤ gate min < max; the gate (m).
    fn gate(&self) -> Result<(f64, f64), KeyError> {
        if !(1..=10_000).contains(&self.frames_per_section) {
            return Err(key_err(
                "pipeline.frames_per_section",
                format!("= {}: must lie in [1, 10000]", self.frames_per_section),
            ));
        }
        if !(self.frame_spacing_m > 0.0 && self.frame_spacing_m.is_finite()) {
            return Err(key_err(
                "pipeline.frame_spacing_m",
                format!("= {}: must be a finite number > 0", self.frame_spacing_m),
            ));
        }
        let [g0, g1] = self.range_gate_m;
        if !(g0 >= 0.0 && g1 > g0 && g1.is_finite()) {
            return Err(key_err(
                "pipeline.range_gate_m",
                format!("= [{g0}, {g1}]: need 0 ≤ min < max"),
            ));
        }
        Ok((g0, g1))
    }

    /// The sensor preset's error model with the file's changes, checked.
    fn physics(&self) -> Result<ToFPhysics, KeyError> {
        let mut physics = match self.sensor.as_str() {
            "helios2" => ToFPhysics::helios2(),
            other => {
                return Err(key_err(
                    "pipeline.sensor",
                    format!("= \"{other}\": the one preset is \"helios2\""),
                ));
            }
        };
        let m = &self.sensor_model;
        for (v, field) in [
            (m.reflectivity, &mut physics.reflectivity),
            (m.sigma_ref_m, &mut physics.sigma_ref_m),
            (m.ambient, &mut physics.ambient),
            (m.wiggle_amplitude_m, &mut physics.wiggle_amplitude_m),
            (
                m.amplitude_offset_m_per_ln,
                &mut physics.amplitude_offset_m_per_ln,
            ),
            (m.multipath_ratio, &mut physics.multipath_ratio),
            (
                m.multipath_extra_path_m,
                &mut physics.multipath_extra_path_m,
            ),
        ] {
            if let Some(v) = v {
                *field = v;
            }
        }
        physics
            .validate()
            .map_err(|e| key_err("pipeline.sensor_model", e.to_string()))?;
        Ok(physics)
    }

    /// 1 to 100 sections, each named for a CSV cell, starting at a finite distance, of a
    /// valid pipe.
    fn sections(&self) -> Result<Vec<Section>, KeyError> {
        if self.section.is_empty() || self.section.len() > 100 {
            return Err(key_err(
                "pipeline.section",
                format!("has {} sections: list 1 to 100", self.section.len()),
            ));
        }
        let mut sections = Vec::new();
        for (k, s) in self.section.iter().enumerate() {
            let key = format!("pipeline.section[{k}]");
            if s.name.is_empty() || s.name.contains([',', '"', '\n']) {
                return Err(key_err(
                    &format!("{key}.name"),
                    format!("= {:?}: a non-empty name without commas or quotes", s.name),
                ));
            }
            if !s.start_m.is_finite() {
                return Err(key_err(&format!("{key}.start_m"), "must be finite".into()));
            }
            sections.push(Section {
                name: s.name.clone(),
                pipe: pipe_of(&key, s.nominal_od_in, s.wall_mm, s.ovality)?,
                start_m: s.start_m,
            });
        }
        Ok(sections)
    }

    /// How frames that see a fitting are meshed: `mesh_segments` cells around the pipe.
    fn mesh(&self) -> Result<MeshResolution, KeyError> {
        let mesh = MeshResolution {
            segments: self.mesh_segments,
            bend_step: 0.5f64.to_radians(),
            straight_ring_spacing: 0.25,
            tee_ring_spacing: 0.004,
        };
        mesh.validate()
            .map_err(|e| key_err("pipeline.mesh_segments", e.to_string()))?;
        Ok(mesh)
    }
}

impl RigFile {
    /// The rig's round pipe, its frame count, passes and table bins checked.
    fn pipe(&self) -> Result<Pipe, KeyError> {
        let rig = pipe_of("pipeline.rig", self.nominal_od_in, self.wall_mm, 0.0)?;
        if !(1..=1000).contains(&self.frames) {
            return Err(key_err(
                "pipeline.rig.frames",
                format!("= {}: must lie in [1, 1000]", self.frames),
            ));
        }
        if !(1..=20).contains(&self.passes) {
            return Err(key_err(
                "pipeline.rig.passes",
                format!("= {}: must lie in [1, 20]", self.passes),
            ));
        }
        let bins_ok = |n: usize| (1..=1000).contains(&n);
        if !(bins_ok(self.range_bins) && bins_ok(self.intensity_bins)) {
            return Err(key_err(
                "pipeline.rig.range_bins",
                "and intensity_bins must lie in [1, 1000]".into(),
            ));
        }
        Ok(rig)
    }

    /// The pose along the rig: the run's `drift` with the rig's offset amplitude (mm → m).
    fn drift(&self, drift: Drift) -> Result<Drift, KeyError> {
        if !(0.0..1e4).contains(&self.offset_mm) {
            return Err(key_err(
                "pipeline.rig.offset_mm",
                format!("= {}: must lie in [0, 10000)", self.offset_mm),
            ));
        }
        Ok(Drift {
            offset: self.offset_mm * 1e-3,
            ..drift
        })
    }
}

impl DriftFile {
    /// The drift in SI units (degrees → rad, mm → m), each value in its range.
    fn to_drift(&self) -> Result<Drift, KeyError> {
        let deg = std::f64::consts::PI / 180.0;
        for (key, v, ok) in [
            (
                "pipeline.drift.roll_deg_per_m",
                self.roll_deg_per_m,
                self.roll_deg_per_m.is_finite(),
            ),
            (
                "pipeline.drift.tilt_deg",
                self.tilt_deg,
                (0.0..30.0).contains(&self.tilt_deg),
            ),
            (
                "pipeline.drift.tilt_period_m",
                self.tilt_period_m,
                self.tilt_period_m > 0.0,
            ),
            (
                "pipeline.drift.offset_mm",
                self.offset_mm,
                (0.0..1e4).contains(&self.offset_mm),
            ),
            (
                "pipeline.drift.offset_period_m",
                self.offset_period_m,
                self.offset_period_m > 0.0,
            ),
        ] {
            if !(ok && v.is_finite()) {
                return Err(key_err(key, format!("= {v}: out of range")));
            }
        }
        Ok(Drift {
            roll_per_m: self.roll_deg_per_m * deg,
            tilt: self.tilt_deg * deg,
            tilt_period_m: self.tilt_period_m,
            offset: self.offset_mm * 1e-3,
            offset_period_m: self.offset_period_m,
        })
    }
}

impl PipelineScenario {
    /// Check a pipeline scenario given as text (`path` names it in errors).
    pub fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        let f: File = toml::from_str(source).map_err(|e| ScenarioError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim_end().to_string(),
        })?;
        Self::check(&f, path, source).map_err(|(key, message)| ScenarioError::Invalid {
            path: path.to_path_buf(),
            key,
            message,
        })
    }

    /// File units → a checked scenario, or (key, message). Checked in the order of the
    /// steps below, so a file with several errors names the first.
    fn check(f: &File, path: &Path, source: &str) -> Result<Self, KeyError> {
        let p = &f.pipeline;
        check_name(&f.name)?;
        let range_gate = p.gate()?;
        let physics = p.physics()?;
        let sections = p.sections()?;
        let rig = p.rig.pipe()?;
        let drift = p.drift.to_drift()?;
        let rig_drift = p.rig.drift(drift)?;
        let mesh = p.mesh()?;
        let route = parse_route(
            &p.fitting,
            &sections,
            p.frames_per_section,
            p.frame_spacing_m,
        )?;
        let scenario = Self {
            name: f.name.clone(),
            seed: f.seed,
            frames_per_section: p.frames_per_section,
            frame_spacing_m: p.frame_spacing_m,
            range_gate,
            sensor: Sensor::helios2(),
            physics,
            sections,
            rig,
            rig_frames: p.rig.frames,
            table_bins: (p.rig.range_bins, p.rig.intensity_bins),
            calibration_passes: p.rig.passes,
            drift,
            rig_drift,
            route,
            mesh,
            source: source.to_string(),
            path: path.to_path_buf(),
        };
        scenario.check_sensor_inside(p)?;
        Ok(scenario)
    }

    /// Every pose along the way (the rig's frames, then the run's) must leave the sensor
    /// inside its pipe; else the offset amplitude that takes it out (`p`'s value).
    fn check_sensor_inside(&self, p: &PipelineFile) -> Result<(), KeyError> {
        let plans = self.plans();
        let legs = std::iter::once((
            0,
            self.rig,
            (0..self.rig_frames).map(|k| self.rig_distance(k)).collect(),
        ))
        .chain(plans.iter().map(|p| (p.drift_leg, p.pipe, vec![p.x])));
        for (leg, pipe, xs) in legs {
            for x in xs {
                let pose = self.drift_of(leg).pose(&pipe, self.seed, leg, x);
                if !pose.sensor_inside() {
                    let (key, v, leg) = if leg == 0 {
                        (
                            "pipeline.rig.offset_mm",
                            p.rig.offset_mm,
                            "the rig".to_string(),
                        )
                    } else {
                        let name = &self.sections[leg as usize - 1].name;
                        (
                            "pipeline.drift.offset_mm",
                            p.drift.offset_mm,
                            format!("section {name}"),
                        )
                    };
                    return Err(key_err(
                        key,
                        format!("= {v}: at {x:.2} m the sensor leaves the pipe of {leg}"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Every frame of the run in driving order: each section's frames, then (when
    /// fittings lie between two sections) the frames the robot records on its way from
    /// one section to the next, at the same spacing.
    pub fn plans(&self) -> Vec<FramePlan> {
        let n = self.sections.len();
        let mut plans = Vec::new();
        for (si, sec) in self.sections.iter().enumerate() {
            let leg = si as u64 + 1;
            let last = sec.start_m + (self.frames_per_section as f64 - 1.0) * self.frame_spacing_m;
            for k in 0..self.frames_per_section {
                plans.push(FramePlan {
                    place: si,
                    drift_leg: leg,
                    seed_leg: leg,
                    index: k,
                    x: sec.start_m + k as f64 * self.frame_spacing_m,
                    pipe: sec.pipe,
                });
            }
            let Some(next) = self.sections.get(si + 1) else {
                continue;
            };
            let gap: Vec<&Fitting> = self
                .route
                .fittings
                .iter()
                .filter(|f| f.at_m > last && f.at_m < next.start_m)
                .collect();
            let Some(change) = gap.last().map(|f| f.end_m()) else {
                continue;
            };
            let mut j = 1;
            loop {
                let x = last + j as f64 * self.frame_spacing_m;
                if x > next.start_m - 0.5 * self.frame_spacing_m {
                    break;
                }
                plans.push(FramePlan {
                    place: n + si,
                    drift_leg: leg,
                    seed_leg: TRANSIT_LEG + si as u64,
                    index: j - 1,
                    x,
                    // The pipe changes to the next section's after the gap's last fitting.
                    pipe: if x < change { sec.pipe } else { next.pipe },
                });
                j += 1;
            }
        }
        plans
    }

    /// The name of a place in the CSV files: a section's, or `A..B` between sections A
    /// and B.
    pub fn place_name(&self, place: usize) -> String {
        let n = self.sections.len();
        match self.sections.get(place) {
            Some(s) => s.name.clone(),
            None => format!(
                "{}..{}",
                self.sections[place - n].name,
                self.sections[place - n + 1].name
            ),
        }
    }

    /// Where rig frame k is taken: the frames span one period of the offset's drift,
    /// so the sensor sits off the axis in every direction (a pose error the fit trades
    /// for a systematic error then averages out of the table instead of entering it).
    fn rig_distance(&self, k: usize) -> f64 {
        k as f64 * self.rig_drift.offset_period_m / self.rig_frames as f64
    }

    /// The drift of a leg: the rig's (leg 0) or the sections'.
    fn drift_of(&self, leg: u64) -> &Drift {
        if leg == 0 {
            &self.rig_drift
        } else {
            &self.drift
        }
    }

    fn noise(&self) -> Noise {
        Noise {
            physics: Some(self.physics),
            ..Noise::none()
        }
    }

    /// A rig frame: the straight rig pipe.
    fn rig_frame(&self, index: usize, x: f64) -> anyhow::Result<Frame> {
        let truth = self.rig_drift.pose(&self.rig, self.seed, 0, x);
        let scene = Scene::new(&truth, WallModel::Exact, self.sensor.max_range)?;
        self.cast(&scene, 0, index)
    }

    fn cast(&self, scene: &Scene, leg: u64, index: usize) -> anyhow::Result<Frame> {
        Ok(simulate(
            &self.sensor,
            scene,
            &self.noise(),
            Subsample::All,
            FrameSeed {
                seed: self.seed,
                trial: index as u64,
                sweep_index: leg,
            },
        )?)
    }

    /// A frame of the run: the exact straight pipe when no fitting is in the sensor's
    /// range, else the local pipeline ([`Route::local`]) meshed. Returns the truth (in an
    /// elbow: the pose about the centreline frame, the bend's round diameter), the frame
    /// and the local pipeline.
    fn frame(
        &self,
        plan: &FramePlan,
    ) -> anyhow::Result<(Params, Frame, Option<tof_sim::Pipeline>)> {
        let mut truth =
            self.drift_of(plan.drift_leg)
                .pose(&plan.pipe, self.seed, plan.drift_leg, plan.x);
        let view = self.sensor.max_range;
        let local = self
            .route
            .local(plan.x, view, plan.pipe.d_max(), plan.pipe.d_min());
        let scene = match &local {
            None => Scene::new(&truth, WallModel::Exact, self.sensor.max_range)?,
            Some((p, f)) => {
                if self.route.in_elbow(plan.x).is_some() {
                    let d = 2.0 * p.bend_tube_radius();
                    (truth.d_max, truth.d_min) = (d, d);
                }
                Scene::with_labeled_mesh(&truth, local_mesh(p, f, &self.mesh)?)?
            }
        };
        let frame = self.cast(&scene, plan.seed_leg, plan.index)?;
        Ok((truth, frame, local.map(|l| l.0)))
    }
}

/// `FrameSeed::sweep_index` of the frames between sections A and A + 1: this + A.
const TRANSIT_LEG: u64 = 1000;

/// Where and how one frame of the run is taken.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FramePlan {
    /// A section's index, or `n_sections + A` between sections A and A + 1.
    pub place: usize,
    /// The drift's leg (its phases): the section's, continued between sections.
    pub drift_leg: u64,
    /// The frame's noise stream (`FrameSeed::sweep_index`).
    pub seed_leg: u64,
    /// Frame index within its place.
    pub index: usize,
    /// Odometer distance (m).
    pub x: f64,
    /// The pipe at x.
    pub pipe: Pipe,
}

/// What the survey said of one frame and what the route holds there.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Geometry {
    /// The survey's layout name.
    found: &'static str,
    /// Its straight_until (m).
    straight_until: Option<f64>,
    /// Its bend radius (mm), as `epd estimate` reports it.
    bend_radius_mm: Option<f64>,
    /// The bend radius as fitted (mm), also where it is withheld.
    bend_radius_fit_mm: Option<f64>,
    /// The fraction of the bend's points the depth table observed.
    bend_table_coverage: Option<f64>,
    /// The truth.
    truth: TruthAhead,
}

/// What became of one method's estimate on one frame (`status` in `profile.csv`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FrameStatus {
    /// The estimator ran: how its fit ended.
    Fit(FitOutcome),
    /// Not estimated: the survey found no straight section to fit on its own.
    Withheld,
    /// The estimator returned an error (too few points, …).
    Error,
}

impl FrameStatus {
    /// The name in `profile.csv`: the fit's outcome, `withheld` or `error`.
    fn name(self) -> &'static str {
        match self {
            FrameStatus::Fit(o) => o.name(),
            FrameStatus::Withheld => "withheld",
            FrameStatus::Error => "error",
        }
    }
}

/// One estimate of one frame.
#[derive(Clone, Debug)]
struct Row {
    /// [`FramePlan::place`].
    section: usize,
    pipe: Pipe,
    geometry: Geometry,
    frame: usize,
    distance_m: f64,
    method: &'static str,
    calibrated: bool,
    status: FrameStatus,
    /// Dmax, Dmin (m) when converged.
    d: Option<(f64, f64)>,
    truth: (f64, f64),
    n_points: usize,
    crb: (Option<f64>, Option<f64>),
}

/// What a pipeline run wrote.
#[derive(Debug)]
pub struct PipelineReport {
    /// Files written.
    pub files: Vec<PathBuf>,
    /// Wall time (s).
    pub wall_time_s: f64,
    /// Estimates that returned an error (status `error`).
    pub errors: usize,
    /// The section rows, as written.
    pub sections: Vec<SectionRow>,
}

impl StagedFiles for PipelineReport {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }
}

/// One row of `sections.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct SectionRow {
    /// Section name.
    pub section: String,
    /// Nominal wall (mm), the x of the figures.
    pub wall_true_mm: f64,
    /// Method name.
    pub method: &'static str,
    /// Whether the depth table was applied.
    pub calibrated: bool,
    /// Converged frames.
    pub n_frames: usize,
    /// Frames without a result.
    pub n_failed: usize,
    /// Mean estimated wall (OD − mean ID)/2 (mm).
    pub wall_est_mm: f64,
    /// Half-width of its 95 % confidence interval (mm).
    pub wall_ci95_mm: f64,
    /// Statistics of the per-frame errors (mm): Dmax, Dmin, mean diameter.
    pub dmax: crate::stats::Stats,
    /// See `dmax`.
    pub dmin: crate::stats::Stats,
    /// See `dmax`.
    pub dmean: crate::stats::Stats,
    /// RMS over frames of the Cramér–Rao 1-σ of Dmax, Dmin (mm).
    pub crb: (f64, f64),
}

/// The estimator options of the run: Cauchy with the scale from the residuals, the gate.
fn options(gate: (f64, f64)) -> anyhow::Result<EstimateOptions> {
    Ok(EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", 0.05)?)?
        .with_loss_scale(LossScale::Auto)
        .with_range_gate(gate.0, gate.1)?)
}

/// Build the depth table from the rig's frames ([`epd_core::calibration::calibrate`]).
fn calibrate(s: &PipelineScenario) -> anyhow::Result<(DepthTable, usize)> {
    let frames: Vec<(Frame, Vec<f64>)> = (0..s.rig_frames)
        .into_par_iter()
        .with_max_len(1)
        .map(|k| -> anyhow::Result<(Frame, Vec<f64>)> {
            let frame = s.rig_frame(k, s.rig_distance(k))?;
            let intensity = frame.intensity.iter().map(|&i| i as f64).collect();
            Ok((frame, intensity))
        })
        .collect::<anyhow::Result<_>>()?;
    let views: Vec<CalibrationFrame<'_>> = frames
        .iter()
        .map(|(f, i)| CalibrationFrame {
            points: &f.measured,
            intensity: i,
        })
        .collect();
    let settings = CalibrationSettings {
        known: (s.rig.d_max(), s.rig.d_min()),
        gate: s.range_gate,
        bins: s.table_bins,
        min_count: 30,
        passes: s.calibration_passes,
    };
    let cal = epd_core::calibration::calibrate(&views, &settings, &options(s.range_gate)?)?;
    if let Some(e) = cal.fits.iter().find_map(|f| f.as_ref().err()) {
        anyhow::bail!("a rig frame could not be fitted with the known diameters: {e}");
    }
    Ok((cal.table, cal.n_observations))
}

/// Every method on one frame, without and with the table. The geometry ahead is
/// surveyed on the calibrated points as `epd estimate` does (ML-EPD, the run's options):
/// when something lies ahead every method fits the straight section's points only, and
/// in a bend every estimate is withheld (status `withheld`).
fn frame_rows(
    s: &PipelineScenario,
    table: &DepthTable,
    plan: &FramePlan,
) -> anyhow::Result<Vec<Row>> {
    let (truth, frame, local) = s.frame(plan)?;
    let opts = options(s.range_gate)?;
    let sv = Surveyed::of(s, table, plan, &frame, &opts)?;
    let crb = straight_crb(s, plan, &frame, local.as_ref(), &truth);
    let mut rows = Vec::new();
    for calibrated in [false, true] {
        let (points, sigma) = if calibrated {
            (&sv.corrected, &sv.table_sigma)
        } else {
            (&frame.measured, &frame.sigma)
        };
        let pts = kept(sv.keep.as_deref(), points);
        let sigma = kept(sv.keep.as_deref(), sigma);
        for method in METHODS {
            let (status, d, n_points) = if sv.withheld {
                (FrameStatus::Withheld, None, 0)
            } else {
                estimate_one(method, &pts, &sigma, &opts)
            };
            rows.push(Row {
                section: plan.place,
                pipe: plan.pipe,
                geometry: sv.geometry,
                frame: plan.index,
                distance_m: plan.x,
                method,
                calibrated,
                status,
                d,
                truth: (truth.d_max, truth.d_min),
                n_points,
                crb,
            });
        }
    }
    Ok(rows)
}

/// One frame corrected with the depth table and surveyed as `epd estimate` does.
struct Surveyed {
    /// The measured points corrected with the table (SCS, m).
    corrected: Vec<[f64; 3]>,
    /// Each point's σ from the table's spread at its range and intensity (m).
    table_sigma: Vec<f64>,
    /// The survey's verdict and the route's truth.
    geometry: Geometry,
    /// The survey withholds the estimate (the sensor is in a bend).
    withheld: bool,
    /// When something lies ahead: which points belong to the straight section.
    keep: Option<Vec<bool>>,
}

impl Surveyed {
    /// Correct `frame` with `table` and read its scene from the corrected points as
    /// `epd estimate` does (`epd_frame::scene::FrameScene::survey`, ML-EPD, `opts`).
    fn of(
        s: &PipelineScenario,
        table: &DepthTable,
        plan: &FramePlan,
        frame: &Frame,
        opts: &EstimateOptions,
    ) -> anyhow::Result<Self> {
        let intensity: Vec<f64> = frame.intensity.iter().map(|&i| i as f64).collect();
        let mut corrected = frame.measured.clone();
        let (_, table_sigma) = table.correct_with_sigmas(&mut corrected, &intensity)?;
        let raw_range_m = ranges(&frame.measured);
        let scene = FrameScene::survey(
            &corrected,
            Method::MlEpd,
            opts,
            Some((table, &raw_range_m, &intensity)),
        )
        .with_context(|| {
            format!(
                "the geometry survey of {} frame {} at {:.2} m ({} valid points)",
                s.place_name(plan.place),
                plan.index,
                plan.x,
                corrected.iter().filter(|p| **p != [0.0; 3]).count()
            )
        })?;
        let report = &scene.geometry;
        let geometry = Geometry {
            found: report.layout,
            straight_until: report.straight_until_m,
            bend_radius_mm: report.bend_radius_mm,
            bend_radius_fit_mm: scene.bend_radius_fit_mm,
            bend_table_coverage: scene.bend_table_coverage,
            truth: s.route.truth(plan.x, s.sensor.max_range),
        };
        Ok(Self {
            withheld: report.withheld().is_some(),
            corrected,
            table_sigma,
            geometry,
            keep: scene.straight,
        })
    }
}

/// The Cramér–Rao bound (Dmax, Dmin) of the heteroscedastic model over the valid pixels
/// in the gate on the sensor's straight pipe (before any bend of `local`, the mesh the
/// frame was cast on); none in an elbow or when the bound is undefined.
fn straight_crb(
    s: &PipelineScenario,
    plan: &FramePlan,
    frame: &Frame,
    local: Option<&tof_sim::Pipeline>,
    truth: &Params,
) -> (Option<f64>, Option<f64>) {
    if s.route.in_elbow(plan.x).is_some() {
        return (None, None);
    }
    let first_bend = local.and_then(|p| {
        p.segments
            .iter()
            .position(|g| matches!(g, Segment::Bend { .. }))
    });
    let on_straight = |i: usize| match frame.part.get(i).copied().flatten() {
        None => true,
        Some(part) => {
            part.kind == PartKind::Straight
                && first_bend.is_none_or(|b| (part.segment as usize) < b)
        }
    };
    let (mut exact, mut sig) = (Vec::new(), Vec::new());
    for i in 0..frame.len() {
        let e = frame.exact[i];
        let r = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        let valid = frame.measured[i] != [0.0; 3] && frame.sigma[i].is_finite();
        if valid && on_straight(i) && (s.range_gate.0..=s.range_gate.1).contains(&r) {
            exact.push(e);
            sig.push(frame.sigma[i]);
        }
    }
    cramer_rao_bound_weighted(&exact, &sig, truth)
        .map(|c| (c[0], c[1]))
        .unwrap_or((None, None))
}

/// One method of [`METHODS`] on `pts` (`ml-epd-w`: weighted by 1/σᵢ², `sigma`): its
/// status, (Dmax, Dmin) when converged (m) and the points it used.
fn estimate_one(
    method: &str,
    pts: &[[f64; 3]],
    sigma: &[f64],
    opts: &EstimateOptions,
) -> (FrameStatus, Option<(f64, f64)>, usize) {
    let result = match method {
        "c-epd" => estimate(pts, Method::CEpd, opts),
        "ru-epd" => estimate(pts, Method::RuEpd, opts),
        "ml-epd" => estimate(pts, Method::MlEpd, opts),
        _ => estimate_weighted(pts, sigma, Method::MlEpd, opts),
    };
    match result {
        Ok(e) => (
            FrameStatus::Fit(e.status.outcome()),
            e.status
                .is_converged()
                .then_some((e.params.d_max, e.params.d_min)),
            e.n_points,
        ),
        Err(_) => (FrameStatus::Error, None, 0),
    }
}

/// The entries of `v` whose `keep` flag is set (all of them without flags).
fn kept<T: Copy>(keep: Option<&[bool]>, v: &[T]) -> Vec<T> {
    match keep {
        None => v.to_vec(),
        Some(k) => v
            .iter()
            .zip(k)
            .filter(|(_, k)| **k)
            .map(|(p, _)| *p)
            .collect(),
    }
}

/// Two-sided 95 % quantile of Student's t with ν degrees of freedom (the exact 0.975
/// quantile, [`crate::stats::student_t_quantile`]).
pub fn t95(nu: f64) -> f64 {
    crate::stats::student_t_quantile(0.975, nu)
}

fn summarise(s: &PipelineScenario, rows: &[Row]) -> Vec<SectionRow> {
    let mut out = Vec::new();
    for (si, sec) in s.sections.iter().enumerate() {
        let od = sec.pipe.outer_diameter();
        let id = sec.pipe.inner_diameter();
        for calibrated in [false, true] {
            for method in METHODS {
                let sel: Vec<&Row> = rows
                    .iter()
                    .filter(|r| r.section == si && r.method == method && r.calibrated == calibrated)
                    .collect();
                let ok: Vec<(&Row, (f64, f64))> =
                    sel.iter().filter_map(|r| r.d.map(|d| (*r, d))).collect();
                let mm = |f: &dyn Fn(&Row, (f64, f64)) -> f64| -> Vec<f64> {
                    ok.iter().map(|&(r, d)| 1e3 * f(r, d)).collect()
                };
                let walls: Vec<f64> = mm(&|_, d| (od - 0.5 * (d.0 + d.1)) / 2.0);
                let w = crate::stats::Stats::of(&walls);
                let n = w.n as f64;
                let ci = if w.n >= 2 {
                    t95(n - 1.0) * w.std / n.sqrt()
                } else {
                    f64::NAN
                };
                let rms = |v: Vec<f64>| {
                    let v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
                    if v.is_empty() {
                        f64::NAN
                    } else {
                        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
                    }
                };
                out.push(SectionRow {
                    section: sec.name.clone(),
                    wall_true_mm: sec.pipe.wall_thickness * 1e3,
                    method,
                    calibrated,
                    n_frames: ok.len(),
                    n_failed: sel.len() - ok.len(),
                    wall_est_mm: w.mean,
                    wall_ci95_mm: ci,
                    dmax: crate::stats::Stats::of(&mm(&|r, d| d.0 - r.truth.0)),
                    dmin: crate::stats::Stats::of(&mm(&|r, d| d.1 - r.truth.1)),
                    dmean: crate::stats::Stats::of(&mm(&|_, d| 0.5 * (d.0 + d.1) - id)),
                    crb: (
                        rms(sel
                            .iter()
                            .map(|r| r.crb.0.map_or(f64::NAN, |v| v * 1e3))
                            .collect()),
                        rms(sel
                            .iter()
                            .map(|r| r.crb.1.map_or(f64::NAN, |v| v * 1e3))
                            .collect()),
                    ),
                });
            }
        }
    }
    out
}

fn profile_line(s: &PipelineScenario, r: &Row) -> String {
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
    .join(",")
}

fn section_line(r: &SectionRow) -> String {
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
    .join(",")
}

/// Run a pipeline scenario into `out` (replaced as a whole, see [`crate::output`]).
pub fn run_pipeline(
    s: &PipelineScenario,
    out: &Path,
    progress: bool,
) -> anyhow::Result<PipelineReport> {
    write_run(out, |dir| stage(s, dir, progress))
}

fn stage(s: &PipelineScenario, dir: &Path, progress: bool) -> anyhow::Result<PipelineReport> {
    let start = Instant::now();
    let say = |m: &str| {
        if progress {
            eprintln!("{}: {m}", s.name);
        }
    };
    say(&format!("calibration rig: {} frames", s.rig_frames));
    let (table, n_obs) = calibrate(s).context("the calibration rig")?;
    let filled = table.count.iter().filter(|&&c| c > 0).count();
    say(&format!(
        "depth table: {} × {} bins, {filled} filled, from {n_obs} points",
        table.range.n, table.log_intensity.n
    ));
    let rows = estimate_run(s, &table, &say)?;
    let profile = rows.iter().map(|r| profile_line(s, r));
    let mut files = vec![write_lines(
        &dir.join("profile.csv"),
        PROFILE_COLUMNS,
        profile,
    )?];
    let sections = summarise(s, &rows);
    let lines = sections.iter().map(section_line);
    files.push(write_lines(
        &dir.join("sections.csv"),
        SECTION_COLUMNS,
        lines,
    )?);
    files.push(write_new(&dir.join("scenario.toml"), s.source.as_bytes())?);
    files.push(write_new(
        &dir.join("depth_table.json"),
        table_file(&table, n_obs, s).to_json().as_bytes(),
    )?);
    for png in figures::plot_pipeline(s, &profile_points(&rows), &sections)? {
        files.push(write_new(&dir.join(&png.name), &png.bytes)?);
    }
    let errors = rows
        .iter()
        .filter(|r| r.status == FrameStatus::Error)
        .count();
    let wall_time_s = start.elapsed().as_secs_f64();
    let meta = metadata(s, wall_time_s, filled, n_obs);
    files.push(write_new(
        &dir.join("metadata.json"),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?);
    Ok(PipelineReport {
        files,
        wall_time_s,
        errors,
        sections,
    })
}

/// Every frame of the run ([`PipelineScenario::plans`]) by every method, place by place
/// (the frames of a place in parallel), in driving order; stops between places when the
/// run is interrupted.
fn estimate_run(
    s: &PipelineScenario,
    table: &DepthTable,
    say: &dyn Fn(&str),
) -> anyhow::Result<Vec<Row>> {
    let mut rows = Vec::new();
    let plans = s.plans();
    let mut places: Vec<usize> = plans.iter().map(|p| p.place).collect();
    places.dedup();
    for place in places {
        if INTERRUPTED.load(Ordering::SeqCst) {
            return Err(Interrupted.into());
        }
        let here: Vec<&FramePlan> = plans.iter().filter(|p| p.place == place).collect();
        say(&format!("{}: {} frames", s.place_name(place), here.len()));
        let done: Vec<anyhow::Result<Vec<Row>>> = here
            .into_par_iter()
            .with_max_len(1)
            .map(|p| frame_rows(s, table, p))
            .collect();
        for d in done {
            rows.extend(d?);
        }
    }
    Ok(rows)
}

/// A CSV file at `path`: the header `columns`, then one line per entry of `lines`.
fn write_lines(
    path: &Path,
    columns: &[&str],
    lines: impl Iterator<Item = String>,
) -> anyhow::Result<PathBuf> {
    let mut w = create_new(path)?;
    writeln!(w, "{}", columns.join(",")).map_err(wrote(path))?;
    for line in lines {
        writeln!(w, "{line}").map_err(wrote(path))?;
    }
    finish(w, path)
}

/// `metadata.json`: the scenario, the build and the machine, the run's wall time and
/// the depth table's fill (`filled` bins from `n_obs` points).
fn metadata(
    s: &PipelineScenario,
    wall_time_s: f64,
    filled: usize,
    n_obs: usize,
) -> serde_json::Value {
    let (git_commit, git_dirty) = crate::provenance::git_provenance();
    serde_json::json!({
        "scenario": s.name,
        "kind": "pipeline",
        "scenario_file": s.path.display().to_string(),
        "seed": s.seed,
        "crate_version": env!("CARGO_PKG_VERSION"),
        "git_commit": git_commit,
        "git_dirty": git_dirty,
        "threads": rayon::current_num_threads(),
        "cpu_model": crate::provenance::cpu_model(),
        "wall_time_s": wall_time_s,
        "depth_table": { "bins_filled": filled, "observations": n_obs },
        "profile": if cfg!(debug_assertions) { "dev" } else { "release" },
    })
}

/// The depth table in the file format of `epd calibrate` (`epd estimate --calibration`
/// reads it).
fn table_file(t: &DepthTable, n_obs: usize, s: &PipelineScenario) -> CalibrationTable {
    CalibrationTable {
        table: t.clone(),
        known: (s.rig.d_max(), s.rig.d_min()),
        frames: s.rig_frames,
        n_observations: n_obs as u64,
    }
}

/// Per-frame values for the figures.
#[derive(Clone, Debug)]
pub struct ProfilePoint {
    /// Section index.
    pub section: usize,
    /// Frame index in the section.
    pub frame: usize,
    /// Odometer distance (m).
    pub distance_m: f64,
    /// Method name.
    pub method: &'static str,
    /// With the depth table.
    pub calibrated: bool,
    /// Dmax, Dmin (mm) when converged.
    pub d_mm: Option<(f64, f64)>,
    /// The survey's verdict (layout name).
    pub geometry: &'static str,
    /// The survey's distance to the straight section's end (m).
    pub straight_until_m: Option<f64>,
    /// The route's truth.
    pub truth: TruthAhead,
}

fn profile_points(rows: &[Row]) -> Vec<ProfilePoint> {
    rows.iter()
        .map(|r| ProfilePoint {
            section: r.section,
            frame: r.frame,
            distance_m: r.distance_m,
            method: r.method,
            calibrated: r.calibrated,
            d_mm: r.d.map(|(a, b)| (a * 1e3, b * 1e3)),
            geometry: r.geometry.found,
            straight_until_m: r.geometry.straight_until,
            truth: r.geometry.truth,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use epd_core::segment::Layout;

    /// A small valid pipeline scenario: two sections of two frames, a tee between them.
    const OK: &str = "name = \"p\"\n[pipeline]\nframes_per_section = 2\n\
        [[pipeline.section]]\nname = \"a\"\nwall_mm = 10.0\nstart_m = 0.0\n\
        [[pipeline.fitting]]\nkind = \"tee\"\nat_m = 5.0\nbranch_diameter_mm = 100.0\n\
        [[pipeline.section]]\nname = \"b\"\nwall_mm = 10.0\nstart_m = 10.0\n\
        [pipeline.rig]\nnominal_od_in = 20\nwall_mm = 9.5\n[pipeline.drift]\n";

    /// [`OK`] with `from` replaced by `to`.
    fn set(from: &str, to: &str) -> String {
        assert!(OK.contains(from), "{from}");
        OK.replacen(from, to, 1)
    }

    /// [`OK`] with `line` added to the `[pipeline]` table.
    fn pipeline(line: &str) -> String {
        set("[pipeline]\n", &format!("[pipeline]\n{line}\n"))
    }

    /// [`OK`] with `line` added to the `[pipeline.rig]` table.
    fn rig(line: &str) -> String {
        set("wall_mm = 9.5\n", &format!("wall_mm = 9.5\n{line}\n"))
    }

    /// [`OK`] with `line` added to the `[pipeline.drift]` table (the last).
    fn drift(line: &str) -> String {
        format!("{OK}{line}\n")
    }

    /// `source` is refused naming `key`, with a message that contains `reason`.
    fn refused(source: &str, key: &str, reason: &str) {
        match PipelineScenario::parse(Path::new("p.toml"), source) {
            Err(ScenarioError::Invalid {
                key: k, message, ..
            }) => {
                assert_eq!(k, key, "{message}\n{source}");
                assert!(message.contains(reason), "{key}: {message}");
            }
            other => panic!("{key}: {other:?}\n{source}"),
        }
    }

    /// The run's own keys, checked first; with several errors, the first checked.
    #[test]
    fn parse_refuses_the_run_keys_naming_key_and_reason() {
        let s = PipelineScenario::parse(Path::new("p.toml"), OK).expect("a valid scenario");
        assert_eq!((s.sections.len(), s.route.fittings.len()), (2, 1));
        for (source, key, reason) in [
            (
                set("\"p\"", "\"a/b\""),
                "name",
                "= \"a/b\": must be a plain folder name",
            ),
            (
                set("frames_per_section = 2", "frames_per_section = 0"),
                "pipeline.frames_per_section",
                "= 0: must lie in [1, 10000]",
            ),
            (
                pipeline("frame_spacing_m = 0.0"),
                "pipeline.frame_spacing_m",
                "= 0: must be a finite number > 0",
            ),
            (
                pipeline("range_gate_m = [2.0, 1.0]"),
                "pipeline.range_gate_m",
                "= [2, 1]: need 0 ≤ min < max",
            ),
            (
                pipeline("sensor = \"x\""),
                "pipeline.sensor",
                "= \"x\": the one preset is \"helios2\"",
            ),
            (
                pipeline("sensor_model = { reflectivity = 2.0 }"),
                "pipeline.sensor_model",
                "reflectivity",
            ),
            (pipeline("mesh_segments = 0"), "pipeline.mesh_segments", ""),
            (
                set(
                    "frames_per_section = 2",
                    "frames_per_section = 0\nsensor = \"x\"",
                ),
                "pipeline.frames_per_section",
                "must lie in [1, 10000]",
            ),
        ] {
            refused(&source, key, reason);
        }
    }

    /// Sections (apart when fittings lie between them) and the rig: each key with its
    /// range.
    #[test]
    fn parse_refuses_sections_and_rig_naming_key_and_reason() {
        for (source, key, reason) in [
            (
                set("\"a\"", "\"a,b\""),
                "pipeline.section[0].name",
                "a non-empty name without commas or quotes",
            ),
            (
                set("= 10.0\nstart_m = 10.0", "= 10.0\nstart_m = nan"),
                "pipeline.section[1].start_m",
                "must be finite",
            ),
            (
                set("= 10.0\nstart_m = 10.0", "= -1.0\nstart_m = 10.0"),
                "pipeline.section[1]",
                "",
            ),
            (set("wall_mm = 9.5", "wall_mm = -1.0"), "pipeline.rig", ""),
            (
                rig("frames = 0"),
                "pipeline.rig.frames",
                "= 0: must lie in [1, 1000]",
            ),
            (
                rig("passes = 21"),
                "pipeline.rig.passes",
                "= 21: must lie in [1, 20]",
            ),
            (
                rig("intensity_bins = 0"),
                "pipeline.rig.range_bins",
                "and intensity_bins must lie in [1, 1000]",
            ),
            (
                rig("offset_mm = -1.0"),
                "pipeline.rig.offset_mm",
                "= -1: must lie in [0, 10000)",
            ),
            (
                rig("offset_mm = 400.0"),
                "pipeline.rig.offset_mm",
                "= 400: at 0.00 m the sensor leaves the pipe of the rig",
            ),
            (
                set("start_m = 10.0", "start_m = 0.1"),
                "pipeline.section",
                "with fittings, the sections must follow each other",
            ),
        ] {
            refused(&source, key, reason);
        }
    }

    /// The drift: each key with its range, and the sensor inside the pipe all along.
    #[test]
    fn parse_refuses_drift_naming_key_and_reason() {
        for (source, key, reason) in [
            (
                drift("roll_deg_per_m = inf"),
                "pipeline.drift.roll_deg_per_m",
                "= inf: out of range",
            ),
            (
                drift("tilt_deg = 30.0"),
                "pipeline.drift.tilt_deg",
                "= 30: out of range",
            ),
            (
                drift("tilt_period_m = 0.0"),
                "pipeline.drift.tilt_period_m",
                "= 0: out of range",
            ),
            (
                drift("offset_mm = 1e4"),
                "pipeline.drift.offset_mm",
                "= 10000: out of range",
            ),
            (
                drift("offset_period_m = -1.0"),
                "pipeline.drift.offset_period_m",
                "= -1: out of range",
            ),
            (
                drift("offset_mm = 400.0"),
                "pipeline.drift.offset_mm",
                "= 400: at 0.00 m the sensor leaves the pipe of section a",
            ),
        ] {
            refused(&source, key, reason);
        }
    }

    /// Fittings: kind and size, between two sections' frames, in driving order.
    #[test]
    fn parse_refuses_fittings_naming_key_and_reason() {
        let at = |v: &str| set("at_m = 5.0", &format!("at_m = {v}"));
        let elbow = |line: &str| {
            set(
                "\"tee\"\nat_m = 5.0\nbranch_diameter_mm = 100.0",
                &format!("\"elbow\"\nat_m = 5.0\n{line}"),
            )
        };
        let second_tee =
            "[[pipeline.fitting]]\nkind = \"tee\"\nat_m = 5.1\nbranch_diameter_mm = 100.0\n";
        for (source, field, reason) in [
            (at("inf"), "at_m", "= inf: must be finite"),
            (
                at("5.0\ndirection_deg = nan"),
                "direction_deg",
                "must be finite",
            ),
            (
                at("-1.0"),
                "at_m",
                "= -1: must lie after the first section's frames",
            ),
            (at("11.0"), "at_m", "= 11: must lie before the last section"),
            (
                at("0.1"),
                "at_m",
                "= 0.1: the fitting (0.20 m long) must lie between section a's last frame \
                 (0.20 m) and section b's first (10.00 m)",
            ),
            (
                set(
                    "[[pipeline.section]]\nname = \"b\"",
                    &format!("{second_tee}[[pipeline.section]]\nname = \"b\""),
                ),
                "at_m",
                "= 5.1: overlaps the fitting before it (ends at 5.200 m); list them in driving order",
            ),
            (
                set("\"tee\"", "\"wye\""),
                "kind",
                "= \"wye\": must be \"tee\" or \"elbow\"",
            ),
            (
                at("5.0\nangle_deg = 90.0"),
                "kind",
                "= \"tee\" takes branch_diameter_mm, not bend_radius_d or angle_deg",
            ),
            (
                set("branch_diameter_mm = 100.0", ""),
                "branch_diameter_mm",
                "a tee needs its branch's inner diameter",
            ),
            (
                set("= 100.0", "= 1000.0"),
                "branch_diameter_mm",
                "= 1000: must lie in (0, ",
            ),
            (
                set("\"tee\"", "\"elbow\""),
                "kind",
                "= \"elbow\" takes bend_radius_d and angle_deg, not branch_diameter_mm",
            ),
            (
                elbow("bend_radius_d = 0.5"),
                "bend_radius_d",
                "= 0.5: must lie in [0.75, 50] pipe diameters",
            ),
            (
                elbow("angle_deg = 181.0"),
                "angle_deg",
                "= 181: must lie in (0, 180]",
            ),
        ] {
            let k = if reason.contains("overlaps") { 1 } else { 0 };
            refused(&source, &format!("pipeline.fitting[{k}].{field}"), reason);
        }
    }

    #[test]
    fn student_t_quantiles() {
        // Tables: t(0.975; 9) = 2.262, 49 → 2.010, 1000 → 1.962.
        for (nu, t) in [(9.0, 2.262_157), (49.0, 2.009_575), (1000.0, 1.962_339)] {
            assert!((t95(nu) - t).abs() / t < 2e-3, "{nu}: {}", t95(nu));
        }
    }

    /// Regression: with a 256-cell mesh, the frame 0.4 m before the elbow made the
    /// survey's near-point restart cut the straight section to too few points, and the
    /// whole survey failed ("only 0 usable points") instead of saying `in_bend`.
    #[test]
    fn the_frame_before_the_elbow_is_surveyed_with_a_coarse_mesh() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenarios/pipeline_run.toml"
        ));
        let source = std::fs::read_to_string(path).expect("the committed scenario");
        let source = source.replace("[pipeline]\n", "[pipeline]\nmesh_segments = 256\n");
        let s = PipelineScenario::parse(path, &source).expect("a valid scenario");
        let plan = s
            .plans()
            .into_iter()
            .find(|p| (p.x - 17.6).abs() < 1e-9)
            .expect("a frame at 17.6 m");
        let (_, frame, _) = s.frame(&plan).expect("the frame");
        let (table, _) = calibrate(&s).expect("the rig's table");
        let intensity: Vec<f64> = frame.intensity.iter().map(|&i| i as f64).collect();
        let mut corrected = frame.measured.clone();
        table
            .correct_with_sigmas(&mut corrected, &intensity)
            .expect("the table applies");
        let opts = options(s.range_gate).expect("options");
        let sv = epd_core::segment::survey(
            &corrected,
            Method::MlEpd,
            &opts,
            &epd_core::segment::SegmentOptions::default(),
        )
        .expect("a verdict, not an error");
        // The elbow starts 0.4 m ahead: the survey must see a bend (today it says the
        // sensor is already in it, and the estimate is withheld).
        let layout = sv.segmentation.layout;
        assert!(
            matches!(layout, Layout::InBend | Layout::BendAhead),
            "{layout:?}"
        );
    }

    /// The frame 1 m before the elbow, corrected by the rig's table: the survey fits the
    /// bend, but most of its points lie where the straight rig never showed the camera's
    /// error (beyond its ranges, or brighter), so the radius is withheld with the reason,
    /// as `epd estimate` does; the fitted radius stays in the run's diagnostics.
    #[test]
    fn a_bend_the_rigs_table_did_not_observe_has_its_radius_withheld() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenarios/pipeline_run.toml"
        ));
        let source = std::fs::read_to_string(path).expect("the committed scenario");
        let s = PipelineScenario::parse(path, &source).expect("a valid scenario");
        let plan = s
            .plans()
            .into_iter()
            .find(|p| (p.x - 17.0).abs() < 1e-9)
            .expect("a frame at 17.0 m");
        let (_, frame, _) = s.frame(&plan).expect("the frame");
        let (table, _) = calibrate(&s).expect("the rig's table");
        let opts = options(s.range_gate).expect("options");
        let sv = Surveyed::of(&s, &table, &plan, &frame, &opts).expect("a verdict");
        let g = &sv.geometry;
        assert_eq!(g.found, "bend_ahead");
        assert!(g.bend_radius_fit_mm.is_some(), "the bend was fitted");
        let c = g.bend_table_coverage.expect("a coverage");
        assert!(
            c < epd_frame::scene::MIN_BEND_TABLE_COVERAGE,
            "coverage {c}"
        );
        assert_eq!(g.bend_radius_mm, None);
        assert!(!sv.withheld, "the straight estimate is still reported");
    }
}
