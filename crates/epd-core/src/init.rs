//! The initial guess of β from the point cloud alone (no ground truth).
//!
//! An elliptic cylinder is the quadric xᵀA x + bᵀx = 1 (SCS) whose symmetric A has one
//! zero eigenvalue (along the axis) and two positive ones (the normalisation "= 1" is
//! safe: the sensor, at the origin, lies strictly inside, where the left side is < 1).
//! A linear least-squares fit of the nine coefficients is exact on noise-free points and
//! a good start on noisy ones:
//! - the pipe axis d is the eigenvector of A with the smallest |eigenvalue|, turned to
//!   look forward (d·X > 0);
//! - with A = λ₁ m mᵀ + λ₂ n nᵀ on the plane ⊥ d (λ₁ ≤ λ₂), the major axis is m, the
//!   axis passes through c = −½ A⁺ b, and the semi-axes are √(k/λ₁) ≥ √(k/λ₂) with
//!   k = 1 + cᵀA c.
//!
//! The rotation with rows (d, m, d × m) maps SCS → PCS; its Z-Y-X Euler angles are the
//! pose of eq. (3), and (δy, δz) = (−m·c, −(d × m)·c).

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

use crate::error::EpdError;
use crate::params::Params;

/// At most this many points (evenly strided) feed the quadric fit.
const MAX_FIT_POINTS: usize = 20_000;

/// Largest |λ_axis|/λ₁ of the fitted quadric still taken for a cylinder.
const MAX_AXIAL_CURVATURE: f64 = 0.3;

