//! Robust losses for point clouds with outliers (flying pixels, multipath).
//!
//! The fit minimises Σ c(rᵢ), c = 2ρ, instead of Σ rᵢ² (eq. 4), through reweighted
//! normal equations: g = Σ w_g(r)·r·Jᵢ with w_g = c'(r)/(2r) (the exact half-gradient)
//! and H = Σ w_H(r)·JᵢJᵢᵀ with w_H = max(c''(r)/2, 0) (the Gauss–Newton Hessian of the
//! robust cost, curvature clipped at zero for outliers so H stays positive
//! semi-definite). Plain reweighting (w_H = w_g) converges only linearly; with the true
//! curvature the solver converges as fast as for least squares. For the squared loss
//! w_g = w_H = 1 and c = r², eq. (4) itself.

use crate::error::EpdError;

/// Normal σ per unit of median absolute deviation: for e ~ N(μ, σ²) the median of
/// |e − μ| is Φ⁻¹(3/4)·σ = 0.674 489 750…·σ, so σ = MAD/Φ⁻¹(3/4) = 1.482 602 218…·MAD.
/// Kept at the 4 decimals this code has always used, 1.4826 (1.5·10⁻⁶ relative below
/// the exact factor): every robust σ here multiplies by this literal, and its results
/// stay bit for bit what they were.
pub const MAD_TO_SIGMA: f64 = 1.4826;

/// Huber's k for 95 % asymptotic efficiency at the normal, in units of the residuals'
/// σ. An M-estimator with ψ = ρ' has efficiency (E ψ')²/E ψ² under N(0, 1); for
/// Huber's ψ(r) = clamp(r, −k, k) that is (2Φ(k) − 1)²/(2Φ(k) − 1 − 2kφ(k) +
/// 2k²(1 − Φ(k))), which is 0.95 at k = 1.344 997… (efficiency 0.950 000 3 at 1.345).
pub const HUBER_K95: f64 = 1.345;

/// The Cauchy loss's k for 95 % asymptotic efficiency at the normal, in units of the
/// residuals' σ: with ψ(r) = r/(1 + (r/k)²), (E ψ')²/E ψ² under N(0, 1) (by numerical
/// integration) is 0.95 at k = 2.384 947… (efficiency 0.949 997 7 at 2.3849).
pub const CAUCHY_K95: f64 = 2.3849;

/// The normal σ of residuals about a known centre (0): [`MAD_TO_SIGMA`]·median|rᵢ| of
/// their absolute values `abs_residuals` (reordered in place; the median by nearest
/// rank). NaN when empty.
pub fn mad_sigma(abs_residuals: &mut [f64]) -> f64 {
    MAD_TO_SIGMA * crate::check::quantile(abs_residuals, 0.5)
}

/// The median m of `v` and the normal σ of its spread about it, [`MAD_TO_SIGMA`]·
/// median|vᵢ − m| (`v` is reordered; medians by nearest rank). (NaN, NaN) when empty.
pub fn median_and_mad_sigma(v: &mut [f64]) -> (f64, f64) {
    median_and_mad_sigma_in(v, &mut Vec::new())
}

/// [`median_and_mad_sigma`] with the deviations held in `scratch` (cleared first), so
/// that a caller taking many small medians allocates once: the same values.
pub fn median_and_mad_sigma_in(v: &mut [f64], scratch: &mut Vec<f64>) -> (f64, f64) {
    let m = crate::check::quantile(v, 0.5);
    scratch.clear();
    scratch.extend(v.iter().map(|x| (x - m).abs()));
    (m, mad_sigma(scratch))
}

/// The loss ρ applied to each residual.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Loss {
    /// ρ(r) = r²/2: plain least squares, eq. (4).
    #[default]
    Squared,
    /// Huber: quadratic within ±k, linear beyond: 2ρ = r² (|r| ≤ k), 2k|r| − k² (else).
    Huber {
        /// The threshold k, in residual units (m for RU-EPD and ML-EPD).
        scale: f64,
    },
    /// Cauchy (Lorentzian): 2ρ = k²·ln(1 + (r/k)²); far outliers weigh almost nothing.
    Cauchy {
        /// The scale k, in residual units (m for RU-EPD and ML-EPD).
        scale: f64,
    },
}

