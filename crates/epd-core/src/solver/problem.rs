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
