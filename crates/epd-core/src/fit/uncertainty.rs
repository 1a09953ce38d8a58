//! The 1-σ of an estimate: the least-squares covariance σ̂²(JᵀJ)⁻¹, the M-estimator's
//! sandwich H⁻¹BH⁻¹, the inverse on the parameters the data determine, and whether the
//! roll is determined.

use nalgebra::{DMatrix, SMatrix};

use crate::estimate::Sigmas;
use crate::lm::NormalEquations;
use crate::params::{N_PARAMS, Params};

/// Whether the roll is determined (see [`Estimate::roll_determined`]); held diameters
/// have an exactly known ovality.
pub(crate) fn roll_is_determined(
    p: &Params,
    sigma: &Sigmas,
    cov: Option<&SMatrix<f64, N_PARAMS, N_PARAMS>>,
    diameters_held: bool,
) -> bool {
    let dd = p.d_max - p.d_min;
    let mean = 0.5 * (p.d_max + p.d_min);
    let sd_diff = if diameters_held {
        0.0
    } else {
        cov.map(|c| (c[(0, 0)] + c[(1, 1)] - 2.0 * c[(0, 1)]).max(0.0).sqrt())
            .unwrap_or(f64::INFINITY)
    };
    let roll_ok = sigma[2].is_some_and(|s| s < std::f64::consts::FRAC_PI_4);
    dd > (1e-6 * mean).max(3.0 * sd_diff) && roll_ok
}

/// A 7 × 7 matrix over β.
pub(crate) type Mat7 = SMatrix<f64, N_PARAMS, N_PARAMS>;

/// σ²·H⁻¹ for H = JᵀJ, with the parameters the data do not determine left out (see
/// [`determined_inverse`]). Returns the per-parameter 1-σ and, when all parameters are
/// determined, the full covariance.
pub(crate) fn covariance(eq: &NormalEquations<N_PARAMS>, sigma2: f64) -> (Sigmas, Option<Mat7>) {
    let (inv, keep) = determined_inverse(&eq.jtj);
    sigmas_of(&(inv * sigma2), &keep)
}

/// The cluster jackknife covariance ("CR3"): (G − 1)/G · Σ_g A_g s_g s_gᵀ A_gᵀ with
/// A_g = (H − H_g)⁻¹, s_g the score and H_g the bread of cell g — each term the one-step
/// change of the estimate when cell g is left out, exact for linear least squares. Unlike
/// H⁻¹BH⁻¹ it does not shrink the cells that weigh most in the fit (whose scores the fit
/// itself has pulled towards zero), which makes H⁻¹BH⁻¹ too small when a few cells carry
/// most of the information — as the near wall does in a ToF frame of a pipe, where most
/// points lie within a metre. Undetermined parameters are left out as in [`covariance`].
pub(crate) fn jackknife_covariance(
    bread: &Mat7,
    cells: &[(nalgebra::SVector<f64, N_PARAMS>, Mat7)],
) -> (Sigmas, Option<Mat7>) {
    let (_, keep) = determined_inverse(bread);
    let g = cells.len() as f64;
    let mut v = Mat7::zeros();
    for (s, h) in cells {
        let (a, _) = determined_inverse(&(bread - h));
        let d = a * s;
        v += d * d.transpose();
    }
    v *= (g - 1.0) / g;
    sigmas_of(&v, &keep)
}

/// 1-σ of the determined parameters and, when all are determined, the covariance.
pub(crate) fn sigmas_of(cov: &Mat7, keep: &[bool; N_PARAMS]) -> (Sigmas, Option<Mat7>) {
    let mut sig: Sigmas = [None; N_PARAMS];
    for i in 0..N_PARAMS {
        let var = cov[(i, i)];
        sig[i] = (keep[i] && var.is_finite() && var >= 0.0).then(|| var.sqrt());
    }
    let complete = keep.iter().all(|&k| k);
    (sig, complete.then_some(*cov))
}

/// H⁻¹ on the parameters the data determine, zero elsewhere, and which those are: a
/// zero column of J, or a direction of H whose eigenvalue (after Jacobi scaling) is
/// below 1e-12 of the largest, is left out (the parameter dominating the null direction
/// is dropped, and the rest inverted again).
pub(crate) fn determined_inverse(h: &Mat7) -> (Mat7, [bool; N_PARAMS]) {
    let hmax = (0..N_PARAMS).map(|i| h[(i, i)]).fold(0.0, f64::max);
    let mut keep: Vec<usize> = (0..N_PARAMS)
        .filter(|&i| h[(i, i)] > 1e-300 && h[(i, i)] > 1e-24 * hmax)
        .collect();
    loop {
        let k = keep.len();
        if k == 0 {
            return (Mat7::zeros(), [false; N_PARAMS]);
        }
        let s: Vec<f64> = keep.iter().map(|&i| h[(i, i)].sqrt()).collect();
        let hs = DMatrix::from_fn(k, k, |a, b| h[(keep[a], keep[b])] / (s[a] * s[b]));
        let eig = hs.symmetric_eigen();
        let lmax = eig.eigenvalues.max();
        let (imin, lmin) =
            eig.eigenvalues
                .iter()
                .enumerate()
                .fold(
                    (0, f64::INFINITY),
                    |acc, (i, &l)| if l < acc.1 { (i, l) } else { acc },
                );
        if lmin > 1e-12 * lmax && lmin.is_finite() {
            // Invert via the eigen-decomposition.
            let mut inv = DMatrix::zeros(k, k);
            for e in 0..k {
                let v = eig.eigenvectors.column(e);
                inv += v * v.transpose() / eig.eigenvalues[e];
            }
            let mut full = Mat7::zeros();
            let mut mask = [false; N_PARAMS];
            for a in 0..k {
                mask[keep[a]] = true;
                for b in 0..k {
                    full[(keep[a], keep[b])] = inv[(a, b)] / (s[a] * s[b]);
                }
            }
            return (full, mask);
        }
        // Drop the parameter that dominates the null direction, and try again.
        let v = eig.eigenvectors.column(imin);
        let worst = (0..k)
            .max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()))
            .unwrap_or(0);
        keep.remove(worst);
    }
}