/// The initial guess (see the module doc). `points` are finite, non-zero SCS points.
pub fn initial_guess(points: &[[f64; 3]]) -> Result<Params, EpdError> {
    if points.len() < 9 {
        return Err(EpdError::TooFewPoints {
            usable: points.len(),
            dropped: 0,
            needed: 9,
        });
    }
    let stride = (points.len() / MAX_FIT_POINTS).max(1);
    // Scale for conditioning: RMS distance from the sensor.
    let (mut n, mut s2) = (0usize, 0.0);
    for p in points.iter().step_by(stride) {
        s2 += p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
        n += 1;
    }
    let scale = (s2 / n as f64).sqrt();
    if !(scale > 0.0 && scale.is_finite()) {
        return Err(EpdError::Degenerate(
            "all points are at the sensor origin".into(),
        ));
    }
    let mut m = SMatrix::<f64, 9, 9>::zeros();
    let mut rhs = SVector::<f64, 9>::zeros();
    for p in points.iter().step_by(stride) {
        let (x, y, z) = (p[0] / scale, p[1] / scale, p[2] / scale);
        let row = SVector::<f64, 9>::from([
            x * x,
            y * y,
            z * z,
            2.0 * x * y,
            2.0 * x * z,
            2.0 * y * z,
            x,
            y,
            z,
        ]);
        m += row * row.transpose();
        rhs += row;
    }
    let coef = m
        .cholesky()
        .map(|c| c.solve(&rhs))
        .filter(|c| c.iter().all(|v| v.is_finite()))
        .ok_or_else(|| {
            EpdError::Degenerate(
                "the points do not determine a quadric surface (identical points, a line or a plane?)"
                    .into(),
            )
        })?;
    // Reject near-singular fits, where the points lie on many quadrics (a plane, a line).
    let eig_m = m.symmetric_eigen();
    let (mmin, mmax) = (eig_m.eigenvalues.min(), eig_m.eigenvalues.max());
    if !(mmin > 1e-13 * mmax) {
        return Err(EpdError::Degenerate(
            "the points lie on a plane, a line or a few lines, not on a cylinder".into(),
        ));
    }
    // Back to metres: xᵀA x/s² + bᵀx/s = 1.
    let a = Matrix3::new(
        coef[0], coef[3], coef[4], //
        coef[3], coef[1], coef[5], //
        coef[4], coef[5], coef[2],
    ) / (scale * scale);
    let b = Vector3::new(coef[6], coef[7], coef[8]) / scale;
    let eig = a.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| {
        eig.eigenvalues[i]
            .abs()
            .total_cmp(&eig.eigenvalues[j].abs())
    });
    let (i_axis, i1, i2) = (idx[0], idx[1], idx[2]);
    let (l1, l2) = (eig.eigenvalues[i1], eig.eigenvalues[i2]);
    if !(l1 > 0.0 && l2 > 0.0) {
        return Err(EpdError::NotAPipe(
            "the points do not lie on an elliptic cylinder around the sensor".into(),
        ));
    }
    // A cylinder has one (near-)zero curvature; a sphere or an ellipsoid has none.
    let l0 = eig.eigenvalues[i_axis];
    if l0.abs() > MAX_AXIAL_CURVATURE * l1 {
        return Err(EpdError::NotAPipe(format!(
            "the points curve along every direction (quadric eigenvalues {:.3e}, {:.3e}, {:.3e} 1/m²): \
             a closed surface, not a cylinder",
            l0, l1, l2
        )));
    }
    let mut d: Vector3<f64> = eig.eigenvectors.column(i_axis).into_owned();
    if d.x < 0.0 {
        d = -d;
    }
    let major: Vector3<f64> = eig.eigenvectors.column(i1).into_owned();
    let minor_dir: Vector3<f64> = eig.eigenvectors.column(i2).into_owned();
    // Centre on the plane ⊥ d through the origin: c = −½ (b·m/λ₁ m + b·n/λ₂ n).
    let c = -0.5 * (major * (b.dot(&major) / l1) + minor_dir * (b.dot(&minor_dir) / l2));
    let k = 1.0 + l1 * c.dot(&major).powi(2) + l2 * c.dot(&minor_dir).powi(2);
    let semi_major = (k / l1).sqrt();
    let semi_minor = (k / l2).sqrt();
    let mm = (major - d * d.dot(&major)).normalize();
    let nz = d.cross(&mm);
    let r = Matrix3::from_rows(&[d.transpose(), mm.transpose(), nz.transpose()]);
    let base = Params {
        d_max: 2.0 * semi_major,
        d_min: 2.0 * semi_minor,
        roll: 0.0,
        pitch: 0.0,
        yaw: 0.0,
        dy: 0.0,
        dz: 0.0,
    };
    let guess = base.with_rotation(&r, -mm.dot(&c), -nz.dot(&c));
    if !guess.is_finite() {
        return Err(EpdError::Degenerate(
            "the initial guess is not finite".into(),
        ));
    }
    if !guess.sensor_inside() {
        return Err(EpdError::NotAPipe(
            "the sensor lies outside the fitted cylinder: the points are not the inside of a pipe seen from within"
                .into(),
        ));
    }
    Ok(guess)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::symmetry::errors_against;
    use nalgebra::Point3;

    #[test]
    fn exact_on_noise_free_points() {
        let truth = Params {
            d_max: 0.50,
            d_min: 0.47,
            roll: 2.0,
            pitch: 0.2,
            yaw: -0.25,
            dy: 0.05,
            dz: -0.04,
        };
        let pts: Vec<[f64; 3]> = (0..500)
            .map(|i| {
                let phi = i as f64 * 0.7;
                let w = Point3::new(
                    0.5 + (i % 37) as f64 * 0.1,
                    0.25 * phi.cos(),
                    0.235 * phi.sin(),
                );
                let s = truth.pcs_to_scs(&w);
                [s.x, s.y, s.z]
            })
            .collect();
        let g = initial_guess(&pts).unwrap();
        let e = errors_against(&g, &truth);
        for v in [e.d_max, e.d_min, e.roll, e.pitch, e.yaw, e.dy, e.dz] {
            assert!(v.abs() < 1e-8, "{e:?}");
        }
    }

    #[test]
    fn plane_is_degenerate() {
        let pts: Vec<[f64; 3]> = (0..100)
            .map(|i| [1.0 + (i % 10) as f64, (i / 10) as f64, 0.3])
            .collect();
        assert!(initial_guess(&pts).is_err());
    }
}
