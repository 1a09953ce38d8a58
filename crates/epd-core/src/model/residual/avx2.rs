//! The wall kernels of [`Geometry`] in AVX2 registers, four points at a time (x86-64):
//! each line is the scalar code's operation on four lanes, in its order and without fused
//! multiply-adds, so each lane's result is the scalar code's to the bit (tested in the
//! parent module and in `problem`). The compiler had left the wall's root, its divisions
//! and its square roots scalar, lane by lane. The `unsafe` functions without a
//! `target_feature` attribute are `inline(always)`: their intrinsics are inlined where
//! they are inlined into a function compiled for AVX2, their only callers.

use super::{Geometry, N_PARAMS, Residual, dot};

impl Geometry {
    /// [`residuals_and_gradients`](Self::residuals_and_gradients) of 4 points with the
    /// wall's root, its divisions and square roots in AVX2 registers (the compiler leaves
    /// them scalar, lane by lane, in the generic code), the same operations in the same
    /// order, so the same bits.
    ///
    /// # Safety
    /// Only where the CPU has AVX2. Its intrinsics are inlined where it is inlined into
    /// a function compiled for AVX2 (`problem`'s `accumulate_avx2`, its only caller).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) unsafe fn residuals_and_gradients_avx2(
        &self,
        kind: Residual,
        p: &[[f64; 3]; 4],
    ) -> ([f64; 4], [[f64; 4]; N_PARAMS]) {
        let (u, v, du, dv) = self.projections(p);
        let (r, g_prim) = match kind {
            Residual::Canonical => self.primitives(kind, p, &u, &v),
            Residual::ErrorBased | Residual::Range => {
                // SAFETY: the caller runs only where the CPU has AVX2.
                unsafe { self.wall_primitives_avx2(kind, p, &u, &v) }
            }
        };
        self.chain(r, g_prim, &du, &dv)
    }

    /// [`primitives`](Self::primitives) of the wall's range residuals (ML-EPD's and the
    /// range's) for 4 points in AVX2 registers: each line is the scalar code's operation
    /// on four lanes, in its order (no fused multiply-adds), so each lane's result is the
    /// scalar code's to the bit (tested: `problem`'s kernels agree bit for bit).
    ///
    /// # Safety
    /// Only where the CPU has AVX2 (see [`residuals_and_gradients_avx2`](Self::residuals_and_gradients_avx2)).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn wall_primitives_avx2(
        &self,
        kind: Residual,
        p: &[[f64; 3]; 4],
        u: &[f64; 4],
        v: &[f64; 4],
    ) -> ([f64; 4], [[f64; 4]; 6]) {
        // SAFETY: the CPU has AVX2 (the caller's contract); every load and store is of
        // an array of 4 f64.
        unsafe {
            use std::arch::x86_64::*;
            use {
                _mm256_add_pd as add, _mm256_div_pd as div, _mm256_mul_pd as mul,
                _mm256_set1_pd as splat, _mm256_sub_pd as sub,
            };
            // u and v hold 4 f64 each.
            let (uu, vv) = (_mm256_loadu_pd(u.as_ptr()), _mm256_loadu_pd(v.as_ptr()));
            let (alpha, gamma, c) = (splat(self.alpha), splat(self.gamma), splat(self.c));
            let zero = _mm256_setzero_pd();
            let one = splat(1.0);
            // A t² + 2B t + C = 0 (see `primitives`).
            let a_raw = add(mul(mul(alpha, uu), uu), mul(mul(gamma, vv), vv));
            let valid = _mm256_cmp_pd::<_CMP_GT_OQ>(a_raw, splat(1e-300));
            let a = _mm256_blendv_pd(one, a_raw, valid);
            let b = add(
                mul(splat(self.alpha * self.y0), uu),
                mul(splat(self.gamma * self.z0), vv),
            );
            // max(x, 0) as f64::max: 0 for NaN (the second operand is returned then).
            let sq = _mm256_sqrt_pd(_mm256_max_pd(sub(mul(b, b), mul(a, c)), zero));
            let pos = _mm256_cmp_pd::<_CMP_GT_OQ>(b, zero);
            let num = _mm256_blendv_pd(sub(sq, b), splat(-self.c), pos);
            let den = _mm256_blendv_pd(a, add(b, sq), pos);
            let t = div(num, den);
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
                let range: [f64; 4] = std::array::from_fn(|l| dot(&p[l], &p[l]));
                _mm256_sqrt_pd(_mm256_loadu_pd(range.as_ptr()))
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
            // Invalid lanes give 0 (+0.0, as the scalar code), then out of the registers.
            let mut r = [0.0; 4];
            let mut g = [[0.0; 4]; 6];
            _mm256_storeu_pd(r.as_mut_ptr(), _mm256_and_pd(mul(one_t, scale), valid));
            for k in 0..6 {
                _mm256_storeu_pd(g[k].as_mut_ptr(), _mm256_and_pd(gp[k], valid));
            }
            (r, g)
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
        use std::arch::x86_64::*;
        let qx: [f64; 4] = std::array::from_fn(|l| dot(&self.r_x, &p[l]));
        let u: [f64; 4] = std::array::from_fn(|l| dot(&self.r_y, &p[l]));
        let v: [f64; 4] = std::array::from_fn(|l| dot(&self.r_z, &p[l]));
        let mut w = [[0.0; 4]; 3];
        let mut ts = [0.0; 4];
        // SAFETY: the CPU has AVX2 (the caller's contract); every load and store is of
        // an array of 4 f64.
        unsafe {
            use {
                _mm256_add_pd as add, _mm256_div_pd as div, _mm256_mul_pd as mul,
                _mm256_set1_pd as splat, _mm256_sub_pd as sub,
            };
            let (uu, vv) = (_mm256_loadu_pd(u.as_ptr()), _mm256_loadu_pd(v.as_ptr()));
            let zero = _mm256_setzero_pd();
            // `wall_root`: A, B, S and the cancellation-free root; t = 1 off the wall.
            let a = add(
                mul(mul(splat(self.alpha), uu), uu),
                mul(mul(splat(self.gamma), vv), vv),
            );
            let valid = _mm256_cmp_pd::<_CMP_GT_OQ>(a, splat(1e-300));
            let b = add(
                mul(splat(self.alpha * self.y0), uu),
                mul(splat(self.gamma * self.z0), vv),
            );
            let sq = _mm256_sqrt_pd(_mm256_max_pd(sub(mul(b, b), mul(a, splat(self.c))), zero));
            let pos = _mm256_cmp_pd::<_CMP_GT_OQ>(b, zero);
            let root = _mm256_blendv_pd(div(sub(sq, b), a), div(splat(-self.c), add(b, sq)), pos);
            let t = _mm256_blendv_pd(splat(1.0), root, valid);
            _mm256_storeu_pd(ts.as_mut_ptr(), t);
            _mm256_storeu_pd(w[0].as_mut_ptr(), mul(t, _mm256_loadu_pd(qx.as_ptr())));
            _mm256_storeu_pd(w[1].as_mut_ptr(), add(splat(self.y0), mul(t, uu)));
            _mm256_storeu_pd(w[2].as_mut_ptr(), add(splat(self.z0), mul(t, vv)));
        }
        (w, ts, u, v)
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
        let mut blocks = chunk.chunks_exact(4);
        for b in &mut blocks {
            let arr: &[[f64; 3]; 4] = b.try_into().expect("chunks_exact yields 4 points");
            // SAFETY: this function runs only where the CPU has AVX2.
            let (_, t, _, _) = unsafe { self.wall_points_avx2(arr) };
            for (l, p) in arr.iter().enumerate() {
                each(l, (1.0 - t[l]) * dot(p, p).sqrt());
            }
        }
        blocks.remainder()
    }

    /// [`wall_deviations`](Self::wall_deviations) compiled for AVX2: the wall points by
    /// [`wall_points_avx2`](Self::wall_points_avx2), then d as in
    /// [`wall_deviation`](Self::wall_deviation).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn wall_deviations_avx2(&self, points: &[[f64; 3]], out: &mut Vec<[f64; 4]>) {
        let mut blocks = points.chunks_exact(4);
        for b in &mut blocks {
            let arr: &[[f64; 3]; 4] = b.try_into().expect("chunks_exact yields 4 points");
            // SAFETY: this function runs only where the CPU has AVX2.
            let ([x, y, z], t, u, v) = unsafe { self.wall_points_avx2(arr) };
            for l in 0..4 {
                out.push(self.deviation_at(x[l], y[l], z[l], t[l], u[l], v[l]));
            }
        }
        out.extend(blocks.remainder().iter().map(|p| self.wall_deviation(p)));
    }
}
