//! The torus: the exact wall of a pipe bend (an elbow) of circular cross-section.
//!
//! A bend whose centreline is a circular arc of radius R (the *bend radius*, e.g. 1.5·D
//! for a long-radius elbow) and whose tube has radius r is a piece of the ring torus
//!
//! ```text
//! F(p) = (|p'|² + R² − r²)² − 4R²(|p'|² − (p'·a)²) = 0,   p' = p − c,
//! ```
//!
//! with centre `c` (the centre of curvature of the bend) and unit axis `a` (the normal of
//! the bend plane). With h = p'·a (height above the bend plane), ρ = |p' − h·a| (distance
//! from the axis) and the distance to the centreline circle d = √((ρ − R)² + h²), the
//! quartic factors as
//!
//! ```text
//! F = (d² − r²)·((ρ + R)² + h² − r²),
//! ```
//!
//! whose second factor is ≥ R² − r² > 0 for a ring torus (R > r): F has the sign of the
//! exact signed distance s(p) = d − r (< 0 inside the tube, > 0 outside), which is
//! 1-Lipschitz and well conditioned near the wall. Both are provided; the ray cast uses F
//! (a polynomial in the ray parameter) to isolate the crossings and s to refine them.
//!
//! All points and vectors are in one frame chosen by the caller (in this workspace the
//! PCS of the first straight section, metres), as `Vector3` from that frame's origin.

use nalgebra::{Unit, Vector3};

use crate::error::EpdError;

/// A ring torus: the centreline circle of radius `major_radius` about `axis` through
/// `centre`, swept by a circle of radius `minor_radius`. Plain data; [`Torus::new`] and
/// [`Torus::validate`] check it. Every method returns NaN, `None` or no crossing for an
/// invalid torus or non-finite input rather than panicking.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Torus {
    /// Centre c of the torus (of curvature of the bend), m.
    pub centre: Vector3<f64>,
    /// Unit axis a: the normal of the bend plane (the plane of the centreline circle).
    pub axis: Unit<Vector3<f64>>,
    /// Centreline radius R (the bend radius), m. Must exceed `minor_radius`.
    pub major_radius: f64,
    /// Tube radius r (half the bend's inner diameter), m, > 0.
    pub minor_radius: f64,
}

/// The ray's crossings of the torus wall in (0, t_max], nearest first: at most four (a
/// line meets a quartic surface at most four times). Plain `Copy` data.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RayCrossings {
    /// The ray parameters t of the crossings; only the first `len` are meaningful.
    pub t: [f64; 4],
    /// How many crossings.
    pub len: usize,
}

impl RayCrossings {
    /// The crossings found, nearest first.
    pub fn as_slice(&self) -> &[f64] {
        &self.t[..self.len]
    }

    fn push(&mut self, t: f64) {
        if self.len < 4 {
            self.t[self.len] = t;
            self.len += 1;
        }
    }
}

impl Torus {
    /// A validated torus; `axis` need not be unit (it is normalised).
    pub fn new(
        centre: Vector3<f64>,
        axis: Vector3<f64>,
        major_radius: f64,
        minor_radius: f64,
    ) -> Result<Self, EpdError> {
        let n = axis.norm();
        if !(n.is_finite() && n > 0.0) {
            return Err(EpdError::InvalidGeometry(format!(
                "torus axis {axis:?} must be a finite non-zero vector"
            )));
        }
        let t = Self {
            centre,
            axis: Unit::new_unchecked(axis / n),
            major_radius,
            minor_radius,
        };
        t.validate()?;
        Ok(t)
    }

    /// Check the fields: finite centre, unit axis (|a| = 1 within 1e-9), and
    /// 0 < r < R < ∞ (a ring torus: the bend radius exceeds the tube radius).
    pub fn validate(&self) -> Result<(), EpdError> {
        if !self.centre.iter().all(|v| v.is_finite()) {
            return Err(EpdError::InvalidGeometry(format!(
                "torus centre {:?} must be finite",
                self.centre
            )));
        }
        let n = self.axis.norm();
        if !((n - 1.0).abs() <= 1e-9) {
            return Err(EpdError::InvalidGeometry(format!(
                "torus axis {:?} must be a finite unit vector",
                self.axis.into_inner()
            )));
        }
        if !(self.minor_radius > 0.0
            && self.minor_radius < self.major_radius
            && self.major_radius.is_finite())
        {
            return Err(EpdError::InvalidGeometry(format!(
                "torus radii R = {}, r = {} must satisfy 0 < r < R < ∞",
                self.major_radius, self.minor_radius
            )));
        }
        Ok(())
    }

