//! Bounds and summaries of a fit against its points: the Cramér–Rao lower bound on each
//! parameter's 1-σ (constant and per-point σ) and the RMS range residual.

use crate::cloud::{clean, usable};
use crate::error::EpdError;
use crate::estimate::{Sigmas, View, weighted_cloud};
use crate::params::{N_PARAMS, Params};
use crate::points::Points;
use crate::residual::{Geometry, Residual};
use crate::uncertainty::covariance;
use rayon::prelude::*;

/// The Cramér–Rao lower bound on the 1-σ of each parameter, for range noise N(0, σ²)
/// along each sensing line: the Fisher information is JᵀJ/σ² with J the Jacobian of the
/// ML-EPD range residual at the true β over the noise-free points (SCS, m). The case
/// σᵢ = σ of [`cramer_rao_bound_weighted`].
pub fn cramer_rao_bound(
    noise_free_points: &[[f64; 3]],
    truth: &Params,
    sigma_range: f64,
) -> Result<Sigmas, EpdError> {
    if !(sigma_range >= 0.0 && sigma_range.is_finite()) {
        return Err(EpdError::InvalidOption(format!(
            "sigma_range = {sigma_range}: must be a finite number ≥ 0"
        )));
    }
    let cloud = clean(noise_free_points);
    let view = View {
        points: Points::all(&cloud.points),
        scales: None,
    };
    fisher_bound(view, cloud.dropped, truth, sigma_range * sigma_range)
}

/// The Cramér–Rao lower bound on the 1-σ of each parameter for independent range noise
/// N(0, σᵢ²) along each sensing line, σᵢ (m) per point: the Fisher information is
/// Σ gᵢgᵢᵀ/σᵢ² with gᵢ the gradient of the ML-EPD range residual at the true β of the
/// noise-free point i (SCS, m); the bound of [`estimate_weighted`](crate::estimate::estimate_weighted) with ML-EPD.
/// Computed as σ̃²·(Σ sᵢ²gᵢgᵢᵀ)⁻¹ with sᵢ = σ̃/σᵢ, σ̃ the median σᵢ. Points (with their
/// σᵢ) are dropped as in [`estimate_weighted`](crate::estimate::estimate_weighted); `sigma.len() != points.len()` is an
/// [`EpdError::InvalidOption`].
pub fn cramer_rao_bound_weighted(
    noise_free_points: &[[f64; 3]],
    sigma: &[f64],
    truth: &Params,
) -> Result<Sigmas, EpdError> {
    if sigma.len() != noise_free_points.len() {
        return Err(EpdError::InvalidOption(format!(
            "{} range standard deviations for {} points: need one per point",
            sigma.len(),
            noise_free_points.len()
        )));
    }
    let (cloud, scales, typical) = weighted_cloud(noise_free_points, sigma);
    let view = View {
        points: Points::all(&cloud.points),
        scales: Some(&scales),
    };
    fisher_bound(view, cloud.dropped, truth, typical * typical)
}

/// σ̃²·(J̃ᵀJ̃)⁻¹ on the determined parameters, J̃ the scaled Jacobian of the range residual
/// of `cloud` at `truth`.
fn fisher_bound(
    cloud: View<'_>,
    n_dropped: usize,
    truth: &Params,
    sigma2: f64,
) -> Result<Sigmas, EpdError> {
    if cloud.len() < N_PARAMS {
        return Err(EpdError::TooFewPoints {
            usable: cloud.len(),
            dropped: n_dropped,
            needed: N_PARAMS,
        });
    }
    let eq = cloud
        .fit(Residual::Range)
        .equations_at(truth)
        .ok_or_else(|| {
            EpdError::InvalidOption("the true β puts the sensor outside the pipe".into())
        })?;
    Ok(covariance(&eq, sigma2).0)
}

/// RMS of the range residual r_m (ML-EPD's residual, m) of measured points (SCS) at β:
/// a fit quality in metres comparable across methods. `None` when no point is usable or
/// β puts the sensor outside the pipe.
pub fn rms_range_residual(points: &[[f64; 3]], beta: &Params) -> Option<f64> {
    let cloud = clean(points);
    if cloud.points.is_empty() {
        return None;
    }
    // Σ r² as the solver's cost (`PipeFit::equations_at`) sums it, chunk by chunk in
    // order, without its gradients.
    let geom = Geometry::new(beta)?;
    let chunks: Vec<f64> = cloud
        .points
        .par_chunks(crate::problem::CHUNK)
        .map(|c| geom.range_sum_of_squares(c))
        .collect();
    let cost = chunks.iter().fold(0.0, |t, c| t + c);
    Some((cost / cloud.points.len() as f64).sqrt())
}

