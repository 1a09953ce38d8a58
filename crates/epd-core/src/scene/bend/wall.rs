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
//!
//! **An oval tube.** With a tube ovality ε ≠ 0 ([`BendGeometry::tube_ovality`]) the
//! cross-section is an ellipse of semi-axes r_y = r(1 + ε/2), r_z = r(1 − ε/2) (mean radius
//! r, ovality (r_y − r_z)/r = ε) along the straight pipe's PCS y and z at the start, carried
//! along the bend: a point's offset from the centreline, w along the outward radial
//! direction ê (from the centre of curvature) and h along the plane's normal a, has the
//! section coordinates y = −w·cos φ − h·sin φ, z = −w·sin φ + h·cos φ (at the start ê = −u
//! and a = (0, −sin φ, cos φ), so (y, z) are the PCS coordinates there); on the outlet ê is
//! the radial direction at Θ. The wall is g = 0 for the radial distance
//! g = ρ_s − r_e(y, z), ρ_s = √(y² + z²) and r_e = r_y·r_z·ρ_s/√(r_z²y² + r_y²z²) the
//! ellipse's radius toward (y, z); its gradient
//! ∂g/∂y = y/ρ_s − K·y·z², ∂g/∂z = z/ρ_s + K·z·y², K = r_y·r_z·(r_y² − r_z²)/(ρ_s·N³),
//! N = √(r_z²y² + r_y²z²), mapped to (w, h) by the rotation above and to the PCS by
//! ∇w = ê, ∇h = a ([`Section::radial`]). The signed distance is g/|∇g| (first order in
//! g, exact for a circle, where |∇g| = 1 and g = d − r) and the normal ∇g/|∇g|. A ray's
//! exit is the round torus's (of the mean radius r) refined by Newton's method on g along
//! the ray, and the outlet's the larger root of its ellipse's quadratic. A round tube
//! (ε = 0) takes the torus's and the round outlet's own forms.

use nalgebra::{Unit, Vector3};

use super::BendGeometry;
use crate::torus::{Torus, planar_norm};

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
    /// The oval tube's section; `None` for a round tube (ε = 0).
    section: Option<Section>,
}

/// An oval tube's cross-section (see the module documentation): its semi-axes along the
/// carried PCS y and z, and cos φ, sin φ of the turn's direction.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Section {
    ry: f64,
    rz: f64,
    cos: f64,
    sin: f64,
}

impl Section {
    /// (g, ∂g/∂w, ∂g/∂h): the radial distance g = ρ_s − r_e outside the ellipse of a
    /// point at offset (w, h) from the centreline, and its derivatives; `None` on the
    /// centreline (ρ_s = 0).
    #[inline]
    fn radial(&self, w: f64, h: f64) -> Option<(f64, f64, f64)> {
        let (c, s) = (self.cos, self.sin);
        let (y, z) = (-w * c - h * s, -w * s + h * c);
        let d = planar_norm(y, z);
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let (ry2, rz2) = (self.ry * self.ry, self.rz * self.rz);
        let n2 = rz2 * y * y + ry2 * z * z;
        let n = n2.sqrt();
        let re = self.ry * self.rz * d / n;
        let k = self.ry * self.rz * (ry2 - rz2) / (d * n2 * n);
        let gy = y / d - k * y * z * z;
        let gz = z / d + k * z * y * y;
        Some((d - re, -c * gy - s * gz, -s * gy + c * gz))
    }

    /// The signed distance g/|∇g| and the unit outward normal of a point at offset
    /// (w, h), with ê the outward radial direction there and `a` the plane's normal.
    #[inline]
    fn distance_and_normal(
        &self,
        w: f64,
        h: f64,
        e: &Vector3<f64>,
        a: &Vector3<f64>,
    ) -> Option<(f64, Unit<Vector3<f64>>)> {
        let (g, gw, gh) = self.radial(w, h)?;
        let len = planar_norm(gw, gh);
        (len > 0.0 && len.is_finite())
            .then(|| (g / len, Unit::new_unchecked((e * gw + a * gh) / len)))
    }

