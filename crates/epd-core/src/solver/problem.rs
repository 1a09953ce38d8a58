//! The pipe fit as a [`NormalEquationsProblem`]: eq. (4) over a point cloud with one of
//! the three [`Residual`]s, accumulated in parallel in fixed-size chunks.

use std::borrow::Cow;
use std::ops::Range;

use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

use crate::lm::{NormalEquations, NormalEquationsProblem};
use crate::loss::Loss;
use crate::params::{N_PARAMS, Params};
use crate::residual::{Geometry, Residual};

use super::cells::cells_of;
pub use super::cells::{CellIndexer, Cells, for_each_range_and_cell, wall_point_pcs};
use super::points::Points;

/// Points per chunk. Chunks are fixed, and their partial sums are added in order, so
/// the result does not depend on the number of threads.
pub(crate) const CHUNK: usize = 4096;

/// Eq. (4): F(β) = Σ (sᵢ·rᵢ)²(x̂_i,P, β) over measured points in the SCS (m), with
/// per-point scales sᵢ (1 unless given) and optionally some parameters held.
#[derive(Clone, Copy, Debug)]
pub struct PipeFit<'a> {
    /// Measured points x̂_i,S (SCS, m), finite and non-zero, read in place (all of a
    /// slice or those a mask keeps).
    pub points: Points<'a>,
    /// The residual function.
    pub residual: Residual,
    /// The loss applied to each (scaled) residual (squared: eq. 4 itself).
    pub loss: Loss,
    /// Per-point scales sᵢ, one per point (finite, > 0): the residual rᵢ and its
    /// gradient gᵢ enter as sᵢ·rᵢ and sᵢ·gᵢ. With sᵢ = σ̃/σᵢ (σᵢ the point's range noise,
    /// σ̃ a typical value) F is the heteroscedastic weighted least squares in metres.
    /// `None`: all 1.
    pub scales: Option<&'a [f64]>,
    /// Parameters held at their current value (in the order of eq. 2): their rows and
    /// columns of JᵀJ and entries of Jᵀr are zeroed, so the solver's step for them is
    /// exactly zero (see [`crate::lm`]) and the covariance leaves them out.
    pub fixed: [bool; N_PARAMS],
}

impl<'a> PipeFit<'a> {
    /// Eq. (4) over `points` with `residual` and the squared loss.
    pub fn new(points: &'a [[f64; 3]], residual: Residual) -> Self {
        Self::over(Points::all(points), residual)
    }

    /// Eq. (4) over `points` (all of a slice or those a mask keeps) with `residual` and
    /// the squared loss.
    pub fn over(points: Points<'a>, residual: Residual) -> Self {
        Self {
            points,
            residual,
            loss: Loss::Squared,
            scales: None,
            fixed: [false; N_PARAMS],
        }
    }

    /// The same fit with a robust loss.
    pub fn with_loss(self, loss: Loss) -> Self {
        Self { loss, ..self }
    }

    /// The same fit with per-point scales sᵢ (see [`scales`](Self::scales)); `None` for
    /// none. Panics when the lengths differ (a programming error, not user input).
    pub fn with_scales(self, scales: Option<&'a [f64]>) -> Self {
        if let Some(s) = scales {
            assert_eq!(s.len(), self.points.len(), "one scale per point");
        }
        Self { scales, ..self }
    }

    /// The same fit with the parameters marked `true` held (see [`fixed`](Self::fixed)).
    pub fn with_fixed(self, fixed: [bool; N_PARAMS]) -> Self {
        Self { fixed, ..self }
    }

    /// Chunk `k`'s points and their scales (the scales empty when `None`): the points
    /// numbered `k·CHUNK..` (at most `CHUNK`), read when the chunk's turn comes (through
    /// a mask, a copy of that chunk only).
    fn chunk(&self, k: usize) -> (Cow<'a, [[f64; 3]]>, &'a [f64]) {
        let r = k * CHUNK..((k + 1) * CHUNK).min(self.points.len());
        let scales = self.scales.map_or(&[][..], |s| &s[r.clone()]);
        (self.points.range(r), scales)
    }

    /// The chunks' numbers.
    fn chunk_ids(&self) -> Range<usize> {
        0..self.points.len().div_ceil(CHUNK)
    }

