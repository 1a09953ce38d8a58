//! The pipe: nominal size, wall and ovality (README, Conventions).

use crate::error::SimError;

/// Metres per inch.
pub const INCH: f64 = 0.0254;

/// A pipe of nominal outer diameter and wall thickness, with an elliptical inner
/// cross-section: ID = OD − 2·thickness, Dmax = ID·(1 + ovality/2),
/// Dmin = ID·(1 − ovality/2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pipe {
    /// Nominal outer diameter (inches).
    pub nominal_od_in: f64,
    /// Wall thickness (m).
    pub wall_thickness: f64,
    /// Ovality (Dmax − Dmin)/ID, in [0, 1).
    pub ovality: f64,
}

impl Pipe {
    /// A 20" pipe with a 12 mm wall and 2 % ovality (the paper's set-up, §4.1).
    pub fn paper_20in() -> Self {
        Self {
            nominal_od_in: 20.0,
            wall_thickness: 0.012,
            ovality: 0.02,
        }
    }

    /// Check every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SimError> {
        if !(self.nominal_od_in > 0.0 && self.nominal_od_in.is_finite()) {
            return Err(SimError::invalid(
                "pipe.nominal_od_in",
                self.nominal_od_in,
                "must be a finite number > 0",
            ));
        }
        if !(self.wall_thickness >= 0.0 && self.wall_thickness < self.outer_diameter() / 2.0) {
            return Err(SimError::invalid(
                "pipe.wall_thickness_mm",
                self.wall_thickness * 1e3,
                "must be ≥ 0 and less than half the outer diameter",
            ));
        }
        if !(0.0..1.0).contains(&self.ovality) {
            return Err(SimError::invalid(
                "pipe.ovality",
                self.ovality,
                "must lie in [0, 1)",
            ));
        }
        Ok(())
    }

    /// Outer diameter OD (m).
    pub fn outer_diameter(&self) -> f64 {
        self.nominal_od_in * INCH
    }

    /// Inner diameter ID = OD − 2·thickness (m).
    pub fn inner_diameter(&self) -> f64 {
        self.outer_diameter() - 2.0 * self.wall_thickness
    }

    /// Major inner diameter Dmax = ID·(1 + ovality/2) (m).
    pub fn d_max(&self) -> f64 {
        self.inner_diameter() * (1.0 + self.ovality / 2.0)
    }

    /// Minor inner diameter Dmin = ID·(1 − ovality/2) (m).
    pub fn d_min(&self) -> f64 {
        self.inner_diameter() * (1.0 - self.ovality / 2.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diameters() {
        let p = Pipe::paper_20in();
        assert!((p.inner_diameter() - 0.484).abs() < 1e-12);
        assert!((p.d_max() - 0.48884).abs() < 1e-12);
        assert!((p.d_min() - 0.47916).abs() < 1e-12);
        assert!(((p.d_max() - p.d_min()) / p.inner_diameter() - 0.02).abs() < 1e-12);
    }

    #[test]
    fn validation_names_the_field() {
        let mut p = Pipe::paper_20in();
        p.ovality = 1.0;
        assert!(
            p.validate()
                .unwrap_err()
                .to_string()
                .contains("pipe.ovality")
        );
        let mut p = Pipe::paper_20in();
        p.wall_thickness = 0.254;
        assert!(
            p.validate()
                .unwrap_err()
                .to_string()
                .contains("pipe.wall_thickness_mm")
        );
        let mut p = Pipe::paper_20in();
        p.nominal_od_in = f64::NAN;
        assert!(
            p.validate()
                .unwrap_err()
                .to_string()
                .contains("pipe.nominal_od_in")
        );
    }
}
