//! The survey on straight pipes whose far points carry a range bias (multipath: every
//! range within a band read long by a common amount): the fit on every point is pulled off
//! the pipe by the band and its profile departs where the band begins; the straight pipe
//! refitted on the points before that departure sees none, and the frame must read
//! straight (`epd_core::segment`, `refine`).

mod common;

use epd_core::segment::{Layout, SegmentOptions, survey};
use epd_core::{EstimateOptions, Method};
use rand::RngExt;

/// Range noise σ (m) and the band: ranges in [1, 2] m read `BAND_BIAS_SIGMAS`·σ long.
const SIGMA_M: f64 = 0.02;
const BAND_M: (f64, f64) = (1.0, 2.0);

/// One straight frame of a 20" pipe at 320 × 240 within 6 m, its band read long by
/// `bias_m`.
fn banded_frame(seed: u64, bias_m: f64) -> Vec<[f64; 3]> {
    banded_frame_of(seed, bias_m, 20.0)
}

/// [`banded_frame`] of a pipe `od_in` inches outside.
fn banded_frame_of(seed: u64, bias_m: f64, od_in: f64) -> Vec<[f64; 3]> {
    common::banded_frame(seed, od_in, SIGMA_M, BAND_M, bias_m)
}

/// The survey of a straight frame with the defaults (ML-EPD).
fn survey_of(pts: &[[f64; 3]]) -> epd_core::segment::Survey {
    survey(
        pts,
        Method::MlEpd,
        &EstimateOptions::default(),
        &SegmentOptions::default(),
    )
    .expect("the survey runs on a straight frame")
}

/// 100 straight frames (poses as the numpy caster's: tilt within ±6°, offsets within a
/// fifth of the radius), the band read 2.5σ long (the numpy caster's multipath model): the
/// count read otherwise is binomial; at the goal of 1 % its mean is 1 and its
/// standard deviation 0.99, and the test fails above 1 + 4·0.99 ≈ 5, i.e. at 5 or more,
/// which a true rate of 1 % reaches with probability 0.003. Measured: 0 of 100 (before
/// the refit's verdict was kept, 0 of 100 too: these frames rarely pull the wider fit; the
/// next test holds one that does).
#[test]
fn a_band_of_long_ranges_is_no_departure() {
    let misread = read_otherwise(9, 5000, 20.0);
    assert!(misread.len() < 5, "{misread:?}");
}

/// The frames of 100 straight frames of a pipe `od_in` inches outside, their band read
/// 2.5σ long, seeded from `pick` and `base`, that read otherwise than straight: (seed,
/// layout, straight until).
fn read_otherwise(pick: u64, base: u64, od_in: f64) -> Vec<(u64, &'static str, Option<f64>)> {
    let frames = 100;
    let mut misread = Vec::new();
    let mut pick = common::rng(pick);
    for k in 0..frames {
        let seed = base + pick.random_range(0..1_000_000u64) + k;
        let s = survey_of(&banded_frame_of(seed, 2.5 * SIGMA_M, od_in));
        let seg = &s.segmentation;
        if seg.layout != Layout::Straight {
            misread.push((seed, seg.layout.name(), seg.straight_until));
        }
    }
    println!("{} of {frames} read otherwise: {misread:?}", misread.len());
    misread
}

/// As [`a_band_of_long_ranges_is_no_departure`], on a 30" pipe: there the band begins
/// about 0.9 m ahead, within the survey's near windows, and the sector medians of its
/// slices lie ≈ 15 mm out all around (the band's 2.5σ along rays that graze the wall), far
/// beyond their standard errors: the wall reads wider all around, as neither a branch
/// opening nor a bend makes it (`epd_core::segment`, `widens_all_around`), and the frame
/// reads straight, its straight section ending where the band begins. The same bound as
/// there (fails at 5 or more of 100). Measured: 0 of 100; 2 of 100, both `in_bend` (no
/// result; the band's edge departs at the start of the view), before the straight pipe was
/// refitted without the ring (`ring_refit`); 7 of 100 (5 `tee_ahead`) without the test of
/// the wall's least half.
#[test]
fn a_band_across_a_wide_pipe_is_no_fitting() {
    let misread = read_otherwise(30, 7000, 30.0);
    assert!(misread.len() < 5, "{misread:?}");
}

/// One frame (seed 116350, the band read 5σ long) whose fit on every point is pulled off
/// the pipe by the band: its profile departs at 0.46 m, and the straight pipe refitted
/// before that sees no departure. It reads straight; it read `tee_ahead` at 0.46 m while
/// the survey went back to the fit on every point (checked: the test fails then).
#[test]
fn a_frame_whose_wide_fit_the_band_pulled_reads_straight() {
    let s = survey_of(&banded_frame(116_350, 5.0 * SIGMA_M));
    let seg = &s.segmentation;
    assert_eq!(
        seg.layout,
        Layout::Straight,
        "read {} until {:?}",
        seg.layout.name(),
        seg.straight_until
    );
}
