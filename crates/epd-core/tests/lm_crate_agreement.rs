//! Our solver agrees with the `levenberg-marquardt` crate (a MINPACK port, QR on the full
//! N×7 Jacobian) on the EPD problem: same minimum from the same start.

mod common;

use epd_core::lm::{LmOptions, minimize};
use epd_core::problem::PipeFit;
use epd_core::residual::{Geometry, Residual};
use epd_core::{Params, init::initial_guess};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra_lm::{Dyn, OMatrix, OVector, U7, storage::Owned};

struct CratePipe<'a> {
    points: &'a [[f64; 3]],
    kind: Residual,
    x: OVector<f64, U7>,
}

impl LeastSquaresProblem<f64, Dyn, U7> for CratePipe<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, U7>;
    type ParameterStorage = Owned<f64, U7>;

    fn set_params(&mut self, x: &OVector<f64, U7>) {
        self.x = *x;
    }
    fn params(&self) -> OVector<f64, U7> {
        self.x
    }
    fn residuals(&self) -> Option<OVector<f64, Dyn>> {
        let g = Geometry::new(&Params::from_array(self.x.as_slice().try_into().ok()?))?;
        Some(OVector::<f64, Dyn>::from_iterator(
            self.points.len(),
            self.points.iter().map(|p| g.residual(self.kind, p)),
        ))
    }
    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U7>> {
        let g = Geometry::new(&Params::from_array(self.x.as_slice().try_into().ok()?))?;
        let mut j = OMatrix::<f64, Dyn, U7>::zeros(self.points.len());
        for (i, p) in self.points.iter().enumerate() {
            let (_, row) = g.residual_and_gradient(self.kind, p);
            for k in 0..7 {
                j[(i, k)] = row[k];
            }
        }
        Some(j)
    }
}

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
            let problem = CratePipe {
                points: &pts,
                kind,
                x: OVector::<f64, U7>::from(x0.to_array()),
            };
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