    /// Whether the section point (y, z) lies outside the ellipse.
    #[inline]
    fn outside(&self, y: f64, z: f64) -> bool {
        (y / self.ry).powi(2) + (z / self.rz).powi(2) > 1.0
    }
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
        let section = (geometry.tube_ovality != 0.0).then(|| {
            let (ry, rz) = geometry.semi_axes();
            let (sin, cos) = geometry.direction.sin_cos();
            Section { ry, rz, cos, sin }
        });
        Some(Self {
            geometry: *geometry,
            torus,
            outlet,
            section,
        })
    }

    /// The outward radial direction ê at α = Θ (the outlet's), and the plane's normal a.
    #[inline]
    fn outlet_axes(&self) -> (Vector3<f64>, Vector3<f64>) {
        let (s, c) = self.geometry.direction.sin_cos();
        let u = Vector3::new(0.0, c, s);
        let (sa, ca) = self.geometry.angle.sin_cos();
        (-ca * u + sa * Vector3::x(), self.torus.axis.into_inner())
    }

    /// An oval tube's signed distance and normal at `p` on its piece.
    fn oval_distance_and_normal(
        &self,
        section: &Section,
        p: &Vector3<f64>,
    ) -> Option<(f64, Unit<Vector3<f64>>)> {
        match self.outlet_offset(p) {
            Some(off) => {
                let (e, a) = self.outlet_axes();
                section.distance_and_normal(off.dot(&e), off.dot(&a), &e, &a)
            }
            None => {
                let a = self.torus.axis.into_inner();
                let pp = p - self.torus.centre;
                let h = pp.dot(&a);
                let v = pp - a * h;
                let rho = v.norm();
                if !(rho > 0.0) {
                    return None;
                }
                section.distance_and_normal(rho - self.geometry.radius, h, &(v / rho), &a)
            }
        }
    }

    /// Whether the point (y, z) of the start's plane (PCS, from the axis) lies outside
    /// the tube's section there.
    pub fn outside_section_at_start(&self, y: f64, z: f64) -> bool {
        match &self.section {
            Some(s) => s.outside(y, z),
            None => planar_norm(y, z) > self.geometry.tube_radius,
        }
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
    /// |off| − r to the outlet's cylinder; for an oval tube g/|∇g| (module
    /// documentation); negative inside.
    #[inline]
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        if let Some(section) = &self.section {
            return self
                .oval_distance_and_normal(section, p)
                .map_or(f64::NAN, |(d, _)| d);
        }
        match self.outlet_offset(p) {
            Some(off) => off.norm() - self.geometry.tube_radius,
            None => self.torus.signed_distance(p),
        }
    }

    /// The unit outward normal of its piece's wall at the wall point nearest to `p` (for
    /// an oval tube ∇g/|∇g|); `None` where undefined (on the torus's centreline or axis,
    /// on the outlet's axis).
    #[inline]
    pub fn normal(&self, p: &Vector3<f64>) -> Option<Unit<Vector3<f64>>> {
        if let Some(section) = &self.section {
            return self.oval_distance_and_normal(section, p).map(|(_, n)| n);
        }
        match self.outlet_offset(p) {
            Some(off) => {
                let n = off.norm();
                (n > 0.0 && n.is_finite()).then(|| Unit::new_unchecked(off / n))
            }
            None => self.torus.normal(p),
        }
    }

    /// The signed distance s = g/|∇g|, the unit outward normal and the gradient ∂s/∂θ of
    /// the signed distance at the fixed point `p` in the placement's parameters
    /// θ = (x₀, φ, R, r, ε, Θ), on `p`'s piece, analytically (round and oval tubes alike:
    /// a round tube is the ellipse with r_y = r_z = r, g = ρ_s − r, |∇g| = 1).
    ///
    /// With the section offset (w, h) of `p` (module documentation) and its section
    /// coordinates y = −w·cos φ − h·sin φ, z = −w·sin φ + h·cos φ:
    /// ∂g/∂θ_k = g_y·∂y/∂θ_k + g_z·∂z/∂θ_k + g_{r_y}·∂r_y/∂θ_k + g_{r_z}·∂r_z/∂θ_k, where
    /// g_{r_y} = −r_z³y²ρ_s/N³, g_{r_z} = −r_y³z²ρ_s/N³ (from r_e = r_y·r_z·ρ_s/N),
    /// ∂r_y/∂r = 1 + ε/2, ∂r_z/∂r = 1 − ε/2, ∂r_y/∂ε = r/2 = −∂r_z/∂ε, and the explicit φ
    /// of the section's rotation adds ∂y/∂φ = −z, ∂z/∂φ = y. The offset's derivatives,
    /// from c = (x₀, R cos φ, R sin φ), u = (0, cos φ, sin φ), a = (0, −sin φ, cos φ)
    /// (∂u/∂φ = a, ∂a/∂φ = −u):
    /// - torus, p' = p − c, h = p'·a, ê = (p' − h·a)/ρ: ∂w/∂x₀ = −ê_x, ∂w/∂φ = h·(ê·u),
    ///   ∂w/∂R = −ê·u − 1, ∂h/∂φ = −R − p'·u, the others 0;
    /// - outlet, q = p − E, w = q·ê_Θ, h = q·a, E = c + R·ê_Θ, ê_Θ = −cos Θ·u + sin Θ·x̂,
    ///   T = cos Θ·x̂ + sin Θ·u: ∂w/∂x₀ = −sin Θ, ∂w/∂φ = −cos Θ·h, ∂w/∂R = cos Θ − 1,
    ///   ∂w/∂Θ = q·T, ∂h/∂φ = −R(1 − cos Θ) − q·u, the others 0.
    ///
    /// The gradient returned is (∂g/∂θ)/|∇g|: exact on the wall (g = 0, where the range
    /// error's gradient is taken) and everywhere for a round tube (|∇g| ≡ 1); off an oval
    /// tube's wall it leaves out g·∂(1/|∇g|)/∂θ, of relative size ε·|s|/r. `None` where
    /// the normal is undefined (on the centreline or the torus's axis).
    pub fn distance_normal_and_gradient(
        &self,
        p: &Vector3<f64>,
    ) -> Option<(f64, Unit<Vector3<f64>>, [f64; super::NP])> {
        let g = &self.geometry;
        let (sin, cos) = g.direction.sin_cos();
        let u = Vector3::new(0.0, cos, sin);
        let a = self.torus.axis.into_inner();
        let big_r = g.radius;
        // The section offset (w, h), the outward radial direction and ∂w/∂θ, ∂h/∂θ.
        let (w, h, e, dw, dh) = match self.outlet {
            Some((end, t)) if g.turned(p) > g.angle => {
                let (sa, ca) = g.angle.sin_cos();
                let e = -ca * u + sa * Vector3::x();
                let q = p - end;
                let h = q.dot(&a);
                let dw = [-sa, -ca * h, ca - 1.0, 0.0, 0.0, q.dot(&t)];
                let dh = [0.0, -big_r * (1.0 - ca) - q.dot(&u), 0.0, 0.0, 0.0, 0.0];
                (q.dot(&e), h, e, dw, dh)
            }
            _ => {
                let pp = p - self.torus.centre;
                let h = pp.dot(&a);
                let v = pp - a * h;
                let rho = v.norm();
                if !(rho > 0.0 && rho.is_finite()) {
                    return None;
                }
                let e = v / rho;
                let eu = e.dot(&u);
                let dw = [-e.x, h * eu, -eu - 1.0, 0.0, 0.0, 0.0];
                let dh = [0.0, -big_r - pp.dot(&u), 0.0, 0.0, 0.0, 0.0];
                (rho - big_r, h, e, dw, dh)
            }
        };
        let (ry, rz) = g.semi_axes();
        let (y, z) = (-w * cos - h * sin, -w * sin + h * cos);
        let d = planar_norm(y, z);
        if !(d > 0.0 && d.is_finite()) {
            return None;
        }
        let (ry2, rz2) = (ry * ry, rz * rz);
        let n2 = rz2 * y * y + ry2 * z * z;
        let n = n2.sqrt();
        let n3 = n2 * n;
        let k = ry * rz * (ry2 - rz2) / (d * n3);
        let gy = y / d - k * y * z * z;
        let gz = z / d + k * z * y * y;
        let value = d - ry * rz * d / n;
        let (gw, gh) = (-cos * gy - sin * gz, -sin * gy + cos * gz);
        let len = planar_norm(gw, gh);
        if !(len > 0.0 && len.is_finite()) {
            return None;
        }
        let g_ry = -rz2 * rz * y * y * d / n3;
        let g_rz = -ry2 * ry * z * z * d / n3;
        let mut grad = [0.0; super::NP];
        for (kk, out) in grad.iter_mut().enumerate() {
            let mut dy = -cos * dw[kk] - sin * dh[kk];
            let mut dz = -sin * dw[kk] + cos * dh[kk];
            if kk == 1 {
                dy -= z;
                dz += y;
            }
            *out = (gy * dy + gz * dz) / len;
        }
        let half = 0.5 * g.tube_ovality;
        grad[3] += (g_ry * (1.0 + half) + g_rz * (1.0 - half)) / len;
        grad[4] += 0.5 * g.tube_radius * (g_ry - g_rz) / len;
        let normal = Unit::new_unchecked((e * gw + a * gh) / len);
        Some((value / len, normal, grad))
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
        let torus = crossings.as_slice().iter().find_map(|&tau| {
            // An oval tube's crossing: the round one's, refined.
            let tau = match &self.section {
                Some(section) => self.refine_oval(section, origin, d, tau)?,
                None => tau,
            };
            let w = origin + d * tau;
            let leaving = self.normal(&w).is_some_and(|n| n.dot(d) > 0.0);
            let a = self.geometry.turned(&w);
            (leaving && (0.0..=angle).contains(&a) && tau <= tau_max).then_some(tau)
        });
        if let Some(section) = &self.section {
            let outlet = self.oval_outlet_exit(section, origin, d, tau_max);
            return nearer(torus, outlet);
        }
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
        nearer(torus, outlet)
    }

    /// Newton's method on the oval tube's radial distance g along the ray from the round
    /// torus's crossing `tau0` (g' = ∇g·d): at most [`OVAL_NEWTON_STEPS`] steps, until a
    /// step is below 10⁻¹² m; `None` when it does not settle there or leaves the ray.
    fn refine_oval(
        &self,
        section: &Section,
        origin: &Vector3<f64>,
        d: &Vector3<f64>,
        tau0: f64,
    ) -> Option<f64> {
        let a = self.torus.axis.into_inner();
        let mut tau = tau0;
        for _ in 0..OVAL_NEWTON_STEPS {
            let pp = origin + d * tau - self.torus.centre;
            let h = pp.dot(&a);
            let v = pp - a * h;
            let rho = v.norm();
            if !(rho > 0.0) {
                return None;
            }
            let (g, gw, gh) = section.radial(rho - self.geometry.radius, h)?;
            let slope = gw * (v / rho).dot(d) + gh * a.dot(d);
            if !(slope != 0.0 && slope.is_finite()) {
                return None;
            }
            let step = g / slope;
            tau -= step;
            if !(tau > 0.0 && tau.is_finite()) {
                return None;
            }
            if step.abs() <= 1e-12 {
                return Some(tau);
            }
        }
        None
    }

    /// Where the ray leaves an oval tube's outlet: the larger root of the ellipse's
    /// quadratic in the outlet's section coordinates (linear in τ along the ray), when
    /// the point lies past the end.
    fn oval_outlet_exit(
        &self,
        section: &Section,
        origin: &Vector3<f64>,
        d: &Vector3<f64>,
        tau_max: f64,
    ) -> Option<f64> {
        let (end, t) = self.outlet?;
        let (e, a) = self.outlet_axes();
        let w = origin - end;
        let wp = w - t * w.dot(&t);
        let dp = d - t * d.dot(&t);
        let (c, s) = (section.cos, section.sin);
        // Section coordinates y = y0 + τ·y1, z = z0 + τ·z1 of the ray's offset.
        let yz = |v: &Vector3<f64>| {
            let (wv, hv) = (v.dot(&e), v.dot(&a));
            (-wv * c - hv * s, -wv * s + hv * c)
        };
        let ((y0, z0), (y1, z1)) = (yz(&wp), yz(&dp));
        let (ry2, rz2) = (section.ry * section.ry, section.rz * section.rz);
        let qa = y1 * y1 / ry2 + z1 * z1 / rz2;
        let qb = 2.0 * (y0 * y1 / ry2 + z0 * z1 / rz2);
        let qc = y0 * y0 / ry2 + z0 * z0 / rz2 - 1.0;
        let disc = qb * qb - 4.0 * qa * qc;
        if !(qa > 0.0 && disc >= 0.0) {
            return None;
        }
        let tau = (-qb + disc.sqrt()) / (2.0 * qa);
        (tau > 0.0 && tau <= tau_max && self.piece(&(origin + d * tau)) == Piece::Outlet)
            .then_some(tau)
    }
}

