//! What else a camera in a pipe sees: a floor layer (sediment, water), an obstacle on it,
//! a dent in the wall, and a partial view. Each is exact geometry in the PCS (X along the
//! axis, Y along the major axis, Z along the minor axis; the README's Conventions) with
//! its own closed-form ray cast, except the dent, whose wall is found by a bracketed root
//! search to the last bits of a `f64`.
//!
//! **Up and clock angle.** The pipe's "down" is −Z of the PCS: the *bottom* of the wall
//! is its lowest point (0, 0, −Dmin/2) of the cross-section. The *clock angle* of a point
//! (x, y, z) of the PCS is φ = atan2(y, z) taken in [0, 2π): 0 at the top (+Z,
//! 12 o'clock), π/2 at +Y (3 o'clock, looking along +X with Z up), π at the bottom
//! (6 o'clock).
//!
//! A [`Contamination`] is placed on a scene by [`crate::Scene::with_contamination`] and
//! then changes every ray cast of that scene ([`crate::Scene::cast`] and its variants):
//! a ray stops at the first of the wall (dented or not), the floor layer's surface and
//! the obstacle. The partial view does not change the geometry: it marks the pixels
//! whose hit lies outside the seen sector as invalid ([`crate::Scene::in_view`]).

use std::f64::consts::{PI, TAU};

use nalgebra::{Matrix3, Vector3};

use crate::error::{Rule, SimError, first_broken};

/// How far (in standard deviations) a dent's Gaussian reaches: beyond it the dent is
/// cut to 0 (there exp(−8²/2) = 1.3·10⁻¹⁴ of its depth, below a range's last bit).
pub const DENT_REACH: f64 = 8.0;

/// The scene contamination; every part `None` (the default) leaves the pipe as it was.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Contamination {
    /// A flat layer on the bottom of the pipe (sediment, standing water).
    pub floor: Option<FloorLayer>,
    /// An object lying on the floor layer (or on the bottom of the wall without one).
    pub obstacle: Option<Obstacle>,
    /// A local inward deformation of the wall.
    pub dent: Option<Dent>,
    /// The sector of clock angles the camera sees; pixels outside it are invalid.
    pub view: Option<ViewSector>,
}

/// A floor layer: everything of the pipe below the plane z = −Dmin/2 + `depth_m` (PCS),
/// a plane parallel to the axis `depth_m` above the bottom of the wall, endless along it
/// (past the end of a finite meshed wall, rays meet it far away). Rays that meet its
/// surface before the wall stop there, with the plane's normal +Z; under the physical
/// model it reflects as the wall does (`ToFPhysics::reflectivity`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FloorLayer {
    /// The layer's depth (m) above the bottom of the wall, in [0, Dmin); the sensor must
    /// lie above it.
    pub depth_m: f64,
}

/// An obstacle standing on the floor: on the floor layer's surface, or on the plane
/// z = −Dmin/2 through the bottom of the wall when there is no layer (its corners then
/// pass through the wall, where no ray from inside sees them). Its *base* z_b is that
/// plane's height (PCS).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Obstacle {
    /// An axis-aligned box (PCS): x in [`x_m`, `x_m` + `length_m`], y in
    /// [`y_m` − `width_m`/2, `y_m` + `width_m`/2], z in [z_b, z_b + `height_m`].
    Box {
        /// Its near face's distance along the axis (m, PCS x).
        x_m: f64,
        /// Its length along the axis (m), > 0.
        length_m: f64,
        /// Its width across the pipe (m, along PCS Y), > 0.
        width_m: f64,
        /// Its height above the base (m), > 0.
        height_m: f64,
        /// The lateral position of its centre line (m, PCS y).
        y_m: f64,
    },
    /// Half of a circular cylinder lying across the pipe, flat side down: its axis along
    /// PCS Y at x = `x_m`, z = z_b; the solid (x − `x_m`)² + (z − z_b)² ≤ `radius_m`²,
    /// z ≥ z_b (a fallen pipe section, a weld bead), cut by the wall at its ends.
    HalfCylinder {
        /// Its axis' distance along the pipe axis (m, PCS x).
        x_m: f64,
        /// Its radius (m), > 0.
        radius_m: f64,
    },
}

