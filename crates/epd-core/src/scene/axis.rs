//! The straight pipe the survey's profile tests the slices of a frame against: the
//! straight wall's fit and its uncertainty, not what a fitting ahead does to them.
//!
//! The profile ([`crate::scene::profile`]) asks whether a slice of the wall departs from
//! the fitted straight pipe by more than its own noise and the fit's uncertainty of
//! where its axis lies there ([`AxisSigma`]). That uncertainty is meant under the
//! straight pipe, the hypothesis the profile tests. The fit's cluster jackknife
//! (`crate::fit::covariance`) measures instead what the frame's points do to the fit,
//! and the points of a fitting ahead, off the straight wall by many noise scales, do
//! much: on an 8" pipe under σ = 5 cm with an elbow 1 m ahead (the numpy caster of
//! `crates/epd-py/tests/test_independent_bends.py`, 320 × 240), 2.7 % of the points lie
//! beyond 3.9 noise scales (Gaussian noise puts 10⁻⁴ there), the fit's pitch 1-σ was 2.1°
//! against 0.02° with the elbow 3 m ahead, and every slice's shift took a standard error
//! of 13–20 mm beyond 0.8 m: no slice departed and the frame read `straight`. The profile
//! then tests against the fit of the points within those scales: its axis and its
//! uncertainty (the estimate the survey answers with is still the fit on every point, or
//! the refit before the end the profile finds).

use rayon::prelude::*;

use crate::check::FitStatus;
use crate::estimate::{Estimate, EstimateOptions, Method, estimate_masked};
use crate::fit::form::normal_upper_quantile;
use crate::fit::student::incomplete_beta;
use crate::params::Params;
use crate::points::Mask;
use crate::residual::{Geometry, Residual};
use crate::scene::profile::{AxisSigma, SURVEY_FALSE_ALARM};

/// The two-sided tail of Gaussian range noise beyond which a point counts as off the
/// straight wall: |r| > z·s with z = Φ⁻¹(1 − `OFF_WALL_TAIL`/2) = 3.89 and s the fit's
/// robust scale of its range residuals (1.4826·median|r|, [`crate::Diagnostics`]). Under
/// Gaussian noise a frame of N points has N·10⁻⁴ such points (31 of a full 640 × 480
/// frame); their Cauchy-loss scores are at most 2z/(1 + z²) = 0.48 of the largest a point
/// can have, so leaving them out of the straight pipe's fit changes its uncertainty by a
/// share of the order of 10⁻⁴.
pub const OFF_WALL_TAIL: f64 = 1e-4;

/// The straight pipe (β and its axis's uncertainty) to test the profile of `fit` against,
/// `fit` a fit on every point of `pts` (SCS, m): `fit`'s own ([`AxisSigma::of`]), unless
/// more points lie off its wall ([`OFF_WALL_TAIL`]) than Gaussian noise puts there at the
/// survey's false-alarm rate — a binomial count of N trials at the Gaussian tail of the
/// whole frame's median (`gaussian_tail`, about 10⁻⁴) exceeded with probability below
/// [`SURVEY_FALSE_ALARM`], so that a straight frame under Gaussian noise keeps its fit's
/// own in all but 10⁻³ of frames. Then the fit on the points within the
/// limit, started from `fit`'s β. A straight frame with stray returns (far outliers,
/// flying pixels, a multipath band) takes the second too: measured on
/// `scenarios/straight_false_alarm.toml`'s 1080 frames and on the numpy caster's 4000
/// straight frames (`crates/epd-py/tests/test_straight_false_alarms.py`), none more read
/// otherwise than with the fit's own (docs/bends-and-tees.md, "What the profile tests against").
pub fn axis_under_straight_pipe(
    pts: &[[f64; 3]],
    fit: &Estimate,
    method: Method,
    options: &EstimateOptions,
) -> (Params, AxisSigma) {
    let own = (fit.params, AxisSigma::of(fit));
    let Some(off) = OffWall::count(pts, fit).filter(|o| o.excess(o.beyond, o.tail)) else {
        return own;
    };
    let within = Mask::new(pts, |p| {
        off.geom.residual(Residual::Range, p).abs() <= off.limit
    });
    let Ok(start) = options.with_start(fit.params) else {
        return own;
    };
    estimate_masked(pts, &within, method, &start).map_or(own, |e| (e.params, AxisSigma::of(&e)))
}

