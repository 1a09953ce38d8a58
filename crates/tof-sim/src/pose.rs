//! Random sensor poses in the pipe (README, Conventions).

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
    /// When set, the tilt T (the angle between the pipe axis and the sensor's X axis)
    /// is drawn from this range with a uniform azimuth ψ, and replaces the pitch and
    /// yaw ranges: pitch = atan(tan T·sin ψ), yaw = ±acos(cos T/cos pitch) with the
    /// sign of cos ψ, so that cos T = cos(pitch)·cos(yaw) (the (0,0) entry of eq. 3's R).
    pub tilt: Option<(f64, f64)>,
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
            tilt: None,
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
        if let Some(t) = self.tilt {
            check("poses.tilt_deg", t, 0.5 * pi - 1e-6)?;
            if t.0 < 0.0 {
                return Err(SimError::invalid(
                    "poses.tilt_deg",
                    format!("[{}, {}]", t.0, t.1),
                    "must lie in [0°, 90°)",
                ));
            }
        }
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
        let mut pitch = u(self.pitch);
        let mut yaw = u(self.yaw);
        let dy = u(self.dy);
        let dz = u(self.dz);
        if let Some(t) = self.tilt {
            // Drawn after the others, so the other parameters do not depend on it.
            let tilt = u(t);
            let psi = u((0.0, std::f64::consts::TAU));
            pitch = (tilt.tan() * psi.sin()).atan();
            yaw = (tilt.cos() / pitch.cos()).clamp(-1.0, 1.0).acos() * psi.cos().signum();
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_set_tilt_is_the_angle_between_the_axes() {
        let pipe = Pipe::paper_20in();
        for t in [0.0f64, 5.0, 12.5, 20.0] {
            let ranges = PoseRanges {
                tilt: Some((t.to_radians(), t.to_radians())),
                ..PoseRanges::default()
            };
            let mut seen = [false; 4];
            for k in 0..200 {
                let p = ranges.sample(&pipe, 3, k).unwrap();
                // cos T = R[0][0], the X component of the PCS axis in the SCS.
                let r = p.rotation();
                let tilt = r.matrix()[(0, 0)].clamp(-1.0, 1.0).acos();
                assert!((tilt - t.to_radians()).abs() < 1e-9, "{t}: {p:?}");
                seen[usize::from(p.pitch > 0.0) * 2 + usize::from(p.yaw > 0.0)] = true;
            }
            // Every azimuth quadrant occurs.
            if t > 0.0 {
                assert_eq!(seen, [true; 4], "tilt {t}");
            }
        }
    }
}