/// A dent: the wall pushed inwards, towards the axis, by a Gaussian of depth h. In
/// cylindrical coordinates of the PCS (x, ρ = √(y² + z²), clock angle φ) the wall lies
/// at ρ_w(x, φ) = ρ_E(φ) − h·G(x, φ), with ρ_E(φ) = (sin²φ/a² + cos²φ/b²)^(−1/2) the
/// undented ellipse (a = Dmax/2, b = Dmin/2) and
/// G = exp(−(x − x_d)²/(2 s_x²) − (R̄·Δφ)²/(2 s_c²)), Δφ = φ − φ_d wrapped into (−π, π],
/// R̄ = (a + b)/2; G is cut to 0 beyond [`DENT_REACH`] standard deviations. So the wall
/// point at (x_d, φ_d) moves radially inwards by exactly h.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dent {
    /// Its centre's distance along the axis x_d (m, PCS x).
    pub x_m: f64,
    /// Its centre's clock angle φ_d (rad, see the module doc).
    pub clock_rad: f64,
    /// Its depth h (m), radially inwards at the centre, in [0, min(a, b)/2].
    pub depth_m: f64,
    /// Its extent along the axis: the Gaussian's standard deviation s_x (m), in
    /// [1 mm, 10 m].
    pub axial_sigma_m: f64,
    /// Its extent around the wall: the standard deviation s_c (m) of arc length R̄·Δφ,
    /// in [1 mm, 10 m].
    pub circumferential_sigma_m: f64,
}

/// A sector of clock angles (see the module doc): a pixel is valid when the clock
/// angle φ of its hit (PCS) satisfies (φ − `start_rad`) mod 2π ≤ `width_rad`, that is,
/// from `start_rad` clockwise (increasing φ) through `width_rad`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewSector {
    /// Where the seen sector starts (rad, finite).
    pub start_rad: f64,
    /// Its width (rad), in (0, 2π]; 2π sees everything.
    pub width_rad: f64,
}

impl ViewSector {
    /// The upper half blocked: only the lower half, from 3 o'clock through 6 to 9
    /// (φ in [π/2, 3π/2]), is seen.
    pub fn upper_half_blocked() -> Self {
        Self {
            start_rad: 0.5 * PI,
            width_rad: PI,
        }
    }

    /// Whether clock angle `phi` (rad) lies in the sector.
    pub fn contains(&self, phi: f64) -> bool {
        (phi - self.start_rad).rem_euclid(TAU) <= self.width_rad
    }
}

/// The clock angle φ = atan2(y, z) in [0, 2π) of a PCS point (module doc).
pub fn clock_angle(p: &Vector3<f64>) -> f64 {
    p.y.atan2(p.z).rem_euclid(TAU)
}

/// The radius ρ_E(φ) = (sin²φ/a² + cos²φ/b²)^(−1/2) of the ellipse y²/a² + z²/b² = 1 at
/// clock angle φ, and its derivative dρ_E/dφ = −ρ_E³·sin φ·cos φ·(1/a² − 1/b²).
fn ellipse_radius(a: f64, b: f64, phi: f64) -> (f64, f64) {
    let (s, c) = phi.sin_cos();
    let (ia2, ib2) = (1.0 / (a * a), 1.0 / (b * b));
    let r = 1.0 / (s * s * ia2 + c * c * ib2).sqrt();
    (r, -r * r * r * s * c * (ia2 - ib2))
}

/// φ − φ_d wrapped into (−π, π].
fn wrap(d: f64) -> f64 {
    let w = d.rem_euclid(TAU);
    if w > PI { w - TAU } else { w }
}