    fn is_valid(&self) -> bool {
        self.validate().is_ok()
    }

    /// (h, v, ρ) of a point: h = p'·a, the radial vector v = p' − h·a in the bend plane
    /// and ρ = |v|, with p' = p − c.
    #[inline]
    fn local(&self, p: &Vector3<f64>) -> (f64, Vector3<f64>, f64) {
        let pp = p - self.centre;
        let h = pp.dot(&self.axis);
        let v = pp - self.axis.into_inner() * h;
        (h, v, v.norm())
    }

    /// The quartic F(p) = (|p'|² + R² − r²)² − 4R²(|p'|² − (p'·a)²) (m⁴), evaluated in the
    /// factored form (d² − r²)·((ρ + R)² + h² − r²) of the module documentation, with
    /// d² − r² = (d − r)(d + r): no cancellation near the wall. < 0 inside the tube, 0 on
    /// the wall, > 0 outside. NaN for non-finite input.
    pub fn implicit(&self, p: &Vector3<f64>) -> f64 {
        let (r0, r1) = (self.major_radius, self.minor_radius);
        let (h, _, rho) = self.local(p);
        let d = planar_norm(rho - r0, h);
        (d - r1) * (d + r1) * ((rho + r0) * (rho + r0) + h * h - r1 * r1)
    }

    /// ∇F (m³) of [`Torus::implicit`]: 4(|p'|² + R² − r²)·p' − 8R²(p' − (p'·a)·a).
    /// On the wall it is the outward normal times 2r·((ρ + R)² + h² − r²) ≈ 8rR².
    pub fn gradient(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let (r0, r1) = (self.major_radius, self.minor_radius);
        let pp = p - self.centre;
        let h = pp.dot(&self.axis);
        let v = pp - self.axis.into_inner() * h;
        pp * (4.0 * (pp.norm_squared() + r0 * r0 - r1 * r1)) - v * (8.0 * r0 * r0)
    }

