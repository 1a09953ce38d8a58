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

/// Eq. (4): F(β) = Σ r²(x̂_i,P, β) over measured points in the SCS (m).
#[derive(Clone, Copy, Debug)]
pub struct PipeFit<'a> {
    /// Measured points x̂_i,S (SCS, m), finite and non-zero.
    pub points: &'a [[f64; 3]],
    /// The residual function.
    pub residual: Residual,
    /// The loss applied to each residual (squared: eq. 4 itself).
    pub loss: Loss,
}

impl<'a> PipeFit<'a> {
    /// Eq. (4) over `points` with `residual` and the squared loss.
    pub fn new(points: &'a [[f64; 3]], residual: Residual) -> Self {
        Self {
            points,
            residual,
            loss: Loss::Squared,
        }
    }

    /// The same fit with a robust loss.
    pub fn with_loss(self, loss: Loss) -> Self {
        Self { loss, ..self }
    }

    /// The normal equations at β, or `None` outside the model's domain.
    pub fn equations_at(&self, beta: &Params) -> Option<NormalEquations<N_PARAMS>> {
        let geom = Geometry::new(beta)?;
        let kind = self.residual;
        let loss = self.loss;
        let accumulate = |chunk: &[[f64; 3]]| accumulate_chunk(&geom, kind, loss, chunk);
        let mut total = if self.points.len() <= CHUNK {
            accumulate(self.points)
        } else {
            let parts: Vec<NormalEquations<N_PARAMS>> =
                self.points.par_chunks(CHUNK).map(accumulate).collect();
            let mut t = NormalEquations::zero();
            for p in &parts {
                t.merge(p);
            }
            t
        };
        total.symmetrize();
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
    /// The sandwich terms at β (one pass), or `None` outside the model's domain.
    pub fn sandwich_at(&self, beta: &Params) -> Option<Sandwich> {
        let geom = Geometry::new(beta)?;
        let (kind, loss) = (self.residual, self.loss);
        let one = |chunk: &[[f64; 3]]| {
            let mut sw = Sandwich {
                bread: SMatrix::zeros(),
                meat: SMatrix::zeros(),
                raw_cost: 0.0,
            };
            for p in chunk {
                let (r, g) = geom.residual_and_gradient(kind, p);
                let (_, wg, wh) = loss.cost_and_weights(r);
                let j = SVector::<f64, N_PARAMS>::from(g);
                let psi = wg * r;
                sw.bread.syger(wh, &j, &j, 1.0);
                sw.meat.syger(psi * psi, &j, &j, 1.0);
                sw.raw_cost += r * r;
            }
            sw
        };
        let parts: Vec<Sandwich> = self.points.par_chunks(CHUNK).map(one).collect();
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
        Some(total)
    }
}

/// Lanes of the SIMD kernel.
const LANES: usize = 4;

/// Σ over a chunk of 2ρ(r), w·JᵀJ (upper triangle) and w·Jᵀr, `LANES` points at a time with
/// one accumulator per lane (summed in a fixed order at the end).
#[inline(always)]
fn accumulate_lanes(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
) -> NormalEquations<N_PARAMS> {
    const NT: usize = N_PARAMS * (N_PARAMS + 1) / 2;
    let mut cost = [0.0; LANES];
    let mut jtr = [[0.0; LANES]; N_PARAMS];
    let mut jtj = [[0.0; LANES]; NT];
    let mut blocks = chunk.chunks_exact(LANES);
    for block in &mut blocks {
        let pts: &[[f64; 3]; LANES] = block.try_into().expect("chunks_exact yields LANES points");
        let (r, g) = geom.residuals_and_gradients::<LANES>(kind, pts);
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
    for p in blocks.remainder() {
        let (r, g) = geom.residual_and_gradient(kind, p);
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
fn accumulate_avx2(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
) -> NormalEquations<N_PARAMS> {
    accumulate_lanes(geom, kind, loss, chunk)
}

/// [`accumulate_lanes`] compiled for AVX2 + FMA when the CPU has them.
fn accumulate_chunk(
    geom: &Geometry,
    kind: Residual,
    loss: Loss,
    chunk: &[[f64; 3]],
) -> NormalEquations<N_PARAMS> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features the function is compiled for.
        return unsafe { accumulate_avx2(geom, kind, loss, chunk) };
    }
    accumulate_lanes(geom, kind, loss, chunk)
}

impl NormalEquationsProblem<N_PARAMS> for PipeFit<'_> {
    fn normal_equations(&self, x: &SVector<f64, N_PARAMS>) -> Option<NormalEquations<N_PARAMS>> {
        let beta = Params::from_array(x.as_slice().try_into().ok()?);
        self.equations_at(&beta)
    }
}