    /// The normal equations at β, or `None` outside the model's domain.
    pub fn equations_at(&self, beta: &Params) -> Option<NormalEquations<N_PARAMS>> {
        let geom = Geometry::new(beta)?;
        let kind = self.residual;
        let loss = self.loss;
        // A stop request skips the remaining chunks; the checkpoint after the pass
        // unwinds before the partial sums are used (`crate::cancel::Watch`).
        let watch = crate::cancel::watch();
        let accumulate = |k: usize| {
            if watch.stopped() {
                return NormalEquations::zero();
            }
            let (chunk, s) = self.chunk(k);
            accumulate_chunk(&geom, kind, loss, &chunk, s, Curvature::Clipped).eq
        };
        let mut total = if self.points.len() <= CHUNK {
            accumulate(0)
        } else {
            let parts: Vec<NormalEquations<N_PARAMS>> =
                self.chunk_ids().into_par_iter().map(accumulate).collect();
            crate::cancel::checkpoint();
            let mut t = NormalEquations::zero();
            for p in &parts {
                t.merge(p);
            }
            t
        };
        total.symmetrize();
        for i in (0..N_PARAMS).filter(|&i| self.fixed[i]) {
            total.jtr[i] = 0.0;
            for j in 0..N_PARAMS {
                total.jtj[(i, j)] = 0.0;
                total.jtj[(j, i)] = 0.0;
            }
        }
        Some(total)
    }
}

/// What the sandwich covariance of an M-estimator needs at one β.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sandwich {
    /// H = Σ w_H(rᵢ)·JᵢJᵢᵀ, the robust Gauss–Newton matrix.
    pub bread: SMatrix<f64, N_PARAMS, N_PARAMS>,
    /// B = Σ (w_g(rᵢ)·rᵢ)²·JᵢJᵢᵀ, the spread of the per-point gradients.
    pub meat: SMatrix<f64, N_PARAMS, N_PARAMS>,
    /// Σ rᵢ², the plain least-squares cost.
    pub raw_cost: f64,
}

impl PipeFit<'_> {
    /// The sandwich terms at β (one pass), or `None` outside the model's domain. With
    /// scales, of the scaled residuals sᵢrᵢ and gradients sᵢgᵢ; held parameters have
    /// zero rows and columns.
    pub fn sandwich_at(&self, beta: &Params) -> Option<Sandwich> {
        let geom = Geometry::new(beta)?;
        let (kind, loss) = (self.residual, self.loss);
        let watch = crate::cancel::watch();
        let one = |k: usize| {
            let mut sw = Sandwich {
                bread: SMatrix::zeros(),
                meat: SMatrix::zeros(),
                raw_cost: 0.0,
            };
            if watch.stopped() {
                return sw;
            }
            let (chunk, scales) = self.chunk(k);
            for (i, p) in chunk.iter().enumerate() {
                let (r, g) = geom.residual_and_gradient(kind, p);
                let s = scales.get(i).copied().unwrap_or(1.0);
                let (r, g) = (s * r, g.map(|v| s * v));
                let (_, wg, wh) = loss.cost_and_weights(r);
                let j = SVector::<f64, N_PARAMS>::from(g);
                let psi = wg * r;
                sw.bread.syger(wh, &j, &j, 1.0);
                sw.meat.syger(psi * psi, &j, &j, 1.0);
                sw.raw_cost += r * r;
            }
            sw
        };
        let parts: Vec<Sandwich> = self.chunk_ids().into_par_iter().map(one).collect();
        crate::cancel::checkpoint();
        let mut total = Sandwich {
            bread: SMatrix::zeros(),
            meat: SMatrix::zeros(),
            raw_cost: 0.0,
        };
        for p in &parts {
            total.bread += p.bread;
            total.meat += p.meat;
            total.raw_cost += p.raw_cost;
        }
        total.bread.fill_upper_triangle_with_lower_triangle();
        total.meat.fill_upper_triangle_with_lower_triangle();
        for i in (0..N_PARAMS).filter(|&i| self.fixed[i]) {
            for j in 0..N_PARAMS {
                for m in [&mut total.bread, &mut total.meat] {
                    m[(i, j)] = 0.0;
                    m[(j, i)] = 0.0;
                }
            }
        }
        Some(total)
    }
}

/// The cluster-robust sandwich terms at one β ([`PipeFit::cluster_sandwich_at`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ClusterSandwich {
    /// H = Σ w_H(rᵢ)·JᵢJᵢᵀ over all points, w_H as the [`Curvature`] asked for.
    pub bread: SMatrix<f64, N_PARAMS, N_PARAMS>,
    /// B = Σ_g s_g s_gᵀ with s_g = Σ_{i ∈ g} ψ(rᵢ)Jᵢ the score of cell g.
    pub meat: SMatrix<f64, N_PARAMS, N_PARAMS>,
    /// Each cell's score s_g and its own part H_g of the bread (empty cells left out).
    pub cells: Vec<(SVector<f64, N_PARAMS>, SMatrix<f64, N_PARAMS, N_PARAMS>)>,
    /// The index in [`Cells`] of each of `cells` (axial bin · sectors + sector).
    pub cell_ids: Vec<usize>,
    /// Σ rᵢ², the plain least-squares cost.
    pub raw_cost: f64,
    /// Cells holding at least one point (the clusters G).
    pub clusters: usize,
}