impl Dent {
    /// The Gaussian G(x, φ) (cut at [`DENT_REACH`]) and its partial derivatives
    /// (∂G/∂x, ∂G/∂φ), for a pipe of mean radius `r_mean`.
    fn gaussian(&self, x: f64, phi: f64, r_mean: f64) -> (f64, f64, f64) {
        let (sx, sphi) = (self.axial_sigma_m, self.circumferential_sigma_m / r_mean);
        let (dx, dphi) = (x - self.x_m, wrap(phi - self.clock_rad));
        if dx.abs() > DENT_REACH * sx || dphi.abs() > DENT_REACH * sphi {
            return (0.0, 0.0, 0.0);
        }
        let g = (-0.5 * (dx * dx / (sx * sx) + dphi * dphi / (sphi * sphi))).exp();
        (g, -g * dx / (sx * sx), -g * dphi / (sphi * sphi))
    }
}

/// A contamination placed in one scene: the parts, the pipe's semi-axes and the ray
/// origin and rotation that take SCS rays into the PCS.
#[derive(Clone, Debug)]
pub(crate) struct Placed {
    pub(crate) parts: Contamination,
    /// Semi-axes a = Dmax/2, b = Dmin/2 (m).
    a: f64,
    b: f64,
    /// R of eq. (3), SCS → PCS directions.
    rot: Matrix3<f64>,
    /// The sensor in the PCS, [0, δy, δz].
    origin: Vector3<f64>,
    /// The floor layer's surface z_f (PCS), if any.
    floor_z: Option<f64>,
    /// The obstacle's base z_b (PCS).
    base_z: f64,
    /// (sin φ_d, cos φ_d) of the dent's clock angle (0, 1 without a dent).
    dent_sin_cos: (f64, f64),
}

/// A hit on the contaminated scene: range along the unit SCS ray (m) and the unit
/// normal of the surface hit, in the PCS (zero when the cast was asked for no normal).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Hit {
    pub(crate) range: f64,
    pub(crate) normal: Vector3<f64>,
}

