//! The EPD fit as a problem of the `levenberg-marquardt` crate (a MINPACK port that
//! needs the full N×7 Jacobian and a QR), for the agreement test and the benchmark.
#![allow(dead_code)]

use epd_core::Params;
use epd_core::residual::{Geometry, Residual};
use levenberg_marquardt::LeastSquaresProblem;
use nalgebra_lm::{Dyn, OMatrix, OVector, U7, storage::Owned};

/// Eq. (4) with one residual kind, for the crate's solver.
pub struct CratePipe<'a> {
    pub points: &'a [[f64; 3]],
    pub kind: Residual,
    pub x: OVector<f64, U7>,
}

impl<'a> CratePipe<'a> {
    pub fn new(points: &'a [[f64; 3]], kind: Residual, start: &Params) -> Self {
        Self {
            points,
            kind,
            x: OVector::<f64, U7>::from(start.to_array()),
        }
    }
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
