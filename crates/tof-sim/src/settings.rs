//! What `epd simulate` does for one frame, shared by the `epd` binary and the Python
//! package (`epd.simulate`): the checked settings ([`Simulator::new`]), the frame
//! ([`Simulator::frame`]) and its ground truth as the fields of the JSON file written
//! beside it ([`truth_fields`]).

use std::num::NonZeroUsize;

use crate::{
    Frame, FrameSeed, MeshResolution, Noise, NoiseModel, Pipe, Pipeline, PoseRanges, Scene,
    Segment, Sensor, SimError, Subsample, WallModel, simulate_into,
};
use epd_core::Params;
use epd_core::report::Field;

/// The settings of `epd simulate` as given.
#[derive(Clone, Debug, PartialEq)]
pub struct SimulateSettings {
    /// Seed of the poses and the noise.
    pub seed: u64,
    /// Standard deviation of the depth noise (m); not used by the Helios2 model.
    pub sigma: f64,
    /// Nominal outer diameter (inch).
    pub od_in: f64,
    /// Ovality (Dmax − Dmin)/ID.
    pub ovality: f64,
    /// Wall thickness (mm).
    pub wall_mm: f64,
    /// Keep a uniform subsample of this many points (`None`: all).
    pub points: Option<NonZeroUsize>,
    /// Fraction of range outliers.
    pub outliers: f64,
    /// Noise model of the plain sensor.
    pub noise: NoiseModel,
    /// The realistic Helios2 error model instead of plain noise of `sigma`.
    pub helios2: bool,
    /// Pose parameters to use instead of the sampled ones (radians, metres).
    pub pose: PoseOverride,
    /// A bend or a tee ahead of the sensor (`None`: a straight pipe).
    pub feature: Option<Feature>,
}

/// What lies ahead of the sensor in a simulated frame (`epd simulate --bend-at M` /
/// `--tee-at M`), as in the `elbow_approach` and `tee_pass` scenarios.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Feature {
    /// A 90° long-radius elbow ([`BEND_RADIUS_D`] × the mean inner diameter) starting this
    /// far ahead of the sensor along the pipe (m), turning toward [`FEATURE_DIRECTION_DEG`].
    BendAt(f64),
    /// A tee whose branch ([`TEE_BRANCH_D`] × the mean inner diameter) opens this far ahead
    /// of the sensor along the pipe (m: the opening's near edge), toward
    /// [`FEATURE_DIRECTION_DEG`].
    TeeAt(f64),
}

/// A simulated bend's centreline radius in mean inner diameters: 1.5, a long-radius elbow
/// (ASME B16.9), as in the `elbow_approach` scenario.
pub const BEND_RADIUS_D: f64 = 1.5;

/// A simulated tee's branch diameter in mean inner diameters: 0.6, the `tee_pass`
/// scenario's 300 mm branch on a 20" pipe (0.62 of its 484 mm inner diameter).
pub const TEE_BRANCH_D: f64 = 0.6;

/// The direction of a simulated bend's turn or tee's branch in the pipe frame (deg from
/// the major axis toward the minor one): 40°, the scenarios' (neither axis, so that the
/// roll matters).
pub const FEATURE_DIRECTION_DEG: f64 = 40.0;

/// The farthest a simulated feature may start (m): 20 m, beyond the Helios2's 8.3 m
/// reach (the frame is then straight) and the scenarios' limit.
pub const MAX_FEATURE_DISTANCE_M: f64 = 20.0;

/// The straight pipe after a simulated bend or tee (m): 6 m, past the camera's reach
/// seen through the feature.
const AFTER_FEATURE_M: f64 = 6.0;

/// Pose parameters given instead of drawn from the paper's ranges; `None` keeps the
/// drawn value.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseOverride {
    /// Roll θx (rad).
    pub roll: Option<f64>,
    /// Pitch θy (rad).
    pub pitch: Option<f64>,
    /// Yaw θz (rad).
    pub yaw: Option<f64>,
    /// δy (m).
    pub dy: Option<f64>,
    /// δz (m).
    pub dz: Option<f64>,
}

