//! Reproducible numbers for the unit tests, without a dependency.

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
