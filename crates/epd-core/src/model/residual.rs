//! The three residual functions of the fit and their analytic gradients over β.
//!
//! All three share one geometry ([`Geometry`]): the rotation of eq. (3) and, for the
//! error-based residuals, the root t of eq. (22) where the sensing line through the
//! sensor origin x0_P and the measured point x̂_P meets the ellipse of eq. (5) in the
//! PCS YZ plane.
//!
//! Notation used below, for one measured point p (SCS) and parameters β:
//! - q = R·p, so x̂_P = q + [0, δy, δz]; (u, v) = (q_y, q_z) is the YZ projection of the
//!   sensing line from x0_P to x̂_P and ρ = ‖(u, v)‖ its length.
//! - α = (2/Dmax)², γ = (2/Dmin)², (y0, z0) = (δy, δz).
//! - t > 0 is the root of eq. (22): A t² + 2B t + C = 0 with A = αu² + γv²,
//!   B = α y0 u + γ z0 v, C = α y0² + γ z0² − 1 < 0 (sensor inside);
//!   S = √(B² − AC) = A t + B > 0.
//! - (Y, Z) = (y0 + t u, z0 + t v) is the wall point, and implicit differentiation gives
//!   ∂t/∂α = −Y²/(2S), ∂t/∂γ = −Z²/(2S), ∂t/∂y0 = −αY/S, ∂t/∂z0 = −γZ/S,
//!   ∂t/∂u = −tαY/S, ∂t/∂v = −tγZ/S.

use nalgebra::Matrix3;

use crate::params::{N_PARAMS, Params};

#[cfg(target_arch = "x86_64")]
mod avx2;

/// Which residual the fit minimises (eq. 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Residual {
    /// C-EPD, eq. (6): r_c = ŷ²/(Dmax/2)² + ẑ²/(Dmin/2)² − 1 (dimensionless).
    Canonical,
    /// RU-EPD, eqs. (20)–(23): r_d = (1 − t)·‖(ŷ − y0, ẑ − z0)‖, the signed depth error
    /// projected on the PCS YZ plane (m), positive beyond the wall.
    ErrorBased,
    /// ML-EPD (ours): r_m = (1 − t)·‖x̂_P − x0_P‖, the signed range error along the
    /// sensing line (m): the maximum-likelihood residual for noise along the ray.
    /// Since rotations keep lengths, ‖x̂_P − x0_P‖ = ‖p‖, the measured range.
    Range,
}

/// Per-β quantities shared by all points: the rows of R (eq. 3) that the residuals use,
/// their derivatives over the three angles, and the ellipse coefficients.
#[derive(Clone, Copy, Debug)]
pub struct Geometry {
    /// Rows X, Y and Z of R = Rz·Ry·Rx (SCS → PCS).
    r_x: [f64; 3],
    r_y: [f64; 3],
    r_z: [f64; 3],
    /// Rows Y and Z of ∂R/∂θx, ∂R/∂θy, ∂R/∂θz.
    dr_y: [[f64; 3]; 3],
    dr_z: [[f64; 3]; 3],
    /// α = (2/Dmax)², γ = (2/Dmin)².
    alpha: f64,
    gamma: f64,
    /// dα/dDmax = −8/Dmax³, dγ/dDmin = −8/Dmin³.
    dalpha: f64,
    dgamma: f64,
    /// Sensor origin (y0, z0) = (δy, δz) in the PCS.
    y0: f64,
    z0: f64,
    /// C = α y0² + γ z0² − 1 (< 0 inside the pipe).
    c: f64,
}

/// Elementary rotation about X, Y or Z and its derivative over the angle.
fn elementary(axis: usize, a: f64) -> (Matrix3<f64>, Matrix3<f64>) {
    let (s, c) = a.sin_cos();
    match axis {
        0 => (
            Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
            Matrix3::new(0.0, 0.0, 0.0, 0.0, -s, -c, 0.0, c, -s),
        ),
        1 => (
            Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c),
            Matrix3::new(-s, 0.0, c, 0.0, 0.0, 0.0, -c, 0.0, -s),
        ),
        _ => (
            Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(-s, -c, 0.0, c, -s, 0.0, 0.0, 0.0, 0.0),
        ),
    }
}

fn row(m: &Matrix3<f64>, i: usize) -> [f64; 3] {
    [m[(i, 0)], m[(i, 1)], m[(i, 2)]]
}

