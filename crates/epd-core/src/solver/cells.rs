//! The wall's cells for the cluster-robust covariance and the form test: bins along the
//! axis times sectors of the clock angle, a point's cell chosen where its sensing line
//! meets the fitted wall ([`wall_point_pcs`]), and the indexing of many points, four at
//! a time in AVX2 registers where the CPU has them.

use crate::residual::{Geometry, Residual};

/// Lanes of the wall-point and index kernels.
const LANES: usize = 4;

/// Cells of the wall for a cluster-robust covariance: `axial_edges.len() + 1` bins of the
/// distance along the pipe axis (PCS x, m) times `sectors` equal sectors of the clock
/// angle around it. Errors that are correlated within a cell (neighbouring pixels, a
/// camera's filtering) but not between cells leave the cluster-robust sandwich unbiased.
#[derive(Clone, Debug, PartialEq)]
pub struct Cells {
    /// Increasing inner edges of the axial bins (PCS x, m).
    pub axial_edges: Vec<f64>,
    /// Sectors of the clock angle, each 2π/sectors wide.
    pub sectors: usize,
}

impl Cells {
    /// Number of cells.
    pub fn len(&self) -> usize {
        (self.axial_edges.len() + 1) * self.sectors.max(1)
    }

    /// Whether there are none (never: at least one bin and one sector).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The cell of a PCS point (x along the axis, y and z across it). For many points,
    /// [`indexer`](Self::indexer) once and its [`CellIndexer::index`] per point.
    pub fn index(&self, x: f64, y: f64, z: f64) -> usize {
        self.indexer().index(x, y, z)
    }

    /// The cells' boundaries prepared for indexing many points.
    pub fn indexer(&self) -> CellIndexer<'_> {
        let s = self.sectors.max(1);
        let per_quadrant = if s.is_multiple_of(4) { s / 4 } else { 0 };
        // Inner boundaries of a quadrant's sectors, at j·2π/s (j = 1 … s/4 − 1).
        let quadrant_bounds = (1..per_quadrant)
            .map(|j| {
                let a = std::f64::consts::TAU * j as f64 / s as f64;
                (a.cos(), a.sin())
            })
            .collect();
        CellIndexer {
            axial_edges: &self.axial_edges,
            sectors: s,
            per_quadrant,
            quadrant_bounds,
        }
    }
}

/// [`Cells`] ready to index many points without a transcendental function per point.
#[derive(Clone, Debug)]
pub struct CellIndexer<'c> {
    axial_edges: &'c [f64],
    sectors: usize,
    /// s/4 when the sectors divide the quadrants, else 0 (then [`atan2`](f64::atan2)).
    per_quadrant: usize,
    /// (cos a_j, sin a_j) of the quadrant's inner sector boundaries a_j = j·2π/s.
    quadrant_bounds: Vec<(f64, f64)>,
}

