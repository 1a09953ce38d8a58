//! Random sensor poses in the pipe (SPEC §5).

use epd_core::Params;
use rand::RngExt;

use crate::error::SimError;
use crate::noise::{Stream, stream};
use crate::pipe::Pipe;

/// Uniform ranges [lo, hi] of the pose parameters: angles in radians, offsets in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseRanges {
    /// Roll θx.
    pub roll: (f64, f64),
    /// Pitch θy.
    pub pitch: (f64, f64),
    /// Yaw θz.
    pub yaw: (f64, f64),
    /// δy.
    pub dy: (f64, f64),
    /// δz.
    pub dz: (f64, f64),
}

impl Default for PoseRanges {
    /// The paper's ranges (§4.1): roll U[−180°, 180°), pitch and yaw U[−5°, 5°],
    /// δy and δz U[−50, 50] mm.
    fn default() -> Self {
        let d = |x: f64| x.to_radians();
        Self {
            roll: (d(-180.0), d(180.0)),
            pitch: (d(-5.0), d(5.0)),
            yaw: (d(-5.0), d(5.0)),
            dy: (-0.05, 0.05),
            dz: (-0.05, 0.05),
        }
    }
}

impl PoseRanges {
    /// Check every range; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SimError> {
        let check = |field: &'static str, (lo, hi): (f64, f64), limit: f64| {
            if lo.is_finite()
                && hi.is_finite()
                && lo <= hi
                && lo.abs() <= limit
                && hi.abs() <= limit
            {
                Ok(())
            } else {
                Err(SimError::invalid(
                    field,
                    format!("[{lo}, {hi}]"),
                    "must be a finite range [lo, hi] with lo ≤ hi",
                ))
            }
        };
        let pi = std::f64::consts::PI;
        check("poses.roll_deg", self.roll, 2.0 * pi)?;
        check("poses.pitch_deg", self.pitch, 0.5 * pi - 1e-6)?;
        check("poses.yaw_deg", self.yaw, 0.5 * pi - 1e-6)?;
        check("poses.dy_mm", self.dy, f64::MAX)?;
        check("poses.dz_mm", self.dz, f64::MAX)?;
        Ok(())
    }

    /// The pose of trial `trial`: a pure function of (seed, trial). Errors when the
    /// drawn offsets put the sensor outside the pipe's cross-section.
    pub fn sample(&self, pipe: &Pipe, seed: u64, trial: u64) -> Result<Params, SimError> {
        self.validate()?;
        pipe.validate()?;
        let mut rng = stream(seed, trial, 0, Stream::Pose, 0);
        let mut u = |(lo, hi): (f64, f64)| {
            if hi > lo {
                rng.random_range(lo..hi)
            } else {
                lo
            }
        };
        let roll = u(self.roll);
        let pitch = u(self.pitch);
        let yaw = u(self.yaw);
        let dy = u(self.dy);
        let dz = u(self.dz);
        let p = Params {
            d_max: pipe.d_max(),
            d_min: pipe.d_min(),
            roll,
            pitch,
            yaw,
            dy,
            dz,
        };
        check_inside(&p)?;
        Ok(p)
    }
}

/// An error when the sensor origin is not strictly inside the pipe's cross-section.
pub fn check_inside(p: &Params) -> Result<(), SimError> {
    if p.sensor_inside() {
        Ok(())
    } else {
        Err(SimError::invalid(
            "poses.dy_mm/dz_mm",
            format!("({:.1}, {:.1}) mm", p.dy * 1e3, p.dz * 1e3),
            "puts the sensor outside the pipe: narrow the offset ranges",
        ))
    }
}