impl Placed {
    /// Check `c` and place it in the pipe of semi-axes `a`, `b` seen from the sensor at
    /// PCS `origin` with SCS → PCS rotation `rot`. `exact_wall`: whether the wall is the
    /// exact elliptic cylinder (a dent needs it).
    pub(crate) fn new(
        c: Contamination,
        a: f64,
        b: f64,
        rot: Matrix3<f64>,
        origin: Vector3<f64>,
        exact_wall: bool,
    ) -> Result<Self, SimError> {
        use Rule::{Finite, Holds, Positive};
        let o = origin;
        let floor_z = match c.floor {
            None => None,
            Some(f) => {
                let d = f.depth_m;
                if !(d.is_finite() && (0.0..2.0 * b).contains(&d)) {
                    return Err(SimError::invalid(
                        "contamination.floor.depth_m",
                        d,
                        "must lie in [0, Dmin)",
                    ));
                }
                let z = -b + d;
                if o.z <= z {
                    return Err(SimError::invalid(
                        "contamination.floor.depth_m",
                        d,
                        "puts the sensor (PCS z = δz) in the layer: the layer must stay below it",
                    ));
                }
                Some(z)
            }
        };
        let base_z = floor_z.unwrap_or(-b);
        match c.obstacle {
            None => {}
            Some(Obstacle::Box {
                x_m,
                length_m,
                width_m,
                height_m,
                y_m,
            }) => {
                let checks = [
                    ("contamination.obstacle.x_m", x_m, Finite),
                    ("contamination.obstacle.length_m", length_m, Positive),
                    ("contamination.obstacle.width_m", width_m, Positive),
                    ("contamination.obstacle.height_m", height_m, Positive),
                    ("contamination.obstacle.y_m", y_m, Finite),
                ];
                if let Some((k, v, r)) = first_broken(checks) {
                    return Err(SimError::invalid(k, v, r.reason()));
                }
                let inside = (x_m..=x_m + length_m).contains(&o.x)
                    && (o.y - y_m).abs() <= 0.5 * width_m
                    && o.z <= base_z + height_m;
                if inside {
                    return Err(SimError::invalid(
                        "contamination.obstacle.x_m",
                        x_m,
                        "puts the sensor inside the obstacle",
                    ));
                }
            }
            Some(Obstacle::HalfCylinder { x_m, radius_m }) => {
                let checks = [
                    ("contamination.obstacle.x_m", x_m, Finite),
                    ("contamination.obstacle.radius_m", radius_m, Positive),
                ];
                if let Some((k, v, r)) = first_broken(checks) {
                    return Err(SimError::invalid(k, v, r.reason()));
                }
                if (o.x - x_m).hypot(o.z - base_z) <= radius_m {
                    return Err(SimError::invalid(
                        "contamination.obstacle.x_m",
                        x_m,
                        "puts the sensor inside the obstacle",
                    ));
                }
            }
        }
        if let Some(d) = c.dent {
            let extent = |s: f64| s.is_finite() && (1e-3..=10.0).contains(&s);
            let checks = [
                ("contamination.dent.x_m", d.x_m, Finite),
                ("contamination.dent.clock_rad", d.clock_rad, Finite),
                (
                    "contamination.dent.depth_m",
                    d.depth_m,
                    Holds(
                        d.depth_m.is_finite() && d.depth_m >= 0.0 && d.depth_m <= 0.5 * a.min(b),
                        "must lie in [0, min(Dmax, Dmin)/4]",
                    ),
                ),
                (
                    "contamination.dent.axial_sigma_m",
                    d.axial_sigma_m,
                    Holds(extent(d.axial_sigma_m), "must lie in [0.001, 10] m"),
                ),
                (
                    "contamination.dent.circumferential_sigma_m",
                    d.circumferential_sigma_m,
                    Holds(
                        extent(d.circumferential_sigma_m),
                        "must lie in [0.001, 10] m",
                    ),
                ),
            ];
            if let Some((k, v, r)) = first_broken(checks) {
                return Err(SimError::invalid(k, v, r.reason()));
            }
            if !exact_wall {
                return Err(SimError::invalid(
                    "contamination.dent",
                    "on a meshed or pipeline wall",
                    "a dent needs the exact elliptic wall (WallModel::Exact)",
                ));
            }
        }
        if let Some(v) = c.view {
            let checks = [
                ("contamination.view.start_rad", v.start_rad, Finite),
                (
                    "contamination.view.width_rad",
                    v.width_rad,
                    Holds(
                        v.width_rad > 0.0 && v.width_rad <= TAU,
                        "must lie in (0, 2π]",
                    ),
                ),
            ];
            if let Some((k, val, r)) = first_broken(checks) {
                return Err(SimError::invalid(k, val, r.reason()));
            }
        }
        let placed = Self {
            parts: c,
            a,
            b,
            rot,
            origin,
            floor_z,
            base_z,
            dent_sin_cos: c.dent.map_or((0.0, 1.0), |d| d.clock_rad.sin_cos()),
        };
        if c.dent.is_some() && placed.dent_implicit(&origin) >= 0.0 {
            return Err(SimError::invalid(
                "contamination.dent.depth_m",
                c.dent.map_or(0.0, |d| d.depth_m),
                "puts the sensor outside the dented wall",
            ));
        }
        Ok(placed)
    }

    /// The unit SCS ray `dir` in the PCS.
    pub(crate) fn to_pcs(&self, dir: &Vector3<f64>) -> Vector3<f64> {
        self.rot * dir
    }

    /// Whether the hit at `range` along SCS `dir` lies in the seen sector.
    pub(crate) fn in_view(&self, dir: &Vector3<f64>, range: f64) -> bool {
        match &self.parts.view {
            None => true,
            Some(v) => v.contains(clock_angle(&(self.origin + self.to_pcs(dir) * range))),
        }
    }

