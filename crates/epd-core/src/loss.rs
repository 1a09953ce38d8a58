//! Robust losses for point clouds with outliers (flying pixels, multipath).
//!
//! The fit minimises Σ 2ρ(rᵢ) instead of Σ rᵢ² (eq. 4), by iteratively reweighted
//! normal equations: H = Σ w(r) JᵢJᵢᵀ, g = Σ w(r) r Jᵢ with w(r) = ρ'(r)/r. For the
//! squared loss w = 1 and 2ρ(r) = r², eq. (4) itself.

use crate::error::EpdError;

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

    /// An error when the scale is not a finite number > 0.
    pub fn validate(&self) -> Result<(), EpdError> {
        match self {
            Loss::Squared => Ok(()),
            Loss::Huber { scale } | Loss::Cauchy { scale } => {
                if *scale > 0.0 && scale.is_finite() {
                    Ok(())
                } else {
                    Err(EpdError::InvalidOption(format!(
                        "loss scale = {scale}: must be a finite number > 0 (m)"
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

    /// (2ρ(r), w(r)) for a residual r.
    #[inline(always)]
    pub fn cost_and_weight(&self, r: f64) -> (f64, f64) {
        match *self {
            Loss::Squared => (r * r, 1.0),
            Loss::Huber { scale: k } => {
                let a = r.abs();
                if a <= k {
                    (r * r, 1.0)
                } else {
                    (2.0 * k * a - k * k, k / a)
                }
            }
            Loss::Cauchy { scale: k } => {
                let q = (r / k) * (r / k);
                (k * k * q.ln_1p(), 1.0 / (1.0 + q))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_are_the_derivative_over_r() {
        for loss in [
            Loss::Squared,
            Loss::Huber { scale: 0.05 },
            Loss::Cauchy { scale: 0.05 },
        ] {
            for r in [-0.3, -0.05, -0.01, 0.002, 0.04, 0.2] {
                let h = 1e-7;
                let d = (loss.cost_and_weight(r + h).0 - loss.cost_and_weight(r - h).0) / (2.0 * h);
                // d(2ρ)/dr = 2ρ'(r) = 2 w r.
                let (_, w) = loss.cost_and_weight(r);
                assert!(
                    (d - 2.0 * w * r).abs() < 1e-6,
                    "{loss:?} r={r}: {d} vs {}",
                    2.0 * w * r
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