/// Why a frame cannot be simulated.
#[derive(Clone, Debug, thiserror::Error)]
pub enum SimulateError {
    /// A setting out of its range (the `epd` binary's usage error, exit code 2).
    #[error("{0}")]
    Setting(String),
    /// The simulator refused the configuration.
    #[error(transparent)]
    Sim(#[from] SimError),
}

/// Checked settings of `epd simulate`: makes frame after frame.
#[derive(Clone, Debug)]
pub struct Simulator {
    pipe: Pipe,
    noise: Noise,
    sub: Subsample,
    sensor: Sensor,
    seed: u64,
    helios2: bool,
    pose: PoseOverride,
    feature: Option<Feature>,
}

impl Simulator {
    /// Check the settings.
    pub fn new(a: &SimulateSettings) -> Result<Self, SimulateError> {
        let pipe = Pipe {
            nominal_od_in: a.od_in,
            wall_thickness: a.wall_mm * 1e-3,
            ovality: a.ovality,
        };
        let noise = Noise {
            model: a.noise,
            sigma: a.sigma,
            outlier_fraction: a.outliers,
            far_outlier_fraction: 0.0,
            bias_b0: 0.0,
            bias_b1: 0.0,
            physics: a.helios2.then(crate::ToFPhysics::helios2),
        };
        let sub = match a.points {
            None => Subsample::All,
            Some(n) => Subsample::Points(n.get()),
        };
        let sensor = Sensor::helios2();
        sensor.validate()?;
        noise
            .validate()
            .map_err(|e| SimulateError::Setting(e.to_string()))?;
        pipe.validate()
            .map_err(|e| SimulateError::Setting(e.to_string()))?;
        let p = a.pose;
        for (name, v, limit) in [
            ("roll", p.roll, f64::INFINITY),
            ("pitch", p.pitch, std::f64::consts::FRAC_PI_2),
            ("yaw", p.yaw, std::f64::consts::FRAC_PI_2),
            ("dy", p.dy, f64::INFINITY),
            ("dz", p.dz, f64::INFINITY),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v.abs() < limit)
            {
                return Err(SimulateError::Setting(format!(
                    "pose {name} = {v}: expected a finite value{}",
                    if limit.is_finite() {
                        " between −90° and 90°"
                    } else {
                        ""
                    }
                )));
            }
        }
        if let Some(f) = a.feature {
            let (flag, at) = match f {
                Feature::BendAt(m) => ("bend_at", m),
                Feature::TeeAt(m) => ("tee_at", m),
            };
            if !(at > 0.0 && at <= MAX_FEATURE_DISTANCE_M) {
                return Err(SimulateError::Setting(format!(
                    "{flag} = {at} m: expected a distance ahead of the sensor in (0, \
                     {MAX_FEATURE_DISTANCE_M}] m"
                )));
            }
        }
        Ok(Simulator {
            pipe,
            noise,
            sub,
            sensor,
            seed: a.seed,
            helios2: a.helios2,
            pose: a.pose,
            feature: a.feature,
        })
    }

    /// Simulate frame `k` (the pose of trial `k` of the seed) into `frame`.
    pub fn frame(&self, k: u64, frame: &mut Frame) -> Result<(), SimulateError> {
        let mut truth = PoseRanges::default().sample(&self.pipe, self.seed, k)?;
        self.apply_pose(&mut truth)?;
        let scene = match self.pipeline(&truth) {
            None => Scene::new(&truth, WallModel::Exact, self.sensor.max_range)?,
            Some(p) => Scene::pipeline(&truth, &p, &MeshResolution::default())?,
        };
        simulate_into(
            &self.sensor,
            &scene,
            &self.noise,
            self.sub,
            FrameSeed {
                seed: self.seed,
                trial: k,
                sweep_index: 0,
            },
            frame,
        )?;
        Ok(())
    }

    /// The pipeline of the feature ahead, in the pipe frame of `truth` (`None`: straight),
    /// built as the `elbow_approach` and `tee_pass` scenarios build theirs.
    pub fn pipeline(&self, truth: &Params) -> Option<Pipeline> {
        let (d_max, d_min) = (truth.d_max, truth.d_min);
        let d = 0.5 * (d_max + d_min);
        let direction = FEATURE_DIRECTION_DEG.to_radians();
        Some(match self.feature? {
            Feature::BendAt(at) => Pipeline::with_one_bend(
                d_max,
                d_min,
                -1.0,
                at,
                Segment::Bend {
                    radius: BEND_RADIUS_D * d,
                    angle: std::f64::consts::FRAC_PI_2,
                    direction,
                },
                AFTER_FEATURE_M,
            ),
            Feature::TeeAt(at) => {
                // The opening's near edge at `at`: a main run of 2·b whose branch is
                // centred at its middle.
                let b = TEE_BRANCH_D * d;
                let len = 2.0 * b;
                Pipeline {
                    d_max,
                    d_min,
                    bend_diameter: None,
                    start_x: -1.0,
                    segments: vec![
                        Segment::Straight {
                            length: 1.0 + at - 0.5 * (len - b),
                        },
                        Segment::Tee {
                            length: len,
                            branch_diameter: b,
                            direction,
                        },
                        Segment::Straight {
                            length: AFTER_FEATURE_M,
                        },
                    ],
                }
            }
        })
    }