/// The scales a robust loss accepts (m): the losses compute r²/c², c²·ρ(r/c) and sums of
/// such terms over up to 2³² points, and after the conversion to C-EPD's residual units
/// (a factor 2/R) c² must stay a normal f64 with that much room: within [1e-100, 1e100]
/// m, c² lies in [1e-200, 1e200] and N·c² below 1e210, far from f64's limits (2.2e-308,
/// 1.8e308). A scale of 1e200 m had overflowed c² and stopped the solver at its start with
/// "converged after 0 iterations".
pub const SCALE_RANGE: (f64, f64) = (1e-100, 1e100);

impl Loss {
    /// A loss by name (`none`, `huber`, `cauchy`) with a scale (m), checked.
    pub fn from_name(name: &str, scale: f64) -> Result<Self, EpdError> {
        let loss = match name.to_ascii_lowercase().as_str() {
            "none" | "squared" | "l2" => Loss::Squared,
            "huber" => Loss::Huber { scale },
            "cauchy" => Loss::Cauchy { scale },
            other => {
                return Err(EpdError::InvalidOption(format!(
                    "unknown loss `{other}`: expected none, huber or cauchy"
                )));
            }
        };
        loss.validate()?;
        Ok(loss)
    }

    /// The name used on command lines and in CSV.
    pub fn name(&self) -> &'static str {
        match self {
            Loss::Squared => "none",
            Loss::Huber { .. } => "huber",
            Loss::Cauchy { .. } => "cauchy",
        }
    }

    /// An error when the scale lies outside [`SCALE_RANGE`].
    pub fn validate(&self) -> Result<(), EpdError> {
        match self {
            Loss::Squared => Ok(()),
            Loss::Huber { scale } | Loss::Cauchy { scale } => {
                let (lo, hi) = SCALE_RANGE;
                if (lo..=hi).contains(scale) {
                    Ok(())
                } else {
                    Err(EpdError::InvalidOption(format!(
                        "loss scale = {scale:e}: must lie in [{lo:e}, {hi:e}] (m); a scale far \
                         above the range errors is least squares (`none`)"
                    )))
                }
            }
        }
    }

    /// The same loss with its scale multiplied by `f` (to residual units).
    pub fn scaled(&self, f: f64) -> Self {
        match *self {
            Loss::Squared => Loss::Squared,
            Loss::Huber { scale } => Loss::Huber { scale: scale * f },
            Loss::Cauchy { scale } => Loss::Cauchy { scale: scale * f },
        }
    }

    /// The same loss with its scale set to `scale` (residual units).
    pub fn with_scale(&self, scale: f64) -> Self {
        match *self {
            Loss::Squared => Loss::Squared,
            Loss::Huber { .. } => Loss::Huber { scale },
            Loss::Cauchy { .. } => Loss::Cauchy { scale },
        }
    }

    /// The scale (residual units), `None` for the squared loss.
    pub fn scale(&self) -> Option<f64> {
        match *self {
            Loss::Squared => None,
            Loss::Huber { scale } | Loss::Cauchy { scale } => Some(scale),
        }
    }

    /// The loss's 95 %-efficiency constant in units of the residuals' σ
    /// ([`HUBER_K95`], [`CAUCHY_K95`]); 1 for the squared loss, which has no scale.
    pub fn k95(&self) -> f64 {
        match self {
            Loss::Squared => 1.0,
            Loss::Huber { .. } => HUBER_K95,
            Loss::Cauchy { .. } => CAUCHY_K95,
        }
    }

    /// (c(r), w_g(r), w_H(r)) for a residual r: the cost 2ρ(r), the gradient weight
    /// c'(r)/(2r) and the curvature weight max(c''(r)/2, 0) — clipped at zero, which
    /// keeps the solver's H positive (see [`cost_and_exact_weights`](Self::cost_and_exact_weights)
    /// for the unclipped one).
    #[inline(always)]
    pub fn cost_and_weights(&self, r: f64) -> (f64, f64, f64) {
        match *self {
            Loss::Squared => (r * r, 1.0, 1.0),
            Loss::Huber { scale: k } => {
                let a = r.abs();
                if a <= k {
                    (r * r, 1.0, 1.0)
                } else {
                    (2.0 * k * a - k * k, k / a, 0.0)
                }
            }
            Loss::Cauchy { scale: k } => {
                let q = (r / k) * (r / k);
                let w = 1.0 / (1.0 + q);
                (k * k * ln_1p_nonneg(q), w, ((1.0 - q) * w * w).max(0.0))
            }
        }
    }

    /// [`cost_and_weights`](Self::cost_and_weights) with the curvature weight c''(r)/2
    /// unclipped: negative past the Cauchy loss's knee (|r| > k, where (1 − q)/(1 + q)²
    /// with q = (r/k)² turns negative); the squared and Huber losses have no negative
    /// curvature, so theirs are the same. The curvature of the cost itself, as the
    /// sandwich's bread needs it (`crate::fit::covariance`).
    #[inline(always)]
    pub fn cost_and_exact_weights(&self, r: f64) -> (f64, f64, f64) {
        match *self {
            Loss::Cauchy { scale: k } => {
                let q = (r / k) * (r / k);
                let w = 1.0 / (1.0 + q);
                (k * k * ln_1p_nonneg(q), w, (1.0 - q) * w * w)
            }
            _ => self.cost_and_weights(r),
        }
    }
}