impl PipeFit<'_> {
    /// The cluster-robust sandwich terms at β over every point, the points grouped by
    /// `cells` at the PCS position where each point's sensing line meets the wall of β
    /// ([`wall_point_pcs`]), or `None` outside the model's domain. Scales and held
    /// parameters as in [`sandwich_at`](Self::sandwich_at).
    ///
    /// One pass in at most `CLUSTER_PARTS` parts, each in blocks of `CLUSTER_BLOCK`
    /// points: a block's points are put in cell order and every cell's run is summed by
    /// the SIMD kernel of the solver's own normal equations (its Jᵀr is the cell's score,
    /// its JᵀJ the cell's bread). Parts and blocks are cut by the point count alone and
    /// added in order, so the result does not depend on the number of threads.
    pub fn cluster_sandwich_at(
        &self,
        beta: &Params,
        cells: &Cells,
        curvature: Curvature,
    ) -> Option<ClusterSandwich> {
        let geom = Geometry::new(beta)?;
        let indexer = cells.indexer();
        let g = cells.len();
        let (kind, loss) = (self.residual, self.loss);
        let n = self.points.len();
        let scales = self.scales;
        let watch = crate::cancel::watch();
        // One part of the points, block by block into its own per-cell sums.
        let part = |range: std::ops::Range<usize>| -> Vec<Sums> {
            let mut sums = vec![Sums::zero(); g];
            let mut cell = vec![0u32; CLUSTER_BLOCK];
            let mut sorted = vec![[0.0; 3]; CLUSTER_BLOCK];
            let mut sorted_scales = vec![0.0; scales.map_or(0, |_| CLUSTER_BLOCK)];
            let mut start = vec![0usize; g + 1];
            for from in range.clone().step_by(CLUSTER_BLOCK) {
                if watch.stopped() {
                    break;
                }
                let block = from..(from + CLUSTER_BLOCK).min(range.end);
                let points = self.points.range(block.clone());
                let len = points.len();
                cells_of(&geom, &indexer, &points, &mut cell[..len]);
                // Counting sort of the block's points (and scales) by cell.
                start.fill(0);
                for &c in &cell[..len] {
                    start[c as usize + 1] += 1;
                }
                for c in 0..g {
                    start[c + 1] += start[c];
                }
                let mut next = start.clone();
                for (i, &c) in cell[..len].iter().enumerate() {
                    let at = next[c as usize];
                    next[c as usize] += 1;
                    sorted[at] = points[i];
                    if let Some(s) = scales {
                        sorted_scales[at] = s[from + i];
                    }
                }
                for (c, total) in sums.iter_mut().enumerate() {
                    let run = start[c]..start[c + 1];
                    if run.is_empty() {
                        continue;
                    }
                    let sc = if sorted_scales.is_empty() {
                        &[][..]
                    } else {
                        &sorted_scales[run.clone()]
                    };
                    total.merge(&accumulate_chunk(
                        &geom,
                        kind,
                        loss,
                        &sorted[run],
                        sc,
                        curvature,
                    ));
                }
            }
            sums
        };
        let size = n.div_ceil(CLUSTER_PARTS).max(CLUSTER_BLOCK);
        let parts: Vec<Vec<Sums>> = (0..n.div_ceil(size))
            .into_par_iter()
            .map(|k| part(k * size..((k + 1) * size).min(n)))
            .collect();
        crate::cancel::checkpoint();
        let mut per_cell = vec![Sums::zero(); g];
        for p in &parts {
            for (t, v) in per_cell.iter_mut().zip(p) {
                t.merge(v);
            }
        }
        let mut bread = Mat::zeros();
        let mut meat = Mat::zeros();
        let mut raw_cost = 0.0;
        let mut kept = Vec::new();
        let mut cell_ids = Vec::new();
        for (id, mut c) in per_cell.into_iter().enumerate() {
            raw_cost += c.raw_cost;
            c.eq.symmetrize();
            let (mut s, mut h) = (c.eq.jtr, c.eq.jtj);
            if s.iter().all(|v| *v == 0.0) && h.iter().all(|v| *v == 0.0) {
                continue;
            }
            for i in (0..N_PARAMS).filter(|&i| self.fixed[i]) {
                s[i] = 0.0;
                for j in 0..N_PARAMS {
                    h[(i, j)] = 0.0;
                    h[(j, i)] = 0.0;
                }
            }
            bread += h;
            meat += s * s.transpose();
            kept.push((s, h));
            cell_ids.push(id);
        }
        Some(ClusterSandwich {
            bread,
            meat,
            raw_cost,
            clusters: kept.len(),
            cells: kept,
            cell_ids,
        })
    }
}

/// A 7 × 7 matrix over β.
type Mat = SMatrix<f64, N_PARAMS, N_PARAMS>;