    /// The first hit along the unit SCS ray `dir` within `max_range`: the nearest of the
    /// wall (`wall(limit)`: the undented wall's hit within `limit`, range and PCS normal,
    /// cast without a limit when there is a dent), the floor layer and the obstacle. The
    /// dented wall's normal only `with_normal` (else zero, as `wall` may give it).
    pub(crate) fn cast(
        &self,
        dir: &Vector3<f64>,
        max_range: f64,
        with_normal: bool,
        wall: impl FnOnce(f64) -> Option<Hit>,
    ) -> Option<Hit> {
        let d = self.to_pcs(dir);
        let mut best = match &self.parts.dent {
            None => wall(max_range),
            Some(dent) => {
                wall(f64::INFINITY).map(|h| self.dent_cast(dent, &d, h.range, with_normal))
            }
        }
        .filter(|h| h.range <= max_range);
        let mut take = |h: Option<Hit>| {
            if let Some(h) = h
                && h.range <= max_range
                && best.is_none_or(|b| h.range < b.range)
            {
                best = Some(h);
            }
        };
        if let Some(zf) = self.floor_z {
            take(self.floor_cast(zf, &d));
        }
        if let Some(ob) = &self.parts.obstacle {
            take(self.obstacle_cast(ob, &d));
        }
        best
    }

    /// The floor's surface z = z_f, met from above: t = (z_f − o_z)/d_z for d_z < 0.
    fn floor_cast(&self, zf: f64, d: &Vector3<f64>) -> Option<Hit> {
        (d.z < 0.0).then(|| Hit {
            range: (zf - self.origin.z) / d.z,
            normal: Vector3::z(),
        })
    }