    /// The exact signed Euclidean distance (m) from `p` to the torus wall,
    /// s = √((ρ − R)² + h²) − r: negative inside the tube. Exact for a ring torus
    /// (R > r): the nearest wall point lies on the segment from the nearest centreline
    /// point through `p`.
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        let (h, _, rho) = self.local(p);
        planar_norm(rho - self.major_radius, h) - self.minor_radius
    }

    /// The unit outward normal of the wall at the wall point nearest to `p`: the gradient
    /// of [`Torus::signed_distance`], ((ρ − R)·v/ρ + h·a)/d. `None` where it is undefined:
    /// on the centreline circle (d = 0) or on the axis (ρ = 0), or for non-finite input.
    pub fn normal(&self, p: &Vector3<f64>) -> Option<Unit<Vector3<f64>>> {
        let (h, v, rho) = self.local(p);
        if !(rho > 0.0) {
            return None;
        }
        let n = v * ((rho - self.major_radius) / rho) + self.axis.into_inner() * h;
        let len = n.norm();
        (len > 0.0 && len.is_finite()).then(|| Unit::new_unchecked(n / len))
    }

    /// The centreline point nearest to `p`, c + R·v/ρ; `None` on the axis (ρ = 0, every
    /// centreline point is as near) or for non-finite input.
    pub fn centreline_point(&self, p: &Vector3<f64>) -> Option<Vector3<f64>> {
        let (_, v, rho) = self.local(p);
        (rho > 0.0 && rho.is_finite()).then(|| self.centre + v * (self.major_radius / rho))
    }

    /// Every crossing of the wall by the ray `origin + t·dir`, t ∈ (0, t_max], nearest
    /// first. `dir` need not be unit: t is in units of `dir` (as parry's time of impact);
    /// `t_max` may be +∞. Non-finite or zero `dir`, non-finite `origin`, NaN or
    /// non-positive `t_max`, or an invalid torus give no crossing.
    ///
    /// Method (exact root isolation, no sampling step to choose):
    /// 1. With u = dir/|dir|, τ = t·|dir| (metres) and τ = τ₀ + σ about the point
    ///    q = p' + τ₀u of the line nearest to the centre (τ₀ = −p'·u), F along the ray is
    ///    the monic quartic F(σ) = σ⁴ + c₃σ³ + c₂σ² + c₁σ + c₀ with, for k = q·u (≈ 0),
    ///    m = |q|² + R² − r², h₀ = q·a, u_a = u·a:
    ///    c₃ = 4k, c₂ = 4k² + 2m − 4R²|u − u_a a|², c₁ = 4km − 8R²(k − h₀u_a), c₀ = F(q).
    /// 2. The wall lies in the bounding sphere |p'| ≤ R + r, so only
    ///    |σ| ≤ √((R + r)² − |q|²) matters (none if |q| > R + r), intersected with
    ///    τ ∈ (0, τ_max].
    /// 3. F″ is a quadratic: its roots (closed form, cancellation-free) split the interval
    ///    into pieces where F′ is monotone; each piece holds at most one root of F′, found
    ///    by safeguarded Newton (bisection whenever Newton leaves the bracket). The roots
    ///    of F′ split the interval into pieces where F is monotone: each holds at most one
    ///    crossing, present iff the signed distance s (which has F's sign) changes sign
    ///    between its ends. That crossing is refined by safeguarded Newton on s along the
    ///    ray (slope = n·u), to the last bit the bracket allows.
    ///
    /// A ray that only touches the wall (a root of even multiplicity: tangency) does not
    /// cross it and is not reported, as with a sign-change oracle; within rounding of a
    /// tangency (|s| ~ 1e-16 m along a stretch) either answer may come out. A ray starting
    /// exactly on the wall does not report t = 0.
    pub fn ray_crossings(
        &self,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        t_max: f64,
    ) -> RayCrossings {
        let mut out = RayCrossings::default();
        let len = dir.norm();
        if !(origin.iter().all(|v| v.is_finite())
            && len.is_finite()
            && len > 0.0
            && t_max > 0.0
            && self.is_valid())
        {
            return out;
        }
        let (r0, r1) = (self.major_radius, self.minor_radius);
        let a = self.axis.into_inner();
        let u = dir / len;
        let tau_max = t_max * len;
        let pp = origin - self.centre;
        let tau0 = -pp.dot(&u);
        let q = pp + u * tau0;
        let q2 = q.norm_squared();
        let bound = (r0 + r1) * (r0 + r1) * (1.0 + 1e-9) - q2;
        if !(bound > 0.0) {
            return out;
        }
        let half = bound.sqrt();
        let lo = (-tau0).max(-half);
        let hi = (tau_max - tau0).min(half);
        if !(lo < hi) {
            return out;
        }
        // The quartic's coefficients (step 1).
        let k = q.dot(&u);
        let m = q2 + r0 * r0 - r1 * r1;
        let h0 = q.dot(&a);
        let ua = u.dot(&a);
        let w2 = (u - a * ua).norm_squared();
        let c3 = 4.0 * k;
        let c2 = 4.0 * k * k + 2.0 * m - 4.0 * r0 * r0 * w2;
        let c1 = 4.0 * k * m - 8.0 * r0 * r0 * (k - h0 * ua);
        let (crit, nc) = monotone_pieces([c3, c2, c1], lo, hi);
        // Signed distance along the ray and its slope.
        let sd = |s: f64| self.signed_distance(&(q + u * s + self.centre));
        let slope = |s: f64| {
            self.normal(&(q + u * s + self.centre))
                .map_or(f64::NAN, |n| n.dot(&u))
        };
        let mut vals = [0.0; 6];
        for (v, &s) in vals.iter_mut().zip(&crit[..nc]) {
            *v = sd(s);
        }
        for i in 0..nc - 1 {
            let (x0, x1) = (crit[i], crit[i + 1]);
            let (g0, g1) = (vals[i], vals[i + 1]);
            if g0 == 0.0 {
                // A crossing at a breakpoint: only if the sign changes through it.
                if i > 0 && vals[i - 1] * g1 < 0.0 {
                    out.push((tau0 + x0) / len);
                }
                continue;
            }
            if g0 * g1 < 0.0 {
                let root = newton_bisect(sd, slope, x0, x1, g0);
                out.push((tau0 + root) / len);
            }
        }
        // A crossing exactly at τ_max.
        if nc >= 2 && vals[nc - 1] == 0.0 && vals[nc - 2] != 0.0 && hi == tau_max - tau0 {
            out.push(t_max);
        }
        out
    }

    /// The first crossing of the wall by the ray `origin + t·dir` with t ∈ (0, t_max]:
    /// the first element of [`Torus::ray_crossings`] (see there for the method, units and
    /// refused input). From inside the tube (the in-pipe case) it is where the ray leaves
    /// the tube.
    pub fn ray_hit(&self, origin: &Vector3<f64>, dir: &Vector3<f64>, t_max: f64) -> Option<f64> {
        let c = self.ray_crossings(origin, dir, t_max);
        (c.len > 0).then_some(c.t[0])
    }
}

