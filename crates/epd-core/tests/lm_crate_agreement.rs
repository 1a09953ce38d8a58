//! Our solver agrees with the `levenberg-marquardt` crate (a MINPACK port, QR on the full
//! N×7 Jacobian) on the EPD problem: same minimum from the same start.

mod common;
#[path = "common/crate_lm.rs"]
mod crate_lm;

use crate_lm::CratePipe;

use epd_core::init::initial_guess;
use epd_core::lm::{LmOptions, minimize};
use epd_core::problem::PipeFit;
use epd_core::residual::Residual;
use levenberg_marquardt::LevenbergMarquardt;

#[test]
fn same_minimum_as_the_minpack_port() {
    let mut rng = common::rng(31);
    for k in 0..6 {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 5.0, 0.2);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.03, 3000, 70 + k);
        let x0 = initial_guess(&pts).unwrap();
        for kind in [Residual::Canonical, Residual::ErrorBased, Residual::Range] {
            let ours = minimize(
                &PipeFit::new(&pts, kind),
                nalgebra::SVector::from(x0.to_array()),
                &LmOptions::default(),
            );
            let problem = CratePipe::new(&pts, kind, &x0);
            let (solved, report) = LevenbergMarquardt::new().minimize(problem);
            assert!(
                report.termination.was_successful(),
                "{kind:?}: {:?}",
                report.termination
            );
            let theirs = solved.x;
            // Cost: the crate reports ½‖r‖².
            let their_cost = 2.0 * report.objective_function;
            let rel = (ours.equations.cost - their_cost).abs() / their_cost;
            assert!(
                rel < 1e-9,
                "{kind:?}: cost {} vs {}",
                ours.equations.cost,
                their_cost
            );
            for i in 0..7 {
                assert!(
                    (ours.x[i] - theirs[i]).abs() < 1e-6,
                    "{kind:?} param {i}: {} vs {}",
                    ours.x[i],
                    theirs[i]
                );
            }
        }
    }
}