#[inline(always)]
fn dot(a: &[f64; 3], p: &[f64; 3]) -> f64 {
    a[0] * p[0] + a[1] * p[1] + a[2] * p[2]
}

/// The chunk's total of [`Geometry::range_sum_of_squares`]: the squares of the last few
/// points' residuals (`rest`, by `residual`) summed from zero in order, then the four
/// lane sums in order, as the solver's kernel orders its cost.
#[inline(always)]
fn sum_lanes(rest: &[[f64; 3]], lanes: [f64; 4], residual: impl Fn(&[f64; 3]) -> f64) -> f64 {
    let mut total = 0.0;
    for p in rest {
        let r = residual(p);
        total += r * r;
    }
    for v in lanes {
        total += v;
    }
    total
}

/// How many points of `points` have |residual| beyond each of `limits`.
fn count_beyond<const K: usize>(
    points: &[[f64; 3]],
    limits: &[f64; K],
    residual: impl Fn(&[f64; 3]) -> f64,
) -> [usize; K] {
    let mut n = [0; K];
    for p in points {
        let r = residual(p).abs();
        for (c, l) in n.iter_mut().zip(limits) {
            *c += usize::from(r > *l);
        }
    }
    n
}

impl Geometry {
    /// The shared geometry at β, or `None` when β is outside the model's domain:
    /// a non-positive or non-finite diameter, or the sensor origin not strictly inside
    /// the ellipse (then eq. 22 has no positive root for some lines).
    pub fn new(beta: &Params) -> Option<Self> {
        if !beta.is_finite() || !beta.sensor_inside() {
            return None;
        }
        let (rx, drx) = elementary(0, beta.roll);
        let (ry, dry) = elementary(1, beta.pitch);
        let (rz, drz) = elementary(2, beta.yaw);
        let r = rz * ry * rx;
        let d = [rz * ry * drx, rz * dry * rx, drz * ry * rx];
        let alpha = 4.0 / (beta.d_max * beta.d_max);
        let gamma = 4.0 / (beta.d_min * beta.d_min);
        let (y0, z0) = (beta.dy, beta.dz);
        Some(Self {
            r_x: row(&r, 0),
            r_y: row(&r, 1),
            r_z: row(&r, 2),
            dr_y: [row(&d[0], 1), row(&d[1], 1), row(&d[2], 1)],
            dr_z: [row(&d[0], 2), row(&d[1], 2), row(&d[2], 2)],
            alpha,
            gamma,
            dalpha: -8.0 / beta.d_max.powi(3),
            dgamma: -8.0 / beta.d_min.powi(3),
            y0,
            z0,
            c: alpha * y0 * y0 + gamma * z0 * z0 - 1.0,
        })
    }

    /// The residual of one measured point `p` (SCS, m) and its gradient over β in the
    /// order of eq. (2). Always finite for a finite, non-zero `p`.
    #[inline(always)]
    pub fn residual_and_gradient(&self, kind: Residual, p: &[f64; 3]) -> (f64, [f64; N_PARAMS]) {
        let (r, g) = self.residuals_and_gradients::<1>(kind, &[*p]);
        (r[0], g.map(|c| c[0]))
    }

    /// [`residual_and_gradient`](Self::residual_and_gradient) for `L` points at once,
    /// lane by lane (the compiler turns the lanes into SIMD). Returns the residuals and,
    /// per parameter, the gradient lanes.
    #[inline(always)]
    pub fn residuals_and_gradients<const L: usize>(
        &self,
        kind: Residual,
        p: &[[f64; 3]; L],
    ) -> ([f64; L], [[f64; L]; N_PARAMS]) {
        let (u, v, du, dv) = self.projections(p);
        let (r, g_prim) = self.primitives(kind, p, &u, &v);
        self.chain(r, g_prim, &du, &dv)
    }

    /// The rotated coordinates (u, v) = (R_y·p, R_z·p) of `L` points and their
    /// derivatives over the three angles.
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    fn projections<const L: usize>(
        &self,
        p: &[[f64; 3]; L],
    ) -> ([f64; L], [f64; L], [[f64; L]; 3], [[f64; L]; 3]) {
        let u: [f64; L] = std::array::from_fn(|l| dot(&self.r_y, &p[l]));
        let v: [f64; L] = std::array::from_fn(|l| dot(&self.r_z, &p[l]));
        let du: [[f64; L]; 3] =
            std::array::from_fn(|k| std::array::from_fn(|l| dot(&self.dr_y[k], &p[l])));
        let dv: [[f64; L]; 3] =
            std::array::from_fn(|k| std::array::from_fn(|l| dot(&self.dr_z[k], &p[l])));
        (u, v, du, dv)
    }