/// Points per block of [`PipeFit::cluster_sandwich_at`]: a block sorted by cell takes
/// 4096 · 36 B = 147 kB (points, scales and cells); with G = 96 cells a cell's run then
/// averages 43 points, of which the scalar remainder of the 4-lane kernel (< 4) is a few
/// per cent.
const CLUSTER_BLOCK: usize = 4096;

/// Parts of [`PipeFit::cluster_sandwich_at`] summed in parallel: each holds G per-cell
/// sums (G · 60 f64, 46 kB for 96 cells), so 8 of them bound the pass's memory at
/// 0.37 MB plus a block's buffers per thread, whatever the points, with work for 8
/// threads.
const CLUSTER_PARTS: usize = 8;

/// One pass's sums: the normal equations of the loss and Σ (sᵢrᵢ)² without it.
#[derive(Clone, Copy, Debug)]
struct Sums {
    eq: NormalEquations<N_PARAMS>,
    raw_cost: f64,
}

impl Sums {
    fn zero() -> Self {
        Self {
            eq: NormalEquations::zero(),
            raw_cost: 0.0,
        }
    }

    fn merge(&mut self, other: &Self) {
        self.eq.merge(&other.eq);
        self.raw_cost += other.raw_cost;
    }
}

/// Lanes of the SIMD kernel.
const LANES: usize = 4;

/// Σ over a chunk of 2ρ(s·r), w·(s·J)ᵀ(s·J) (upper triangle) and w·(s·J)ᵀ(s·r), `LANES`
/// points at a time with one accumulator per lane (summed in a fixed order at the end).
/// `WEIGHTED`: each point's residual and gradient are multiplied by its scale sᵢ from
/// `scales` (one per point); otherwise `scales` is ignored and no multiplication is
/// compiled in. The portable kernel; [`accumulate_avx2`] gives its sums to the bit.
#[inline(always)]
fn accumulate_lanes<const WEIGHTED: bool, const EXACT: bool>(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
    scales: &[f64],
) -> Sums {
    let mut cost = [0.0; LANES];
    let mut raw = [0.0; LANES];
    let mut jtr = [[0.0; LANES]; N_PARAMS];
    let mut jtj = [[0.0; LANES]; NT];
    let mut blocks = chunk.chunks_exact(LANES);
    let mut scale_blocks = scales.chunks_exact(LANES);
    for block in &mut blocks {
        let pts: &[[f64; 3]; LANES] = block.try_into().expect("chunks_exact yields LANES points");
        let (mut r, mut g) = geom.residuals_and_gradients::<LANES>(kind, pts);
        if WEIGHTED {
            let s: &[f64; LANES] = scale_blocks
                .next()
                .and_then(|s| s.try_into().ok())
                .expect("one scale per point");
            for l in 0..LANES {
                r[l] *= s[l];
            }
            for ga in &mut g {
                for l in 0..LANES {
                    ga[l] *= s[l];
                }
            }
        }
        // Robust weights (all 1 for the squared loss): cost Σ c(r), H = Σ w_H JJᵀ,
        // g = Σ w_g r J (see `loss`).
        let mut wg = [1.0; LANES];
        let mut wh = [1.0; LANES];
        if loss == Loss::Squared {
            for l in 0..LANES {
                cost[l] += r[l] * r[l];
            }
        } else {
            for l in 0..LANES {
                let (c, g_w, h_w) = if EXACT {
                    loss.cost_and_exact_weights(r[l])
                } else {
                    loss.cost_and_weights(r[l])
                };
                cost[l] += c;
                raw[l] += r[l] * r[l];
                wg[l] = g_w;
                wh[l] = h_w;
            }
        }
        let mut idx = 0;
        for a in 0..N_PARAMS {
            for l in 0..LANES {
                jtr[a][l] += wg[l] * g[a][l] * r[l];
            }
            let hg: [f64; LANES] = std::array::from_fn(|l| wh[l] * g[a][l]);
            for b in a..N_PARAMS {
                for l in 0..LANES {
                    jtj[idx][l] += hg[l] * g[b][l];
                }
                idx += 1;
            }
        }
    }
    let lanes = LaneSums {
        cost,
        raw,
        jtr,
        jtj,
    };
    finish_sums::<WEIGHTED, EXACT>(
        geom,
        kind,
        loss,
        (blocks.remainder(), scale_blocks.remainder()),
        &lanes,
        chunk.len(),
    )
}

/// Upper-triangle entries of H.
const NT: usize = N_PARAMS * (N_PARAMS + 1) / 2;

/// The per-lane sums of a chunk's whole blocks of `LANES` points.
struct LaneSums {
    /// Σ c(rᵢ).
    cost: [f64; LANES],
    /// Σ rᵢ² (robust losses only).
    raw: [f64; LANES],
    /// Σ w_g r J.
    jtr: [[f64; LANES]; N_PARAMS],
    /// Σ w_H J Jᵀ, upper triangle row by row.
    jtj: [[f64; LANES]; NT],
}