/// Batches of [`rms_range_residual_of`]: 16 of the solver's chunks (1.5 MiB of points).
const RMS_BATCH_CHUNKS: usize = 16;

/// [`rms_range_residual`] of the points an iterator yields (the unusable ones skipped),
/// without holding them: they pass through a buffer of `RMS_BATCH_CHUNKS` solver
/// chunks, so that the RMS of a selection (a straight section, a range gate) costs no
/// copy of it (issue 27), and the sum is the one of the selection held in one slice, bit
/// for bit: the chunks' sums in order (tested against [`rms_range_residual`]).
pub fn rms_range_residual_of(points: impl Iterator<Item = [f64; 3]>, beta: &Params) -> Option<f64> {
    let geom = Geometry::new(beta);
    let batch_len = RMS_BATCH_CHUNKS * crate::problem::CHUNK;
    let mut batch: Vec<[f64; 3]> = Vec::with_capacity(batch_len);
    let (mut cost, mut n) = (0.0, 0usize);
    let mut points = points.filter(usable).peekable();
    while points.peek().is_some() {
        batch.clear();
        batch.extend(points.by_ref().take(batch_len));
        n += batch.len();
        // Σ r² as the solver's cost (`PipeFit::equations_at`) sums it, chunk by chunk in
        // order, without its gradients.
        let geom = geom.as_ref()?;
        let chunks: Vec<f64> = batch
            .par_chunks(crate::problem::CHUNK)
            .map(|c| geom.range_sum_of_squares(c))
            .collect();
        cost = chunks.iter().fold(cost, |t, c| t + c);
    }
    if n == 0 {
        return None;
    }
    geom?;
    Some((cost / n as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::PipeFit;

    /// The RMS from the residual-only pass against the solver's own cost at β
    /// (`PipeFit::equations_at`, gradients and all), bit for bit, for clouds of one point,
    /// a few, one chunk and several chunks with remainders, points on both forms of the
    /// root and a ray along the axis.
    #[test]
    fn rms_is_the_solvers_cost_to_the_bit() {
        let beta = crate::test_numbers::test_pipe();
        let mut r = crate::test_numbers::numbers(17);
        let axis = beta.dir_pcs_to_scs(&nalgebra::Vector3::new(1.0, 0.0, 0.0));
        for n in [1usize, 3, 4, 7, 4096, 4099, 3 * 4096 + 5] {
            let mut pts: Vec<[f64; 3]> =
                (0..n).map(|_| [2.0 * r().abs() + 0.2, r(), r()]).collect();
            pts[n / 2] = [axis.x, axis.y, axis.z];
            let eq = PipeFit::new(&pts, Residual::Range)
                .equations_at(&beta)
                .expect("inside");
            let want = (eq.cost / n as f64).sqrt();
            let got = rms_range_residual(&pts, &beta).expect("inside");
            assert_eq!(got.to_bits(), want.to_bits(), "{n} points: {got} vs {want}");
        }
    }

    /// The RMS of a selection streamed through the batches against the same selection
    /// held in one slice, bit for bit: selections that end inside a chunk, on a batch's
    /// edge and past it, with unusable points (NaN, the origin) mixed in; nothing usable,
    /// and β outside the model, give `None` both ways.
    #[test]
    fn a_streamed_selection_is_the_held_one_to_the_bit() {
        let beta = crate::test_numbers::test_pipe();
        let mut r = crate::test_numbers::numbers(23);
        let batch = RMS_BATCH_CHUNKS * crate::problem::CHUNK;
        for n in [5usize, batch, batch + 1, 2 * batch + 4099] {
            let mut pts: Vec<[f64; 3]> =
                (0..n).map(|_| [2.0 * r().abs() + 0.2, r(), r()]).collect();
            pts[n / 3] = [f64::NAN, 0.0, 0.0];
            pts[n / 4] = [0.0; 3];
            // Every point but those whose y is in the upper third.
            let keep = |p: &&[f64; 3]| !(p[1] > 0.33);
            let held: Vec<[f64; 3]> = pts.iter().filter(keep).copied().collect();
            let want = rms_range_residual(&held, &beta).expect("inside");
            let got =
                rms_range_residual_of(pts.iter().filter(keep).copied(), &beta).expect("inside");
            assert_eq!(got.to_bits(), want.to_bits(), "{n} points: {got} vs {want}");
        }
        assert_eq!(rms_range_residual_of([[0.0; 3]].into_iter(), &beta), None);
        let outside = Params { dy: 10.0, ..beta };
        let pts = [[1.0, 0.1, 0.1]];
        assert_eq!(rms_range_residual(&pts, &outside), None);
        assert_eq!(rms_range_residual_of(pts.into_iter(), &outside), None);
    }
}