/// ln(1 + q) for q ≥ 0, within a few ulp of `f64::ln_1p`, without branches or calls
/// so that the SIMD kernel of the normal equations can inline and vectorise it (the
/// Cauchy cost is evaluated at every point of every solver step). +∞ gives +∞ and NaN
/// gives NaN; q < 0 is outside the contract (a squared ratio is never negative).
///
/// With x = 1 + q rounded and e = q − (x − 1) its rounding error, ln(1 + q) =
/// ln x + e/x to first order. x = 2ᵏ·m with m ∈ [√½, √2) (bits shifted so that the
/// exponent is rounded), and ln m = 2·atanh(s) = 2s·Σ s²ʲ/(2j + 1), s = (m − 1)/(m + 1),
/// |s| ≤ 0.1716: the series to s²⁰ leaves a relative error below 10⁻¹⁷.
#[inline(always)]
pub fn ln_1p_nonneg(q: f64) -> f64 {
    let x = 1.0 + q;
    let e = (q - (x - 1.0)) / x;
    let ix = x.to_bits().wrapping_add(ONE_BITS - SQRT_HALF_BITS);
    // k = (ix >> 52) − 1023 through the 2⁵² trick (no integer → float conversion).
    let k = f64::from_bits((ix >> 52) | 0x4330_0000_0000_0000) - 4_503_599_627_370_496.0 - 1023.0;
    let m = f64::from_bits((ix & 0x000f_ffff_ffff_ffff).wrapping_add(SQRT_HALF_BITS));
    let f = m - 1.0;
    let s = f / (2.0 + f);
    let z = s * s;
    // Σ_{j=0..10} z^j/(2j + 1) by Horner.
    let mut p = ATANH_SERIES[10];
    for c in ATANH_SERIES[..10].iter().rev() {
        p = p * z + c;
    }
    // ln(1 + q) = k·ln 2 + 2s·Σ + e, with k·ln 2 split in a high and a low part.
    let ln = k * LN2_HI + (2.0 * s * p + (k * LN2_LO + e));
    // ∞ and NaN pass through (a select, not a branch).
    if q.is_finite() { ln } else { q }
}

