//! A fit started from a given β (`EstimateOptions::with_start`), as `--max-points` starts
//! the fit of the chosen points from the informed choice's pilot: the same minimum as the
//! data-only start.

mod common;

use epd_core::{EpdError, EstimateOptions, Loss, LossScale, Method, Params, estimate};
use rand::RngExt;

/// A pilot as `--max-points` makes one: the fit of every `stride`-th point.
fn pilot(pts: &[[f64; 3]], stride: usize, method: Method, opts: &EstimateOptions) -> Params {
    let sample: Vec<[f64; 3]> = pts.iter().step_by(stride).copied().collect();
    estimate(&sample, method, opts).expect("pilot").params
}

/// Noise-free clouds of 60 random poses (16–30" pipes, 1–6 % ovality, tilt ±15°, offsets
/// up to 25 % of the radius), every method, started from a pilot fit on a sixteenth of the
/// points: β recovered to 1e-6 (m, rad), as from the data-only start.
#[test]
fn noise_free_clouds_are_recovered_from_a_start() {
    let mut rng = common::rng(77);
    for k in 0..60 {
        let od = rng.random_range(16.0..30.0f64);
        let ovality = rng.random_range(0.01..0.06f64);
        let truth = common::random_params(&mut rng, common::id_m(od), ovality, 15.0, 0.25);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.0, 0, k);
        let method = Method::ALL[(k % 3) as usize];
        let plain = EstimateOptions::default();
        let start = pilot(&pts, 16, method, &plain);
        let opts = plain.with_start(start).expect("start");
        let est = estimate(&pts, method, &opts).expect("estimate");
        assert!(
            est.status.is_converged(),
            "pose {k} {method}: {:?}",
            est.status
        );
        let e = epd_core::errors_against(&est.params, &truth);
        let worst = [e.d_max, e.d_min, e.roll, e.pitch, e.yaw, e.dy, e.dz]
            .iter()
            .map(|v| v.abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-6, "pose {k} {method}: worst error {worst:e}");
    }
}

/// Noisy clouds (σ = 20 mm, 160 × 120 rays, ML-EPD, plain least squares): the fit from a
/// pilot on 1/16 of the points and the fit from the data-only start minimise the same
/// cost, and each stops once its last step is below 0.1 of the parameters' 1-σ
/// (`EstimateOptions::default`'s stop rule). Newton-like steps near the minimum leave each
/// within about that step of it, so the two differ by at most 2 × 0.1σ̂ per parameter.
#[test]
fn a_start_reaches_the_same_least_squares_minimum() {
    let mut rng = common::rng(78);
    for k in 0..20 {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 10.0, 0.2);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.02, 0, 100 + k);
        let plain = EstimateOptions::default();
        let cold = estimate(&pts, Method::MlEpd, &plain).expect("cold");
        let start = pilot(&pts, 16, Method::MlEpd, &plain);
        let warm = estimate(
            &pts,
            Method::MlEpd,
            &plain.with_start(start).expect("start"),
        )
        .expect("warm");
        assert!(warm.status.is_converged(), "frame {k}: {:?}", warm.status);
        // The solver started there, and skipped the subsample stage.
        assert_eq!(warm.initial, start);
        assert!(warm.iterations < cold.iterations, "frame {k}");
        let (a, b) = (cold.params.to_array(), warm.params.to_array());
        for j in [0, 1, 3, 4, 5, 6] {
            let s = cold.sigma[j].expect("1-σ");
            assert!(
                (a[j] - b[j]).abs() <= 0.2 * s,
                "frame {k} parameter {j}: cold {} warm {} 1-σ {s}",
                a[j],
                b[j]
            );
        }
    }
}

/// The same with the robust loss `epd estimate` uses (Cauchy, scale from the data),
/// started at the pilot directly or through a first stage on twice its points
/// (`EstimateOptions::with_start_fitted_on`, as `--max-points` starts): the
/// scale is measured at the start instead of at the subsample stage's fit, 1.4826·median|r|
/// of the same points at two β a fraction of σ̂ apart, so it differs by a few per cent and
/// the minimum moves by a small part of σ̂; the two fits stay within 0.5σ̂ per parameter.
#[test]
fn a_start_reaches_the_robust_minimum_too() {
    let mut rng = common::rng(79);
    let robust = EstimateOptions::default()
        .with_loss(Loss::Cauchy { scale: 0.05 })
        .expect("loss")
        .with_loss_scale(LossScale::Auto);
    let mut worst: f64 = 0.0;
    for k in 0..20 {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 10.0, 0.2);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.02, 0, 200 + k);
        let cold = estimate(&pts, Method::MlEpd, &robust).expect("cold");
        let start = pilot(&pts, 16, Method::MlEpd, &robust);
        // Started there directly, and (as `--max-points` starts from its pilot) through a
        // first stage on twice the pilot's points.
        let pilot_points = pts.len().div_ceil(16);
        for opts in [
            robust.with_start(start).expect("start"),
            robust
                .with_start_fitted_on(start, pilot_points)
                .expect("start"),
        ] {
            let warm = estimate(&pts, Method::MlEpd, &opts).expect("warm");
            assert!(warm.status.is_converged(), "frame {k}: {:?}", warm.status);
            assert_eq!(warm.initial, start);
            let (a, b) = (cold.params.to_array(), warm.params.to_array());
            for j in [0, 1, 3, 4, 5, 6] {
                let s = cold.sigma[j].expect("1-σ");
                worst = worst.max((a[j] - b[j]).abs() / s);
                assert!(
                    (a[j] - b[j]).abs() <= 0.5 * s,
                    "frame {k} parameter {j}: cold {} warm {} 1-σ {s}",
                    a[j],
                    b[j]
                );
            }
        }
    }
    eprintln!("largest |warm − cold| / σ̂: {worst:.3}");
}

/// A start that is not finite or not a pipe is refused by name; held diameters replace
/// the start's, bit for bit.
#[test]
fn starts_are_checked_and_held_diameters_win() {
    let truth = Params {
        d_max: 0.49,
        d_min: 0.48,
        roll: 0.3,
        pitch: 0.02,
        yaw: -0.01,
        dy: 0.01,
        dz: 0.0,
    };
    for bad in [
        Params {
            pitch: f64::NAN,
            ..truth
        },
        Params {
            d_min: 0.0,
            ..truth
        },
    ] {
        match EstimateOptions::default().with_start(bad) {
            Err(EpdError::InvalidOption(m)) => assert!(m.contains("start"), "{m}"),
            other => panic!("{other:?}"),
        }
    }
    let pts = common::cloud(&truth, 160, 120, 6.0, 0.0, 0, 5);
    let off = Params {
        d_max: 0.6,
        d_min: 0.3,
        ..truth
    };
    let opts = EstimateOptions::default()
        .with_fixed_diameters(truth.d_max, truth.d_min)
        .expect("held")
        .with_start(off)
        .expect("start");
    assert_eq!(opts.start(), Some(off));
    let est = estimate(&pts, Method::MlEpd, &opts).expect("estimate");
    assert_eq!(est.params.d_max.to_bits(), truth.d_max.to_bits());
    assert_eq!(est.params.d_min.to_bits(), truth.d_min.to_bits());
    assert!(est.status.is_converged(), "{:?}", est.status);
    assert_eq!(opts.without_start().start(), None);
}