/// The count of a fit's points off its wall ([`OFF_WALL_TAIL`]) and what Gaussian noise
/// puts there.
pub(crate) struct OffWall {
    /// The fit's wall.
    pub geom: Geometry,
    /// z·s (m): a point whose range residual exceeds it in size is off the wall.
    pub limit: f64,
    /// How many of the `n` points are.
    pub beyond: usize,
    /// Of how many points.
    pub n: usize,
    /// The two-sided Gaussian share beyond ±`limit` at the whole frame's scale
    /// ([`gaussian_tail`]).
    pub tail: f64,
}

impl OffWall {
    /// The count over `pts` (SCS, m) off the wall of `fit`; `None` for a fit the form test
    /// refused (lack of fit: its scale is not the noise's), without a usable scale, or
    /// without a usable count.
    pub fn count(pts: &[[f64; 3]], fit: &Estimate) -> Option<Self> {
        if matches!(fit.status, FitStatus::LackOfFit(_)) {
            return None;
        }
        let s = fit
            .diagnostics
            .as_ref()
            .map(|d| d.residual_scale)
            .filter(|s| *s > 0.0 && s.is_finite())?;
        let geom = Geometry::new(&fit.params)?;
        let limit = normal_upper_quantile(0.5 * OFF_WALL_TAIL) * s;
        let limits = [MEDIAN_Z * s, limit];
        let counts = pts
            .par_chunks(crate::problem::CHUNK)
            .map(|c| geom.count_range_beyond(c, &limits))
            .reduce(|| [0, 0], |a, b| [a[0] + b[0], a[1] + b[1]]);
        let tail = gaussian_tail(pts.len(), counts[0], limit, limits[0])?;
        Some(Self {
            geom,
            limit,
            beyond: counts[1],
            n: pts.len(),
            tail,
        })
    }

    /// Whether `k` of the `n` points beyond a limit that Gaussian noise passes with
    /// probability `p` are more than it puts there at the survey's false-alarm rate: a
    /// binomial count exceeded with probability below [`SURVEY_FALSE_ALARM`].
    pub fn excess(&self, k: usize, p: f64) -> bool {
        binomial_upper_tail(k, self.n, p) < SURVEY_FALSE_ALARM
    }
}

/// Φ⁻¹(3/4): the median of |r| for N(0, s²) residuals is `MEDIAN_Z`·s.
const MEDIAN_Z: f64 = 0.674_489_750_196_081_7;

/// The share of N(0, ŝ²) residuals beyond ±`limit`, 2Φ(−limit/ŝ), with ŝ the Gaussian
/// scale for which `beyond_median` of the `n` residuals lie beyond ±`median_limit`:
/// ŝ = `median_limit` / Φ⁻¹(1 − q/2), q = `beyond_median`/n. The robust scale s of the fit's
/// diagnostics is the median of a subsample (8192 points, a relative standard error of
/// about 1.3 %), and 3.89 scales out an error δ in s changes the expected count by a
/// factor e^(z²δ) (1.5 at δ = 2.6 %): enough to make clean frames look as if they had
/// stray returns (2 of 10 plain tof-sim frames did). q is counted over every point (its
/// standard error 0.5/√N, 0.1 % on a full frame), so ŝ carries the whole frame's median.
/// `None` without a usable count.
fn gaussian_tail(n: usize, beyond_median: usize, limit: f64, median_limit: f64) -> Option<f64> {
    let q = beyond_median as f64 / n as f64;
    if !(q > 0.0 && q < 1.0) {
        return None;
    }
    let s_hat = median_limit / normal_upper_quantile(0.5 * q);
    let tail = crate::fit::form::erfc(limit / s_hat / std::f64::consts::SQRT_2);
    (tail > 0.0 && tail < 1.0).then_some(tail)
}