/// The chunk's sums: the points after its last whole block (`rest` and their scales)
/// into the total first, then the lanes in order — the one order both kernels share.
fn finish_sums<const WEIGHTED: bool, const EXACT: bool>(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    (rest, rest_scales): (&[[f64; 3]], &[f64]),
    lanes: &LaneSums,
    n: usize,
) -> Sums {
    let LaneSums {
        cost,
        raw,
        jtr,
        jtj,
    } = lanes;
    let mut eq = NormalEquations::<N_PARAMS>::zero();
    let mut raw_cost = 0.0;
    for (i, p) in rest.iter().enumerate() {
        let (mut r, mut g) = geom.residual_and_gradient(kind, p);
        if WEIGHTED {
            let s = rest_scales[i];
            r *= s;
            g = g.map(|v| s * v);
        }
        let (c, wg, wh) = if EXACT {
            loss.cost_and_exact_weights(r)
        } else {
            loss.cost_and_weights(r)
        };
        eq.push_weighted(r, &g, c, wg, wh);
        raw_cost += r * r;
    }
    for l in 0..LANES {
        eq.cost += cost[l];
        raw_cost += if loss == Loss::Squared {
            cost[l]
        } else {
            raw[l]
        };
        let mut idx = 0;
        for a in 0..N_PARAMS {
            eq.jtr[a] += jtr[a][l];
            for b in a..N_PARAMS {
                eq.jtj[(a, b)] += jtj[idx][l];
                idx += 1;
            }
        }
    }
    eq.n_residuals = n;
    Sums { eq, raw_cost }
}

/// [`accumulate_lanes`]'s sums with every lane's residual, gradient and sums in AVX2
/// registers ([`Geometry::residuals_and_gradients_m256`]): each operation the portable
/// kernel's on four lanes, in its order, so the same bits (tested below). The Cauchy
/// loss's weights in registers too ([`crate::loss::cauchy_m256`]), Huber's lane by lane by
/// the scalar code. With the squared loss the weights are 1 and their products (exact)
/// are left out.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn accumulate_avx2<const WEIGHTED: bool, const EXACT: bool>(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
    scales: &[f64],
) -> Sums {
    use std::arch::x86_64::*;
    let zero = _mm256_setzero_pd();
    let mut acc = LaneRegisters {
        cost: zero,
        raw: zero,
        jtr: [zero; N_PARAMS],
        jtj: [zero; NT],
    };
    // Two blocks at a time: their robust weights (a serial chain of divisions and a
    // polynomial each) are computed before either is summed, so that the two chains
    // overlap; the sums still take block after block, in order.
    let mut pairs = chunk.chunks_exact(2 * LANES);
    let mut scale_pairs = scales.chunks_exact(2 * LANES);
    for pair in &mut pairs {
        let s = if WEIGHTED { scale_pairs.next() } else { None };
        let half = |h: usize| {
            let pts: &[[f64; 3]; LANES] = pair[h * LANES..(h + 1) * LANES]
                .try_into()
                .expect("a pair holds two blocks");
            (pts, s.map(|s| &s[h * LANES..(h + 1) * LANES]))
        };
        // SAFETY: this function is compiled for AVX2 and runs only where the CPU has it.
        unsafe {
            // Not through `array::map`: a closure inlined into a function not compiled for
            // AVX2 calls its intrinsics out of line (3.5× slower).
            let blocks = [
                block_m256::<WEIGHTED>(geom, kind, half(0)),
                block_m256::<WEIGHTED>(geom, kind, half(1)),
            ];
            acc.add_blocks::<EXACT, 2>(loss, &blocks);
        }
    }
    // One more whole block, if any, then the points after it.
    let rest = pairs.remainder();
    let rest_scales = scale_pairs.remainder();
    let (rest, rest_scales) = if rest.len() >= LANES {
        let pts: &[[f64; 3]; LANES] = rest[..LANES].try_into().expect("LANES points");
        let s = WEIGHTED.then(|| &rest_scales[..LANES]);
        // SAFETY: as above.
        unsafe {
            let block = block_m256::<WEIGHTED>(geom, kind, (pts, s));
            acc.add_blocks::<EXACT, 1>(loss, &[block]);
        }
        (
            &rest[LANES..],
            if WEIGHTED {
                &rest_scales[LANES..]
            } else {
                rest_scales
            },
        )
    } else {
        (rest, rest_scales)
    };
    let out = |v: __m256d| {
        let mut a = [0.0; LANES];
        // SAFETY: `a` holds LANES = 4 f64.
        unsafe { _mm256_storeu_pd(a.as_mut_ptr(), v) };
        a
    };
    let lanes = LaneSums {
        cost: out(acc.cost),
        raw: out(acc.raw),
        jtr: acc.jtr.map(out),
        jtj: acc.jtj.map(out),
    };
    finish_sums::<WEIGHTED, EXACT>(geom, kind, loss, (rest, rest_scales), &lanes, chunk.len())
}

