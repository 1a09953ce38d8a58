//! Statistics over the trials of one setting (README, Conventions): bias, spread, error range.

/// Summary statistics of a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stats {
    /// Number of values.
    pub n: usize,
    /// Mean (the bias, for errors).
    pub mean: f64,
    /// Sample standard deviation (n − 1); 0 for one value.
    pub std: f64,
    /// √(mean of squares).
    pub rmse: f64,
    /// Median.
    pub median: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// max − min (the paper's error range).
    pub range: f64,
}

impl Stats {
    /// Statistics of `v`; all NaN when `v` is empty.
    pub fn of(v: &[f64]) -> Self {
        let n = v.len();
        if n == 0 {
            let nan = f64::NAN;
            return Self {
                n,
                mean: nan,
                std: nan,
                rmse: nan,
                median: nan,
                min: nan,
                max: nan,
                range: nan,
            };
        }
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = if n > 1 {
            v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64
        } else {
            0.0
        };
        let rmse = (v.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            s[n / 2]
        } else {
            0.5 * (s[n / 2 - 1] + s[n / 2])
        };
        Self {
            n,
            mean,
            std: var.sqrt(),
            rmse,
            median,
            min: s[0],
            max: s[n - 1],
            range: s[n - 1] - s[0],
        }
    }

    /// The standard error of the mean, std/√n.
    pub fn sem(&self) -> f64 {
        self.std / (self.n as f64).sqrt()
    }
}

pub use epd_core::fit::student::student_t_quantile;

/// The one-sided level of [`FalseAlarms::upper95`]: the bound is exceeded by the true rate
/// in at most 5 % of runs (a 95 % upper confidence bound).
pub const UPPER_BOUND_LEVEL: f64 = 0.05;

/// Bisection steps of [`binomial_upper_bound`]: 2⁻¹⁰⁰ of the unit interval, below the
/// resolution of an `f64` near any bound (the bound is found to ~1e-16).
const UPPER_BOUND_STEPS: usize = 100;

/// How often straight frames were read as something else (a bend, a tee, in a bend): the
/// columns `geometry_frames`, `false_alarms`, `false_alarm_rate`, `false_alarm_se` and
/// `false_alarm_upper95` of `summary.csv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FalseAlarms {
    /// Frames whose geometry was reported (the denominator).
    pub frames: usize,
    /// Of them, frames read as anything but `straight`.
    pub count: usize,
    /// count / frames (NaN without frames).
    pub rate: f64,
    /// The binomial standard error √(p̂(1 − p̂)/n) (0 when no frame or every frame
    /// alarmed: say the bound instead).
    pub se: f64,
    /// The one-sided 95 % upper bound on the rate (Clopper–Pearson: the rate p at which
    /// P(X ≤ count | n, p) = 5 %), which, unlike the SE, says something when no frame
    /// alarmed (1 − 0.05^(1/n) then).
    pub upper95: f64,
}

impl FalseAlarms {
    /// `count` alarms in `frames` frames (`count` ≤ `frames`).
    pub fn of(count: usize, frames: usize) -> Self {
        let n = frames as f64;
        let rate = count as f64 / n;
        let se = if frames == 0 {
            f64::NAN
        } else {
            (rate * (1.0 - rate) / n).sqrt()
        };
        Self {
            frames,
            count,
            rate,
            se,
            upper95: binomial_upper_bound(count, frames, UPPER_BOUND_LEVEL),
        }
    }
}

/// The Clopper–Pearson one-sided upper confidence bound of level 1 − `alpha` on a
/// binomial rate after `k` successes in `n` trials: the p at which P(X ≤ k | n, p) =
/// `alpha` (the CDF falls monotonically in p), by bisection. 1 when k ≥ n, NaN when n = 0.
pub fn binomial_upper_bound(k: usize, n: usize, alpha: f64) -> f64 {
    if n == 0 {
        return f64::NAN;
    }
    if k >= n {
        return 1.0;
    }
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    for _ in 0..UPPER_BOUND_STEPS {
        let mid = 0.5 * (lo + hi);
        if binomial_cdf(k, n, mid) > alpha {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// P(X ≤ k) for X ~ Binomial(n, p), 0 < p < 1, summed in log space from P(X = 0) =
/// (1 − p)ⁿ by the ratio P(j + 1)/P(j) = (n − j)/(j + 1) · p/(1 − p), so that no term
/// underflows before it is added.
fn binomial_cdf(k: usize, n: usize, p: f64) -> f64 {
    if p <= 0.0 {
        return 1.0;
    }
    if p >= 1.0 {
        return if k >= n { 1.0 } else { 0.0 };
    }
    let odds = (p / (1.0 - p)).ln();
    let mut log_term = n as f64 * (-p).ln_1p();
    let mut log_sum = log_term;
    for j in 0..k.min(n) {
        log_term += ((n - j) as f64 / (j + 1) as f64).ln() + odds;
        let (a, b) = if log_sum > log_term {
            (log_sum, log_term)
        } else {
            (log_term, log_sum)
        };
        log_sum = a + (b - a).exp().ln_1p();
    }
    log_sum.exp().min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_sample() {
        let s = Stats::of(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(s.n, 4);
        assert_eq!(s.mean, 2.5);
        assert!((s.std - (5.0f64 / 3.0).sqrt()).abs() < 1e-15);
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert_eq!((s.median, s.min, s.max, s.range), (2.5, 1.0, 4.0, 3.0));
        assert_eq!(Stats::of(&[5.0, 1.0, 3.0]).median, 3.0);
        assert!(Stats::of(&[]).mean.is_nan());
        assert_eq!(Stats::of(&[2.0]).std, 0.0);
    }

    #[test]
    fn false_alarm_bounds() {
        // No alarm: the bound is 1 − α^(1/n) in closed form ((1 − p)ⁿ = α).
        for n in [1, 40, 1000, 100_000] {
            let want = 1.0 - 0.05f64.powf(1.0 / n as f64);
            let got = binomial_upper_bound(0, n, 0.05);
            assert!(
                (got - want).abs() < 1e-12 * want.max(1e-3),
                "n {n}: {got} vs {want}"
            );
        }
        // All alarmed: 1. One alarm in two: (1 − p)² + 2p(1 − p) = 1 − p² = α.
        assert_eq!(binomial_upper_bound(5, 5, 0.05), 1.0);
        assert!((binomial_upper_bound(1, 2, 0.05) - 0.95f64.sqrt()).abs() < 1e-12);
        // The CDF at the bound is α, and the bound lies above the rate.
        for (k, n) in [(3, 1000), (17, 400), (250, 500)] {
            let p = binomial_upper_bound(k, n, 0.05);
            assert!((binomial_cdf(k, n, p) - 0.05).abs() < 1e-9, "{k}/{n}");
            assert!(p > k as f64 / n as f64);
        }
        // Large n, many successes: no underflow (the normal approximation's bound,
        // p̂ + 1.645·SE, is within a few percent of the exact one here).
        let (k, n) = (50_000, 1_000_000);
        let p = binomial_upper_bound(k, n, 0.05);
        let approx = 0.05 + 1.645 * (0.05f64 * 0.95 / n as f64).sqrt();
        assert!(
            (p - approx).abs() < 0.02 * (approx - 0.05),
            "{p} vs {approx}"
        );
        let f = FalseAlarms::of(3, 12);
        assert_eq!((f.count, f.frames, f.rate), (3, 12, 0.25));
        assert!((f.se - (0.25f64 * 0.75 / 12.0).sqrt()).abs() < 1e-15);
        assert!(FalseAlarms::of(0, 0).rate.is_nan());
    }
}