/// The bits of √½ ([`ln_1p_nonneg`]): mantissas from it upward map to exponent k.
const SQRT_HALF_BITS: u64 = 0x3fe6_a09e_667f_3bcd;
/// The bits of 1.0.
const ONE_BITS: u64 = 0x3ff0_0000_0000_0000;
/// ln 2's high part, its low 32 bits zero (fdlibm's split).
const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
/// ln 2 − [`LN2_HI`].
const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
/// The series of [`ln_1p_nonneg`]: 1/(2j + 1), j = 0..10.
const ATANH_SERIES: [f64; 11] = [
    1.0,
    1.0 / 3.0,
    1.0 / 5.0,
    1.0 / 7.0,
    1.0 / 9.0,
    1.0 / 11.0,
    1.0 / 13.0,
    1.0 / 15.0,
    1.0 / 17.0,
    1.0 / 19.0,
    1.0 / 21.0,
];

/// [`ln_1p_nonneg`] of four lanes in AVX2 registers: each operation the scalar code's,
/// in its order, so the same bits (tested).
///
/// # Safety
/// Only where the CPU has AVX2; inlined into a function compiled for it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn ln_1p_nonneg_m256(
    q: std::arch::x86_64::__m256d,
) -> std::arch::x86_64::__m256d {
    // SAFETY: the CPU has AVX2 (the caller's contract).
    unsafe {
        use std::arch::x86_64::*;
        use {
            _mm256_add_pd as add, _mm256_castpd_si256 as bits, _mm256_castsi256_pd as from_bits,
            _mm256_div_pd as div, _mm256_mul_pd as mul, _mm256_set1_pd as splat,
            _mm256_sub_pd as sub,
        };
        let one = splat(1.0);
        let x = add(one, q);
        let e = div(sub(q, sub(x, one)), x);
        let ix = _mm256_add_epi64(
            bits(x),
            _mm256_set1_epi64x((ONE_BITS - SQRT_HALF_BITS) as i64),
        );
        let k_bits = _mm256_or_si256(
            _mm256_srli_epi64::<52>(ix),
            _mm256_set1_epi64x(0x4330_0000_0000_0000),
        );
        let k = sub(
            sub(from_bits(k_bits), splat(4_503_599_627_370_496.0)),
            splat(1023.0),
        );
        let m = from_bits(_mm256_add_epi64(
            _mm256_and_si256(ix, _mm256_set1_epi64x(0x000f_ffff_ffff_ffff)),
            _mm256_set1_epi64x(SQRT_HALF_BITS as i64),
        ));
        let f = sub(m, one);
        let s = div(f, add(splat(2.0), f));
        let z = mul(s, s);
        let mut p = splat(ATANH_SERIES[10]);
        for c in ATANH_SERIES[..10].iter().rev() {
            p = add(mul(p, z), splat(*c));
        }
        let ln = add(
            mul(k, splat(LN2_HI)),
            add(mul(mul(splat(2.0), s), p), add(mul(k, splat(LN2_LO)), e)),
        );
        // q finite: |q| < ∞ (false for NaN).
        let abs = _mm256_andnot_pd(splat(-0.0), q);
        let finite = _mm256_cmp_pd::<_CMP_LT_OQ>(abs, splat(f64::INFINITY));
        _mm256_blendv_pd(q, ln, finite)
    }
}

