//! The informed choice checked against its pilot: does the fit of the chosen points say
//! what the frame as a whole says?

/// The level of the check of the informed choice against its pilot ([`Witness`]): one
/// frame in a thousand whose fits agree is taken for one where they do not. A false
/// alarm costs time and precision, not correctness: the frame is measured again on a
/// uniform sample, whose answer targets the full frame's.
pub const WITNESS_ALPHA: f64 = 1e-3;

/// The pilot fit's mean diameter and its 1-σ (m): a witness of what the frame as a whole
/// says, against which the fit of the informed choice is checked.
///
/// **Why.** The pilot's [`PILOT_POINTS`](super::PILOT_POINTS) are a uniform sample: its parts of the wall
/// weigh in it as in the frame. The informed choice is not: it favours the far, grazing
/// rays. Where the model fits, both fits estimate the same β. Where a part of the wall
/// lies off the model (a multipath band lengthening the ranges of 1–2 m, which sits in
/// those far rays), a robust fit follows the majority of its points, and the two
/// majorities differ: measured on 400 frames of an independent numpy caster with such a
/// band (`crates/epd-py/tests/test_independent_frames.py`'s generator, 320 × 240), the
/// informed choice of 20 000 points answered `converged` about 20 mm (8–12 σ̂) off in
/// 6 frames where the full frame was right.
///
/// **The test.** With D_s, σ_s the chosen points' mean diameter and 1-σ, and D_p, σ_p the
/// pilot's, z = |D_s − D_p| / √(σ_s² + σ_p²) is compared with the two-sided normal
/// quantile at [`WITNESS_ALPHA`] (3.29). The variance of the difference is
/// σ_s² + σ_p² − 2 cov; the two samples share at most the pilot's points, whose errors
/// enter both fits with the same sign (cov ≥ 0), so the sum bounds it and the test's
/// false-alarm rate is at most the level, as far as the two 1-σ hold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Witness {
    /// The pilot's mean diameter (m).
    pub d_mean_m: f64,
    /// Its 1-σ (m).
    pub sigma_m: f64,
}

impl Witness {
    /// The witness of a pilot `fit`, when it has a finite 1-σ.
    pub fn of(fit: &epd_core::Estimate) -> Option<Self> {
        let sigma_m = fit.sigma_d_mean()?;
        (sigma_m.is_finite() && sigma_m > 0.0).then(|| Self {
            d_mean_m: fit.d_mean(),
            sigma_m,
        })
    }

    /// The standardised difference z = |D − D_p| / √(σ² + σ_p²) of a mean diameter `d_mean_m`
    /// with 1-σ `sigma_m` (m) from the witness's.
    pub fn z(&self, d_mean_m: f64, sigma_m: f64) -> f64 {
        (d_mean_m - self.d_mean_m).abs() / (sigma_m * sigma_m + self.sigma_m * self.sigma_m).sqrt()
    }

    /// Whether `fit` (of the chosen points) and the witness disagree beyond
    /// [`WITNESS_ALPHA`]: only a converged fit with a 1-σ is judged (any other is not
    /// an answer to check).
    pub fn disagrees(&self, fit: &epd_core::Estimate) -> bool {
        let Some(sigma) = fit.sigma_d_mean() else {
            return false;
        };
        let z_star = epd_core::fit::form::normal_upper_quantile(WITNESS_ALPHA / 2.0);
        fit.status.is_converged() && self.z(fit.d_mean(), sigma) > z_star
    }
}