/// A block's residuals and gradients in registers.
#[cfg(target_arch = "x86_64")]
type BlockM256 = (
    std::arch::x86_64::__m256d,
    [std::arch::x86_64::__m256d; N_PARAMS],
);

/// The residuals and gradients of one block of `LANES` points, times their scales when
/// `WEIGHTED` (`s`: one per point), as [`accumulate_lanes`] takes them.
///
/// # Safety
/// Only where the CPU has AVX2; inlined into a function compiled for it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn block_m256<const WEIGHTED: bool>(
    geom: &Geometry,
    kind: Residual,
    (pts, s): (&[[f64; 3]; LANES], Option<&[f64]>),
) -> BlockM256 {
    // SAFETY: the CPU has AVX2 (the caller's contract); `s` holds LANES = 4 f64.
    unsafe {
        use std::arch::x86_64::*;
        let (mut r, mut g) = geom.residuals_and_gradients_m256(kind, pts);
        if WEIGHTED {
            let s = s.filter(|s| s.len() == LANES).expect("one scale per point");
            let s = _mm256_loadu_pd(s.as_ptr());
            r = _mm256_mul_pd(r, s);
            for ga in &mut g {
                *ga = _mm256_mul_pd(*ga, s);
            }
        }
        (r, g)
    }
}

/// The robust loss's (c(r), w_g, w_H) of a block's residuals in registers: the Cauchy
/// loss's computed there ([`crate::loss::cauchy_m256`]), Huber's lane by lane by the
/// scalar code.
///
/// # Safety
/// Only where the CPU has AVX2; inlined into a function compiled for it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn weights_m256<const EXACT: bool>(
    loss: Loss,
    r: std::arch::x86_64::__m256d,
) -> [std::arch::x86_64::__m256d; 3] {
    // SAFETY: the CPU has AVX2 (the caller's contract); each array holds LANES = 4 f64.
    unsafe {
        use std::arch::x86_64::*;
        if let Loss::Cauchy { scale } = loss {
            return crate::loss::cauchy_m256(scale, r, EXACT);
        }
        let mut rl = [0.0; LANES];
        _mm256_storeu_pd(rl.as_mut_ptr(), r);
        let mut w = [[0.0; LANES]; 3];
        for l in 0..LANES {
            (w[0][l], w[1][l], w[2][l]) = if EXACT {
                loss.cost_and_exact_weights(rl[l])
            } else {
                loss.cost_and_weights(rl[l])
            };
        }
        w.map(|a| _mm256_loadu_pd(a.as_ptr()))
    }
}

/// [`LaneSums`] in AVX2 registers.
#[cfg(target_arch = "x86_64")]
struct LaneRegisters {
    cost: std::arch::x86_64::__m256d,
    raw: std::arch::x86_64::__m256d,
    jtr: [std::arch::x86_64::__m256d; N_PARAMS],
    jtj: [std::arch::x86_64::__m256d; NT],
}

#[cfg(target_arch = "x86_64")]
impl LaneRegisters {
    /// The terms of `K` blocks in order, their robust weights all taken before the first
    /// is summed (see [`accumulate_avx2`]).
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[inline(always)]
    unsafe fn add_blocks<const EXACT: bool, const K: usize>(
        &mut self,
        loss: Loss,
        blocks: &[BlockM256; K],
    ) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::_mm256_setzero_pd;
            if loss == Loss::Squared {
                for b in blocks {
                    self.add_squared(b);
                }
                return;
            }
            let mut weights = [[_mm256_setzero_pd(); 3]; K];
            for (w, b) in weights.iter_mut().zip(blocks) {
                *w = weights_m256::<EXACT>(loss, b.0);
            }
            for (b, w) in blocks.iter().zip(&weights) {
                self.add_robust(b, w);
            }
        }
    }

    /// A block's terms under the squared loss: its weights are 1, whose products are
    /// exact and left out.
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[inline(always)]
    unsafe fn add_squared(&mut self, (r, g): &BlockM256) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::{_mm256_add_pd as add, _mm256_mul_pd as mul};
            self.cost = add(self.cost, mul(*r, *r));
            let mut idx = 0;
            for a in 0..N_PARAMS {
                self.jtr[a] = add(self.jtr[a], mul(g[a], *r));
                for b in a..N_PARAMS {
                    self.jtj[idx] = add(self.jtj[idx], mul(g[a], g[b]));
                    idx += 1;
                }
            }
        }
    }

    /// A block's terms under a robust loss with its (c, w_g, w_H).
    ///
    /// # Safety
    /// Only where the CPU has AVX2; inlined into a function compiled for it.
    #[inline(always)]
    unsafe fn add_robust(
        &mut self,
        (r, g): &BlockM256,
        [c, wg, wh]: &[std::arch::x86_64::__m256d; 3],
    ) {
        // SAFETY: the CPU has AVX2 (the caller's contract).
        unsafe {
            use std::arch::x86_64::{_mm256_add_pd as add, _mm256_mul_pd as mul};
            self.cost = add(self.cost, *c);
            self.raw = add(self.raw, mul(*r, *r));
            let mut idx = 0;
            for a in 0..N_PARAMS {
                self.jtr[a] = add(self.jtr[a], mul(mul(*wg, g[a]), *r));
                let hg = mul(*wh, g[a]);
                for b in a..N_PARAMS {
                    self.jtj[idx] = add(self.jtj[idx], mul(hg, g[b]));
                    idx += 1;
                }
            }
        }
    }
}

