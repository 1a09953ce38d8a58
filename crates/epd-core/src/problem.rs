//! The pipe fit as a [`NormalEquationsProblem`]: eq. (4) over a point cloud with one of
//! the three [`Residual`]s, accumulated in parallel in fixed-size chunks.

use nalgebra::SVector;
use rayon::prelude::*;

use crate::lm::{NormalEquations, NormalEquationsProblem};
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
}

impl PipeFit<'_> {
    /// The normal equations at β, or `None` outside the model's domain.
    pub fn equations_at(&self, beta: &Params) -> Option<NormalEquations<N_PARAMS>> {
        let geom = Geometry::new(beta)?;
        let kind = self.residual;
        let accumulate = |chunk: &[[f64; 3]]| {
            let mut eq = NormalEquations::<N_PARAMS>::zero();
            for p in chunk {
                let (r, g) = geom.residual_and_gradient(kind, p);
                eq.push(r, &g);
            }
            eq
        };
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

impl NormalEquationsProblem<N_PARAMS> for PipeFit<'_> {
    fn normal_equations(&self, x: &SVector<f64, N_PARAMS>) -> Option<NormalEquations<N_PARAMS>> {
        let beta = Params::from_array(x.as_slice().try_into().ok()?);
        self.equations_at(&beta)
    }
}