impl CellIndexer<'_> {
    /// The cell of a PCS point (x along the axis, y and z across it): axial bin × sector
    /// k = ⌊(atan2(y, z) + π)·s/2π⌋. When s is a multiple of 4 the point is turned into
    /// its quadrant q (by the signs of y and z), where its angle α = atan2(Y, Z) ∈ [0, π/2)
    /// has passed a boundary a_j when Y·cos a_j − Z·sin a_j ≥ 0; atan2(y, z) + π is then
    /// α + (q + 2)·π/2 (mod 2π), that is sector ((q + 2) mod 4)·s/4 + j.
    #[inline(always)]
    pub fn index(&self, x: f64, y: f64, z: f64) -> usize {
        let a = self.axial_edges.iter().filter(|&&e| e <= x).count();
        let s = self.sectors;
        if self.per_quadrant == 0 {
            let phi = y.atan2(z) + std::f64::consts::PI;
            let k = ((phi / std::f64::consts::TAU) * s as f64) as usize;
            return a * s + k.min(s - 1);
        }
        // Quadrants of ψ = atan2(y, z) in [0, 2π): 0 [0, π/2), 1 [π/2, π), 2 [π, 3π/2),
        // 3 [3π/2, 2π); (Z, Y) is the point turned back by q·π/2.
        let (q, zz, yy) = if y >= 0.0 {
            if z > 0.0 { (0, z, y) } else { (1, y, -z) }
        } else if z < 0.0 {
            (2, -z, -y)
        } else {
            (3, -y, z)
        };
        let j = self
            .quadrant_bounds
            .iter()
            .filter(|&&(c, sn)| yy * c - zz * sn >= 0.0)
            .count();
        a * s + ((q + 2) % 4) * self.per_quadrant + j
    }

    /// [`index`](Self::index) of four PCS points in AVX2 registers, the same cells: each
    /// comparison of `index` a mask, each choice a blend, the counts summed in f64 (exact
    /// for cell numbers far below 2⁵³), the products of the boundary test in its order
    /// without fused multiply-adds, so each lane's comparison is the scalar one's.
    /// With sectors that do not divide the quadrants, [`index`](Self::index) lane by lane.
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) unsafe fn index_avx2(&self, x: &[f64; 4], y: &[f64; 4], z: &[f64; 4]) -> [u32; 4] {
        if self.per_quadrant == 0 {
            return std::array::from_fn(|l| self.index(x[l], y[l], z[l]) as u32);
        }
        // SAFETY: the CPU has AVX2 (the caller's contract); every load and store is of an
        // array of 4 f64 or 4 i32.
        unsafe {
            use std::arch::x86_64::*;
            use {
                _mm256_add_pd as add, _mm256_and_pd as and, _mm256_blendv_pd as blend,
                _mm256_mul_pd as mul, _mm256_set1_pd as splat, _mm256_sub_pd as sub,
            };
            let (xv, yv, zv) = (
                _mm256_loadu_pd(x.as_ptr()),
                _mm256_loadu_pd(y.as_ptr()),
                _mm256_loadu_pd(z.as_ptr()),
            );
            let (zero, one) = (_mm256_setzero_pd(), splat(1.0));
            // The axial bin: the edges e ≤ x (false for a NaN x).
            let mut a = zero;
            for &e in self.axial_edges {
                a = add(a, and(_mm256_cmp_pd::<_CMP_LE_OQ>(splat(e), xv), one));
            }
            // The quadrant and the turned point (Z, Y) of `index`; blend(p, q, m) is q
            // where m holds. −v as the scalar code negates: the sign bit flipped.
            let up = _mm256_cmp_pd::<_CMP_GE_OQ>(yv, zero);
            let front = _mm256_cmp_pd::<_CMP_GT_OQ>(zv, zero);
            let back = _mm256_cmp_pd::<_CMP_LT_OQ>(zv, zero);
            let (ny, nz) = (
                _mm256_xor_pd(yv, splat(-0.0)),
                _mm256_xor_pd(zv, splat(-0.0)),
            );
            let zz = blend(blend(ny, nz, back), blend(yv, zv, front), up);
            let yy = blend(blend(zv, ny, back), blend(nz, yv, front), up);
            // (q + 2) mod 4: quadrant 0 → 2, 1 → 3, 2 → 0, 3 → 1.
            let turned = blend(
                blend(one, zero, back),
                blend(splat(3.0), splat(2.0), front),
                up,
            );
            let mut j = zero;
            for &(c, sn) in &self.quadrant_bounds {
                let side = sub(mul(yy, splat(c)), mul(zz, splat(sn)));
                j = add(j, and(_mm256_cmp_pd::<_CMP_GE_OQ>(side, zero), one));
            }
            let cell = add(
                add(
                    mul(a, splat(self.sectors as f64)),
                    mul(turned, splat(self.per_quadrant as f64)),
                ),
                j,
            );
            let mut out = [0i32; 4];
            _mm_storeu_si128(out.as_mut_ptr().cast(), _mm256_cvttpd_epi32(cell));
            out.map(|c| c as u32)
        }
    }
}