/// [`accumulate_lanes`] compiled for AVX2 + FMA when the CPU has them; weighted when
/// `scales` is not empty (then one per point); with the loss's curvature clipped at zero
/// (the solver's) or exact ([`Curvature`]).
fn accumulate_chunk(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
    scales: &[f64],
    curvature: Curvature,
) -> Sums {
    let weighted = !scales.is_empty();
    let exact = curvature == Curvature::Exact;
    debug_assert!(!weighted || scales.len() == chunk.len());
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features the function is compiled for.
        return unsafe {
            match (weighted, exact) {
                (true, true) => accumulate_avx2::<true, true>(geom, kind, loss, chunk, scales),
                (true, false) => accumulate_avx2::<true, false>(geom, kind, loss, chunk, scales),
                (false, true) => accumulate_avx2::<false, true>(geom, kind, loss, chunk, scales),
                (false, false) => accumulate_avx2::<false, false>(geom, kind, loss, chunk, scales),
            }
        };
    }
    match (weighted, exact) {
        (true, true) => accumulate_lanes::<true, true>(geom, kind, loss, chunk, scales),
        (true, false) => accumulate_lanes::<true, false>(geom, kind, loss, chunk, scales),
        (false, true) => accumulate_lanes::<false, true>(geom, kind, loss, chunk, scales),
        (false, false) => accumulate_lanes::<false, false>(geom, kind, loss, chunk, scales),
    }
}

/// Which curvature of the loss the normal equations' H carries: the solver's, clipped at
/// zero so that H stays positive (Triggs' correction), or the cost's exact one, which a
/// sandwich's bread needs (a residual past a redescending loss's knee lowers F's
/// curvature; clipped, the bread overstates it and the variance comes out too small).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Curvature {
    /// max(c''/2, 0): the solver's.
    Clipped,
    /// c''/2.
    Exact,
}

