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

    /// (c(r), w_g(r), w_H(r)) for a residual r: the cost 2ρ(r), the gradient weight
    /// c'(r)/(2r) and the curvature weight max(c''(r)/2, 0).
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
                (k * k * q.ln_1p(), w, ((1.0 - q) * w * w).max(0.0))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