/// Add `x` to the first `n` entries of `v` unless already there.
fn push_unique(v: &mut [f64; 6], n: &mut usize, x: f64) {
    if !v[..*n].contains(&x) && *n < v.len() {
        v[*n] = x;
        *n += 1;
    }
}

/// Step 3 of [`Torus::ray_crossings`]: the ends of the pieces of [lo, hi] on which the
/// quartic F(σ) = σ⁴ + c₃σ³ + c₂σ² + c₁σ + c₀ is monotone (`c` = [c₃, c₂, c₁]), in
/// order: lo, the roots of F′ inside, hi. F″ is a quadratic whose roots split [lo, hi]
/// into pieces where F′ is monotone; each holds at most one root of F′, found by
/// safeguarded Newton. Returns the ends and their number.
fn monotone_pieces(c: [f64; 3], lo: f64, hi: f64) -> ([f64; 6], usize) {
    let [c3, c2, c1] = c;
    let d1 = |s: f64| ((4.0 * s + 3.0 * c3) * s + 2.0 * c2) * s + c1;
    let d2 = |s: f64| (12.0 * s + 6.0 * c3) * s + 2.0 * c2;
    // Roots of F″/2 = 6σ² + 3c₃σ + c₂.
    let mut breaks = [lo; 6];
    let mut nb = 1;
    for s in quadratic_roots(6.0, 3.0 * c3, c2).iter().flatten() {
        if *s > lo && *s < hi {
            breaks[nb] = *s;
            nb += 1;
        }
    }
    breaks[nb] = hi;
    nb += 1;
    breaks[..nb].sort_by(f64::total_cmp);
    // Roots of F′ on the pieces where it is monotone.
    let mut crit = [lo; 6];
    let mut nc = 1;
    for w in breaks[..nb].windows(2) {
        let (x0, x1) = (w[0], w[1]);
        let (f0, f1) = (d1(x0), d1(x1));
        if f0 == 0.0 && x0 > lo {
            push_unique(&mut crit, &mut nc, x0);
        } else if f0 * f1 < 0.0 {
            let root = newton_bisect(d1, d2, x0, x1, f0);
            push_unique(&mut crit, &mut nc, root);
        }
    }
    push_unique(&mut crit, &mut nc, hi);
    crit[..nc].sort_by(f64::total_cmp);
    (crit, nc)
}

