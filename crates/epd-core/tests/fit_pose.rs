//! `fit_pose`: the β of `estimate` without its 1-σ and form test, for fits used only for
//! their β (a depth table's incidence rounds).

mod common;

use epd_core::{EstimateOptions, FitStatus, Loss, Method, Params, estimate, fit_pose};
use rand::RngExt;

/// Noisy clouds of random poses (16–30" pipes, 1–6 % ovality, tilt ±15°, σ 0–30 mm, a
/// few far outliers) under every method, with and without a robust loss, a range gate
/// and held diameters: `fit_pose` gives `estimate`'s β to the bit, its iterations and
/// points, and the status `estimate` has before the form test (the same unless the
/// estimate lacks fit). A quarter start from the truth turned 90° about the axis (Dmax
/// and Dmin swapped, roll + 90°): the solver ends there with Dmax < Dmin and the
/// solution is turned into canonical form, whose normal equations `estimate` evaluates
/// afresh and `fit_pose` does not.
#[test]
fn the_pose_is_estimates_to_the_bit() {
    let mut rng = common::rng(5);
    for k in 0..48u64 {
        let od = rng.random_range(16.0..30.0f64);
        let ovality = rng.random_range(0.01..0.06f64);
        let truth = common::random_params(&mut rng, common::id_m(od), ovality, 15.0, 0.25);
        let sigma = [0.0, 0.01, 0.03][(k % 3) as usize];
        let pts = common::cloud(&truth, 160, 120, 6.0, sigma, (k % 4) as usize * 20, k);
        let method = Method::ALL[(k / 3 % 3) as usize];
        let mut opts = EstimateOptions::default();
        if k % 2 == 1 {
            opts = opts.with_loss(Loss::Cauchy { scale: 0.05 }).expect("loss");
        }
        if k % 5 == 2 {
            opts = opts.with_range_gate(0.5, 2.0).expect("gate");
        }
        if k % 4 == 1 {
            let turned = Params {
                d_max: truth.d_min,
                d_min: truth.d_max,
                roll: truth.roll + std::f64::consts::FRAC_PI_2,
                ..truth
            };
            opts = opts.with_start(turned).expect("start");
        } else if k % 7 == 3 {
            opts = opts
                .with_fixed_diameters(truth.d_max, truth.d_min)
                .expect("held");
        }
        let est = estimate(&pts, method, &opts).expect("estimate");
        let pose = fit_pose(&pts, method, &opts).expect("pose");
        assert_eq!(pose.params, est.params, "cloud {k} {method}");
        assert_eq!(pose.iterations, est.iterations, "cloud {k}");
        assert_eq!(pose.n_points, est.n_points, "cloud {k}");
        if !matches!(est.status, FitStatus::LackOfFit(_)) {
            assert_eq!(pose.status, est.status, "cloud {k}");
        }
    }
}

/// Clouds cut to 8–12 points (fewer than three residual degrees of freedom for the
/// smallest): `fit_pose` reports the status `estimate` does, `TooFewForUncertainty`
/// included, and the same β.
#[test]
fn tiny_clouds_have_estimates_status() {
    let mut rng = common::rng(9);
    let mut too_few = 0;
    for k in 0..40u64 {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 10.0, 0.2);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.01, 0, k);
        let stride = pts.len() / (8 + (k as usize % 5));
        let few: Vec<[f64; 3]> = pts.iter().step_by(stride).copied().collect();
        let o = EstimateOptions::default();
        let (Ok(est), Ok(pose)) = (
            estimate(&few, Method::RuEpd, &o),
            fit_pose(&few, Method::RuEpd, &o),
        ) else {
            continue;
        };
        assert_eq!(pose.params, est.params, "cloud {k}");
        if !matches!(est.status, FitStatus::LackOfFit(_)) {
            assert_eq!(pose.status, est.status, "cloud {k}");
        }
        too_few += usize::from(matches!(
            est.status,
            FitStatus::Implausible(epd_core::check::Implausible::TooFewForUncertainty { .. })
        ));
    }
    assert!(too_few > 0, "no cloud had too few degrees of freedom");
}