/// P(X ≥ k) for X ~ Binomial(n, p): I_p(k, n − k + 1) (Abramowitz & Stegun 26.5.24); 1 for
/// k = 0, 0 for k > n.
pub(crate) fn binomial_upper_tail(k: usize, n: usize, p: f64) -> f64 {
    if k == 0 {
        return 1.0;
    }
    if k > n {
        return 0.0;
    }
    incomplete_beta(k as f64, (n - k + 1) as f64, p, 1.0 - p)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The binomial tail against sums of the probability mass (exact for small n), and
    /// the limit of a full frame: at N = 307 200 and 10⁻⁴ (mean 30.7) the count the
    /// survey's rate allows lies where a normal approximation with its skew puts it.
    #[test]
    fn binomial_tail_matches_its_sum() {
        let (n, p) = (40usize, 0.07_f64);
        let pmf = |k: usize| {
            let ln_choose: f64 = (0..k).map(|i| ((n - i) as f64 / (i + 1) as f64).ln()).sum();
            (ln_choose + k as f64 * p.ln() + (n - k) as f64 * (1.0 - p).ln()).exp()
        };
        for k in 0..=n {
            let sum: f64 = (k..=n).map(pmf).sum();
            let got = binomial_upper_tail(k, n, p);
            assert!(
                (got - sum).abs() <= 1e-12 * sum.max(1e-300) + 1e-15,
                "k {k}: {got} vs {sum}"
            );
        }
        assert_eq!(binomial_upper_tail(n + 1, n, p), 0.0);
        let n = 307_200;
        let k = (0..n)
            .find(|&k| binomial_upper_tail(k, n, OFF_WALL_TAIL) < SURVEY_FALSE_ALARM)
            .unwrap();
        // Mean 30.72, SD 5.54: 3.09 SD (10⁻³) plus the Poisson's skew puts it near 50.
        assert!((47..=52).contains(&k), "{k}");
    }

    /// z = 3.891 (Φ⁻¹(1 − 5·10⁻⁵), tables of the normal distribution); Φ⁻¹(3/4).
    #[test]
    fn the_limits_are_normal_quantiles() {
        let z = normal_upper_quantile(0.5 * OFF_WALL_TAIL);
        assert!((z - 3.8906).abs() < 1e-3, "{z}");
        assert!((normal_upper_quantile(0.25) - MEDIAN_Z).abs() < 1e-6); // erfc to 1.2e-7
    }

    /// With the median's count at one half the scale is s itself and the tail 2Φ(−z) =
    /// 10⁻⁴; a scale 2.6 % low (the count beyond 0.6745·s is then that of 0.6745·1.026·ŝ,
    /// 0.5138) puts the tail beyond z·s at 1.5·10⁻⁴ (e^(z²·0.026) ≈ 1.48).
    #[test]
    fn the_tail_follows_the_whole_frames_median() {
        let n = 1_000_000;
        let z = normal_upper_quantile(0.5 * OFF_WALL_TAIL);
        let tail = gaussian_tail(n, n / 2, z, MEDIAN_Z).unwrap();
        assert!((tail / OFF_WALL_TAIL - 1.0).abs() < 1e-4, "{tail}"); // erfc to 1.2e-7, times z²
        let q = crate::fit::form::erfc(MEDIAN_Z / 1.026 / std::f64::consts::SQRT_2);
        let low = gaussian_tail(n, (q * n as f64) as usize, z, MEDIAN_Z).unwrap();
        assert!((low / OFF_WALL_TAIL - 1.48).abs() < 0.03, "{low}");
    }
}
