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

/// The largest pitch, yaw or tilt (rad): just under 90°, where the pipe's axis would be
/// perpendicular to the sensor's X axis and the model's cross-section (eq. 3) degenerates.
const MAX_TILT: f64 = 0.5 * std::f64::consts::PI - 1e-6;

const ROLL_RULE: &str = "must be a range [lo, hi] with lo ≤ hi within [−360°, 360°]";
const PITCH_RULE: &str = "must be a range [lo, hi] with lo ≤ hi within (−90°, 90°): at ±90° the \
                          pipe's axis is perpendicular to the sensor's X axis";
const YAW_RULE: &str = PITCH_RULE;
const TILT_RULE: &str = "must be an angle or a range [lo, hi] with lo ≤ hi within [0°, 90°): at \
                         90° the pipe's axis is perpendicular to the sensor's X axis, which then \
                         sees no pipe ahead";
const OFFSET_RULE: &str = "must be a finite range [lo, hi] with lo ≤ hi";

/// The unit a range is given in, in a scenario.
#[derive(Clone, Copy)]
enum Unit {
    Degrees,
    Millimetres,
}

/// An error naming `field` (values in `unit`) unless `lo`, `hi` are finite, lo ≤ hi, and
/// both lie in [min, max] (in SI units); `rule` says what a valid range is.
fn check_range(
    field: &'static str,
    (lo, hi): (f64, f64),
    unit: Unit,
    min: f64,
    max: f64,
    rule: &'static str,
) -> Result<(), SimError> {
    if lo.is_finite() && hi.is_finite() && lo <= hi && lo >= min && hi <= max {
        return Ok(());
    }
    // In the scenario's units, rounded to what a person wrote (to_radians and back
    // leaves 90.00000000000001).
    let shown = |v: f64| {
        let v = match unit {
            Unit::Degrees => v.to_degrees(),
            Unit::Millimetres => v * 1e3,
        };
        let r = (v * 1e9).round() / 1e9;
        if r.is_finite() { r } else { v }
    };
    let value = if lo == hi || (lo.is_nan() && hi.is_nan()) {
        format!("{}", shown(lo))
    } else {
        format!("[{}, {}]", shown(lo), shown(hi))
    };
    Err(SimError::invalid(field, value, rule))
}

impl PoseRanges {
    /// Check every range; the error names the first bad one, its values in the
    /// scenario's units (degrees, mm) and the rule it breaks.
    pub fn validate(&self) -> Result<(), SimError> {
        let pi = std::f64::consts::PI;
        check_range(
            "poses.roll_deg",
            self.roll,
            Unit::Degrees,
            -2.0 * pi,
            2.0 * pi,
            ROLL_RULE,
        )?;
        check_range(
            "poses.pitch_deg",
            self.pitch,
            Unit::Degrees,
            -MAX_TILT,
            MAX_TILT,
            PITCH_RULE,
        )?;
        check_range(
            "poses.yaw_deg",
            self.yaw,
            Unit::Degrees,
            -MAX_TILT,
            MAX_TILT,
            YAW_RULE,
        )?;
        check_range(
            "poses.dy_mm",
            self.dy,
            Unit::Millimetres,
            f64::MIN,
            f64::MAX,
            OFFSET_RULE,
        )?;
        check_range(
            "poses.dz_mm",
            self.dz,
            Unit::Millimetres,
            f64::MIN,
            f64::MAX,
            OFFSET_RULE,
        )?;
        if let Some(t) = self.tilt {
            check_range("poses.tilt_deg", t, Unit::Degrees, 0.0, MAX_TILT, TILT_RULE)?;
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
