//! Pose and elliptical-diameter estimation of a pipe from one 3D time-of-flight frame.
//!
//! A ToF camera inside a pipe measures points x̂_i,S in its sensor coordinate system
//! (SCS). The estimators fit them to an elliptic cylinder by minimising Σ r² (eq. 4) over
//! β = (Dmax, Dmin, θx, θy, θz, δy, δz) (eq. 2), with the SCS → PCS transform of eq. (3):
//! - [`Method::CEpd`]: the canonical ellipse residual, eq. (6) — biased under depth noise;
//! - [`Method::RuEpd`]: the error-based residual, eqs. (20)–(23) — unbiased;
//! - [`Method::MlEpd`]: the range error along the sensing line — maximum likelihood
//!   for noise along the ray.
//!
//! [`estimate_weighted`] takes a range-noise σᵢ per point (heteroscedastic ML for
//! ML-EPD); [`EstimateOptions::with_fixed_diameters`] fits the pose of a pipe of known
//! diameters.
//!
//! Equation numbers refer to the RU-EPD paper (see the README).
//!
//! ```
//! use epd_core::{Method, EstimateOptions, Params, estimate};
//! # let truth = Params { d_max: 0.49, d_min: 0.48, roll: 0.3, pitch: 0.02, yaw: -0.01, dy: 0.01, dz: 0.0 };
//! # let points: Vec<[f64; 3]> = (0..2000).map(|i| {
//! #     let phi = i as f64 * 0.37; let x = 0.5 + (i % 97) as f64 * 0.05;
//! #     let w = nalgebra::Point3::new(x, 0.5 * truth.d_max * phi.cos(), 0.5 * truth.d_min * phi.sin());
//! #     let s = truth.pcs_to_scs(&w); [s.x, s.y, s.z] }).collect();
//! let est = estimate(&points, Method::RuEpd, &EstimateOptions::default())?;
//! assert!((est.params.d_max - 0.49).abs() < 1e-6);
//! # Ok::<(), epd_core::EpdError>(())
//! ```
#![deny(missing_docs)]

// One folder per concept; the modules keep their paths (`epd_core::params`, …).
pub mod calibration;
pub mod cancel;
pub mod error;
pub mod fit;
pub mod model;
pub mod report;
pub mod scene;
pub mod solver;
#[cfg(test)]
mod test_numbers;

pub use fit::{check, cloud, estimate, init, uncertainty};
pub use model::{params, residual, symmetry};
pub use scene::{bend, segment, torus};
pub use solver::{lm, loss, points, problem};

pub use calibration::{DepthTable, Observation, TableBins};
pub use check::{Diagnostics, FitOutcome, FitStatus, Implausible};
pub use error::EpdError;
pub use estimate::{
    Estimate, EstimateOptions, LossScale, Method, PoseFit, Sigmas, cramer_rao_bound,
    cramer_rao_bound_weighted, estimate, estimate_masked, estimate_weighted, fit_pose,
    gate_by_model_range, model_range_gate, rms_range_residual, rms_range_residual_of,
};
pub use lm::{Convergence, DegenerateReason, LmOptions, Status};
pub use loss::Loss;
pub use params::{N_PARAMS, PARAM_NAMES, Params};
pub use residual::Residual;
pub use symmetry::{ParamErrors, canonicalize, errors_against, errors_at_roll};
pub use torus::{RayCrossings, Torus};
