//! Reproducible numbers and a test pipe for the unit tests, without a dependency.

/// A reproducible stream of numbers in [−1, 1): a 64-bit linear congruential generator
/// (Knuth's MMIX constants), its top 53 bits scaled.
pub(crate) fn numbers(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (s >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// A 500 × 480 mm pipe with every pose parameter non-zero (roll 0.3 rad, pitch 0.04, yaw
/// 0.02, δy 10 mm, δz −20 mm), so no term of a residual or its gradient vanishes.
pub(crate) fn test_pipe() -> crate::params::Params {
    crate::params::Params {
        d_max: 0.50,
        d_min: 0.48,
        roll: 0.3,
        pitch: 0.04,
        yaw: 0.02,
        dy: 0.01,
        dz: -0.02,
    }
}
