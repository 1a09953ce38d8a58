//! What lies ahead of the sensor: the survey of a frame near a bend or a tee
//! (`segment`, on the departure profile of `profile`), the torus of a bend with its exact ray cast (`torus`) and the bend's fit
//! (`bend`), where an opening begins (`edge`), and the opening test of the slices too
//! sparse for the medians (`sparse`); which points belong to which part (`select`); the
//! uncertainty of the straight fit's axis the profile tests against (`axis`); a bend far
//! ahead seen where it blocks the view (`blocked`).

pub mod axis;
pub mod bend;
pub mod blocked;
pub mod edge;
pub mod profile;
pub mod segment;
pub mod select;
pub mod sparse;
pub mod torus;

/// A small, seeded generator of uniforms in [0, 1) (SplitMix64), for the scene's tests.
#[cfg(test)]
pub(crate) fn uniforms(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}