    /// The gradients over β from those over the primitives (α, γ, y0, z0, u, v), by the
    /// chain rule through α(Dmax), γ(Dmin) and (u, v)(angles).
    #[inline(always)]
    fn chain<const L: usize>(
        &self,
        r: [f64; L],
        g_prim: [[f64; L]; 6],
        du: &[[f64; L]; 3],
        dv: &[[f64; L]; 3],
    ) -> ([f64; L], [[f64; L]; N_PARAMS]) {
        let [g_alpha, g_gamma, g_y0, g_z0, g_u, g_v] = g_prim;
        let g: [[f64; L]; N_PARAMS] = [
            std::array::from_fn(|l| g_alpha[l] * self.dalpha),
            std::array::from_fn(|l| g_gamma[l] * self.dgamma),
            std::array::from_fn(|l| g_u[l] * du[0][l] + g_v[l] * dv[0][l]),
            std::array::from_fn(|l| g_u[l] * du[1][l] + g_v[l] * dv[1][l]),
            std::array::from_fn(|l| g_u[l] * du[2][l] + g_v[l] * dv[2][l]),
            g_y0,
            g_z0,
        ];
        (r, g)
    }
    /// The residuals of `L` points with rotated coordinates (u, v) and their gradients
    /// over the primitives (α, γ, y0, z0, u, v).
    #[inline(always)]
    fn primitives<const L: usize>(
        &self,
        kind: Residual,
        p: &[[f64; 3]; L],
        u: &[f64; L],
        v: &[f64; L],
    ) -> ([f64; L], [[f64; L]; 6]) {
        let mut r = [0.0; L];
        let mut g_prim = [[0.0; L]; 6];
        match kind {
            Residual::Canonical => {
                for l in 0..L {
                    // Eq. (6) with ŷ = y0 + u, ẑ = z0 + v.
                    let y = self.y0 + u[l];
                    let z = self.z0 + v[l];
                    r[l] = self.alpha * y * y + self.gamma * z * z - 1.0;
                    let gy = 2.0 * self.alpha * y;
                    let gz = 2.0 * self.gamma * z;
                    let gp = [y * y, z * z, gy, gz, gy, gz];
                    for k in 0..6 {
                        g_prim[k][l] = gp[k];
                    }
                }
            }
            Residual::ErrorBased | Residual::Range => {
                for l in 0..L {
                    let (u, v) = (u[l], v[l]);
                    // Eq. (22) for the unnormalised direction (u, v): A t² + 2B t + C = 0
                    // with A = αu² + γv², B = α y0 u + γ z0 v; S = √(B² − AC) = A t + B > 0.
                    let a_raw = self.alpha * u * u + self.gamma * v * v;
                    // A ray along the model axis never meets the wall: no information.
                    let valid = a_raw > 1e-300;
                    let a = if valid { a_raw } else { 1.0 };
                    let b = self.alpha * self.y0 * u + self.gamma * self.z0 * v;
                    let sq = (b * b - a * self.c).max(0.0).sqrt();
                    // Cancellation-free positive root (C < 0 makes both forms positive).
                    let num = if b > 0.0 { -self.c } else { sq - b };
                    let den = if b > 0.0 { b + sq } else { a };
                    let t = num / den;
                    let inv_s = 1.0 / sq;
                    // Wall point (Y, Z) = (y0 + t u, z0 + t v); implicit derivatives
                    // ∂t/∂α = −Y²/(2S), ∂t/∂γ = −Z²/(2S), ∂t/∂y0 = −αY/S, ∂t/∂z0 = −γZ/S,
                    // ∂t/∂u = −tαY/S, ∂t/∂v = −tγZ/S.
                    let wy = self.y0 + t * u;
                    let wz = self.z0 + t * v;
                    let t_y0 = -self.alpha * wy * inv_s;
                    let t_z0 = -self.gamma * wz * inv_s;
                    let dt = [
                        -0.5 * wy * wy * inv_s,
                        -0.5 * wz * wz * inv_s,
                        t_y0,
                        t_z0,
                        t * t_y0,
                        t * t_z0,
                    ];
                    let (res, gp) = if kind == Residual::ErrorBased {
                        // Eq. (23): r_d = (1 − t)·ρ, ρ = ‖(u, v)‖.
                        let rho = (u * u + v * v).sqrt();
                        let w = (1.0 - t) / rho;
                        let mut gp = dt.map(|d| -rho * d);
                        gp[4] += w * u;
                        gp[5] += w * v;
                        ((1.0 - t) * rho, gp)
                    } else {
                        // r_m = (1 − t)·‖p‖ (‖p‖ does not depend on β).
                        let range = dot(&p[l], &p[l]).sqrt();
                        ((1.0 - t) * range, dt.map(|d| -range * d))
                    };
                    r[l] = if valid { res } else { 0.0 };
                    for k in 0..6 {
                        g_prim[k][l] = if valid { gp[k] } else { 0.0 };
                    }
                }
            }
        }
        (r, g_prim)
    }

