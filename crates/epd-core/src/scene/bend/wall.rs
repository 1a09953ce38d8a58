//! The wall of a bend of angle Θ: the torus piece it turns through, then the straight
//! outlet that leaves it tangentially.
//!
//! In the PCS of the straight fit, with the bend's start x₀, turn direction
//! u = (0, cos φ, sin φ), centreline radius R and tube radius r (see the parent module),
//! the centre of curvature is c = (x₀, R cos φ, R sin φ). A point p has turned by
//! α(p) = atan2(p'ₓ, −p'·u), p' = p − c ([`BendGeometry::turned`]): 0 in the start's plane
//! x = x₀, in (0, π] past it. The bend ends at α = Θ, where its centreline point is
//! E = c + R·(−cos Θ·u + sin Θ·x̂) and its tangent T = cos Θ·x̂ + sin Θ·u; the outlet is
//! the round cylinder of radius r about the line E + t·T, t ≥ 0, continuing the tube
//! with a continuous tangent plane (the torus and the cylinder share the circle at α = Θ
//! and their normals there).
//!
//! A point belongs to the outlet when α(p) > Θ, else to the torus. For Θ ≤ π/2 every
//! outlet point has x > x₀ (its x − x₀ ≥ (R − r)·sin Θ), so α never wraps past π on it;
//! for larger Θ (a return bend) the outlet's far part wraps and is read as torus — the
//! model is meant for elbows up to 90°, and a bend open past everything seen (Θ = π,
//! [`OPEN_ANGLE`]) has no outlet at all.

use nalgebra::{Unit, Vector3};

use super::BendGeometry;
use crate::torus::Torus;

/// The angle of a bend whose end is not seen: the torus runs to α = π, no outlet.
pub const OPEN_ANGLE: f64 = std::f64::consts::PI;

/// Which piece of a bend's wall a point or a ray's exit belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Piece {
    /// The torus, α ∈ [0, Θ] (or before the start, α < 0).
    Torus,
    /// The straight outlet past the bend's end, α > Θ.
    Outlet,
}

/// A bend's wall: its placement, the torus and the outlet's line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BendWall {
    /// The placement.
    pub geometry: BendGeometry,
    /// The torus of the turned part.
    pub torus: Torus,
    /// The outlet axis's start E (the centreline point at α = Θ) and unit direction T;
    /// `None` for an open bend (Θ ≥ π).
    outlet: Option<(Vector3<f64>, Vector3<f64>)>,
}

impl BendWall {
    /// The wall of `geometry`; `None` when its torus is not a ring torus, a value is not
    /// finite, or Θ ≤ 0.
    pub fn new(geometry: &BendGeometry) -> Option<Self> {
        let torus = geometry.torus()?;
        if !(geometry.angle > 0.0) {
            return None;
        }
        let outlet = (geometry.angle < OPEN_ANGLE).then(|| {
            let (s, c) = geometry.direction.sin_cos();
            let u = Vector3::new(0.0, c, s);
            let (sa, ca) = geometry.angle.sin_cos();
            let end = torus.centre + geometry.radius * (-ca * u + sa * Vector3::x());
            (end, ca * Vector3::x() + sa * u)
        });
        Some(Self {
            geometry: *geometry,
            torus,
            outlet,
        })
    }

    /// The piece `p` belongs to: the outlet when the bend has one and α(p) > Θ.
    #[inline]
    pub fn piece(&self, p: &Vector3<f64>) -> Piece {
        if self.outlet.is_some() && self.geometry.turned(p) > self.geometry.angle {
            Piece::Outlet
        } else {
            Piece::Torus
        }
    }

    /// `p`'s offset from the outlet's axis, p − E − ((p − E)·T)·T, when it lies on the
    /// outlet (past the end); `None` on the torus or for an open bend.
    #[inline]
    fn outlet_offset(&self, p: &Vector3<f64>) -> Option<Vector3<f64>> {
        let (e, t) = self.outlet?;
        if self.geometry.turned(p) <= self.geometry.angle {
            return None;
        }
        let w = p - e;
        Some(w - t * w.dot(&t))
    }

    /// Signed distance (m) from `p` to the wall of its piece: the torus's (exact), or
    /// |off| − r to the outlet's cylinder; negative inside.
    #[inline]
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        match self.outlet_offset(p) {
            Some(off) => off.norm() - self.geometry.tube_radius,
            None => self.torus.signed_distance(p),
        }
    }

    /// The unit outward normal of its piece's wall at the wall point nearest to `p`;
    /// `None` where undefined (on the torus's centreline or axis, on the outlet's axis).
    #[inline]
    pub fn normal(&self, p: &Vector3<f64>) -> Option<Unit<Vector3<f64>>> {
        match self.outlet_offset(p) {
            Some(off) => {
                let n = off.norm();
                (n > 0.0 && n.is_finite()).then(|| Unit::new_unchecked(off / n))
            }
            None => self.torus.normal(p),
        }
    }

    /// Where the ray `origin + τ·d` (d unit, from inside the tube) leaves the wall within
    /// τ ≤ `tau_max`: the nearer of the torus's first outward crossing at α ∈ [0, Θ] and
    /// the outlet cylinder's exit (the larger root of its quadratic) at α > Θ. The two
    /// pieces meet only in the plane α = Θ, so the nearer is where the ray first leaves
    /// their union.
    pub fn ray_exit(
        &self,
        origin: &Vector3<f64>,
        d: &Vector3<f64>,
        tau_max: f64,
    ) -> Option<(f64, Piece)> {
        let angle = self.geometry.angle.min(OPEN_ANGLE);
        let crossings = self.torus.ray_crossings(origin, d, tau_max);
        let torus = crossings.as_slice().iter().copied().find(|&tau| {
            let w = origin + d * tau;
            let leaving = self.torus.normal(&w).is_some_and(|n| n.dot(d) > 0.0);
            let a = self.geometry.turned(&w);
            leaving && (0.0..=angle).contains(&a)
        });
        let outlet = self.outlet.and_then(|(e, t)| {
            // |(o + τd − E)⊥|² = r²: a τ² + b τ + c = 0 in the plane normal to T.
            let w = origin - e;
            let wp = w - t * w.dot(&t);
            let dp = d - t * d.dot(&t);
            let r = self.geometry.tube_radius;
            let a = dp.norm_squared();
            let b = 2.0 * wp.dot(&dp);
            let c = wp.norm_squared() - r * r;
            let disc = b * b - 4.0 * a * c;
            if !(a > 0.0 && disc >= 0.0) {
                return None;
            }
            let tau = (-b + disc.sqrt()) / (2.0 * a);
            (tau > 0.0 && tau <= tau_max && self.piece(&(origin + d * tau)) == Piece::Outlet)
                .then_some(tau)
        });
        match (torus, outlet) {
            (Some(a), Some(b)) if b < a => Some((b, Piece::Outlet)),
            (Some(a), _) => Some((a, Piece::Torus)),
            (None, Some(b)) => Some((b, Piece::Outlet)),
            (None, None) => None,
        }
    }
}
