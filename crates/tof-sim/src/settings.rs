//! What `epd simulate` does for one frame, shared by the `epd` binary and the Python
//! package (`epd.simulate`): the checked settings ([`Simulator::new`]), the frame
//! ([`Simulator::frame`]) and its ground truth as the fields of the JSON file written
//! beside it ([`truth_fields`]).

use std::num::NonZeroUsize;

use crate::{
    Frame, FrameSeed, Noise, NoiseModel, Pipe, PoseRanges, Scene, Sensor, SimError, Subsample,
    WallModel, simulate_into,
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
}

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
        Ok(Simulator {
            pipe,
            noise,
            sub,
            sensor,
            seed: a.seed,
            helios2: a.helios2,
            pose: a.pose,
        })
    }

    /// Simulate frame `k` (the pose of trial `k` of the seed) into `frame`.
    pub fn frame(&self, k: u64, frame: &mut Frame) -> Result<(), SimulateError> {
        let mut truth = PoseRanges::default().sample(&self.pipe, self.seed, k)?;
        self.apply_pose(&mut truth)?;
        let scene = Scene::new(&truth, WallModel::Exact, self.sensor.max_range)?;
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
    pub fn truth(&self, k: u64, frame: &Frame) -> Vec<(&'static str, Field)> {
        truth_fields(
            &frame.truth,
            frame.len(),
            self.seed,
            k,
            self.noise.sigma,
            self.noise.outlier_fraction,
            if self.helios2 { "helios2" } else { "plain" },
        )
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
