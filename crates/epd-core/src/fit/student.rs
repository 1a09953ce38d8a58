//! Student's t quantile for the small-sample correction of a 1-σ
//! ([`crate::fit::uncertainty`]) and for the confidence intervals of the benchmarks; the
//! F quantile of the test for errors shared along the pipe (`uncertainty::SliceCheck`).

/// The p-quantile of Student's t distribution with ν degrees of freedom (ν > 0, not
/// necessarily whole): the t with P(T ≤ t) = p. NaN unless 0 < p < 1 and ν is finite
/// and > 0.
///
/// Exact up to rounding: for t ≥ 0 the upper tail is P(T > t) = ½·I_x(ν/2, ½) with
/// x = ν/(ν + t²) (Abramowitz & Stegun 26.7.1 with 26.5.27), I the regularised incomplete
/// beta function ([`incomplete_beta`]); the tail falls strictly with t, so t is found by
/// doubling an upper bracket and bisecting it to adjacent floats. Relative error ≈ 10⁻¹³
/// (the tests check ν = 1, 2, 4 against their closed forms).
pub fn student_t_quantile(p: f64, nu: f64) -> f64 {
    if !(p > 0.0 && p < 1.0 && nu > 0.0 && nu.is_finite()) {
        return f64::NAN;
    }
    if p < 0.5 {
        return -student_t_quantile(1.0 - p, nu);
    }
    let target = 1.0 - p;
    if !(target < 0.5) {
        return 0.0;
    }
    invert_falling_tail(|t| student_t_upper_tail(t, nu), target)
}

/// The upper tail P(T > t) of Student's t with ν degrees of freedom, for t ≥ 0:
/// ½·I_x(ν/2, ½) with x = ν/(ν + t²) (Abramowitz & Stegun 26.7.1 with 26.5.27), x and
/// 1 − x formed without cancellation. NaN for t < 0 or ν outside (0, ∞).
pub fn student_t_upper_tail(t: f64, nu: f64) -> f64 {
    if !(t >= 0.0 && nu > 0.0 && nu.is_finite()) {
        return f64::NAN;
    }
    let t2 = t * t;
    0.5 * incomplete_beta(0.5 * nu, 0.5, nu / (nu + t2), t2 / (nu + t2))
}

/// The upper tail P(F > f) of Fisher's F with (ν₁, ν₂) degrees of freedom, for f ≥ 0:
/// I_y(ν₂/2, ν₁/2) with y = ν₂/(ν₂ + ν₁f) (Abramowitz & Stegun 26.6.2). NaN for f < 0 or
/// either ν outside (0, ∞).
pub fn f_upper_tail(f: f64, nu1: f64, nu2: f64) -> f64 {
    if !(f >= 0.0 && nu1 > 0.0 && nu2 > 0.0 && nu1.is_finite() && nu2.is_finite()) {
        return f64::NAN;
    }
    let d = nu2 + nu1 * f;
    incomplete_beta(0.5 * nu2, 0.5 * nu1, nu2 / d, nu1 * f / d)
}

