//! The exact elliptic cylinder, a parry shape with a closed-form [`RayCast`].

use parry3d_f64::math::{Real, Vector};
use parry3d_f64::query::{Ray, RayCast, RayIntersection};
use parry3d_f64::shape::FeatureId;

/// The infinite elliptic cylinder y²/a² + z²/b² = 1 in its own frame (the PCS): axis
/// along X, semi-axis `a` along Y and `b` along Z (eq. 5 with a = Dmax/2, b = Dmin/2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EllipticCylinder {
    /// Semi-axis along Y (m).
    pub a: f64,
    /// Semi-axis along Z (m).
    pub b: f64,
}

impl EllipticCylinder {
    /// The cylinder with the given semi-axes (m).
    pub fn new(a: f64, b: f64) -> Self {
        Self { a, b }
    }

    /// The value of y²/a² + z²/b² − 1 at a point: < 0 inside, 0 on the wall.
    pub fn implicit(&self, p: Vector) -> f64 {
        (p.y / self.a).powi(2) + (p.z / self.b).powi(2) - 1.0
    }
}

impl EllipticCylinder {
    /// The time of impact of `ray` on the wall. The ray o + t·d meets it where
    /// A t² + 2B t + C = 0 with A = d_y²/a² + d_z²/b², B = o_y d_y/a² + o_z d_z/b²,
    /// C = o_y²/a² + o_z²/b² − 1. From inside (C < 0) the exit root is taken,
    /// t = −C/(B + √(B² − AC)) for B > 0 and (√(B² − AC) − B)/A otherwise (no
    /// cancellation); from outside, the entry root. `t` is in units of the ray's own
    /// direction, as parry's time of impact is. With `solid`, a ray starting inside hits
    /// at t = 0.
    #[inline]
    pub fn time_of_impact(&self, ray: &Ray, max_time_of_impact: Real, solid: bool) -> Option<Real> {
        let (ia2, ib2) = (1.0 / (self.a * self.a), 1.0 / (self.b * self.b));
        let (o, d) = (ray.origin, ray.dir);
        let qa = d.y * d.y * ia2 + d.z * d.z * ib2;
        let qb = o.y * d.y * ia2 + o.z * d.z * ib2;
        let qc = o.y * o.y * ia2 + o.z * o.z * ib2 - 1.0;
        let inside = qc < 0.0;
        if inside && solid {
            return Some(0.0);
        }
        if qa <= 0.0 {
            return None; // parallel to the axis: never meets the wall
        }
        let disc = qb * qb - qa * qc;
        if disc < 0.0 {
            return None;
        }
        let sq = disc.sqrt();
        let t = if inside {
            if qb > 0.0 {
                -qc / (qb + sq)
            } else {
                (sq - qb) / qa
            }
        } else {
            // Entry root, the smaller one; also cancellation-free.
            let t = if qb < 0.0 {
                qc / (sq - qb)
            } else {
                -(qb + sq) / qa
            };
            if t < 0.0 {
                return None;
            }
            t
        };
        (t <= max_time_of_impact).then_some(t)
    }
}

impl RayCast for EllipticCylinder {
    #[inline]
    fn cast_local_ray(&self, ray: &Ray, max_time_of_impact: Real, solid: bool) -> Option<Real> {
        self.time_of_impact(ray, max_time_of_impact, solid)
    }

    /// [`EllipticCylinder::time_of_impact`] with the outward normal of the wall.
    fn cast_local_ray_and_get_normal(
        &self,
        ray: &Ray,
        max_time_of_impact: Real,
        solid: bool,
    ) -> Option<RayIntersection> {
        let t = self.time_of_impact(ray, max_time_of_impact, solid)?;
        let p = ray.origin + ray.dir * t;
        let n = if t == 0.0 && solid {
            -ray.dir.normalize_or_zero()
        } else {
            // Outward normal: the gradient of the implicit function.
            Vector::new(0.0, p.y / (self.a * self.a), p.z / (self.b * self.b)).normalize_or_zero()
        };
        Some(RayIntersection::new(t, n, FeatureId::Face(0)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_aligned_cases() {
        let c = EllipticCylinder::new(0.25, 0.2);
        let ray = Ray::new(Vector::new(3.0, 0.0, 0.0), Vector::new(0.0, 1.0, 0.0));
        assert!((c.cast_local_ray(&ray, 10.0, false).unwrap() - 0.25).abs() < 1e-15);
        let ray = Ray::new(Vector::new(0.0, 0.0, 0.0), Vector::new(0.0, 0.0, -2.0));
        // Unnormalised direction: time of impact in units of the direction.
        assert!((c.cast_local_ray(&ray, 10.0, false).unwrap() - 0.1).abs() < 1e-15);
        let ray = Ray::new(Vector::new(0.0, 0.0, 0.0), Vector::new(1.0, 0.0, 0.0));
        assert!(c.cast_local_ray(&ray, 10.0, false).is_none());
        // From outside, the entry point.
        let ray = Ray::new(Vector::new(0.0, -1.0, 0.0), Vector::new(0.0, 1.0, 0.0));
        assert!((c.cast_local_ray(&ray, 10.0, false).unwrap() - 0.75).abs() < 1e-15);
        // Beyond max time of impact.
        let ray = Ray::new(Vector::new(0.0, 0.0, 0.0), Vector::new(0.0, 1.0, 0.0));
        assert!(c.cast_local_ray(&ray, 0.2, false).is_none());
        assert_eq!(c.cast_local_ray(&ray, 0.2, true), Some(0.0));
    }
}