/// The real roots of a·x² + b·x + c (a ≠ 0), by the cancellation-free formula
/// q = −(b + sign(b)·√(b² − 4ac))/2, x = q/a and c/q.
fn quadratic_roots(a: f64, b: f64, c: f64) -> [Option<f64>; 2] {
    let disc = b * b - 4.0 * a * c;
    if !(disc >= 0.0) {
        return [None, None];
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    if q == 0.0 {
        return [Some(0.0), None];
    }
    [Some(q / a), Some(c / q)]
}

/// The root of `f` in [x0, x1] where f(x0) = `f0` and f(x1) have opposite signs:
/// Newton steps with derivative `df`, replaced by bisection whenever a step leaves the
/// current bracket or the derivative is unusable; the bracket shrinks every iteration and
/// the loop ends when it cannot shrink further (adjacent floats) or after 200 steps.
fn newton_bisect(
    f: impl Fn(f64) -> f64,
    df: impl Fn(f64) -> f64,
    mut x0: f64,
    mut x1: f64,
    f0: f64,
) -> f64 {
    let neg_at_x0 = f0 < 0.0;
    let mut x = 0.5 * (x0 + x1);
    for _ in 0..200 {
        let fx = f(x);
        if fx == 0.0 {
            return x;
        }
        if (fx < 0.0) == neg_at_x0 {
            x0 = x;
        } else {
            x1 = x;
        }
        let mid = 0.5 * (x0 + x1);
        if mid <= x0.min(x1) || mid >= x0.max(x1) {
            break;
        }
        let step = fx / df(x);
        let xn = x - step;
        let (a, b) = (x0.min(x1), x0.max(x1));
        x = if xn.is_finite() && xn > a && xn < b {
            // Converged when Newton no longer moves the iterate.
            if (xn - x).abs() <= 4.0 * f64::EPSILON * x.abs().max(1e-300) {
                return xn;
            }
            xn
        } else {
            mid
        };
    }
    x
}

/// √(a² + b²) without `f64::hypot`'s guard against overflow and underflow: the torus's
/// lengths are metres (a square overflows only beyond 10¹⁵⁴ m), and the guard cost a
/// third of a bend fit's time (the signed distance is taken in every step of every ray's
/// crossing). Used by the bend's wall too.
#[inline]
pub(crate) fn planar_norm(a: f64, b: f64) -> f64 {
    (a * a + b * b).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bend() -> Torus {
        Torus::new(Vector3::new(1.0, 0.762, 0.0), Vector3::z(), 0.762, 0.242).unwrap()
    }

    #[test]
    fn forms_agree_and_have_the_right_sign() {
        let t = bend();
        // The raw quartic, for comparison with the factored form.
        let raw = |p: &Vector3<f64>| {
            let pp = p - t.centre;
            let s = pp.norm_squared();
            let h = pp.dot(&t.axis);
            let (r0, r1) = (t.major_radius, t.minor_radius);
            (s + r0 * r0 - r1 * r1).powi(2) - 4.0 * r0 * r0 * (s - h * h)
        };
        for p in [
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(1.0, 0.1, 0.3),
            Vector3::new(1.0, 0.762 + 0.762, 0.0),
            Vector3::new(3.0, -2.0, 1.0),
        ] {
            let (f, g) = (t.implicit(&p), raw(&p));
            assert!((f - g).abs() <= 1e-12 * g.abs().max(1.0), "{f} vs {g}");
            assert_eq!(f.signum(), t.signed_distance(&p).signum());
            // The gradient against central differences of the raw form.
            let e = 1e-6;
            for i in 0..3 {
                let mut dp = Vector3::zeros();
                dp[i] = e;
                let fd = (raw(&(p + dp)) - raw(&(p - dp))) / (2.0 * e);
                let gi = t.gradient(&p)[i];
                assert!((fd - gi).abs() < 1e-6 * gi.abs().max(1.0), "{fd} vs {gi}");
            }
        }
        // The sensor on the bend's start plane, on the centreline: 0.242 m from the wall.
        assert!((t.signed_distance(&Vector3::new(1.0, 0.0, 0.0)) + 0.242).abs() < 1e-15);
    }

    #[test]
    fn bad_tori_and_inputs_are_refused() {
        assert!(Torus::new(Vector3::zeros(), Vector3::z(), 0.2, 0.3).is_err());
        assert!(Torus::new(Vector3::zeros(), Vector3::zeros(), 1.0, 0.3).is_err());
        assert!(Torus::new(Vector3::zeros(), Vector3::z(), f64::NAN, 0.3).is_err());
        assert!(Torus::new(Vector3::repeat(f64::NAN), Vector3::z(), 1.0, 0.3).is_err());
        let t = bend();
        let o = Vector3::new(1.0, 0.0, 0.0);
        assert!(
            t.ray_hit(&o, &Vector3::new(f64::NAN, 0.0, 0.0), 10.0)
                .is_none()
        );
        assert!(t.ray_hit(&o, &Vector3::zeros(), 10.0).is_none());
        assert!(t.ray_hit(&o, &Vector3::y(), f64::NAN).is_none());
        assert!(t.ray_hit(&o, &Vector3::y(), -1.0).is_none());
        let mut bad = t;
        bad.minor_radius = 1.0;
        assert!(bad.ray_hit(&o, &Vector3::y(), 10.0).is_none());
        // A hand-computed hit: from the start centre along −Y to the outer wall.
        assert!((t.ray_hit(&o, &-Vector3::y(), 10.0).unwrap() - 0.242).abs() < 1e-15);
        // Along +Y: leaves the tube at 0.242, crosses the hole, enters the far side at
        // 0.762 + 0.52 and leaves it at 0.762 + 1.004 (the fourth root is at t < 0).
        let c = t.ray_crossings(&o, &Vector3::y(), f64::INFINITY);
        assert_eq!(c.len, 3, "{c:?}");
        for (got, want) in c.as_slice().iter().zip([0.242, 1.282, 1.766]) {
            assert!((got - want).abs() < 1e-14, "{got} vs {want}");
        }
        // A bounded ray stops at t_max.
        assert_eq!(t.ray_crossings(&o, &Vector3::y(), 1.5).len, 2);
        // An unnormalised direction: t in units of it.
        assert!((t.ray_hit(&o, &(Vector3::y() * 2.0), 10.0).unwrap() - 0.121).abs() < 1e-15);
    }
}