/// Where the sensing line of the measured point `p` (SCS, m) meets the wall of the
/// geometry's β, in the PCS: the point t·p with t the line parameter of eq. (21)
/// ([`Geometry::wall_points`]).
/// It depends on the ray's direction only, not on the point's range error: cells chosen
/// by the measured point itself would be chosen by its noise too (a point pushed out
/// along its ray crosses a cell's far edge), and the cells' mean residuals would then be
/// biased — about ±1.3 mm at σ = 20 mm for bins 0.5 m long along a pipe.
pub fn wall_point_pcs(geom: &Geometry, p: &[f64; 3]) -> [f64; 3] {
    let [x, y, z] = geom.wall_points::<1>(&[*p]);
    [x[0], y[0], z[0]]
}

/// The cell of each of `points` ([`wall_point_pcs`] indexed by `indexer`) into `out`,
/// compiled for AVX2 + FMA when the CPU has them (as [`accumulate_chunk`]).
pub(crate) fn cells_of(
    geom: &Geometry,
    indexer: &CellIndexer<'_>,
    points: &[[f64; 3]],
    out: &mut [u32],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features the function is compiled for.
        return unsafe { cells_of_avx2(geom, indexer, points, out) };
    }
    cells_of_lanes(geom, indexer, points, out, false)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn cells_of_avx2(geom: &Geometry, indexer: &CellIndexer<'_>, points: &[[f64; 3]], out: &mut [u32]) {
    cells_of_lanes(geom, indexer, points, out, true)
}

/// [`cells_of`], [`LANES`] points at a time; with `avx2` (only from [`cells_of_avx2`])
/// the wall points from [`Geometry::wall_points_avx2`].
#[inline(always)]
fn cells_of_lanes(
    geom: &Geometry,
    indexer: &CellIndexer<'_>,
    points: &[[f64; 3]],
    out: &mut [u32],
    avx2: bool,
) {
    let mut blocks = points.chunks_exact(LANES);
    let mut outs = out.chunks_exact_mut(LANES);
    for (block, o) in (&mut blocks).zip(&mut outs) {
        let pts: &[[f64; 3]; LANES] = block.try_into().expect("chunks_exact yields LANES points");
        #[cfg(target_arch = "x86_64")]
        let [x, y, z] = if avx2 {
            // SAFETY: `avx2` is set only by `cells_of_avx2`, run where the CPU has AVX2.
            unsafe { geom.wall_points_avx2(pts).0 }
        } else {
            geom.wall_points::<LANES>(pts)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let [x, y, z] = {
            let _ = avx2;
            geom.wall_points::<LANES>(pts)
        };
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: `avx2` is set only by `cells_of_avx2`, run where the CPU has AVX2.
            o.copy_from_slice(&unsafe { indexer.index_avx2(&x, &y, &z) });
            continue;
        }
        for l in 0..LANES {
            o[l] = indexer.index(x[l], y[l], z[l]) as u32;
        }
    }
    for (p, o) in blocks.remainder().iter().zip(outs.into_remainder()) {
        let [x, y, z] = wall_point_pcs(geom, p);
        *o = indexer.index(x, y, z) as u32;
    }
}

/// The range residual ([`Geometry::residual`] with [`Residual::Range`]), the cell and the
/// PCS wall point ([`wall_point_pcs`]) of every `stride`-th of `points` (SCS, m), handed in
/// order to `f(i, r, cell, [x, Y, Z])` with i the point's index in `points`. The residual
/// and the wall point share the line's root t of eq. (22): r = (1 − t)·‖p‖. Four points
/// at a time in AVX2 registers on a CPU that has them, the same values either way
/// (tested).
pub fn for_each_range_and_cell<F: FnMut(usize, f64, usize, [f64; 3])>(
    geom: &Geometry,
    indexer: &CellIndexer<'_>,
    points: &[[f64; 3]],
    stride: usize,
    mut f: F,
) {
    let stride = stride.max(1);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA.
        return unsafe { ranges_and_cells_avx2(geom, indexer, points, stride, &mut f) };
    }
    for (i, p) in points.iter().enumerate().step_by(stride) {
        let [x, y, z] = wall_point_pcs(geom, p);
        f(
            i,
            geom.residual(Residual::Range, p),
            indexer.index(x, y, z),
            [x, y, z],
        );
    }
}