/// The x ≥ 0 where a tail probability that falls strictly from x = 0 reaches `target`:
/// an upper bracket doubled from 1 until tail(hi) ≤ target, then bisected to adjacent
/// floats (infinity when no finite bracket exists).
fn invert_falling_tail(tail: impl Fn(f64) -> f64, target: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while tail(hi) > target {
        lo = hi;
        hi *= 2.0;
        if hi.is_infinite() {
            return f64::INFINITY;
        }
    }
    loop {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            return mid;
        }
        if tail(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
}

/// The upper α quantile of Fisher's F distribution with (ν₁, ν₂) degrees of freedom
/// (ν₁, ν₂ > 0, not necessarily whole): the f with P(F > f) = α. NaN unless 0 < α < 1
/// and both ν are finite and > 0.
///
/// Exact up to rounding: P(F > f) = I_y(ν₂/2, ν₁/2) with y = ν₂/(ν₂ + ν₁f) (Abramowitz
/// & Stegun 26.6.2), falling strictly with f; f is found by doubling an upper bracket and
/// bisecting it to adjacent floats, as in [`student_t_quantile`].
pub fn f_upper_quantile(alpha: f64, nu1: f64, nu2: f64) -> f64 {
    if !(alpha > 0.0 && alpha < 1.0 && nu1 > 0.0 && nu2 > 0.0 && nu1.is_finite() && nu2.is_finite())
    {
        return f64::NAN;
    }
    invert_falling_tail(|f| f_upper_tail(f, nu1, nu2), alpha)
}

/// The regularised incomplete beta function I_x(a, b) for a, b > 0 and x ∈ [0, 1], with
/// `y` = 1 − x given by the caller (so that a y near 0 keeps its digits): the continued
/// fraction of Abramowitz & Stegun 26.5.8, evaluated by the modified Lentz method, on
/// the side of the symmetry I_x(a, b) = 1 − I_y(b, a) where it converges fast
/// (Numerical Recipes §6.4). NaN outside the domain or if it does not converge.
pub fn incomplete_beta(a: f64, b: f64, x: f64, y: f64) -> f64 {
    if !(a > 0.0 && b > 0.0 && (0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y)) {
        return f64::NAN;
    }
    if x == 0.0 || y == 0.0 {
        return if x == 0.0 { 0.0 } else { 1.0 };
    }
    // x^a·y^b / B(a, b).
    let front = (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * y.ln()).exp();
    if x < (a + 1.0) / (a + b + 2.0) {
        front * beta_fraction(a, b, x) / a
    } else {
        1.0 - front * beta_fraction(b, a, y) / b
    }
}

/// The continued fraction of I_x(a, b) (A&S 26.5.8), modified Lentz; NaN when it has
/// not converged to rounding in 10⁵ terms (it needs O(√max(a, b)) where it is used).
fn beta_fraction(a: f64, b: f64, x: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let clamp = |v: f64| if v.abs() < TINY { TINY } else { v };
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let mut c = 1.0;
    let mut d = 1.0 / clamp(1.0 - qab * x / qap);
    let mut h = d;
    for m in 1..=100_000 {
        let m = f64::from(m);
        let m2 = 2.0 * m;
        // The even step d₂ₘ.
        let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1.0 / clamp(1.0 + aa * d);
        c = clamp(1.0 + aa / c);
        h *= d * c;
        // The odd step d₂ₘ₊₁.
        let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1.0 / clamp(1.0 + aa * d);
        c = clamp(1.0 + aa / c);
        let step = d * c;
        h *= step;
        if (step - 1.0).abs() <= f64::EPSILON {
            return h;
        }
    }
    f64::NAN
}

/// ln Γ(x) for x > 0: Lanczos' approximation (g = 7, 9 terms; relative error of Γ
/// below 2·10⁻¹⁵), with Γ(x)Γ(1 − x) = π/sin(πx) below ½.
fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut sum = C[0];
    for (i, c) in C.iter().enumerate().skip(1) {
        sum += c / (x + i as f64);
    }
    let t = x + G + 0.5;
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + sum.ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two-sided 95 % (the 0.975 quantile) for ν = 1…30 against the published table:
    /// NIST/SEMATECH e-Handbook of Statistical Methods, §1.3.6.7.2 "Critical Values of
    /// the Student's t Distribution", column α = 0.025 (upper tail). The table rounds to
    /// 3 decimals, so an exact quantile lies within 0.0005 of each entry (the largest
    /// distance, at ν = 26, is 0.000 47). The old Cornish–Fisher t95 was 0.023 off at
    /// ν = 3 and 3.0 at ν = 1.
    /// F quantiles against the closed forms F(2, 2): f = (1 − α)/α and, through
    /// F(1, ν) = t(ν)², Student's t; and against tabled values (NIST/SEMATECH e-Handbook
    /// 1.3.6.7.3, upper 5 % and 1 % points).
    #[test]
    fn f_quantiles() {
        for alpha in [0.2, 0.05, 1e-3] {
            let f = f_upper_quantile(alpha, 2.0, 2.0);
            assert!((f - (1.0 - alpha) / alpha).abs() < 1e-9 * f, "{alpha}: {f}");
            let t = student_t_quantile(1.0 - alpha / 2.0, 7.0);
            let f = f_upper_quantile(alpha, 1.0, 7.0);
            assert!((f - t * t).abs() < 1e-9 * f, "{alpha}: {f} vs {}", t * t);
        }
        // (α, ν₁, ν₂, tabled value, half its last digit).
        for (alpha, nu1, nu2, f, half_digit) in [
            (0.05, 5.0, 10.0, 3.326, 5e-4),
            (0.05, 10.0, 20.0, 2.348, 5e-4),
            (0.01, 3.0, 30.0, 4.510, 5e-4),
            (0.01, 8.0, 100.0, 2.69, 5e-3),
        ] {
            let q = f_upper_quantile(alpha, nu1, nu2);
            assert!(
                (q - f).abs() <= half_digit,
                "F({nu1}, {nu2}) at {alpha}: {q} vs {f}"
            );
        }
        assert!(f_upper_quantile(0.0, 1.0, 1.0).is_nan());
        assert!(f_upper_quantile(0.5, -1.0, 1.0).is_nan());
    }

    #[test]
    fn student_t_975_matches_the_nist_table() {
        const NIST_T975: [f64; 30] = [
            12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, // 1-10
            2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, // 11-20
            2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042, // 21-30
        ];
        for (i, want) in NIST_T975.iter().enumerate() {
            let nu = (i + 1) as f64;
            let t = student_t_quantile(0.975, nu);
            assert!((t - want).abs() <= 0.0005, "ν = {nu}: {t} vs table {want}");
        }
    }

    /// Closed forms (e.g. Hill 1970, Commun. ACM 13:617): ν = 1 is Cauchy, t =
    /// tan(π(p − ½)) = 1/tan(π(1 − p)) (the second form keeps its digits near p = 1,
    /// where the first rounds π(p − ½) next to the pole); ν = 2 gives t = (2p − 1)/√(2p(1 − p)); ν = 4 gives t = 2√(q − 1),
    /// q = cos(⅓·arccos √α)/√α with α = 4p(1 − p) (p > ½). Each is accurate to a few
    /// ulp in f64; 10⁻¹³ leaves room for the incomplete beta's rounding. Symmetry, the
    /// median, the normal limit and the refused arguments too.
    #[test]
    fn student_t_quantile_closed_forms_and_edges() {
        let close = |a: f64, b: f64, what: &str| {
            assert!((a / b - 1.0).abs() < 1e-13, "{what}: {a} vs {b}");
        };
        for p in [0.6, 0.9, 0.975, 0.995, 0.9999] {
            close(
                student_t_quantile(p, 1.0),
                1.0 / (std::f64::consts::PI * (1.0 - p)).tan(),
                &format!("ν = 1, p = {p}"),
            );
            close(
                student_t_quantile(p, 2.0),
                (2.0 * p - 1.0) / (2.0 * p * (1.0 - p)).sqrt(),
                &format!("ν = 2, p = {p}"),
            );
            let alpha = 4.0 * p * (1.0 - p);
            let q = (alpha.sqrt().acos() / 3.0).cos() / alpha.sqrt();
            close(
                student_t_quantile(p, 4.0),
                2.0 * (q - 1.0).sqrt(),
                &format!("ν = 4, p = {p}"),
            );
            assert_eq!(
                student_t_quantile(1.0 - p, 7.5),
                -student_t_quantile(p, 7.5)
            );
        }
        assert_eq!(student_t_quantile(0.5, 3.0), 0.0);
        // ν → ∞: the normal quantile z(0.975) = 1.959 963 984 540 054; the t's excess is
        // (z³ + z)/(4ν) ≈ 2.4·10⁻⁶ at ν = 10⁶.
        let t = student_t_quantile(0.975, 1e6);
        assert!((t - 1.959_963_984_540_054 - 2.37e-6).abs() < 1e-8, "{t}");
        for (p, nu) in [
            (0.0, 3.0),
            (1.0, 3.0),
            (f64::NAN, 3.0),
            (0.9, 0.0),
            (0.9, -1.0),
        ] {
            assert!(student_t_quantile(p, nu).is_nan(), "p {p}, ν {nu}");
        }
        assert!(student_t_quantile(0.9, f64::INFINITY).is_nan());
        assert!(student_t_quantile(0.9, f64::NAN).is_nan());
    }
}
