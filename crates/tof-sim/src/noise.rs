//! Depth-error models (README, Conventions) and the seeded, version-stable random streams.

use rand::SeedableRng;
use rand_pcg::Pcg64;

use crate::error::SimError;
use crate::physics::ToFPhysics;

/// How the random depth error displaces a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum NoiseModel {
    /// Along the sensing line: x̂ = x + ε·d, ε ~ N(0, σ²), d the unit ray direction.
    #[default]
    Range,
    /// Each coordinate N(0, σ²/3) (the paper's stated model): the same mean squared
    /// displacement σ², in no particular direction.
    Isotropic,
}

/// The depth errors of a simulated frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    /// The random-error model.
    pub model: NoiseModel,
    /// Standard deviation σ of the random error (m).
    pub sigma: f64,
    /// Fraction of points whose range is replaced by a wrong one (flying pixels,
    /// multipath): the true range times U(0.5, 1.5). 0 by default.
    pub outlier_fraction: f64,
    /// Fraction of points replaced by a point anywhere in the view: on the pixel's ray
    /// at a range U(0.1 m, 6 m), whatever the wall (stray light, reflections, dust).
    /// 0 by default.
    pub far_outlier_fraction: f64,
    /// Range-dependent depth bias b(r) = b0 + b1·r added along the ray: b0 (m).
    pub bias_b0: f64,
    /// … and b1 (dimensionless).
    pub bias_b1: f64,
    /// The physical sensor model, or `None` (the default) for the plain model above.
    /// When `Some`, it replaces `sigma` (σ then depends on each pixel's amplitude) and
    /// `bias_b0`, `bias_b1` (its systematic errors take their place), marks dark and
    /// saturated pixels invalid and gives each point an intensity; `model` still chooses
    /// the direction of the random error and the outlier fractions still apply afterwards.
    pub physics: Option<ToFPhysics>,
}

impl Noise {
    /// Range noise of standard deviation `sigma`, nothing else.
    pub fn range(sigma: f64) -> Self {
        Self {
            model: NoiseModel::Range,
            sigma,
            outlier_fraction: 0.0,
            far_outlier_fraction: 0.0,
            bias_b0: 0.0,
            bias_b1: 0.0,
            physics: None,
        }
    }

    /// No error at all.
    pub fn none() -> Self {
        Self::range(0.0)
    }

    /// Check every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SimError> {
        if !(self.sigma >= 0.0 && self.sigma.is_finite()) {
            return Err(SimError::invalid(
                "noise.sigma_m",
                self.sigma,
                "must be a finite number ≥ 0",
            ));
        }
        if !(0.0..=1.0).contains(&self.outlier_fraction) {
            return Err(SimError::invalid(
                "noise.outlier_fraction",
                self.outlier_fraction,
                "must lie in [0, 1]",
            ));
        }
        if !(0.0..=1.0).contains(&self.far_outlier_fraction) {
            return Err(SimError::invalid(
                "noise.far_outlier_fraction",
                self.far_outlier_fraction,
                "must lie in [0, 1]",
            ));
        }
        if !self.bias_b0.is_finite() {
            return Err(SimError::invalid(
                "noise.bias_b0_m",
                self.bias_b0,
                "must be finite",
            ));
        }
        if !(self.bias_b1.is_finite() && self.bias_b1 > -1.0) {
            return Err(SimError::invalid(
                "noise.bias_b1",
                self.bias_b1,
                "must be finite and > −1",
            ));
        }
        if let Some(p) = &self.physics {
            p.validate()?;
        }
        Ok(())
    }
}

impl Default for Noise {
    fn default() -> Self {
        Self::range(0.03)
    }
}

/// SplitMix64's finaliser: a bijective 64-bit mix.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// What a random stream is for; part of its seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u64)]
pub enum Stream {
    /// The pose of a trial.
    Pose = 1,
    /// The depth errors of one image row.
    Row = 2,
    /// The subsample of a frame.
    Subsample = 3,
    /// One padded row of the i.i.d. field behind correlated range errors
    /// ([`crate::CameraNoise::correlation_length_px`]).
    Field = 4,
    /// The flying-pixel draws of one image row ([`crate::FlyingPixels`]).
    Flying = 5,
    /// A frame's random wiggling phase ([`crate::Wiggle::random_phase`]).
    Wiggle = 6,
}

/// A PCG-64 (rand_pcg's `Lcg128Xsl64`, a named, version-stable generator) whose seed is
/// a hash of the scenario seed, the trial, the sweep index, the stream and an index
/// within the stream (the image row). The same arguments always give the same stream,
/// whatever thread draws from it.
pub fn stream(seed: u64, trial: u64, sweep_index: u64, kind: Stream, index: u64) -> Pcg64 {
    let mut h = mix(seed);
    for v in [trial, sweep_index, kind as u64, index] {
        h = mix(h ^ v);
    }
    Pcg64::seed_from_u64(h)
}