    /// The obstacle's entry point along the PCS ray `d` from the sensor.
    fn obstacle_cast(&self, ob: &Obstacle, d: &Vector3<f64>) -> Option<Hit> {
        let o = self.origin;
        match *ob {
            Obstacle::Box {
                x_m,
                length_m,
                width_m,
                height_m,
                y_m,
            } => {
                // Slabs: the ray enters the box at the largest entry time of the three.
                let lo = [x_m, y_m - 0.5 * width_m, self.base_z];
                let hi = [x_m + length_m, y_m + 0.5 * width_m, self.base_z + height_m];
                let (mut t_in, mut t_out, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
                for k in 0..3 {
                    if d[k] == 0.0 {
                        if o[k] < lo[k] || o[k] > hi[k] {
                            return None;
                        }
                        continue;
                    }
                    let (t0, t1) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
                    let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
                    if near > t_in {
                        t_in = near;
                        axis = k;
                    }
                    t_out = t_out.min(far);
                }
                if t_in > t_out || t_in <= 0.0 {
                    return None;
                }
                let mut n = Vector3::zeros();
                n[axis] = -d[axis].signum();
                Some(Hit {
                    range: t_in,
                    normal: n,
                })
            }
            Obstacle::HalfCylinder { x_m, radius_m } => {
                // (o_x + t d_x − x_m)² + (o_z + t d_z − z_b)² = R²: the entry root, on
                // the upper half (from above the base the ray cannot reach the flat side).
                let (px, pz) = (o.x - x_m, o.z - self.base_z);
                let qa = d.x * d.x + d.z * d.z;
                let qb = px * d.x + pz * d.z;
                let qc = px * px + pz * pz - radius_m * radius_m;
                let disc = qb * qb - qa * qc;
                if qa == 0.0 || disc < 0.0 || qc <= 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                // The smaller root, without cancellation (qc > 0: both roots share a sign).
                let t = if qb < 0.0 {
                    qc / (sq - qb)
                } else {
                    -(qb + sq) / qa
                };
                let zt = pz + t * d.z;
                if t <= 0.0 || zt < 0.0 {
                    return None;
                }
                let n = Vector3::new(px + t * d.x, 0.0, zt) / radius_m;
                Some(Hit {
                    range: t,
                    normal: n,
                })
            }
        }
    }

    /// F(p) = ρ − ρ_w(x, φ) = ρ − ρ_E(φ) + h·G(x, φ) at PCS point `p`: < 0 inside the
    /// dented wall, 0 on it.
    ///
    /// Without trigonometry but one atan2: ρ_E(φ) = ρ / √(y²/a² + z²/b²), and
    /// Δφ = atan2(y cos φ_d − z sin φ_d, z cos φ_d + y sin φ_d), only within the dent's
    /// axial reach.
    fn dent_implicit(&self, p: &Vector3<f64>) -> f64 {
        let Some(dent) = &self.parts.dent else {
            return f64::NAN;
        };
        let (y2, z2) = (p.y * p.y, p.z * p.z);
        let rho = (y2 + z2).sqrt();
        let re = rho / (y2 / (self.a * self.a) + z2 / (self.b * self.b)).sqrt();
        let sx = dent.axial_sigma_m;
        let dx = p.x - dent.x_m;
        if dx.abs() > DENT_REACH * sx {
            return rho - re;
        }
        let sphi = dent.circumferential_sigma_m / (0.5 * (self.a + self.b));
        let (sd, cd) = self.dent_sin_cos;
        let dphi = (p.y * cd - p.z * sd).atan2(p.z * cd + p.y * sd);
        if dphi.abs() > DENT_REACH * sphi {
            return rho - re;
        }
        let g = (-0.5 * (dx * dx / (sx * sx) + dphi * dphi / (sphi * sphi))).exp();
        rho - re + dent.depth_m * g
    }

    /// A bound on |d²F/dt²| along a unit ray where ρ ≥ b − h (the only stretch searched),
    /// with a safety factor 2: ρ″ ≤ 1/ρ; (ρ_E∘φ)″ = ρ_E″φ′² + ρ_E′φ″ with φ′ ≤ 1/ρ,
    /// |φ″| ≤ 2/ρ², |ρ_E′|, |ρ_E″| ≤ 2|a − b|·((a/b)³ + (b/a)³); (hG)″ ≤ 2h·(1/s_x² +
    /// (R̄/(ρ s_c))²) (the Gaussian's second derivative along the ray).
    fn dent_curvature(&self, dent: &Dent) -> f64 {
        let (a, b) = (self.a, self.b);
        let rho = a.min(b) - dent.depth_m;
        let k = 2.0 * (a - b).abs() * ((a / b).powi(3) + (b / a).powi(3));
        let r_mean = 0.5 * (a + b);
        let g = 2.0
            * dent.depth_m
            * (1.0 / dent.axial_sigma_m.powi(2)
                + (r_mean / (rho * dent.circumferential_sigma_m)).powi(2));
        2.0 * (1.0 / rho + 3.0 * k / (rho * rho) + g)
    }

    /// The unit outward normal ∇F/|∇F| of the dented wall at PCS point `p`:
    /// ∇F = ∂F/∂x e_x + e_ρ + (1/ρ)∂F/∂φ e_φ, e_ρ = (0, sin φ, cos φ),
    /// e_φ = (0, cos φ, −sin φ), ∂F/∂x = h ∂G/∂x, ∂F/∂φ = −ρ_E′(φ) + h ∂G/∂φ.
    fn dent_normal(&self, dent: &Dent, p: &Vector3<f64>) -> Vector3<f64> {
        let phi = clock_angle(p);
        let rho = p.y.hypot(p.z);
        let (_, dre) = ellipse_radius(self.a, self.b, phi);
        let (_, gx, gphi) = dent.gaussian(p.x, phi, 0.5 * (self.a + self.b));
        let (s, c) = phi.sin_cos();
        let fx = dent.depth_m * gx;
        let fphi = (-dre + dent.depth_m * gphi) / rho;
        Vector3::new(fx, s + fphi * c, c - fphi * s).normalize()
    }

    /// The first crossing of the dented wall along the PCS ray `d` (unit) from the
    /// sensor, given the undented wall's range `t_e`. The dent lies inside the ellipse
    /// (h ≥ 0), so the crossing is in (0, t_e]: where the ray passes the dent's reach
    /// (|x − x_d| ≤ 8 s_x), F is sampled in steps of at most s_x/(4|d_x|) and
    /// s_c/(4|d_yz|) (a quarter of the dent's scale); the first sign change is bisected
    /// to adjacent floats. A ray that skims the dent's crest goes out and back in within
    /// a step (over k²s²/h in x for a ray of slope k against a crest of depth h and width
    /// s): at every negative local maximum of the samples, F's maximum between its
    /// neighbours is found by golden section, and a crossing before it bisected if it
    /// reaches 0. No crossing: the ellipse at t_e.
    fn dent_cast(&self, dent: &Dent, d: &Vector3<f64>, t_e: f64, with_normal: bool) -> Hit {
        let o = self.origin;
        let at = |t: f64| o + d * t;
        let hit = |t: f64| Hit {
            range: t,
            normal: if with_normal {
                self.dent_normal(dent, &at(t))
            } else {
                Vector3::zeros()
            },
        };
        let ellipse = hit;
        // The t-interval of the dent's axial reach, within (0, t_e].
        let reach = DENT_REACH * dent.axial_sigma_m;
        let (mut t0, mut t1) = if d.x.abs() < 1e-300 {
            if (o.x - dent.x_m).abs() > reach {
                return ellipse(t_e);
            }
            (0.0, t_e)
        } else {
            let ta = (dent.x_m - reach - o.x) / d.x;
            let tb = (dent.x_m + reach - o.x) / d.x;
            (ta.min(tb), ta.max(tb))
        };
        t0 = t0.max(0.0);
        t1 = t1.min(t_e);
        // Only where ρ ≥ b − h (no wall point is nearer the axis; for a > b too, as
        // ρ_E ≥ min(a, b)) can the ray meet the dent: ρ(t)² = |o_yz + t·d_yz|² is convex,
        // so that is t ≥ the larger root of ρ(t)² = (b − h)².
        let rho_min = self.a.min(self.b) - dent.depth_m;
        let qa = d.y * d.y + d.z * d.z;
        let qb = o.y * d.y + o.z * d.z;
        let qc = o.y * o.y + o.z * o.z - rho_min * rho_min;
        if qa > 0.0 && qc < 0.0 {
            t0 = t0.max((-qb + (qb * qb - qa * qc).sqrt()) / qa);
        }
        if t0 >= t1 {
            return ellipse(t_e);
        }
        // The clock angle sweeps monotonically along a line (its projection on the YZ
        // plane misses the axis there, ρ ≥ b − h > 0), through less than π: skip a ray
        // whose arc [φ(t0), φ(t1)] stays beyond the dent's angular reach.
        let r_mean = 0.5 * (self.a + self.b);
        let reach_phi = DENT_REACH * dent.circumferential_sigma_m / r_mean;
        if reach_phi < PI {
            let (p0, p1) = (clock_angle(&at(t0)), clock_angle(&at(t1)));
            let sweep = wrap(p1 - p0);
            let (from, width) = if sweep >= 0.0 {
                (p0, sweep)
            } else {
                (p1, -sweep)
            };
            let rel = (dent.clock_rad - from).rem_euclid(TAU);
            let gap = if rel <= width {
                0.0
            } else {
                (rel - width).min(TAU - rel)
            };
            if gap > reach_phi {
                return ellipse(t_e);
            }
        }
        let dyz = d.y.hypot(d.z);
        let mut step = f64::INFINITY;
        if d.x.abs() > 0.0 {
            step = step.min(0.25 * dent.axial_sigma_m / d.x.abs());
        }
        if dyz > 0.0 {
            step = step.min(0.25 * dent.circumferential_sigma_m / dyz);
        }
        let n = ((t1 - t0) / step).ceil().clamp(1.0, 1e6) as usize;
        let f = |t: f64| self.dent_implicit(&at(t));
        let sample = |k: usize| {
            if k == n {
                t1
            } else {
                t0 + (t1 - t0) * k as f64 / n as f64
            }
        };
        // (t, F) at samples k − 1 and k.
        let mut prev: Option<(f64, f64)> = None;
        let mut cur = (t0, f(t0));
        for k in 1..=n {
            let next = (sample(k), f(sample(k)));
            if cur.1 < 0.0 && next.1 >= 0.0 {
                return hit(bisect(&f, cur.0, next.0));
            }
            // A local maximum below 0: the ray may cross the crest and come back between
            // samples. Its maximum by golden section; if it reaches 0, the crossing
            // before it.
            if let Some(p) = prev
                && cur.1 > p.1
                && cur.1 >= next.1
            {
                let (tm, fm) = golden_max(&f, p.0, next.0, self.dent_curvature(dent));
                if fm >= 0.0 {
                    let t_lo = if tm > cur.0 && cur.1 < 0.0 {
                        cur.0
                    } else {
                        p.0
                    };
                    return hit(bisect(&f, t_lo, tm));
                }
            }
            prev = Some(cur);
            cur = next;
        }
        ellipse(t_e)
    }
}

/// The maximum of `f` on [lo, hi], assumed unimodal there, by golden-section search:
/// (argmax, max), stopped as soon as a value ≥ 0 is found, or the bracket is down to
/// adjacent floats, or the maximum is certainly < 0: with |f″| ≤ `curvature`, the
/// maximum exceeds the best value found by at most ½·curvature·w² (w the bracket's
/// width, which holds the maximum).
fn golden_max(f: &impl Fn(f64) -> f64, mut lo: f64, mut hi: f64, curvature: f64) -> (f64, f64) {
    const INV_PHI: f64 = 0.618_033_988_749_894_9;
    let mut x1 = hi - INV_PHI * (hi - lo);
    let mut x2 = lo + INV_PHI * (hi - lo);
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..200 {
        if f1 >= 0.0 {
            return (x1, f1);
        }
        if f2 >= 0.0 {
            return (x2, f2);
        }
        if !(x1 > lo && x2 < hi && x1 < x2)
            || f1.max(f2) + 0.5 * curvature * (hi - lo).powi(2) < 0.0
        {
            break;
        }
        if f1 < f2 {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + INV_PHI * (hi - lo);
            f2 = f(x2);
        } else {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - INV_PHI * (hi - lo);
            f1 = f(x1);
        }
    }
    if f1 >= f2 { (x1, f1) } else { (x2, f2) }
}

/// The root of `f` in [lo, hi] with f(lo) < 0 ≤ f(hi), to adjacent floats: the
/// Illinois variant of regula falsi (superlinear), with a bisection step whenever a step
/// leaves the bracket wider than half of what it was two steps before, so the bracket
/// always closes; returns its end where f ≥ 0.
fn bisect(f: &impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let (mut f_lo, mut f_hi) = (f(lo), f(hi));
    if f_hi == 0.0 {
        return hi;
    }
    // Which end moved last: −1 lo, +1 hi.
    let mut side = 0;
    let mut widths = [hi - lo; 2];
    for k in 0..400 {
        let width = hi - lo;
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        let falsi = hi - f_hi * (hi - lo) / (f_hi - f_lo);
        let x = if width > 0.5 * widths[k % 2] || !(falsi > lo && falsi < hi) {
            mid
        } else {
            falsi
        };
        widths[k % 2] = width;
        let fx = f(x);
        if fx < 0.0 {
            lo = x;
            f_lo = fx;
            if side == -1 {
                f_hi *= 0.5;
            }
            side = -1;
        } else {
            hi = x;
            f_hi = fx;
            if fx == 0.0 {
                break;
            }
            if side == 1 {
                f_lo *= 0.5;
            }
            side = 1;
        }
    }
    hi
}

#[cfg(test)]
mod tests;
