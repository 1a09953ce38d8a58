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
}
