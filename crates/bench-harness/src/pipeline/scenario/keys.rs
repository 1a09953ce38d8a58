//! A pipeline scenario as written: its tables in file units (mm, degrees, inches), the
//! defaults of the keys left out, and each table checked and turned into SI units. Errors
//! name the key.

use serde::Deserialize;
use tof_sim::{MeshResolution, Pipe, ToFPhysics};

use super::super::plan::Drift;
use super::Section;
use crate::route::FittingKind;
use crate::scenario::{KeyError, key_err};

/// One straight section as written in the scenario.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SectionFile {
    pub(super) name: String,
    #[serde(default = "crate::defaults::nominal_od_in")]
    pub(super) nominal_od_in: f64,
    pub(super) wall_mm: f64,
    #[serde(default)]
    pub(super) ovality: f64,
    /// Odometer distance of the first frame (m).
    pub(super) start_m: f64,
}

/// A fitting between sections as written (`[[pipeline.fitting]]`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FittingFile {
    /// `tee` or `elbow`.
    pub(super) kind: String,
    /// Odometer distance where it begins (m).
    pub(super) at_m: f64,
    /// Tee: the branch's inner diameter (mm).
    pub(super) branch_diameter_mm: Option<f64>,
    /// Elbow: centreline radius in pipe diameters (default 1.5, long radius).
    pub(super) bend_radius_d: Option<f64>,
    /// Elbow: angle (degrees, default 90).
    pub(super) angle_deg: Option<f64>,
    /// Toward (0, cos φ, sin φ) of the incoming straight's PCS (degrees).
    #[serde(default)]
    pub(super) direction_deg: f64,
}

/// The calibration rig as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RigFile {
    pub(super) nominal_od_in: f64,
    pub(super) wall_mm: f64,
    #[serde(default = "default_rig_frames")]
    pub(super) frames: usize,
    #[serde(default = "default_range_bins")]
    pub(super) range_bins: usize,
    #[serde(default = "default_intensity_bins")]
    pub(super) intensity_bins: usize,
    /// Bins of the ln cos θ axis of a version-2 (incidence) table; 0: the range ×
    /// intensity table alone.
    #[serde(default)]
    pub(super) incidence_bins: usize,
    /// Amplitude of the sensor's offset from the rig's axis (mm): off the axis the rig
    /// shows each range at more incidence angles, hence intensities.
    #[serde(default = "default_rig_offset_mm")]
    pub(super) offset_mm: f64,
    /// Passes of the alternating pose/table refinement.
    #[serde(default = "default_calibration_passes")]
    pub(super) passes: usize,
}

/// The pose drift along the distance, as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DriftFile {
    #[serde(default)]
    pub(super) roll_deg_per_m: f64,
    #[serde(default)]
    pub(super) tilt_deg: f64,
    #[serde(default = "default_tilt_period_m")]
    pub(super) tilt_period_m: f64,
    #[serde(default)]
    pub(super) offset_mm: f64,
    #[serde(default = "default_offset_period_m")]
    pub(super) offset_period_m: f64,
}

