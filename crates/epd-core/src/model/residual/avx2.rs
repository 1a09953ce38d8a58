//! The wall kernels of [`Geometry`] in AVX2 registers, four points at a time (x86-64):
//! each line is the scalar code's operation on four lanes, in its order and without fused
//! multiply-adds, so each lane's result is the scalar code's to the bit (tested in the
//! parent module and in `problem`). The compiler had left the wall's root, its divisions
//! and its square roots scalar, lane by lane, and each lane's dot products too, passing
//! the arrays between them through memory: the points are loaded into registers once
//! ([`points_m256`]) and stay there. The `unsafe` functions without a
//! `target_feature` attribute are `inline(always)`: their intrinsics are inlined where
//! they are inlined into a function compiled for AVX2, their only callers.

use super::{Geometry, N_PARAMS, Residual};

/// The coordinates of 4 points (SCS, m) lane by lane: [x, y, z] of points 0–3.
///
/// # Safety
/// Only where the CPU has AVX2; inlined into a function compiled for it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn points_m256(p: &[[f64; 3]; 4]) -> [std::arch::x86_64::__m256d; 3] {
    // SAFETY: the CPU has AVX2 (the caller's contract).
    unsafe {
        use std::arch::x86_64::_mm256_set_pd as set;
        // Written out, not by `array::from_fn`: a closure inlined into a generic function
        // not compiled for AVX2 would take its intrinsics out of line.
        [
            set(p[3][0], p[2][0], p[1][0], p[0][0]),
            set(p[3][1], p[2][1], p[1][1], p[0][1]),
            set(p[3][2], p[2][2], p[1][2], p[0][2]),
        ]
    }
}

/// dot(a, p) = a₀x + a₁y + a₂z of 4 points in registers, left to right (`dot`).
///
/// # Safety
/// Only where the CPU has AVX2; inlined into a function compiled for it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn dot_m256(
    a: &[f64; 3],
    [x, y, z]: &[std::arch::x86_64::__m256d; 3],
) -> std::arch::x86_64::__m256d {
    // SAFETY: the CPU has AVX2 (the caller's contract).
    unsafe {
        use std::arch::x86_64::{
            _mm256_add_pd as add, _mm256_mul_pd as mul, _mm256_set1_pd as splat,
        };
        add(
            add(mul(splat(a[0]), *x), mul(splat(a[1]), *y)),
            mul(splat(a[2]), *z),
        )
    }
}

/// ‖p‖² = x² + y² + z² of 4 points in registers, left to right (`dot(p, p)`).
///
/// # Safety
/// Only where the CPU has AVX2; inlined into a function compiled for it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn norm2_m256([x, y, z]: &[std::arch::x86_64::__m256d; 3]) -> std::arch::x86_64::__m256d {
    // SAFETY: the CPU has AVX2 (the caller's contract).
    unsafe {
        use std::arch::x86_64::{_mm256_add_pd as add, _mm256_mul_pd as mul};
        add(add(mul(*x, *x), mul(*y, *y)), mul(*z, *z))
    }
}

