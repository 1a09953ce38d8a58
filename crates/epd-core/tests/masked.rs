//! `estimate_masked`: the estimate of the points a mask keeps, read in place, against
//! `estimate` of their copy (the oracle). The fit reads the kept points in the same order
//! and the same chunks, so every field must agree to the bit, whatever the method, the
//! loss, the options and the mask; unusable kept points are dropped and counted, far ones
//! refused, as for the copy.

mod common;

use epd_core::points::Mask;
use epd_core::{EpdError, EstimateOptions, Loss, Method, estimate, estimate_masked};
use rand::RngExt;

/// A noisy frame of a 20" pipe at 320 × 240 within 6 m (about 60 000 points: 15 chunks
/// of the solver, two stages, every uncertainty pass).
fn frame(seed: u64) -> Vec<[f64; 3]> {
    let truth = common::random_params(&mut common::rng(seed), common::id_m(20.0), 0.02, 5.0, 0.2);
    common::cloud(&truth, 320, 240, 6.0, 0.02, 0, seed)
}

fn copy_of(pts: &[[f64; 3]], mask: &Mask) -> Vec<[f64; 3]> {
    epd_core::points::Points::masked(pts, mask)
        .expect("same length")
        .iter()
        .copied()
        .collect()
}

#[test]
fn a_masked_estimate_is_the_estimate_of_the_copy_to_the_bit() {
    let mut rng = common::rng(11);
    let options = [
        EstimateOptions::default(),
        EstimateOptions::default()
            .with_loss(Loss::Squared)
            .expect("loss"),
        EstimateOptions::default()
            .with_range_gate(0.3, 4.0)
            .expect("gate"),
    ];
    for seed in 0..3u64 {
        let pts = frame(seed);
        // Masks: the near part (a refit before a bend), a random 70 %, every point, a
        // sparse random 3 % (fewer points than one solver chunk's worth of stages).
        let near = pts.iter().map(|p| p[0]).fold(0.0f64, f64::max) * 0.4;
        let draws: Vec<f64> = (0..pts.len()).map(|_| rng.random::<f64>()).collect();
        let random =
            |share: f64| Mask::from_flags(&draws.iter().map(|&u| u < share).collect::<Vec<_>>());
        let masks = [
            Mask::new(&pts, |p| p[0] < near),
            random(0.7),
            Mask::new(&pts, |_| true),
            random(0.03),
        ];
        for (k, mask) in masks.iter().enumerate() {
            let copy = copy_of(&pts, mask);
            for m in Method::ALL {
                for o in &options {
                    let want = estimate(&copy, m, o);
                    let got = estimate_masked(&pts, mask, m, o);
                    assert_eq!(
                        format!("{got:?}"),
                        format!("{want:?}"),
                        "seed {seed} mask {k} {m} {o:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn unusable_kept_points_are_dropped_and_far_ones_refused_as_for_the_copy() {
    let mut pts = frame(5);
    for i in (0..pts.len()).step_by(97) {
        pts[i] = [f64::NAN, 0.0, 1.0];
    }
    pts[10] = [0.0; 3];
    let mask = Mask::new(&pts, |p| !(p[1] > 0.3));
    let copy = copy_of(&pts, &mask);
    let got = estimate_masked(&pts, &mask, Method::MlEpd, &EstimateOptions::default())
        .expect("a frame with invalid pixels");
    let want = estimate(&copy, Method::MlEpd, &EstimateOptions::default()).expect("the copy");
    assert!(got.n_dropped > 0);
    assert_eq!(format!("{got:?}"), format!("{want:?}"));
    // A far point among the kept ones: the same error, naming its place among them.
    pts[20] = [5000.0, 0.0, 0.0];
    let mask = Mask::new(&pts, |p| !(p[1] > 0.3));
    let copy = copy_of(&pts, &mask);
    let got = estimate_masked(&pts, &mask, Method::MlEpd, &EstimateOptions::default());
    let want = estimate(&copy, Method::MlEpd, &EstimateOptions::default());
    assert!(matches!(got, Err(EpdError::FarPoints { .. })), "{got:?}");
    assert_eq!(format!("{got:?}"), format!("{want:?}"));
    // A mask made for other points is refused, not read out of bounds.
    let other = Mask::new(&pts[1..], |_| true);
    assert!(matches!(
        estimate_masked(&pts, &other, Method::MlEpd, &EstimateOptions::default()),
        Err(EpdError::InvalidOption(_))
    ));
}
