//! The diameters' covariance from range errors shared by groups of points: the depth
//! table's own uncertainty. Every point corrected by one bin carries that bin mean's
//! error e_b (standard error se_b): a systematic error, the same for all of them, that no
//! number of points averages away. Linearised at the fitted β̂ of a least-squares fit of
//! the range residuals rₖ(β) with Jacobian rows Jₖ, a shift aₖ·e_g of point k's range
//! moves β̂ by −H⁻¹·Σ_{k∈g} aₖJₖ·e_g (H = Σ JₖJₖᵀ); summed in quadrature over the groups:
//!
//!   Cov(β̂) = Σ_g (H⁻¹ s_g)(H⁻¹ s_g)ᵀ,  s_g = Σ_{k∈g} aₖ Jₖ.
//!
//! The robust loss's weights are left out (unit weights): near the fit they are close to
//! one for the wall's points.

use nalgebra::{SMatrix, SVector};

use crate::params::{N_PARAMS, Params};
use crate::residual::{Geometry, Residual};

/// Relative singular-value floor of H's pseudo-inverse: directions of β the points do
/// not determine (the roll of a round pipe) take no share, as their 1-σ is `None`.
const PINV_RTOL: f64 = 1e-10;

/// The covariance (m²) of (Dmax, Dmin) from shared range errors: `shift[k]` is point
/// k's group and its error's 1-σ in that group (m), `None` for a point with no shared
/// error; `points` are the fitted points (SCS, m) at `beta`. `None` when `beta` is outside
/// the model or H has no usable inverse.
pub fn shared_error_cov(
    points: &[[f64; 3]],
    shift: &[Option<(u32, f64)>],
    n_groups: usize,
    beta: &Params,
) -> Option<[[f64; 2]; 2]> {
    let terms: Vec<[(u32, f64); 1]> = shift
        .iter()
        .map(|s| [s.unwrap_or((u32::MAX, 0.0))])
        .collect();
    shared_error_cov_terms(points, &terms, n_groups, beta)
}

/// [`shared_error_cov`] where a point shares the errors of up to `K` groups:
/// `terms[k]` lists (group, aₖ) pairs, point k's range moving by Σ aₖ·e_g — a point
/// corrected by a value interpolated between bins carries each bin's error times its
/// interpolation weight. A group out of `0..n_groups` (e.g. `u32::MAX`) or a non-finite
/// aₖ is no term.
pub fn shared_error_cov_terms<const K: usize>(
    points: &[[f64; 3]],
    terms: &[[(u32, f64); K]],
    n_groups: usize,
    beta: &Params,
) -> Option<[[f64; 2]; 2]> {
    let geom = Geometry::new(beta)?;
    let mut h = SMatrix::<f64, N_PARAMS, N_PARAMS>::zeros();
    let mut s = vec![SVector::<f64, N_PARAMS>::zeros(); n_groups];
    for (p, sh) in points.iter().zip(terms) {
        if !super::table::usable(p) {
            continue;
        }
        let (_, g) = geom.residual_and_gradient(Residual::Range, p);
        let g = SVector::<f64, N_PARAMS>::from(g);
        if !g.iter().all(|v| v.is_finite()) {
            continue;
        }
        h += g * g.transpose();
        for (grp, a) in sh {
            if let Some(sg) = s.get_mut(*grp as usize)
                && a.is_finite()
            {
                *sg += g * *a;
            }
        }
    }
    let svd = h.svd(true, true);
    let max = svd.singular_values.max();
    if !(max > 0.0) {
        return None;
    }
    let hinv = svd.pseudo_inverse(max * PINV_RTOL).ok()?;
    let mut cov = [[0.0; 2]; 2];
    for sg in &s {
        let d = hinv * sg;
        for a in 0..2 {
            for b in 0..2 {
                cov[a][b] += d[a] * d[b];
            }
        }
    }
    cov.iter().flatten().all(|v| v.is_finite()).then_some(cov)
}