impl Geometry {
    /// [`residuals_and_gradients`](Self::residuals_and_gradients) of 4 points, out of
    /// the registers of [`residuals_and_gradients_m256`](Self::residuals_and_gradients_m256).
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) unsafe fn residuals_and_gradients_avx2(
        &self,
        kind: Residual,
        p: &[[f64; 3]; 4],
    ) -> ([f64; 4], [[f64; 4]; N_PARAMS]) {
        // SAFETY: the CPU has AVX2 (the caller's contract); every store is of an array
        // of 4 f64.
        unsafe {
            use std::arch::x86_64::_mm256_storeu_pd as store;
            let (rv, gv) = self.residuals_and_gradients_m256(kind, p);
            let mut r = [0.0; 4];
            let mut g = [[0.0; 4]; N_PARAMS];
            store(r.as_mut_ptr(), rv);
            for (out, v) in g.iter_mut().zip(gv) {
                store(out.as_mut_ptr(), v);
            }
            (r, g)
        }
    }

    /// [`residuals_and_gradients`](Self::residuals_and_gradients) of 4 points held in
    /// AVX2 registers from the points' load to the gradients over β: the projections,
    /// the residual's primitives (the wall's root, its divisions and square roots) and
    /// the chain rule, each line the scalar code's operation on four lanes in its order
    /// (no fused multiply-adds), so the same bits. Written out because the generic code,
    /// compiled for AVX2, kept each lane's dot products scalar and passed its arrays
    /// through memory: one pass of the normal equations over 306 000 points took 6 ms
    /// whatever the residual (the canonical one, without a root, included).
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) unsafe fn residuals_and_gradients_m256(
        &self,
        kind: Residual,
        p: &[[f64; 3]; 4],
    ) -> (
        std::arch::x86_64::__m256d,
        [std::arch::x86_64::__m256d; N_PARAMS],
    ) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::*;
            use {_mm256_add_pd as add, _mm256_mul_pd as mul, _mm256_set1_pd as splat};
            let xyz = points_m256(p);
            let dot3 = |a: &[f64; 3]| dot_m256(a, &xyz);
            let (u, v) = (dot3(&self.r_y), dot3(&self.r_z));
            let du = [
                dot3(&self.dr_y[0]),
                dot3(&self.dr_y[1]),
                dot3(&self.dr_y[2]),
            ];
            let dv = [
                dot3(&self.dr_z[0]),
                dot3(&self.dr_z[1]),
                dot3(&self.dr_z[2]),
            ];
            let (r, [g_alpha, g_gamma, g_y0, g_z0, g_u, g_v]) = match kind {
                Residual::Canonical => self.canonical_primitives_m256(u, v),
                Residual::ErrorBased | Residual::Range => {
                    self.wall_primitives_avx2(kind, norm2_m256(&xyz), u, v)
                }
            };
            // The chain rule (`chain`).
            let chain = |k: usize| add(mul(g_u, du[k]), mul(g_v, dv[k]));
            let g = [
                mul(g_alpha, splat(self.dalpha)),
                mul(g_gamma, splat(self.dgamma)),
                chain(0),
                chain(1),
                chain(2),
                g_y0,
                g_z0,
            ];
            (r, g)
        }
    }

    /// Eq. (6)'s residual and its gradients over the primitives for 4 points with
    /// rotated coordinates (u, v) in registers, as `primitives` computes them.
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn canonical_primitives_m256(
        &self,
        u: std::arch::x86_64::__m256d,
        v: std::arch::x86_64::__m256d,
    ) -> (std::arch::x86_64::__m256d, [std::arch::x86_64::__m256d; 6]) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::*;
            use {
                _mm256_add_pd as add, _mm256_mul_pd as mul, _mm256_set1_pd as splat,
                _mm256_sub_pd as sub,
            };
            let y = add(splat(self.y0), u);
            let z = add(splat(self.z0), v);
            let r = sub(
                add(
                    mul(mul(splat(self.alpha), y), y),
                    mul(mul(splat(self.gamma), z), z),
                ),
                splat(1.0),
            );
            let gy = mul(splat(2.0 * self.alpha), y);
            let gz = mul(splat(2.0 * self.gamma), z);
            (r, [mul(y, y), mul(z, z), gy, gz, gy, gz])
        }
    }

    /// [`primitives`](Self::primitives) of the wall's range residuals (ML-EPD's and the
    /// range's) for 4 points in AVX2 registers, given ‖p‖² and the rotated coordinates
    /// (u, v): each line is the scalar code's operation on four lanes, in its order (no
    /// fused multiply-adds), so each lane's result is the scalar code's to the bit
    /// (tested: `problem`'s kernels agree bit for bit).
    ///
    /// # Safety
    /// Only where the CPU has AVX2 (see [`residuals_and_gradients_avx2`](Self::residuals_and_gradients_avx2)).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn wall_primitives_avx2(
        &self,
        kind: Residual,
        p2: std::arch::x86_64::__m256d,
        uu: std::arch::x86_64::__m256d,
        vv: std::arch::x86_64::__m256d,
    ) -> (std::arch::x86_64::__m256d, [std::arch::x86_64::__m256d; 6]) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::*;
            use {
                _mm256_add_pd as add, _mm256_div_pd as div, _mm256_mul_pd as mul,
                _mm256_set1_pd as splat, _mm256_sub_pd as sub,
            };
            let zero = _mm256_setzero_pd();
            let one = splat(1.0);
            let (t, sq, valid) = self.root_m256(uu, vv);
            let inv_s = div(one, sq);
            let wy = add(splat(self.y0), mul(t, uu));
            let wz = add(splat(self.z0), mul(t, vv));
            let t_y0 = mul(mul(splat(-self.alpha), wy), inv_s);
            let t_z0 = mul(mul(splat(-self.gamma), wz), inv_s);
            let half = splat(-0.5);
            let dt = [
                mul(mul(mul(half, wy), wy), inv_s),
                mul(mul(mul(half, wz), wz), inv_s),
                t_y0,
                t_z0,
                mul(t, t_y0),
                mul(t, t_z0),
            ];
            let one_t = sub(one, t);
            let scale = if kind == Residual::ErrorBased {
                _mm256_sqrt_pd(add(mul(uu, uu), mul(vv, vv)))
            } else {
                _mm256_sqrt_pd(p2)
            };
            // −x as the scalar code negates: the sign bit flipped.
            let neg_scale = _mm256_xor_pd(scale, splat(-0.0));
            let mut gp = [zero; 6];
            for k in 0..6 {
                gp[k] = mul(neg_scale, dt[k]);
            }
            if kind == Residual::ErrorBased {
                let w = div(one_t, scale);
                gp[4] = add(gp[4], mul(w, uu));
                gp[5] = add(gp[5], mul(w, vv));
            }
            // Invalid lanes give 0 (+0.0, as the scalar code).
            for g in &mut gp {
                *g = _mm256_and_pd(*g, valid);
            }
            (_mm256_and_pd(mul(one_t, scale), valid), gp)
        }
    }

    /// [`gradients`](Self::gradients) compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn gradients_avx2(
        &self,
        kind: Residual,
        points: &[[f64; 3]],
    ) -> Vec<[f64; N_PARAMS]> {
        let mut out = Vec::with_capacity(points.len());
        let mut blocks = points.chunks_exact(4);
        for b in &mut blocks {
            let arr: &[[f64; 3]; 4] = b.try_into().expect("chunks_exact yields 4 points");
            // SAFETY: this function runs only where the CPU has AVX2.
            let (_, g) = unsafe { self.residuals_and_gradients_avx2(kind, arr) };
            for l in 0..4 {
                out.push([
                    g[0][l], g[1][l], g[2][l], g[3][l], g[4][l], g[5][l], g[6][l],
                ]);
            }
        }
        for p in blocks.remainder() {
            out.push(self.residual_and_gradient(kind, p).1);
        }
        out
    }

    /// [`wall_points`](Self::wall_points) of 4 points in AVX2 registers, with the line
    /// parameter t and the rotated coordinates (u, v) beside them: each operation the
    /// scalar code's, in its order, so the same bits (tested).
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    pub(crate) unsafe fn wall_points_avx2(
        &self,
        p: &[[f64; 3]; 4],
    ) -> ([[f64; 4]; 3], [f64; 4], [f64; 4], [f64; 4]) {
        // SAFETY: the CPU has AVX2 (the caller's contract); every store is of an array
        // of 4 f64.
        unsafe {
            use std::arch::x86_64::_mm256_storeu_pd as store;
            let (wv, tv, uv, vv) = self.wall_points_m256(&points_m256(p));
            let mut w = [[0.0; 4]; 3];
            for (out, v) in w.iter_mut().zip(wv) {
                store(out.as_mut_ptr(), v);
            }
            let (mut t, mut u, mut v) = ([0.0; 4], [0.0; 4], [0.0; 4]);
            store(t.as_mut_ptr(), tv);
            store(u.as_mut_ptr(), uv);
            store(v.as_mut_ptr(), vv);
            (w, t, u, v)
        }
    }

    /// [`wall_points_avx2`](Self::wall_points_avx2) held in registers: the wall points
    /// [x, Y, Z], t, u and v of 4 points, the projections taken in registers too.
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    pub(crate) unsafe fn wall_points_m256(
        &self,
        xyz: &[std::arch::x86_64::__m256d; 3],
    ) -> (
        [std::arch::x86_64::__m256d; 3],
        std::arch::x86_64::__m256d,
        std::arch::x86_64::__m256d,
        std::arch::x86_64::__m256d,
    ) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::*;
            use {_mm256_add_pd as add, _mm256_mul_pd as mul, _mm256_set1_pd as splat};
            let (qx, uu, vv) = (
                dot_m256(&self.r_x, xyz),
                dot_m256(&self.r_y, xyz),
                dot_m256(&self.r_z, xyz),
            );
            // `wall_root`; t = 1 off the wall.
            let (root, _, valid) = self.root_m256(uu, vv);
            let t = _mm256_blendv_pd(splat(1.0), root, valid);
            let w = [
                mul(t, qx),
                add(splat(self.y0), mul(t, uu)),
                add(splat(self.z0), mul(t, vv)),
            ];
            (w, t, uu, vv)
        }
    }

    /// The positive root t of eq. (22) for 4 lines with rotated directions (u, v), as
    /// `wall_root` and `primitives` compute it: A t² + 2B t + C = 0 with A = αu² + γv²,
    /// B = α y0 u + γ z0 v, S = √(B² − AC) and the cancellation-free form, −C/(B + S) for
    /// B > 0, else (S − B)/A — one division of the form's operands chosen lane by lane,
    /// the same quotient as either form's own. Returns (t, S, valid): a lane whose A is
    /// not above 10⁻³⁰⁰ (a line along the model axis, which never meets the wall) is not
    /// valid, and its t and S are taken with A = 1 (finite, to be masked by the caller).
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn root_m256(
        &self,
        uu: std::arch::x86_64::__m256d,
        vv: std::arch::x86_64::__m256d,
    ) -> (
        std::arch::x86_64::__m256d,
        std::arch::x86_64::__m256d,
        std::arch::x86_64::__m256d,
    ) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::*;
            use {
                _mm256_add_pd as add, _mm256_div_pd as div, _mm256_mul_pd as mul,
                _mm256_set1_pd as splat, _mm256_sub_pd as sub,
            };
            let zero = _mm256_setzero_pd();
            let a_raw = add(
                mul(mul(splat(self.alpha), uu), uu),
                mul(mul(splat(self.gamma), vv), vv),
            );
            let valid = _mm256_cmp_pd::<_CMP_GT_OQ>(a_raw, splat(1e-300));
            let a = _mm256_blendv_pd(splat(1.0), a_raw, valid);
            let b = add(
                mul(splat(self.alpha * self.y0), uu),
                mul(splat(self.gamma * self.z0), vv),
            );
            // max(x, 0) as f64::max: 0 for NaN (the second operand is returned then).
            let sq = _mm256_sqrt_pd(_mm256_max_pd(sub(mul(b, b), mul(a, splat(self.c))), zero));
            let pos = _mm256_cmp_pd::<_CMP_GT_OQ>(b, zero);
            let num = _mm256_blendv_pd(sub(sq, b), splat(-self.c), pos);
            let den = _mm256_blendv_pd(a, add(b, sq), pos);
            (div(num, den), sq, valid)
        }
    }

    /// [`range_sum_of_squares`](Self::range_sum_of_squares) compiled for AVX2: t by
    /// [`wall_points_avx2`](Self::wall_points_avx2) and r = (1 − t)·‖p‖ per lane (t = 1
    /// off the wall gives the scalar code's 0 for a finite point).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn range_sum_of_squares_avx2(&self, chunk: &[[f64; 3]]) -> f64 {
        let mut lanes = [0.0; 4];
        let rest = self.range_residual_blocks_avx2(chunk, |l, r| lanes[l] += r * r);
        super::sum_lanes(rest, lanes, |p| self.residual(Residual::Range, p))
    }

    /// [`count_range_beyond`](Self::count_range_beyond) compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn count_range_beyond_avx2<const K: usize>(
        &self,
        chunk: &[[f64; 3]],
        limits: &[f64; K],
    ) -> [usize; K] {
        let mut n = [0; K];
        let rest = self.range_residual_blocks_avx2(chunk, |_, r| {
            for (c, l) in n.iter_mut().zip(limits) {
                *c += usize::from(r.abs() > *l);
            }
        });
        let tail = super::count_beyond(rest, limits, |p| self.residual(Residual::Range, p));
        for (c, t) in n.iter_mut().zip(tail) {
            *c += t;
        }
        n
    }

    /// The range residual r = (1 − t)·‖p‖ of each point in the whole blocks of four of
    /// `chunk`, t by [`wall_points_avx2`](Self::wall_points_avx2) (t = 1 off the wall
    /// gives the scalar code's 0 for a finite point), handed to `each` with its lane, block
    /// by block in order; returns the points after the last whole block.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn range_residual_blocks_avx2<'a>(
        &self,
        chunk: &'a [[f64; 3]],
        mut each: impl FnMut(usize, f64),
    ) -> &'a [[f64; 3]] {
        use _mm256_mul_pd as mul;
        use std::arch::x86_64::*;
        let mut blocks = chunk.chunks_exact(4);
        for b in &mut blocks {
            let arr: &[[f64; 3]; 4] = b.try_into().expect("chunks_exact yields 4 points");
            let mut r = [0.0; 4];
            // SAFETY: this function runs only where the CPU has AVX2; `r` holds 4 f64.
            unsafe {
                let xyz = points_m256(arr);
                let (_, t, _, _) = self.wall_points_m256(&xyz);
                // (1 − t)·‖p‖.
                let range = _mm256_sqrt_pd(norm2_m256(&xyz));
                _mm256_storeu_pd(
                    r.as_mut_ptr(),
                    mul(_mm256_sub_pd(_mm256_set1_pd(1.0), t), range),
                );
            }
            for (l, v) in r.into_iter().enumerate() {
                each(l, v);
            }
        }
        blocks.remainder()
    }

    /// [`for_each_wall_deviation`](Self::for_each_wall_deviation) compiled for AVX2: the wall points by
    /// [`wall_points_avx2`](Self::wall_points_avx2), then d as in
    /// [`wall_deviation`](Self::wall_deviation).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn wall_deviations_avx2(&self, points: &[[f64; 3]], mut each: impl FnMut([f64; 4])) {
        use std::arch::x86_64::*;
        use {
            _mm256_div_pd as div, _mm256_mul_pd as mul, _mm256_set1_pd as splat,
            _mm256_sub_pd as sub,
        };
        let mut blocks = points.chunks_exact(4);
        for b in &mut blocks {
            let arr: &[[f64; 3]; 4] = b.try_into().expect("chunks_exact yields 4 points");
            // SAFETY: this function runs only where the CPU has AVX2; every store is of
            // an array of 4 f64.
            let cols = unsafe {
                let ([x, y, z], t, u, v) = self.wall_points_m256(&points_m256(arr));
                // `deviation_at`: d = (1 − t)·|nY·u + nZ·v| / √(nY² + nZ²).
                let (ny, nz) = (mul(splat(self.alpha), y), mul(splat(self.gamma), z));
                let dot = _mm256_add_pd(mul(ny, u), mul(nz, v));
                let abs = _mm256_andnot_pd(splat(-0.0), dot);
                let norm = _mm256_sqrt_pd(_mm256_add_pd(mul(ny, ny), mul(nz, nz)));
                let d = div(mul(sub(splat(1.0), t), abs), norm);
                let mut cols = [[0.0; 4]; 4];
                for (col, c) in cols.iter_mut().zip([x, y, z, d]) {
                    _mm256_storeu_pd(col.as_mut_ptr(), c);
                }
                cols
            };
            for l in 0..4 {
                each([cols[0][l], cols[1][l], cols[2][l], cols[3][l]]);
            }
        }
        blocks
            .remainder()
            .iter()
            .for_each(|p| each(self.wall_deviation(p)));
    }
}