    /// The given pose parameters in place of the drawn ones; the sensor must stay inside
    /// the pipe.
    fn apply_pose(&self, truth: &mut Params) -> Result<(), SimulateError> {
        let p = self.pose;
        truth.roll = p.roll.unwrap_or(truth.roll);
        truth.pitch = p.pitch.unwrap_or(truth.pitch);
        truth.yaw = p.yaw.unwrap_or(truth.yaw);
        truth.dy = p.dy.unwrap_or(truth.dy);
        truth.dz = p.dz.unwrap_or(truth.dz);
        let (a, b) = (truth.d_max / 2.0, truth.d_min / 2.0);
        if (p.dy.is_some() || p.dz.is_some())
            && (truth.dy / a).powi(2) + (truth.dz / b).powi(2) >= 1.0
        {
            return Err(SimulateError::Setting(format!(
                "pose δy = {} mm, δz = {} mm: the sensor would be outside the pipe \
                 (semi-axes {} and {} mm)",
                truth.dy * 1e3,
                truth.dz * 1e3,
                a * 1e3,
                b * 1e3
            )));
        }
        Ok(())
    }

    /// The ground truth of a frame made by [`Simulator::frame`] as `epd simulate` writes
    /// it, frame `k`: see [`truth_fields`].
    /// With a feature ahead, two more fields: `geometry` (`bend_ahead` or `tee_ahead`)
    /// and `straight_until_m` (where the straight section ends, m ahead).
    pub fn truth(&self, k: u64, frame: &Frame) -> Vec<(&'static str, Field)> {
        let mut f = truth_fields(
            &frame.truth,
            frame.len(),
            self.seed,
            k,
            self.noise.sigma,
            self.noise.outlier_fraction,
            if self.helios2 { "helios2" } else { "plain" },
        );
        if let Some(feature) = self.feature {
            let (layout, at) = match feature {
                Feature::BendAt(m) => ("bend_ahead", m),
                Feature::TeeAt(m) => ("tee_ahead", m),
            };
            f.push(("geometry", Field::Text(layout.into())));
            f.push(("straight_until_m", Field::Num(at)));
        }
        f
    }
}

/// The ground-truth fields `epd simulate` writes beside each frame (JSON), in order:
/// `d_max_mm, d_min_mm, roll_deg, pitch_deg, yaw_deg, dy_mm, dz_mm` (the canonical form
/// of `truth`), `n_points, seed, trial, sigma_m, outlier_fraction, sensor`.
pub fn truth_fields(
    truth: &Params,
    n_points: usize,
    seed: u64,
    trial: u64,
    sigma_m: f64,
    outlier_fraction: f64,
    sensor: &str,
) -> Vec<(&'static str, Field)> {
    let t = epd_core::canonicalize(truth);
    let deg = 180.0 / std::f64::consts::PI;
    vec![
        ("d_max_mm", Field::Num(t.d_max * 1e3)),
        ("d_min_mm", Field::Num(t.d_min * 1e3)),
        ("roll_deg", Field::Num(t.roll * deg)),
        ("pitch_deg", Field::Num(t.pitch * deg)),
        ("yaw_deg", Field::Num(t.yaw * deg)),
        ("dy_mm", Field::Num(t.dy * 1e3)),
        ("dz_mm", Field::Num(t.dz * 1e3)),
        ("n_points", Field::Int(n_points as u64)),
        ("seed", Field::Int(seed)),
        ("trial", Field::Int(trial)),
        ("sigma_m", Field::Num(sigma_m)),
        ("outlier_fraction", Field::Num(outlier_fraction)),
        ("sensor", Field::Text(sensor.into())),
    ]
}
