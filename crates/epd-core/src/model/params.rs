//! The parameter vector β of eq. (2) and the SCS → PCS transform of eq. (3).
//!
//! Frames (README, Conventions):
//! - **SCS**, sensor coordinate system: origin at the sensor centre, X forward
//!   (optical axis), Y right, Z up.
//! - **PCS**, pipe coordinate system: X along the pipe axis, Y along the major axis and
//!   Z along the minor axis of the elliptical cross-section; the inner wall is
//!   y²/(Dmax/2)² + z²/(Dmin/2)² = 1 (eq. 5).

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

/// Number of estimated parameters (eq. 2).
pub const N_PARAMS: usize = 7;

/// Names of the parameters in the order of eq. (2), for reports.
pub const PARAM_NAMES: [&str; N_PARAMS] = ["d_max", "d_min", "roll", "pitch", "yaw", "dy", "dz"];

/// β = (Dmax, Dmin, θx, θy, θz, δy, δz) of eq. (2): the pipe's diameters and the
/// sensor's pose in the pipe. Lengths in metres, angles in radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// Major-axis diameter Dmax of the elliptical cross-section (m), along PCS Y.
    pub d_max: f64,
    /// Minor-axis diameter Dmin of the elliptical cross-section (m), along PCS Z.
    pub d_min: f64,
    /// Roll θx (rad): rotation about X, applied first in eq. (3).
    pub roll: f64,
    /// Pitch θy (rad): rotation about Y, applied second in eq. (3).
    pub pitch: f64,
    /// Yaw θz (rad): rotation about Z, applied last in eq. (3).
    pub yaw: f64,
    /// δy (m): PCS Y coordinate of the sensor origin.
    pub dy: f64,
    /// δz (m): PCS Z coordinate of the sensor origin.
    pub dz: f64,
}

impl Params {
    /// The parameters as an array in the order of eq. (2).
    pub fn to_array(&self) -> [f64; N_PARAMS] {
        [
            self.d_max, self.d_min, self.roll, self.pitch, self.yaw, self.dy, self.dz,
        ]
    }

    /// Parameters from an array in the order of eq. (2).
    pub fn from_array(a: [f64; N_PARAMS]) -> Self {
        Self {
            d_max: a[0],
            d_min: a[1],
            roll: a[2],
            pitch: a[3],
            yaw: a[4],
            dy: a[5],
            dz: a[6],
        }
    }

    /// Whether every parameter is a finite number.
    pub fn is_finite(&self) -> bool {
        self.to_array().iter().all(|v| v.is_finite())
    }

    /// The rotation R = Rz(θz)·Ry(θy)·Rx(θx) of eq. (3), SCS → PCS.
    pub fn rotation(&self) -> Rotation3<f64> {
        rotation_zyx(self.roll, self.pitch, self.yaw)
    }

    /// The sensor origin in the PCS, x0_P = [0, δy, δz] (the image of the SCS origin
    /// under eq. 3).
    pub fn sensor_origin_pcs(&self) -> Point3<f64> {
        Point3::new(0.0, self.dy, self.dz)
    }

    /// Eq. (3): a point in the SCS mapped to the PCS.
    pub fn scs_to_pcs(&self, x_s: &Point3<f64>) -> Point3<f64> {
        self.rotation() * x_s + Vector3::new(0.0, self.dy, self.dz)
    }

    /// The inverse of eq. (3): a point in the PCS mapped to the SCS.
    pub fn pcs_to_scs(&self, x_p: &Point3<f64>) -> Point3<f64> {
        self.rotation().inverse() * (x_p - Vector3::new(0.0, self.dy, self.dz))
    }

    /// A direction in the SCS rotated into the PCS (no translation).
    pub fn dir_scs_to_pcs(&self, d_s: &Vector3<f64>) -> Vector3<f64> {
        self.rotation() * d_s
    }

    /// A direction in the PCS rotated into the SCS (no translation).
    pub fn dir_pcs_to_scs(&self, d_p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation().inverse() * d_p
    }

    /// The pose part re-expressed from a rotation matrix (SCS → PCS) and the offsets,
    /// keeping the diameters. The angles are the Z-Y-X Euler angles of `r`
    /// (pitch in [−90°, 90°]).
    pub fn with_rotation(&self, r: &Matrix3<f64>, dy: f64, dz: f64) -> Self {
        let (roll, pitch, yaw) = euler_zyx(r);
        Self {
            roll,
            pitch,
            yaw,
            dy,
            dz,
            ..*self
        }
    }