/// [`for_each_range_and_cell`] compiled for AVX2: four strided points at a time by
/// [`Geometry::wall_points_avx2`] and [`CellIndexer::index_avx2`], r = (1 − t)·‖p‖ from
/// the root t (t = 1 off the wall gives the scalar code's 0 for a finite point and a
/// non-finite r for a non-finite one, as the scalar code), the last few points by the
/// scalar code.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn ranges_and_cells_avx2<F: FnMut(usize, f64, usize, [f64; 3])>(
    geom: &Geometry,
    indexer: &CellIndexer<'_>,
    points: &[[f64; 3]],
    stride: usize,
    f: &mut F,
) {
    let n = points.len().div_ceil(stride);
    let mut k = 0;
    while k + LANES <= n {
        let idx: [usize; LANES] = std::array::from_fn(|l| (k + l) * stride);
        let arr: [[f64; 3]; LANES] = std::array::from_fn(|l| points[idx[l]]);
        // SAFETY: this function runs only where the CPU has AVX2.
        let ([x, y, z], t, _, _) = unsafe { geom.wall_points_avx2(&arr) };
        // SAFETY: as above.
        let cell = unsafe { indexer.index_avx2(&x, &y, &z) };
        for l in 0..LANES {
            let range =
                (arr[l][0] * arr[l][0] + arr[l][1] * arr[l][1] + arr[l][2] * arr[l][2]).sqrt();
            f(
                idx[l],
                (1.0 - t[l]) * range,
                cell[l] as usize,
                [x[l], y[l], z[l]],
            );
        }
        k += LANES;
    }
    for i in (k * stride..points.len()).step_by(stride) {
        let p = &points[i];
        let [x, y, z] = wall_point_pcs(geom, p);
        f(
            i,
            geom.residual(Residual::Range, p),
            indexer.index(x, y, z),
            [x, y, z],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Params;
    use crate::test_numbers::numbers;

    /// The indexer's sector against the definition with `atan2`, for sector counts that
    /// divide the quadrants (the comparisons) and that do not (the fallback), on random
    /// points and on the axes; points within 1e-12 rad of a boundary are skipped (there
    /// the two may round differently).
    #[test]
    fn cell_index_matches_the_atan2_definition() {
        let mut r = numbers(7);
        for sectors in [1usize, 3, 4, 8, 12, 16, 36] {
            let cells = Cells {
                axial_edges: vec![-0.5, 0.0, 0.7],
                sectors,
            };
            let ix = cells.indexer();
            let mut pts: Vec<[f64; 3]> = (0..20_000).map(|_| [2.0 * r(), r(), r()]).collect();
            pts.extend([
                [0.1, 1.0, 0.0],
                [0.1, -1.0, 0.0],
                [0.1, 0.0, 1.0],
                [0.1, 0.0, -1.0],
            ]);
            for [x, y, z] in pts {
                let phi = y.atan2(z) + std::f64::consts::PI;
                let u = phi / std::f64::consts::TAU * sectors as f64;
                if (u - u.round()).abs() < 1e-12 && u.round() != 0.0 && u.round() != sectors as f64
                {
                    continue;
                }
                let k = (u as usize).min(sectors - 1);
                let a = cells.axial_edges.iter().filter(|&&e| e <= x).count();
                assert_eq!(
                    ix.index(x, y, z),
                    a * sectors + k,
                    "{sectors} sectors, ({x}, {y}, {z})"
                );
            }
        }
    }

    /// [`CellIndexer::index_avx2`] against [`CellIndexer::index`], point for point, on
    /// random points, the axes, signed zeros and NaN, for sector counts that divide the
    /// quadrants and that do not. Skipped on a CPU without AVX2.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn lanes_index_as_single_points() {
        let mut r = numbers(9);
        for sectors in [1usize, 4, 8, 12, 16, 36, 7] {
            let cells = Cells {
                axial_edges: vec![-0.5, 0.0, 0.0, 0.7],
                sectors,
            };
            let ix = cells.indexer();
            let mut pts: Vec<[f64; 3]> = (0..4_000).map(|_| [2.0 * r(), r(), r()]).collect();
            for v in [0.0, -0.0, 1.0, -1.0, f64::NAN] {
                for w in [0.0, -0.0, 1.0, -1.0, f64::NAN] {
                    pts.push([0.0, v, w]);
                    pts.push([f64::NAN, v, w]);
                }
            }
            for block in pts.chunks_exact(LANES) {
                let x: [f64; LANES] = std::array::from_fn(|l| block[l][0]);
                let y: [f64; LANES] = std::array::from_fn(|l| block[l][1]);
                let z: [f64; LANES] = std::array::from_fn(|l| block[l][2]);
                if !std::arch::is_x86_feature_detected!("avx2") {
                    return;
                }
                // SAFETY: the CPU has AVX2 (checked above).
                let got = unsafe { ix.index_avx2(&x, &y, &z) };
                for l in 0..LANES {
                    assert_eq!(
                        got[l] as usize,
                        ix.index(x[l], y[l], z[l]),
                        "{:?}",
                        block[l]
                    );
                }
            }
        }
    }

    /// [`for_each_range_and_cell`] against the scalar residual, wall point and index,
    /// for several strides, with a line along the model axis (t = 1, r = 0) and a
    /// non-finite point among the points.
    #[test]
    fn strided_ranges_and_cells_as_single_points() {
        let beta = crate::test_numbers::test_pipe();
        let geom = Geometry::new(&beta).expect("inside");
        let cells = Cells {
            axial_edges: vec![0.8, 1.4],
            sectors: 12,
        };
        let ix = cells.indexer();
        let mut r = numbers(11);
        let mut pts: Vec<[f64; 3]> = (0..203)
            .map(|_| [2.0 * r().abs() + 0.2, r(), r()])
            .collect();
        let axis = beta.dir_pcs_to_scs(&nalgebra::Vector3::new(1.0, 0.0, 0.0));
        pts[3] = [axis.x, axis.y, axis.z];
        pts[6] = [f64::NAN, 0.1, 0.2];
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        for stride in [1, 2, 3, 5] {
            let mut seen = Vec::new();
            for_each_range_and_cell(&geom, &ix, &pts, stride, |i, r, c, w| {
                seen.push((i, r, c, w))
            });
            let want: Vec<usize> = (0..pts.len()).step_by(stride).collect();
            assert_eq!(seen.iter().map(|s| s.0).collect::<Vec<_>>(), want);
            for (i, r, c, w) in seen {
                let p = &pts[i];
                assert!(same(r, geom.residual(Residual::Range, p)), "{i}: {r}");
                let [x, y, z] = wall_point_pcs(&geom, p);
                assert!(same(w[0], x) && same(w[1], y) && same(w[2], z), "{i}");
                assert_eq!(c, ix.index(x, y, z), "{i}");
            }
        }
    }

    /// The wall point of each sensing line against its definition through the line
    /// parameter of eq. (21) ([`Geometry::line_parameter`]) and the rotation of eq. (3).
    #[test]
    fn wall_points_match_the_line_parameter() {
        let beta = Params {
            d_max: 0.51,
            d_min: 0.47,
            roll: 0.7,
            pitch: 0.06,
            yaw: -0.09,
            dy: 0.04,
            dz: -0.03,
        };
        let geom = Geometry::new(&beta).expect("inside");
        let m = *beta.rotation().matrix();
        let mut r = numbers(3);
        for _ in 0..5_000 {
            let p = [3.0 * r().abs() + 0.1, r(), r()];
            let t = geom.line_parameter(&p);
            let q = m * nalgebra::Vector3::new(t * p[0], t * p[1], t * p[2]);
            let want = [q.x, q.y + beta.dy, q.z + beta.dz];
            let got = wall_point_pcs(&geom, &p);
            for k in 0..3 {
                assert!(
                    (got[k] - want[k]).abs() < 1e-12,
                    "{p:?}: {got:?} vs {want:?}"
                );
            }
            // On the ellipse of eq. (5).
            let e = (2.0 * got[1] / beta.d_max).powi(2) + (2.0 * got[2] / beta.d_min).powi(2);
            assert!((e - 1.0).abs() < 1e-12, "{p:?}: {e}");
        }
    }
}
