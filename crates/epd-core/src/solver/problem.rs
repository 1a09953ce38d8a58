//! The pipe fit as a [`NormalEquationsProblem`]: eq. (4) over a point cloud with one of
//! the three [`Residual`]s, accumulated in parallel in fixed-size chunks.

use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

use crate::lm::{NormalEquations, NormalEquationsProblem};
use crate::loss::Loss;
use crate::params::{N_PARAMS, Params};
use crate::residual::{Geometry, Residual};

/// Points per chunk. Chunks are fixed, and their partial sums are added in order, so
/// the result does not depend on the number of threads.
const CHUNK: usize = 4096;

/// Eq. (4): F(β) = Σ (sᵢ·rᵢ)²(x̂_i,P, β) over measured points in the SCS (m), with
/// per-point scales sᵢ (1 unless given) and optionally some parameters held.
#[derive(Clone, Copy, Debug)]
pub struct PipeFit<'a> {
    /// Measured points x̂_i,S (SCS, m), finite and non-zero.
    pub points: &'a [[f64; 3]],
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

    /// The points and their scales, `CHUNK` at a time (the scales empty when `None`).
    fn chunks(&self) -> impl Iterator<Item = (&'a [[f64; 3]], &'a [f64])> + 'a {
        let scales = self.scales;
        self.points.chunks(CHUNK).enumerate().map(move |(i, c)| {
            (
                c,
                scales.map_or(&[][..], |s| &s[i * CHUNK..i * CHUNK + c.len()]),
            )
        })
    }

    /// The normal equations at β, or `None` outside the model's domain.
    pub fn equations_at(&self, beta: &Params) -> Option<NormalEquations<N_PARAMS>> {
        let geom = Geometry::new(beta)?;
        let kind = self.residual;
        let loss = self.loss;
        let accumulate =
            |(chunk, s): (&[[f64; 3]], &[f64])| accumulate_chunk(&geom, kind, loss, chunk, s);
        let mut total = if self.points.len() <= CHUNK {
            accumulate((self.points, self.scales.unwrap_or(&[])))
        } else {
            let work: Vec<_> = self.chunks().collect();
            let parts: Vec<NormalEquations<N_PARAMS>> =
                work.into_par_iter().map(accumulate).collect();
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
        let one = |(chunk, scales): (&[[f64; 3]], &[f64])| {
            let mut sw = Sandwich {
                bread: SMatrix::zeros(),
                meat: SMatrix::zeros(),
                raw_cost: 0.0,
            };
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
        let work: Vec<_> = self.chunks().collect();
        let parts: Vec<Sandwich> = work.into_par_iter().map(one).collect();
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

    /// The cell of a PCS point (x along the axis, y and z across it).
    pub fn index(&self, x: f64, y: f64, z: f64) -> usize {
        let a = self.axial_edges.partition_point(|&e| e <= x);
        let s = self.sectors.max(1);
        let phi = y.atan2(z) + std::f64::consts::PI; // [0, 2π]
        let k = ((phi / std::f64::consts::TAU) * s as f64) as usize;
        a * s + k.min(s - 1)
    }
}

/// Where the sensing line of the measured point `p` (SCS, m) meets the wall of β, in the
/// PCS (`m` = β's rotation matrix): the point t·p with t the line parameter of eq. (21).
/// It depends on the ray's direction only, not on the point's range error: cells chosen
/// by the measured point itself would be chosen by its noise too (a point pushed out
/// along its ray crosses a cell's far edge), and the cells' mean residuals would then be
/// biased — about ±1.3 mm at σ = 20 mm for bins 0.5 m long along a pipe.
pub fn wall_point_pcs(
    geom: &Geometry,
    m: &nalgebra::Matrix3<f64>,
    beta: &Params,
    p: &[f64; 3],
) -> [f64; 3] {
    let t = geom.line_parameter(p);
    let t = if t.is_finite() { t } else { 1.0 };
    let q = [t * p[0], t * p[1], t * p[2]];
    [
        m[(0, 0)] * q[0] + m[(0, 1)] * q[1] + m[(0, 2)] * q[2],
        m[(1, 0)] * q[0] + m[(1, 1)] * q[1] + m[(1, 2)] * q[2] + beta.dy,
        m[(2, 0)] * q[0] + m[(2, 1)] * q[1] + m[(2, 2)] * q[2] + beta.dz,
    ]
}

/// The cluster-robust sandwich terms at one β ([`PipeFit::cluster_sandwich_at`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ClusterSandwich {
    /// H = Σ w_H(rᵢ)·JᵢJᵢᵀ over all points.
    pub bread: SMatrix<f64, N_PARAMS, N_PARAMS>,
    /// B = Σ_g s_g s_gᵀ with s_g = Σ_{i ∈ g} ψ(rᵢ)Jᵢ the score of cell g.
    pub meat: SMatrix<f64, N_PARAMS, N_PARAMS>,
    /// Each cell's score s_g and its own part H_g of the bread (empty cells left out).
    pub cells: Vec<(SVector<f64, N_PARAMS>, SMatrix<f64, N_PARAMS, N_PARAMS>)>,
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
    pub fn cluster_sandwich_at(&self, beta: &Params, cells: &Cells) -> Option<ClusterSandwich> {
        let geom = Geometry::new(beta)?;
        let rot = beta.rotation();
        let m = *rot.matrix();
        let (kind, loss) = (self.residual, self.loss);
        let g = cells.len();
        type Mat = SMatrix<f64, N_PARAMS, N_PARAMS>;
        type Part = (Vec<Mat>, Vec<SVector<f64, N_PARAMS>>, f64);
        let one = |(chunk, scales): (&[[f64; 3]], &[f64])| -> Part {
            let mut bread = vec![Mat::zeros(); g];
            let mut score = vec![SVector::<f64, N_PARAMS>::zeros(); g];
            let mut raw = 0.0;
            for (i, p) in chunk.iter().enumerate() {
                let (r, grad) = geom.residual_and_gradient(kind, p);
                let s = scales.get(i).copied().unwrap_or(1.0);
                let (r, grad) = (s * r, grad.map(|v| s * v));
                let (_, wg, wh) = loss.cost_and_weights(r);
                let j = SVector::<f64, N_PARAMS>::from(grad);
                let [x, y, z] = wall_point_pcs(&geom, &m, beta, p);
                let c = cells.index(x, y, z);
                bread[c].syger(wh, &j, &j, 1.0);
                score[c] += j * (wg * r);
                raw += r * r;
            }
            (bread, score, raw)
        };
        // At most CLUSTER_PARTS partial sums (each G scores and breads), cut by the point
        // count alone, so the result does not depend on the number of threads and the
        // memory does not grow with the points.
        let n = self.points.len();
        let size = n.div_ceil(CLUSTER_PARTS).max(CHUNK);
        let scales = self.scales;
        let parts: Vec<Part> = (0..n.div_ceil(size))
            .into_par_iter()
            .map(|k| {
                let range = k * size..((k + 1) * size).min(n);
                let sc = scales.map_or(&[][..], |s| &s[range.clone()]);
                one((&self.points[range], sc))
            })
            .collect();
        let mut cell_bread = vec![Mat::zeros(); g];
        let mut score = vec![SVector::<f64, N_PARAMS>::zeros(); g];
        let mut raw_cost = 0.0;
        for (b, sc, r) in &parts {
            for (t, v) in cell_bread.iter_mut().zip(b) {
                *t += v;
            }
            for (t, v) in score.iter_mut().zip(sc) {
                *t += v;
            }
            raw_cost += r;
        }
        let free = |mut m: Mat| {
            m.fill_upper_triangle_with_lower_triangle();
            for i in (0..N_PARAMS).filter(|&i| self.fixed[i]) {
                for j in 0..N_PARAMS {
                    m[(i, j)] = 0.0;
                    m[(j, i)] = 0.0;
                }
            }
            m
        };
        let mut bread = Mat::zeros();
        let mut meat = Mat::zeros();
        let mut kept = Vec::new();
        for (mut s, h) in score.into_iter().zip(cell_bread) {
            if s.iter().all(|v| *v == 0.0) && h.iter().all(|v| *v == 0.0) {
                continue;
            }
            for i in (0..N_PARAMS).filter(|&i| self.fixed[i]) {
                s[i] = 0.0;
            }
            let h = free(h);
            bread += h;
            meat += s * s.transpose();
            kept.push((s, h));
        }
        Some(ClusterSandwich {
            bread,
            meat,
            raw_cost,
            clusters: kept.len(),
            cells: kept,
        })
    }
}

/// Partial sums of [`PipeFit::cluster_sandwich_at`]: each holds G scores and breads
/// (G·56 f64, 43 kB for 96 cells), so 8 of them bound its memory at 0.35 MB whatever the
/// points, with work for 8 threads.
const CLUSTER_PARTS: usize = 8;

/// Lanes of the SIMD kernel.
const LANES: usize = 4;

/// Σ over a chunk of 2ρ(s·r), w·(s·J)ᵀ(s·J) (upper triangle) and w·(s·J)ᵀ(s·r), `LANES`
/// points at a time with one accumulator per lane (summed in a fixed order at the end).
/// `WEIGHTED`: each point's residual and gradient are multiplied by its scale sᵢ from
/// `scales` (one per point); otherwise `scales` is ignored and no multiplication is
/// compiled in.
#[inline(always)]
fn accumulate_lanes<const WEIGHTED: bool>(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
    scales: &[f64],
) -> NormalEquations<N_PARAMS> {
    const NT: usize = N_PARAMS * (N_PARAMS + 1) / 2;
    let mut cost = [0.0; LANES];
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
                let (c, g_w, h_w) = loss.cost_and_weights(r[l]);
                cost[l] += c;
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
    let mut eq = NormalEquations::<N_PARAMS>::zero();
    let rest = blocks.remainder();
    let rest_scales = scale_blocks.remainder();
    for (i, p) in rest.iter().enumerate() {
        let (mut r, mut g) = geom.residual_and_gradient(kind, p);
        if WEIGHTED {
            let s = rest_scales[i];
            r *= s;
            g = g.map(|v| s * v);
        }
        let (c, wg, wh) = loss.cost_and_weights(r);
        eq.push_weighted(r, &g, c, wg, wh);
    }
    for l in 0..LANES {
        eq.cost += cost[l];
        let mut idx = 0;
        for a in 0..N_PARAMS {
            eq.jtr[a] += jtr[a][l];
            for b in a..N_PARAMS {
                eq.jtj[(a, b)] += jtj[idx][l];
                idx += 1;
            }
        }
    }
    eq.n_residuals = chunk.len();
    eq
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn accumulate_avx2<const WEIGHTED: bool>(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
    scales: &[f64],
) -> NormalEquations<N_PARAMS> {
    accumulate_lanes::<WEIGHTED>(geom, kind, loss, chunk, scales)
}

/// [`accumulate_lanes`] compiled for AVX2 + FMA when the CPU has them; weighted when
/// `scales` is not empty (then one per point).
fn accumulate_chunk(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
    scales: &[f64],
) -> NormalEquations<N_PARAMS> {
    let weighted = !scales.is_empty();
    debug_assert!(!weighted || scales.len() == chunk.len());
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features the function is compiled for.
        return unsafe {
            if weighted {
                accumulate_avx2::<true>(geom, kind, loss, chunk, scales)
            } else {
                accumulate_avx2::<false>(geom, kind, loss, chunk, scales)
            }
        };
    }
    if weighted {
        accumulate_lanes::<true>(geom, kind, loss, chunk, scales)
    } else {
        accumulate_lanes::<false>(geom, kind, loss, chunk, scales)
    }
}

impl NormalEquationsProblem<N_PARAMS> for PipeFit<'_> {
    fn normal_equations(&self, x: &SVector<f64, N_PARAMS>) -> Option<NormalEquations<N_PARAMS>> {
        let beta = Params::from_array(x.as_slice().try_into().ok()?);
        self.equations_at(&beta)
    }
}