    /// Whether the sensor origin lies strictly inside the elliptical cross-section, the
    /// physical precondition of the model (a positive root t of eq. 22 exists).
    pub fn sensor_inside(&self) -> bool {
        if !(self.d_max > 0.0 && self.d_min > 0.0) {
            return false;
        }
        let a = 0.5 * self.d_max;
        let b = 0.5 * self.d_min;
        (self.dy / a).powi(2) + (self.dz / b).powi(2) < 1.0
    }
}

/// R = Rz(yaw)·Ry(pitch)·Rx(roll) with right-handed elementary rotations (eq. 3).
pub fn rotation_zyx(roll: f64, pitch: f64, yaw: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), roll)
}

/// The Z-Y-X Euler angles (roll, pitch, yaw) of a rotation matrix, the inverse of
/// [`rotation_zyx`] for pitch in (−90°, 90°).
pub fn euler_zyx(r: &Matrix3<f64>) -> (f64, f64, f64) {
    // R = Rz Ry Rx: R[2,0] = −sin θy, R[2,1] = cos θy sin θx, R[2,2] = cos θy cos θx,
    // R[1,0] = sin θz cos θy, R[0,0] = cos θz cos θy.
    let pitch = (-r[(2, 0)]).clamp(-1.0, 1.0).asin();
    let roll = r[(2, 1)].atan2(r[(2, 2)]);
    let yaw = r[(1, 0)].atan2(r[(0, 0)]);
    (roll, pitch, yaw)
}

/// An angle wrapped into [−π, π).
pub fn wrap_pi(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let w = (a + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    // rem_euclid can return exactly 2π for tiny negative inputs after rounding.
    if w >= std::f64::consts::PI {
        w - two_pi
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Params {
        Params {
            d_max: 0.49,
            d_min: 0.47,
            roll: 1.2,
            pitch: -0.07,
            yaw: 0.05,
            dy: 0.03,
            dz: -0.02,
        }
    }

    #[test]
    fn transform_roundtrip() {
        let p = sample();
        let x = Point3::new(1.3, -0.2, 0.1);
        let back = p.pcs_to_scs(&p.scs_to_pcs(&x));
        assert!((back - x).norm() < 1e-14);
    }

    #[test]
    fn rotation_order_is_zyx() {
        // Only yaw: the SCS X axis turns towards PCS +Y.
        let r = rotation_zyx(0.0, 0.0, 0.5);
        let v = r * Vector3::x();
        assert!((v - Vector3::new(0.5f64.cos(), 0.5f64.sin(), 0.0)).norm() < 1e-15);
        // Composite equals the product of elementary matrices written out by hand.
        let (a, b, c) = (0.3f64, -0.2f64, 0.7f64);
        let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, a.cos(), -a.sin(), 0.0, a.sin(), a.cos());
        let ry = Matrix3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
        let rz = Matrix3::new(c.cos(), -c.sin(), 0.0, c.sin(), c.cos(), 0.0, 0.0, 0.0, 1.0);
        let m = rz * ry * rx;
        assert!((rotation_zyx(a, b, c).matrix() - m).norm() < 1e-15);
    }

    #[test]
    fn euler_roundtrip() {
        for &(r, p, y) in &[(0.1, 0.2, 0.3), (-3.0, 0.25, -0.1), (2.9, -1.2, 3.1)] {
            let m = rotation_zyx(r, p, y);
            let (r2, p2, y2) = euler_zyx(m.matrix());
            assert!((wrap_pi(r2 - r)).abs() < 1e-12);
            assert!((p2 - p).abs() < 1e-12);
            assert!((wrap_pi(y2 - y)).abs() < 1e-12);
        }
    }

    #[test]
    fn wrap_range() {
        for a in [-10.0, -std::f64::consts::PI, 0.0, std::f64::consts::PI, 7.0] {
            let w = wrap_pi(a);
            assert!((-std::f64::consts::PI..std::f64::consts::PI).contains(&w));
            assert!(((a - w) / std::f64::consts::TAU).fract().abs() < 1e-12);
        }
    }

    #[test]
    fn sensor_inside_checks_ellipse() {
        let mut p = sample();
        assert!(p.sensor_inside());
        p.dy = 0.3;
        assert!(!p.sensor_inside());
        p.dy = 0.0;
        p.d_min = -1.0;
        assert!(!p.sensor_inside());
    }
}