/// Changes to the sensor preset's error model (`tof_sim::ToFPhysics` fields).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SensorModelFile {
    pub(super) reflectivity: Option<f64>,
    pub(super) sigma_ref_m: Option<f64>,
    pub(super) ambient: Option<f64>,
    pub(super) wiggle_amplitude_m: Option<f64>,
    pub(super) amplitude_offset_m_per_ln: Option<f64>,
    pub(super) multipath_ratio: Option<f64>,
    pub(super) multipath_extra_path_m: Option<f64>,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct PipelineFile {
    #[serde(default = "default_frames_per_section")]
    pub(super) frames_per_section: usize,
    #[serde(default = "default_frame_spacing_m")]
    pub(super) frame_spacing_m: f64,
    #[serde(default = "default_range_gate_m")]
    pub(super) range_gate_m: [f64; 2],
    #[serde(default = "default_sensor")]
    pub(super) sensor: String,
    #[serde(default)]
    pub(super) sensor_model: SensorModelFile,
    pub(super) section: Vec<SectionFile>,
    pub(super) rig: RigFile,
    pub(super) drift: DriftFile,
    #[serde(default)]
    pub(super) fitting: Vec<FittingFile>,
    /// Mesh cells around the pipe for frames that see a fitting.
    #[serde(default = "default_mesh_segments")]
    pub(super) mesh_segments: usize,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct File {
    pub(super) name: String,
    #[serde(default = "crate::defaults::seed")]
    pub(super) seed: u64,
    pub(super) pipeline: PipelineFile,
}

/// `pipeline.rig.frames`: 20 rig frames, as the committed `scenarios/pipeline_run.toml`
/// (the paper does not say how many frames its calibration aggregated).
fn default_rig_frames() -> usize {
    20
}

/// `pipeline.rig.range_bins`: the depth table's range bins over the gate, as `epd
/// calibrate --range-bins` by default.
fn default_range_bins() -> usize {
    30
}

/// `pipeline.rig.intensity_bins`: the depth table's intensity bins, as `epd calibrate
/// --intensity-bins` by default (the committed `scenarios/pipeline_run.toml` sets 24).
fn default_intensity_bins() -> usize {
    12
}

/// `pipeline.rig.offset_mm`: the sensor's offset from the rig's axis, a harness default
/// (the committed `scenarios/pipeline_run.toml` sets 20 mm, the run's own drift).
fn default_rig_offset_mm() -> f64 {
    60.0
}

/// `pipeline.rig.passes`: passes of the alternating pose/table refinement, as `epd
/// calibrate` makes by default ([`epd_frame::rig::DEFAULT_PASSES`]).
fn default_calibration_passes() -> usize {
    epd_frame::rig::DEFAULT_PASSES as usize
}

/// `pipeline.drift.tilt_period_m`: the tilt wanders on a 5 m period, as the committed
/// `scenarios/pipeline_run.toml`.
fn default_tilt_period_m() -> f64 {
    5.0
}

/// `pipeline.drift.offset_period_m`: the offsets wander on a 7 m period, as the committed
/// `scenarios/pipeline_run.toml`.
fn default_offset_period_m() -> f64 {
    7.0
}

/// `pipeline.frames_per_section`: the paper's 50 frames in each straight section (§4.2).
fn default_frames_per_section() -> usize {
    50
}

/// `pipeline.frame_spacing_m`: 0.2 m of odometer between frames, a harness default (the
/// paper does not give its robot's spacing).
fn default_frame_spacing_m() -> f64 {
    0.2
}

/// `pipeline.range_gate_m`: the paper kept the points within [0.5, 2] m (§4.2).
fn default_range_gate_m() -> [f64; 2] {
    [0.5, 2.0]
}

/// `pipeline.sensor`: the paper's camera, a Helios2 (`tof_sim::ToFPhysics::helios2`, the
/// one preset).
fn default_sensor() -> String {
    "helios2".into()
}

/// `pipeline.mesh_segments`: cells around the pipe of a mesh with a fitting; 256 made the
/// survey of the frame before the elbow fail (the regression test in `rows.rs`).
fn default_mesh_segments() -> usize {
    512
}

impl FittingFile {
    /// The sections around the fitting (at a finite `at_m`): the last one starting
    /// before it and the next; else what is wrong with `at_m`.
    pub(super) fn neighbours<'a>(
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
    pub(super) fn kind(&self, k: usize, a: &Section, b: &Section) -> Result<FittingKind, KeyError> {
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
pub(super) fn pipe_of(
    key: &str,
    nominal_od_in: f64,
    wall_mm: f64,
    ovality: f64,
) -> Result<Pipe, KeyError> {
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
    pub(super) fn gate(&self) -> Result<(f64, f64), KeyError> {
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
    pub(super) fn physics(&self) -> Result<ToFPhysics, KeyError> {
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
    pub(super) fn sections(&self) -> Result<Vec<Section>, KeyError> {
        if self.section.is_empty() || self.section.len() > 100 {
            return Err(key_err(
                "pipeline.section",
                format!("has {} sections: list 1 to 100", self.section.len()),
            ));
        }
        let mut sections = Vec::new();
        for (k, s) in self.section.iter().enumerate() {
            let key = format!("pipeline.section[{k}]");
            // Any text a CSV cell can hold (`epd_io::csv` quotes commas and quotes), but no
            // control character: the name is a label in the figures too.
            if s.name.is_empty() || s.name.chars().any(char::is_control) {
                return Err(key_err(
                    &format!("{key}.name"),
                    format!(
                        "= {:?}: a non-empty name without control characters",
                        s.name
                    ),
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
    pub(super) fn mesh(&self) -> Result<MeshResolution, KeyError> {
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
    pub(super) fn pipe(&self) -> Result<Pipe, KeyError> {
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
        if self.incidence_bins > 1000 {
            return Err(key_err(
                "pipeline.rig.incidence_bins",
                format!(
                    "= {}: must lie in [0, 1000] (0: no incidence axis)",
                    self.incidence_bins
                ),
            ));
        }
        Ok(rig)
    }

    /// The pose along the rig: the run's `drift` with the rig's offset amplitude (mm → m).
    pub(super) fn drift(&self, drift: Drift) -> Result<Drift, KeyError> {
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
    pub(super) fn to_drift(&self) -> Result<Drift, KeyError> {
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