impl NormalEquationsProblem<N_PARAMS> for PipeFit<'_> {
    fn normal_equations(&self, x: &SVector<f64, N_PARAMS>) -> Option<NormalEquations<N_PARAMS>> {
        let beta = Params::from_array(x.as_slice().try_into().ok()?);
        self.equations_at(&beta)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_numbers::numbers;

    /// The AVX2 kernel ([`accumulate_avx2`]) against the portable one: the same sums to
    /// the bit, for every residual, loss and weighting, on points that take both forms of
    /// the root (B > 0 and B ≤ 0), rays along the axis (no information: zero) and a
    /// remainder shorter than the lanes. Skipped on a CPU without AVX2.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_kernel_gives_the_portable_sums_to_the_bit() {
        if !(std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma"))
        {
            return;
        }
        let mut r = numbers(11);
        for trial in 0..20 {
            let beta = Params {
                d_max: 0.5 + 0.05 * r(),
                d_min: 0.45 + 0.04 * r(),
                roll: 3.0 * r(),
                pitch: 0.2 * r(),
                yaw: 0.2 * r(),
                dy: 0.05 * r(),
                dz: 0.05 * r(),
            };
            let geom = Geometry::new(&beta).expect("inside");
            let mut pts: Vec<[f64; 3]> = (0..1007)
                .map(|_| [3.0 * (r() + 1.0) + 0.1, 0.3 * r(), 0.3 * r()])
                .collect();
            // Rays along the model axis: the sensor's position along R's X row.
            let axis = beta.rotation().matrix().row(0).transpose();
            pts[5] = [axis.x, axis.y, axis.z];
            pts[6] = [2.0 * axis.x, 2.0 * axis.y, 2.0 * axis.z];
            let scales: Vec<f64> = (0..pts.len()).map(|_| 1.0 + 0.5 * r()).collect();
            for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
                for loss in [
                    Loss::Squared,
                    Loss::Huber { scale: 0.02 },
                    Loss::Cauchy { scale: 0.02 },
                ] {
                    for (n, sc, exact) in [
                        (1003, &[][..], false),
                        (1003, &scales[..1003], false),
                        (1007, &[][..], true),
                        (1007, &scales[..1007], true),
                        (1005, &scales[..1005], false),
                        (7, &[][..], true),
                    ] {
                        let pts = &pts[..n];
                        // SAFETY: the CPU has AVX2 and FMA (checked above).
                        let (fast, plain) = unsafe {
                            match (sc.is_empty(), exact) {
                                (true, false) => (
                                    accumulate_avx2::<false, false>(&geom, kind, loss, pts, sc),
                                    accumulate_lanes::<false, false>(&geom, kind, loss, pts, sc),
                                ),
                                (false, false) => (
                                    accumulate_avx2::<true, false>(&geom, kind, loss, pts, sc),
                                    accumulate_lanes::<true, false>(&geom, kind, loss, pts, sc),
                                ),
                                (true, true) => (
                                    accumulate_avx2::<false, true>(&geom, kind, loss, pts, sc),
                                    accumulate_lanes::<false, true>(&geom, kind, loss, pts, sc),
                                ),
                                (false, true) => (
                                    accumulate_avx2::<true, true>(&geom, kind, loss, pts, sc),
                                    accumulate_lanes::<true, true>(&geom, kind, loss, pts, sc),
                                ),
                            }
                        };
                        let bits = |s: &Sums| -> Vec<u64> {
                            let mut v: Vec<u64> = s.eq.jtj.iter().map(|x| x.to_bits()).collect();
                            v.extend(s.eq.jtr.iter().map(|x| x.to_bits()));
                            v.push(s.eq.cost.to_bits());
                            v.push(s.raw_cost.to_bits());
                            v
                        };
                        assert_eq!(
                            bits(&fast),
                            bits(&plain),
                            "trial {trial} {kind:?} {loss:?} {n} points, weighted {}, exact {exact}",
                            !sc.is_empty()
                        );
                    }
                }
            }
        }
    }

    /// The blocked cluster pass against a direct per-point sum (scalar residual and
    /// gradient, each point's cell by `atan2`), weighted and robust, with more points
    /// than one block.
    #[test]
    fn cluster_sums_match_a_direct_sum() {
        let beta = crate::test_numbers::test_pipe();
        let geom = Geometry::new(&beta).expect("inside");
        let mut r = numbers(5);
        let n = CLUSTER_PARTS * CLUSTER_BLOCK + 12_345;
        let pts: Vec<[f64; 3]> = (0..n).map(|_| [2.0 * r().abs() + 0.2, r(), r()]).collect();
        let scales: Vec<f64> = (0..n).map(|_| 1.0 + 0.5 * r()).collect();
        let cells = Cells {
            axial_edges: vec![0.8, 1.4],
            sectors: 12,
        };
        let fit = PipeFit::new(&pts, Residual::Range)
            .with_loss(Loss::Cauchy { scale: 0.05 })
            .with_scales(Some(&scales));
        let sw = fit
            .cluster_sandwich_at(&beta, &cells, Curvature::Clipped)
            .expect("inside");
        let mut score = vec![SVector::<f64, N_PARAMS>::zeros(); cells.len()];
        let mut bread = vec![Mat::zeros(); cells.len()];
        let mut raw = 0.0;
        for (p, s) in pts.iter().zip(&scales) {
            let (res, g) = geom.residual_and_gradient(Residual::Range, p);
            let (res, g) = (s * res, SVector::<f64, N_PARAMS>::from(g.map(|v| s * v)));
            let (_, wg, wh) = fit.loss.cost_and_weights(res);
            let [x, y, z] = wall_point_pcs(&geom, p);
            let a = cells.axial_edges.iter().filter(|&&e| e <= x).count();
            let phi = y.atan2(z) + std::f64::consts::PI;
            let k = ((phi / std::f64::consts::TAU * 12.0) as usize).min(11);
            score[a * 12 + k] += g * (wg * res);
            bread[a * 12 + k] += g * g.transpose() * wh;
            raw += res * res;
        }
        let kept: Vec<_> = score
            .iter()
            .zip(&bread)
            .filter(|(s, _)| s.norm() > 0.0)
            .collect();
        assert_eq!(sw.clusters, kept.len());
        assert!((sw.raw_cost - raw).abs() <= 1e-10 * raw);
        for ((s, h), (ws, wh)) in sw.cells.iter().zip(kept) {
            assert!((s - ws).norm() <= 1e-9 * ws.norm(), "{s} vs {ws}");
            assert!((h - wh).norm() <= 1e-9 * wh.norm(), "{h} vs {wh}");
        }
    }
}