    /// The residual of one measured point `p` (SCS, m), without the gradient (the same
    /// arithmetic as [`residuals_and_gradients`](Self::residuals_and_gradients)).
    #[inline(always)]
    pub fn residual(&self, kind: Residual, p: &[f64; 3]) -> f64 {
        let u = dot(&self.r_y, p);
        let v = dot(&self.r_z, p);
        if kind == Residual::Canonical {
            let y = self.y0 + u;
            let z = self.z0 + v;
            return self.alpha * y * y + self.gamma * z * z - 1.0;
        }
        let Some(t) = self.wall_root(u, v) else {
            return 0.0;
        };
        if kind == Residual::ErrorBased {
            (1.0 - t) * (u * u + v * v).sqrt()
        } else {
            (1.0 - t) * dot(p, p).sqrt()
        }
    }

    /// Where the sensing line of a measured point `p` (SCS) meets the model wall: the
    /// parameter t of eq. (21) (1 for a point exactly on the wall).
    pub fn line_parameter(&self, p: &[f64; 3]) -> f64 {
        let u = dot(&self.r_y, p);
        let v = dot(&self.r_z, p);
        let rho = (u * u + v * v).sqrt();
        1.0 - self.residual(Residual::ErrorBased, p) / rho
    }

    /// The gradient over β of the residual `kind` of each of `points` (SCS, m), as
    /// [`residual_and_gradient`](Self::residual_and_gradient) gives it, four points at a
    /// time in AVX2 registers on a CPU that has them (the same bits either way).
    pub fn gradients(&self, kind: Residual, points: &[[f64; 3]]) -> Vec<[f64; N_PARAMS]> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA.
            return unsafe { self.gradients_avx2(kind, points) };
        }
        self.gradients_with(kind, points, |p| self.residuals_and_gradients::<4>(kind, p))
    }

    /// [`gradients`](Self::gradients) with `lanes` giving 4 points' residuals and gradients.
    #[inline(always)]
    fn gradients_with(
        &self,
        kind: Residual,
        points: &[[f64; 3]],
        lanes: impl Fn(&[[f64; 3]; 4]) -> ([f64; 4], [[f64; 4]; N_PARAMS]),
    ) -> Vec<[f64; N_PARAMS]> {
        let mut out = Vec::with_capacity(points.len());
        let mut blocks = points.chunks_exact(4);
        for b in &mut blocks {
            let arr: &[[f64; 3]; 4] = b.try_into().expect("chunks_exact yields 4 points");
            let (_, g) = lanes(arr);
            for l in 0..4 {
                out.push(std::array::from_fn(|k| g[k][l]));
            }
        }
        for p in blocks.remainder() {
            out.push(self.residual_and_gradient(kind, p).1);
        }
        out
    }

    /// Where the sensing line of a measured point `p` (SCS) meets the model wall, and how
    /// far `p` lies off it along the wall's normal: (x, Y, Z, d) with (x, Y, Z) the wall
    /// point (t·qx, y0 + t·u, z0 + t·v) in the PCS, q = R·p = (qx, u, v) and t the
    /// positive root of eq. (22), and d = (1 − t)·‖p‖·|n·p̂| the range error along the ray
    /// (ML-EPD's residual) times the cosine of the incidence, n the wall's unit normal
    /// (0, αY, γZ)/‖·‖. As ‖p‖·p̂ = p, d = (1 − t)·|αY·u + γZ·v| / ‖(αY, γZ)‖. A line along
    /// the model axis never meets the wall; it is given t = 1 (d = 0), as in
    /// [`wall_points`](Self::wall_points).
    #[inline(always)]
    pub fn wall_deviation(&self, p: &[f64; 3]) -> [f64; 4] {
        let (qx, u, v) = (dot(&self.r_x, p), dot(&self.r_y, p), dot(&self.r_z, p));
        let t = self.wall_root(u, v).unwrap_or(1.0);
        self.deviation_at(t * qx, self.y0 + t * u, self.z0 + t * v, t, u, v)
    }

    /// The cosine of the incidence angle where the sensing line of a measured point `p`
    /// (SCS) meets the model wall: |d·n| with d the unit ray and n the wall's unit normal
    /// there, (0, αY, γZ)/‖·‖ in the PCS. `None` for a line along the model axis or an
    /// invalid point.
    pub fn cos_incidence(&self, p: &[f64; 3]) -> Option<f64> {
        let range = dot(p, p).sqrt();
        let u = dot(&self.r_y, p);
        let v = dot(&self.r_z, p);
        let t = self.wall_root(u, v)?;
        let (ny, nz) = (
            self.alpha * (self.y0 + t * u),
            self.gamma * (self.z0 + t * v),
        );
        let nn = (ny * ny + nz * nz).sqrt();
        let c = (u * ny + v * nz).abs() / (range * nn);
        (c.is_finite() && range > 0.0).then_some(c.min(1.0))
    }

    /// The positive root t of eq. (22) for the unnormalised direction (u, v) (see the
    /// module doc), cancellation-free; `None` for a line along the model axis (A = 0),
    /// which never meets the wall.
    #[inline(always)]
    fn wall_root(&self, u: f64, v: f64) -> Option<f64> {
        let a = self.alpha * u * u + self.gamma * v * v;
        if a <= 1e-300 {
            return None;
        }
        let b = self.alpha * self.y0 * u + self.gamma * self.z0 * v;
        let sq = (b * b - a * self.c).max(0.0).sqrt();
        Some(if b > 0.0 {
            -self.c / (b + sq)
        } else {
            (sq - b) / a
        })
    }

    /// Where the sensing lines of `L` measured points (SCS, m) meet the wall, in the PCS:
    /// (t·q_x, y0 + t·u, z0 + t·v) with q = R·p and t the positive root of eq. (22) (see
    /// the module doc), lane by lane. A line along the model axis (A = 0) never meets the
    /// wall; it is given t = 1 (the measured point itself).
    #[inline(always)]
    pub fn wall_points<const L: usize>(&self, p: &[[f64; 3]; L]) -> [[f64; L]; 3] {
        let mut w = [[0.0; L]; 3];
        for l in 0..L {
            let (qx, u, v) = (
                dot(&self.r_x, &p[l]),
                dot(&self.r_y, &p[l]),
                dot(&self.r_z, &p[l]),
            );
            let t = self.wall_root(u, v).unwrap_or(1.0);
            w[0][l] = t * qx;
            w[1][l] = self.y0 + t * u;
            w[2][l] = self.z0 + t * v;
        }
        w
    }

    /// [`wall_deviation`](Self::wall_deviation) of each of `points` (SCS, m) into `out`
    /// (cleared first), four at a time in AVX2 registers on a CPU that has them (the same
    /// bits either way).
    pub fn wall_deviations(&self, points: &[[f64; 3]], out: &mut Vec<[f64; 4]>) {
        out.clear();
        out.reserve(points.len());
        self.for_each_wall_deviation(points, |w| out.push(w));
    }

    /// [`wall_deviation`](Self::wall_deviation) of each of `points` (SCS, m) handed to
    /// `each` in their order, none held: four at a time in AVX2 registers on a CPU that
    /// has them (the same bits either way).
    pub fn for_each_wall_deviation(&self, points: &[[f64; 3]], mut each: impl FnMut([f64; 4])) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA.
            return unsafe { self.wall_deviations_avx2(points, each) };
        }
        points.iter().for_each(|p| each(self.wall_deviation(p)));
    }

    /// Σ rᵢ² of the range residual ([`residual`](Self::residual) with [`Residual::Range`])
    /// over `chunk` (SCS, m), summed as the solver's kernel sums its cost over one chunk
    /// with the squared loss: four lane sums over the blocks of four points, the last
    /// few points into the total first, then the lanes in order — so the same bits as
    /// that cost (tested in `problem`), at a fraction of its work (no gradients). Four
    /// points at a time in AVX2 registers on a CPU that has them.
    pub fn range_sum_of_squares(&self, chunk: &[[f64; 3]]) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA.
            return unsafe { self.range_sum_of_squares_avx2(chunk) };
        }
        let mut lanes = [0.0; 4];
        let mut blocks = chunk.chunks_exact(4);
        for b in &mut blocks {
            for l in 0..4 {
                let r = self.residual(Residual::Range, &b[l]);
                lanes[l] += r * r;
            }
        }
        sum_lanes(blocks.remainder(), lanes, |p| {
            self.residual(Residual::Range, p)
        })
    }

    /// How many points of `chunk` (SCS, m) have a range residual ([`residual`](Self::residual)
    /// with [`Residual::Range`]) beyond ±each of `limits` (m); four points at a time in
    /// AVX2 registers on a CPU that has them (the same residuals as the scalar code's).
    pub fn count_range_beyond<const K: usize>(
        &self,
        chunk: &[[f64; 3]],
        limits: &[f64; K],
    ) -> [usize; K] {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA.
            return unsafe { self.count_range_beyond_avx2(chunk, limits) };
        }
        count_beyond(chunk, limits, |p| self.residual(Residual::Range, p))
    }

    /// (x, Y, Z, d) of [`wall_deviation`](Self::wall_deviation) from the wall point
    /// (x, Y, Z), its line parameter t and the rotated coordinates (u, v) of the measured
    /// point.
    #[inline(always)]
    fn deviation_at(&self, x: f64, y: f64, z: f64, t: f64, u: f64, v: f64) -> [f64; 4] {
        let (ny, nz) = (self.alpha * y, self.gamma * z);
        let d = (1.0 - t) * (ny * u + nz * v).abs() / (ny * ny + nz * nz).sqrt();
        [x, y, z, d]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residual_alone_equals_the_kernels() {
        let g = Geometry::new(&beta()).unwrap();
        for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
            for p in points() {
                let (a, b) = (g.residual(kind, &p), g.residual_and_gradient(kind, &p).0);
                assert!(
                    (a - b).abs() <= 1e-15 * (1.0 + b.abs()),
                    "{kind:?} {p:?}: {a} vs {b}"
                );
            }
        }
    }
    use nalgebra::{Point3, Vector3};

    fn beta() -> Params {
        Params {
            d_max: 0.51,
            d_min: 0.47,
            roll: 0.7,
            pitch: 0.06,
            yaw: -0.09,
            dy: 0.04,
            dz: -0.03,
        }
    }

    /// `gradients` (AVX2 where the CPU has it, and the portable lanes) gives each point's
    /// `residual_and_gradient` to the bit, for each residual, over a count that leaves a
    /// remainder.
    #[test]
    fn gradients_are_the_single_points_to_the_bit() {
        let pts = points();
        assert_eq!(pts.len() % 4, 2);
        for b in random_betas(20) {
            let g = Geometry::new(&b).unwrap();
            for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
                let fast = g.gradients(kind, &pts);
                let plain =
                    g.gradients_with(kind, &pts, |p| g.residuals_and_gradients::<4>(kind, p));
                for (i, p) in pts.iter().enumerate() {
                    let one = g.residual_and_gradient(kind, p).1.map(f64::to_bits);
                    assert_eq!(fast[i].map(f64::to_bits), one, "{kind:?} point {i}");
                    assert_eq!(plain[i].map(f64::to_bits), one, "{kind:?} point {i}");
                }
            }
        }
    }

    /// The count of range residuals beyond a limit (AVX2 where the CPU has it) is the
    /// scalar residuals' count, at limits between and around them, over a count of points
    /// that leaves a remainder.
    #[test]
    fn count_beyond_is_the_scalar_count() {
        let pts = points();
        for b in random_betas(20) {
            let g = Geometry::new(&b).unwrap();
            let mut r: Vec<f64> = pts
                .iter()
                .map(|p| g.residual(Residual::Range, p).abs())
                .collect();
            r.sort_by(f64::total_cmp);
            for limit in r.iter().map(|v| 0.999 * v).chain([0.0, 1e9]) {
                let want = r.iter().filter(|&&v| v > limit).count();
                let half = r.iter().filter(|&&v| v > 0.5 * limit).count();
                assert_eq!(
                    g.count_range_beyond(&pts, &[limit, 0.5 * limit]),
                    [want, half],
                    "limit {limit}"
                );
            }
        }
    }

    /// The wall points and deviations of the AVX2 kernels equal the scalar code's to the
    /// bit, rays along the axis included (t = 1).
    #[test]
    fn wall_kernels_match_the_scalar_code_to_the_bit() {
        let mut pts = points();
        for b in random_betas(20) {
            let g = Geometry::new(&b).unwrap();
            let axis = b.rotation().matrix().row(0).transpose();
            pts[3] = [axis.x, axis.y, axis.z];
            let mut all = Vec::new();
            g.wall_deviations(&pts, &mut all);
            for (i, p) in pts.iter().enumerate() {
                assert_eq!(
                    all[i].map(f64::to_bits),
                    g.wall_deviation(p).map(f64::to_bits),
                    "{i}"
                );
            }
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                for c in pts.chunks_exact(4) {
                    let arr: &[[f64; 3]; 4] = c.try_into().unwrap();
                    // SAFETY: the CPU has AVX2 (checked above).
                    let (w, _, _, _) = unsafe { g.wall_points_avx2(arr) };
                    assert_eq!(
                        w.map(|r| r.map(f64::to_bits)),
                        g.wall_points::<4>(arr).map(|r| r.map(f64::to_bits))
                    );
                }
            }
        }
    }

    /// `wall_deviation` against its definition, computed another way: the wall point by
    /// bisection on the ellipse equation along the ray in the PCS (`Params::scs_to_pcs`),
    /// the normal and the ray's direction as vectors. 50 points × 40 random β; the
    /// bisection runs to the last bit, so the two agree to rounding (1e-12 m).
    #[test]
    fn wall_deviation_matches_its_definition() {
        for b in random_betas(40) {
            let g = Geometry::new(&b).unwrap();
            let (a2, b2) = ((0.5 * b.d_max).powi(2), (0.5 * b.d_min).powi(2));
            let at =
                |p: &[f64; 3], t: f64| b.scs_to_pcs(&Point3::new(t * p[0], t * p[1], t * p[2]));
            let f = |w: &Point3<f64>| w.y * w.y / a2 + w.z * w.z / b2 - 1.0;
            for p in points() {
                // The sensor is inside (f < 0 at t = 0); far enough out, the ray is outside.
                let (mut lo, mut hi) = (0.0, 1.0);
                while f(&at(&p, hi)) < 0.0 {
                    hi *= 2.0;
                }
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    if f(&at(&p, mid)) < 0.0 {
                        lo = mid
                    } else {
                        hi = mid
                    }
                }
                let t = 0.5 * (lo + hi);
                let w = at(&p, t);
                let n = Vector3::new(0.0, w.y / a2, w.z / b2).normalize();
                let dir = (at(&p, 1.0) - at(&p, 0.0)).normalize();
                let range = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let d = (1.0 - t) * range * n.dot(&dir).abs();
                let got = g.wall_deviation(&p);
                for (k, want) in [w.x, w.y, w.z, d].into_iter().enumerate() {
                    assert!(
                        (got[k] - want).abs() < 1e-12,
                        "{b:?} {p:?} [{k}]: {} vs {want}",
                        got[k]
                    );
                }
            }
        }
    }

    /// Random-ish points inside and outside the pipe, seen from the sensor.
    fn points() -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for i in 0..50 {
            let a = i as f64 * 0.61;
            let x = 0.4 + 0.1 * i as f64;
            let rad = 0.2 + 0.004 * (i % 17) as f64;
            v.push([x, rad * a.cos(), rad * a.sin()]);
        }
        v
    }

    /// A small deterministic generator for random β (xorshift).
    fn random_betas(n: usize) -> Vec<Params> {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut u = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let d = 0.35 + 0.4 * u();
                Params {
                    d_max: d * (1.0 + 0.05 * u()),
                    d_min: d * (1.0 - 0.05 * u()),
                    roll: (u() - 0.5) * std::f64::consts::TAU,
                    pitch: (u() - 0.5) * 0.5,
                    yaw: (u() - 0.5) * 0.5,
                    dy: (u() - 0.5) * 0.1,
                    dz: (u() - 0.5) * 0.1,
                }
            })
            .collect()
    }

    #[test]
    fn gradients_match_central_differences() {
        for b0 in std::iter::once(beta()).chain(random_betas(20)) {
            for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
                let g0 = Geometry::new(&b0).unwrap();
                for p in points() {
                    let (_, g) = g0.residual_and_gradient(kind, &p);
                    for k in 0..N_PARAMS {
                        let h = 1e-6;
                        let mut a = b0.to_array();
                        a[k] += h;
                        let rp = Geometry::new(&Params::from_array(a))
                            .unwrap()
                            .residual(kind, &p);
                        a[k] -= 2.0 * h;
                        let rm = Geometry::new(&Params::from_array(a))
                            .unwrap()
                            .residual(kind, &p);
                        let fd = (rp - rm) / (2.0 * h);
                        let tol = 1e-6 * (1.0 + fd.abs());
                        assert!(
                            (fd - g[k]).abs() < tol,
                            "{kind:?} k={k} fd={fd} an={} at {b0:?}",
                            g[k]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn lanes_equal_single_points() {
        let g = Geometry::new(&beta()).unwrap();
        let pts = points();
        for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
            for block in pts.chunks_exact(4) {
                let arr: [[f64; 3]; 4] = block.try_into().unwrap();
                let (r, gl) = g.residuals_and_gradients::<4>(kind, &arr);
                for l in 0..4 {
                    let (r1, g1) = g.residual_and_gradient(kind, &arr[l]);
                    assert_eq!(r[l], r1);
                    for k in 0..N_PARAMS {
                        assert_eq!(gl[k][l], g1[k]);
                    }
                }
            }
        }
    }

    #[test]
    fn wall_points_have_zero_residual_and_unit_t() {
        let b = beta();
        let g = Geometry::new(&b).unwrap();
        for i in 0..40 {
            let phi = i as f64 * 0.157;
            let wall = Point3::new(
                0.5 + 0.1 * i as f64,
                0.5 * b.d_max * phi.cos(),
                0.5 * b.d_min * phi.sin(),
            );
            let p = b.pcs_to_scs(&wall);
            let p = [p.x, p.y, p.z];
            for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
                assert!(g.residual(kind, &p).abs() < 1e-13, "{kind:?}");
            }
            assert!((g.line_parameter(&p) - 1.0).abs() < 1e-12);
            // A point at twice the wall distance from x0_P along its sensing line: t = ½.
            let q = b.scs_to_pcs(&nalgebra::Point3::from(p));
            let o = b.sensor_origin_pcs();
            let far = b.pcs_to_scs(&(o + (q - o) * 2.0));
            assert!((g.line_parameter(&[far.x, far.y, far.z]) - 0.5).abs() < 1e-12);
        }
    }

    #[test]
    fn range_residual_is_the_range_error() {
        // A wall point pushed by ε along its ray: r_m = ε exactly, r_d = ε·sin φ.
        let b = beta();
        let g = Geometry::new(&b).unwrap();
        let wall = b.pcs_to_scs(&Point3::new(1.7, 0.0, -0.5 * b.d_min));
        let dir = wall.coords.normalize();
        for eps in [-0.05, -0.01, 0.02, 0.05] {
            let p = wall.coords + dir * eps;
            let p = [p.x, p.y, p.z];
            assert!((g.residual(Residual::Range, &p) - eps).abs() < 1e-13);
            let q = b.dir_scs_to_pcs(&dir);
            let sin_phi = (q.y * q.y + q.z * q.z).sqrt();
            assert!((g.residual(Residual::ErrorBased, &p) - eps * sin_phi).abs() < 1e-13);
        }
    }

    #[test]
    fn outside_domain_is_none() {
        let mut b = beta();
        b.dy = 0.3;
        assert!(Geometry::new(&b).is_none());
        let mut b = beta();
        b.d_min = 0.0;
        assert!(Geometry::new(&b).is_none());
        let mut b = beta();
        b.roll = f64::NAN;
        assert!(Geometry::new(&b).is_none());
    }

    #[test]
    fn axial_ray_is_finite() {
        let b = Params {
            roll: 0.0,
            pitch: 0.0,
            yaw: 0.0,
            ..beta()
        };
        let g = Geometry::new(&b).unwrap();
        for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
            let (r, grad) = g.residual_and_gradient(kind, &[3.0, 0.0, 0.0]);
            assert!(
                r.is_finite() && grad.iter().all(|x| x.is_finite()),
                "{kind:?}"
            );
        }
    }
}