/// The most Newton steps refining an oval tube's crossing from the round torus's
/// (`BendWall::refine_oval`): the two differ by about ε·r/2 along the normal, and Newton's
/// method converges quadratically from there — a few steps to 10⁻¹² m; 20 leaves room for
/// grazing rays, beyond which the ray is given up (its residual then takes the first-order
/// form).
const OVAL_NEWTON_STEPS: usize = 20;

/// The nearer of a torus exit and an outlet exit.
fn nearer(torus: Option<f64>, outlet: Option<f64>) -> Option<(f64, Piece)> {
    match (torus, outlet) {
        (Some(a), Some(b)) if b < a => Some((b, Piece::Outlet)),
        (Some(a), _) => Some((a, Piece::Torus)),
        (None, Some(b)) => Some((b, Piece::Outlet)),
        (None, None) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 20" bend (R = 0.75 m, r = 0.24 m) starting 1 m ahead toward φ = 0.7 that turns
    /// by 0.8 rad (46°).
    fn bend() -> BendGeometry {
        BendGeometry {
            start: 1.0,
            direction: 0.7,
            radius: 0.75,
            tube_radius: 0.24,
            tube_ovality: 0.0,
            angle: 0.8,
        }
    }

    /// [`bend`] with an oval tube, ε = 0.1 (semi-axes 252 and 228 mm).
    fn oval_bend() -> BendGeometry {
        BendGeometry {
            tube_ovality: 0.1,
            ..bend()
        }
    }

    /// Whether `p` lies inside an oval bend's union, from the definition of its section
    /// by rotations (nalgebra's, not [`Section`]'s coordinates): a point of the arc turned
    /// back about the bend's axis through the centre of curvature by its angle, or a point
    /// past the end moved back along the outlet to the end's plane and turned back by Θ,
    /// lands in the start's plane, where the section is the ellipse
    /// (y/r_y)² + (z/r_z)² < 1 of its PCS y and z.
    fn inside_oval(g: &BendGeometry, p: &Vector3<f64>) -> bool {
        let u = Vector3::new(0.0, g.direction.cos(), g.direction.sin());
        let axis = Unit::new_normalize(Vector3::x().cross(&u));
        let c = Vector3::new(g.start, 0.0, 0.0) + g.radius * u;
        let (ry, rz) = g.semi_axes();
        let in_section =
            |at_start: Vector3<f64>| (at_start.y / ry).powi(2) + (at_start.z / rz).powi(2) < 1.0;
        let back = |q: Vector3<f64>, angle: f64| {
            c + nalgebra::Rotation3::from_axis_angle(&axis, -angle) * (q - c)
        };
        let turned = g.turned(p);
        if (0.0..=g.angle).contains(&turned) && in_section(back(*p, turned)) {
            return true;
        }
        let end = c + g.radius * (-g.angle.cos() * u + g.angle.sin() * Vector3::x());
        let t = g.angle.cos() * Vector3::x() + g.angle.sin() * u;
        let along = (p - end).dot(&t);
        along >= 0.0 && in_section(back(p - t * along, g.angle))
    }

    /// Whether `p` lies inside the bend's union, from its definition and nothing of
    /// [`BendWall`]: within r of the centreline arc (the circle of radius R about the
    /// centre of curvature, in the bend's plane, turned by 0 … Θ from the start), or past
    /// the end's plane within r of the outlet's axis.
    fn inside(g: &BendGeometry, p: &Vector3<f64>) -> bool {
        let u = Vector3::new(0.0, g.direction.cos(), g.direction.sin());
        let c = Vector3::new(g.start, 0.0, 0.0) + g.radius * u;
        let q = p - c;
        let (x, back) = (q.x, -q.dot(&u));
        let out_of_plane = q.dot(&Vector3::x().cross(&u));
        let turned = x.atan2(back);
        let in_arc = (0.0..=g.angle).contains(&turned)
            && ((x.hypot(back) - g.radius).hypot(out_of_plane) < g.tube_radius);
        let end = c + g.radius * (-g.angle.cos() * u + g.angle.sin() * Vector3::x());
        let t = g.angle.cos() * Vector3::x() + g.angle.sin() * u;
        let w = p - end;
        let along = w.dot(&t);
        let in_outlet = along >= 0.0 && (w - t * along).norm() < g.tube_radius;
        in_arc || in_outlet
    }

    /// From points inside the bend, rays in 200 directions: where [`BendWall::ray_exit`]
    /// says a ray leaves the wall agrees to 10⁻⁷ m with the first exit from [`inside`]'s
    /// union, found by 1 mm steps and bisection — for the rays that leave through a wall
    /// (not back through the start's plane), on both pieces (measured: 372 rays leave
    /// through the torus, 136 through the outlet).
    #[test]
    fn the_ray_exit_is_where_a_ray_leaves_the_union() {
        exits_match(&bend(), inside);
    }

    /// The same for an oval tube ([`oval_bend`]) against [`inside_oval`]: the round
    /// torus's crossing refined by Newton's method, and the outlet's ellipse.
    #[test]
    fn an_oval_tubes_ray_exit_is_where_a_ray_leaves_its_union() {
        exits_match(&oval_bend(), inside_oval);
        // A round tube's section by the same rotations is the round union.
        let g = bend();
        let p = Vector3::new(1.3, 0.1, 0.2);
        assert_eq!(inside(&g, &p), inside_oval(&g, &p));
    }

    /// Points at `offset` (m) off the wall of `g` along its section's radius (0: on the
    /// wall), 16 around the section (starting `phase` sixteenths of a turn from the
    /// outward radial direction) at each of three stations: turned 0.2 and 0.6 rad on the
    /// torus, and 0.3 m past the end of a bend of 0.8 rad on the outlet.
    fn around_the_wall(g: &BendGeometry, phase: f64, offset: f64) -> Vec<Vector3<f64>> {
        let u = Vector3::new(0.0, g.direction.cos(), g.direction.sin());
        let a = Vector3::x().cross(&u);
        let c = Vector3::new(g.start, 0.0, 0.0) + g.radius * u;
        let mut points = Vec::new();
        for (turned, extra) in [(0.2f64, 0.0), (0.6, 0.0), (0.8, 0.3)] {
            let radial = -turned.cos() * u + turned.sin() * Vector3::x();
            let tangent = turned.cos() * Vector3::x() + turned.sin() * u;
            for k in 0..16 {
                let psi = (k as f64 + phase) * std::f64::consts::TAU / 16.0;
                let towards = psi.cos() * radial + psi.sin() * a;
                points.push(
                    c + g.radius * radial
                        + extra * tangent
                        + (g.section_radius(psi) + offset) * towards,
                );
            }
        }
        points
    }

    /// On both pieces of an oval tube the normal is the gradient of the signed distance
    /// (central differences, 10⁻⁶ m) at points near the wall, and the signed distance of
    /// a wall point displaced along its normal by δ is δ to second order.
    #[test]
    fn an_oval_tubes_normal_is_its_distances_gradient() {
        let g = oval_bend();
        let wall = BendWall::new(&g).unwrap();
        let mut pieces = [0usize; 2];
        for p in around_the_wall(&g, 0.0, 0.0) {
            pieces[wall.piece(&p) as usize] += 1;
            assert!(wall.signed_distance(&p).abs() < 1e-12, "on the wall");
            let n = wall.normal(&p).unwrap().into_inner();
            let h = 1e-6;
            for (axis, nk) in [Vector3::x(), Vector3::y(), Vector3::z()]
                .iter()
                .zip(n.iter())
            {
                let fd = (wall.signed_distance(&(p + axis * h))
                    - wall.signed_distance(&(p - axis * h)))
                    / (2.0 * h);
                assert!((fd - nk).abs() < 1e-6, "{fd} vs {nk}");
            }
            let delta = 2e-3;
            let s = wall.signed_distance(&(p + n * delta));
            assert!((s - delta).abs() < 1e-4 * delta, "{s} vs {delta}");
        }
        assert_eq!(pieces, [32, 16], "torus and outlet points");
    }

    /// [`BendWall::distance_normal_and_gradient`] against central differences of
    /// [`BendWall::signed_distance`] of the walls at θ ± h·e_k (h = 10⁻⁶, in m and rad),
    /// at points all around the torus (turned 0.2 and 0.6 rad) and the outlet (0.3 m past
    /// the end): for the round and the oval tube on the wall, where the gradient is exact,
    /// and for the round tube also 2 cm inside and outside it (exact there too). The
    /// bound 10⁻⁸ on derivatives of order 1: central differences err by h²·s‴/6 ≈ 10⁻¹²
    /// (s‴ ~ 1/r² over a tube of r = 0.24 m) plus rounding, 10⁻¹⁶ m of distances of order
    /// 1 m over 2h: 10⁻¹⁰. Its distance and normal are [`BendWall::signed_distance`]'s
    /// and [`BendWall::normal`]'s.
    #[test]
    fn the_distances_gradient_in_the_placement_matches_differences() {
        for (g, offsets) in [(bend(), &[0.0, -0.02, 0.02][..]), (oval_bend(), &[0.0][..])] {
            let wall = BendWall::new(&g).unwrap();
            let x = g.to_vector();
            let h = 1e-6;
            let shifted: Vec<(BendWall, BendWall)> = (0..super::super::NP)
                .map(|k| {
                    let (mut up, mut down) = (x, x);
                    up[k] += h;
                    down[k] -= h;
                    (
                        BendWall::new(&BendGeometry::from_vector(&up)).unwrap(),
                        BendWall::new(&BendGeometry::from_vector(&down)).unwrap(),
                    )
                })
                .collect();
            let mut pieces = [0usize; 2];
            for off in offsets {
                for p in around_the_wall(&g, 0.3, *off) {
                    pieces[wall.piece(&p) as usize] += 1;
                    let (s, n, grad) = wall.distance_normal_and_gradient(&p).unwrap();
                    assert!((s - wall.signed_distance(&p)).abs() < 1e-12);
                    assert!(
                        (n.into_inner() - wall.normal(&p).unwrap().into_inner()).norm() < 1e-12
                    );
                    for (kk, (up, down)) in shifted.iter().enumerate() {
                        let fd = (up.signed_distance(&p) - down.signed_distance(&p)) / (2.0 * h);
                        assert!(
                            (grad[kk] - fd).abs() < 1e-8,
                            "ε {} offset {off} piece {:?} ∂s/∂θ{kk}: {} vs {fd}",
                            g.tube_ovality,
                            wall.piece(&p),
                            grad[kk]
                        );
                    }
                }
            }
            assert_eq!(
                pieces,
                [32 * offsets.len(), 16 * offsets.len()],
                "torus and outlet points"
            );
        }
    }

    /// [`BendWall::ray_exit`] against the first exit of `inside`'s union (see
    /// [`the_ray_exit_is_where_a_ray_leaves_the_union`]).
    fn exits_match(g: &BendGeometry, inside: fn(&BendGeometry, &Vector3<f64>) -> bool) {
        let g = *g;
        let wall = BendWall::new(&g).unwrap();
        let u = Vector3::new(0.0, g.direction.cos(), g.direction.sin());
        let centre = Vector3::new(g.start, 0.0, 0.0) + g.radius * u;
        let mut seen = [0usize; 2];
        for (k, turned) in [0.1f64, 0.5, 0.75].iter().enumerate() {
            let origin = centre
                + g.radius * (-turned.cos() * u + turned.sin() * Vector3::x())
                + 0.05 * Vector3::new(0.0, (k as f64).sin(), (k as f64).cos());
            assert!(inside(&g, &origin));
            for i in 0..200 {
                // Directions spread over the sphere (a Fibonacci lattice).
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / 200.0;
                let a = i as f64 * 2.399_963_229_728_653;
                let d = Vector3::new(
                    z,
                    (1.0 - z * z).sqrt() * a.cos(),
                    (1.0 - z * z).sqrt() * a.sin(),
                );
                let mut t = 0.0;
                while t < 5.0 && inside(&g, &(origin + d * (t + 1e-3))) {
                    t += 1e-3;
                }
                if t >= 5.0 {
                    continue;
                }
                let (mut lo, mut hi) = (t, t + 1e-3);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if inside(&g, &(origin + d * mid)) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let exit = origin + d * hi;
                if g.turned(&exit) < 0.0 {
                    continue; // back through the start's plane: no wall there
                }
                let (tau, piece) = wall.ray_exit(&origin, &d, 10.0).expect("an exit");
                assert!((tau - hi).abs() < 1e-7, "{tau} vs {hi} ({piece:?})");
                seen[piece as usize] += 1;
                assert_eq!(wall.piece(&exit) as usize, piece as usize);
                assert!(wall.signed_distance(&exit).abs() < 1e-7);
            }
        }
        assert!(seen[0] > 50 && seen[1] > 50, "{seen:?}");
    }
}