/// The Cauchy loss's (c(r), w_g, w_H) of four residuals in AVX2 registers, as
/// [`Loss::cost_and_weights`] (`exact` false: the curvature clipped at zero) or
/// [`Loss::cost_and_exact_weights`] (`exact` true) computes them, the same operations
/// in the same order, so the same bits (tested in `problem`).
///
/// # Safety
/// Only where the CPU has AVX2; inlined into a function compiled for it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn cauchy_m256(
    k: f64,
    r: std::arch::x86_64::__m256d,
    exact: bool,
) -> [std::arch::x86_64::__m256d; 3] {
    // SAFETY: the CPU has AVX2 (the caller's contract).
    unsafe {
        use std::arch::x86_64::*;
        use {
            _mm256_add_pd as add, _mm256_div_pd as div, _mm256_mul_pd as mul,
            _mm256_set1_pd as splat, _mm256_sub_pd as sub,
        };
        let one = splat(1.0);
        let rk = div(r, splat(k));
        let q = mul(rk, rk);
        let w = div(one, add(one, q));
        let c = mul(splat(k * k), ln_1p_nonneg_m256(q));
        let curvature = mul(mul(sub(one, q), w), w);
        let wh = if exact {
            curvature
        } else {
            _mm256_max_pd(curvature, _mm256_setzero_pd())
        };
        [c, w, wh]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ∫ f over [a, b] by composite Simpson with `n` (even) intervals.
    fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
        let h = (b - a) / n as f64;
        let inner: f64 = (1..n)
            .map(|i| f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 })
            .sum();
        (f(a) + inner + f(b)) * h / 3.0
    }

    fn phi(x: f64) -> f64 {
        (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt()
    }

    /// Φ(x) by quadrature of the normal density.
    fn cdf(x: f64) -> f64 {
        0.5 + simpson(phi, 0.0, x, 4_000)
    }

    /// Huber's efficiency (E ψ')²/E ψ² under N(0, 1), in the closed form of
    /// [`HUBER_K95`]'s doc.
    fn huber_efficiency(k: f64) -> f64 {
        let a = 2.0 * cdf(k) - 1.0;
        a * a / (a - 2.0 * k * phi(k) + 2.0 * k * k * (1.0 - cdf(k)))
    }

    /// The Cauchy loss's efficiency (E ψ')²/E ψ² under N(0, 1), ψ(r) = r/(1 + (r/k)²),
    /// integrated over ±12 (the normal's mass beyond is below 10⁻³²; the integrands are
    /// smooth, so Simpson's error with h = 10⁻³ is far below 10⁻¹⁰).
    fn cauchy_efficiency(k: f64) -> f64 {
        let u = |x: f64| (x / k).powi(2);
        let e_dpsi = simpson(
            |x| (1.0 - u(x)) / (1.0 + u(x)).powi(2) * phi(x),
            -12.0,
            12.0,
            24_000,
        );
        let e_psi2 = simpson(|x| (x / (1.0 + u(x))).powi(2) * phi(x), -12.0, 12.0, 24_000);
        e_dpsi * e_dpsi / e_psi2
    }

    /// Each constant is its definition's root rounded to the digits kept: the
    /// defining function changes sign within half a unit of the last digit around it
    /// (Φ(1/c) = 3/4 for MAD_TO_SIGMA; efficiency 0.95 for the two k). A last digit off
    /// by one moves the constant out of that interval.
    #[test]
    fn the_robust_constants_are_their_definitions_rounded() {
        let brackets = |f: &dyn Fn(f64) -> f64, c: f64, half_ulp: f64| {
            let (lo, hi) = (f(c - half_ulp), f(c + half_ulp));
            assert!(lo.signum() != hi.signum(), "{c}: {lo:e} .. {hi:e}");
        };
        brackets(&|c| cdf(1.0 / c) - 0.75, MAD_TO_SIGMA, 0.5e-4);
        brackets(&|k| huber_efficiency(k) - 0.95, HUBER_K95, 0.5e-3);
        brackets(&|k| cauchy_efficiency(k) - 0.95, CAUCHY_K95, 0.5e-4);
        assert_eq!(Loss::Huber { scale: 1.0 }.k95(), HUBER_K95);
        assert_eq!(Loss::Cauchy { scale: 1.0 }.k95(), CAUCHY_K95);
        assert_eq!(Loss::Squared.k95(), 1.0);
    }

    /// The two MAD helpers on a sample worked by hand, and on nothing.
    #[test]
    fn mad_sigma_by_hand() {
        // Median 4; the deviations [1, 2, 0, 1, 96] have median 1 (the outlier moves
        // neither).
        let mut v = [5.0, 2.0, 3.0, 4.0, 100.0];
        assert_eq!(median_and_mad_sigma(&mut v), (4.0, MAD_TO_SIGMA));
        let mut r = [0.5, 2.0, 1.0];
        assert_eq!(mad_sigma(&mut r), MAD_TO_SIGMA * 1.0);
        assert!(mad_sigma(&mut []).is_nan());
        let (m, s) = median_and_mad_sigma(&mut []);
        assert!(m.is_nan() && s.is_nan());
        // With a buffer already holding other values: cleared first, the same answer.
        let mut scratch = vec![7.0, -3.0, 1e9, 0.5, 0.25, 2.0];
        let mut v = [5.0, 2.0, 3.0, 4.0, 100.0];
        assert_eq!(
            median_and_mad_sigma_in(&mut v, &mut scratch),
            (4.0, MAD_TO_SIGMA)
        );
        assert_eq!(scratch.len(), 5);
    }

    /// The AVX2 ln(1 + q) and Cauchy weights against the scalar code, to the bit, over
    /// 60 decades and at the edges (powers of two and their neighbours, subnormals,
    /// huge, ∞, NaN). Skipped on a CPU without AVX2.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_loss_gives_the_scalar_bits() {
        if !(std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma"))
        {
            return;
        }
        let mut q: Vec<f64> = (0..4000)
            .map(|i| 10f64.powf(-30.0 + 60.0 * i as f64 / 4000.0))
            .collect();
        for k in -60..60 {
            let p = 2f64.powi(k);
            q.extend([p, p * (1.0 - f64::EPSILON), p * (1.0 + f64::EPSILON)]);
        }
        q.extend([
            0.0,
            5e-324,
            1e-310,
            1e300,
            f64::MAX,
            f64::INFINITY,
            f64::NAN,
        ]);
        // Residuals of both signs around the knee, and past it.
        let r: Vec<f64> = q
            .iter()
            .flat_map(|&v| [v.sqrt() * 0.02, -(v.sqrt()) * 0.03])
            .collect();
        /// The four lanes of `f` applied to `x`.
        #[target_feature(enable = "avx2,fma")]
        fn lanes<const M: usize>(
            x: &[f64; 4],
            f: impl Fn(std::arch::x86_64::__m256d) -> [std::arch::x86_64::__m256d; M],
        ) -> [[f64; 4]; M] {
            use std::arch::x86_64::*;
            // SAFETY: compiled for AVX2, run only where the CPU has it (checked above);
            // each array holds 4 f64.
            unsafe {
                f(_mm256_loadu_pd(x.as_ptr())).map(|v| {
                    let mut a = [0.0; 4];
                    _mm256_storeu_pd(a.as_mut_ptr(), v);
                    a
                })
            }
        }
        for block in q.chunks_exact(4) {
            let x: &[f64; 4] = block.try_into().expect("4 lanes");
            // SAFETY: the CPU has AVX2 (checked above).
            let [got] = unsafe { lanes(x, |v| [ln_1p_nonneg_m256(v)]) };
            for l in 0..4 {
                assert_eq!(
                    got[l].to_bits(),
                    ln_1p_nonneg(x[l]).to_bits(),
                    "q = {:e}",
                    x[l]
                );
            }
        }
        for block in r.chunks_exact(4) {
            let x: &[f64; 4] = block.try_into().expect("4 lanes");
            for exact in [false, true] {
                let k = 0.02;
                // SAFETY: the CPU has AVX2 (checked above).
                let got = unsafe { lanes(x, |v| cauchy_m256(k, v, exact)) };
                for l in 0..4 {
                    let loss = Loss::Cauchy { scale: k };
                    let (c, wg, wh) = if exact {
                        loss.cost_and_exact_weights(x[l])
                    } else {
                        loss.cost_and_weights(x[l])
                    };
                    let want = [c, wg, wh].map(f64::to_bits);
                    let have = [got[0][l], got[1][l], got[2][l]].map(f64::to_bits);
                    assert_eq!(have, want, "r = {:e}, exact {exact}", x[l]);
                }
            }
        }
    }

    /// The fast ln(1 + q) against the standard library over 60 decades and at the
    /// edges (exact powers of two, the √2 split, subnormals, huge, ∞, NaN).
    #[test]
    fn ln_1p_matches_the_standard_library() {
        let mut worst: f64 = 0.0;
        let mut x: u64 = 0x2545_f491_4f6c_dd1d;
        let mut check = |q: f64| {
            let (a, b) = (ln_1p_nonneg(q), q.ln_1p());
            if b.is_nan() {
                assert!(a.is_nan(), "q = {q:e}");
                return;
            }
            if b.is_infinite() {
                assert_eq!(a, b, "q = {q:e}");
                return;
            }
            let rel = ((a - b) / b.abs().max(f64::MIN_POSITIVE)).abs();
            worst = worst.max(rel);
            assert!(
                rel <= 4.0 * f64::EPSILON,
                "q = {q:e}: {a:e} vs {b:e}, rel {rel:e}"
            );
        };
        for _ in 0..200_000 {
            // xorshift: a decade in [−30, 30), then a mantissa.
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let u = (x >> 11) as f64 / (1u64 << 53) as f64;
            check(10f64.powf(60.0 * u - 30.0));
        }
        for k in -60..60 {
            let p = 2f64.powi(k);
            for q in [p, p * (1.0 - f64::EPSILON), p * (1.0 + f64::EPSILON)] {
                check(q);
            }
            // x = 1 + q at the √2 split of the mantissa (q ≥ 0 only).
            for q in [
                std::f64::consts::SQRT_2 * p - 1.0,
                std::f64::consts::FRAC_1_SQRT_2 * p - 1.0,
            ] {
                if q >= 0.0 {
                    check(q);
                }
            }
        }
        for q in [
            0.0,
            5e-324,
            1e-310,
            1e299,
            1e300,
            1e308,
            f64::MAX,
            f64::INFINITY,
            f64::NAN,
        ] {
            check(q);
        }
        println!("worst relative difference {:.2} ulp", worst / f64::EPSILON);
    }

    #[test]
    fn weights_are_the_derivatives_of_the_cost() {
        for loss in [
            Loss::Squared,
            Loss::Huber { scale: 0.05 },
            Loss::Cauchy { scale: 0.05 },
        ] {
            // Away from Huber's kink at ±k, where c'' jumps.
            for r in [-0.3, -0.04, -0.01, 0.002, 0.03, 0.2] {
                let c = |r: f64| loss.cost_and_weights(r).0;
                let h = 1e-7;
                let d = (c(r + h) - c(r - h)) / (2.0 * h);
                let h2 = 1e-4;
                let d2 = (c(r + h2) - 2.0 * c(r) + c(r - h2)) / (h2 * h2);
                // c'(r) = 2 w_g r and w_H = max(c''(r)/2, 0).
                let (_, wg, wh) = loss.cost_and_weights(r);
                assert!(
                    (d - 2.0 * wg * r).abs() < 1e-6,
                    "{loss:?} r={r}: c' {d} vs {}",
                    2.0 * wg * r
                );
                assert!(
                    (wh - (0.5 * d2).max(0.0)).abs() < 1e-3,
                    "{loss:?} r={r}: w_H {wh} vs {}",
                    0.5 * d2
                );
            }
        }
    }

    #[test]
    fn names_and_validation() {
        assert_eq!(
            Loss::from_name("huber", 0.1).unwrap(),
            Loss::Huber { scale: 0.1 }
        );
        assert!(Loss::from_name("cauchy", 0.0).is_err());
        assert!(
            Loss::from_name("tukey", 0.1)
                .unwrap_err()
                .to_string()
                .contains("tukey")
        );
    }
}
