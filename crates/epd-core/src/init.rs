//! The initial guess of β from the point cloud alone (no ground truth).
//!
//! 1. The pipe axis direction d (SCS): the principal axis of the cloud's covariance —
//!    a ToF frame of a pipe is a tube segment far longer than wide — turned to look
//!    forward (d·X > 0).
//! 2. The cross-section: the points projected on the plane ⊥ d and fitted by the conic
//!    a y² + b yz + c z² + d y + e z = 1 (linear least squares; the normalisation is
//!    safe because the sensor, at the origin of that plane, lies inside the pipe).
//!    Its centre, semi-axes and orientation give (δy, δz), (Dmax, Dmin) and the roll.
//! 3. The axis is refined once: the cross-section fit is repeated on the plane ⊥ the
//!    line through the centres of the cloud's near and far halves.
//!
//! The rotation with rows (d, major axis, d × major axis) maps SCS → PCS; its Z-Y-X Euler
//! angles are the pose of eq. (3).

use nalgebra::{Matrix2, Matrix3, Matrix5, Vector2, Vector3, Vector5};

use crate::error::EpdError;
use crate::params::Params;

/// A fitted cross-section ellipse in a plane ⊥ the axis.
struct Section {
    /// Centre in SCS.
    centre: Vector3<f64>,
    /// Unit major-axis direction in SCS.
    major: Vector3<f64>,
    /// Semi-axes a ≥ b (m).
    a: f64,
    b: f64,
}

/// Two unit vectors completing `d` to an orthonormal basis.
fn plane_basis(d: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if d.z.abs() < 0.9 {
        Vector3::z()
    } else {
        Vector3::y()
    };
    let e1 = helper.cross(d).normalize();
    let e2 = d.cross(&e1);
    (e1, e2)
}

/// Fit the ellipse of the points projected on the plane ⊥ `d` (step 2).
fn fit_section(points: &[[f64; 3]], d: &Vector3<f64>, stride: usize) -> Result<Section, EpdError> {
    let (e1, e2) = plane_basis(d);
    // Scale for conditioning: RMS distance from the axis through the origin.
    let mut n = 0usize;
    let mut s2 = 0.0;
    for p in points.iter().step_by(stride) {
        let p = Vector3::from(*p);
        let (y, z) = (e1.dot(&p), e2.dot(&p));
        s2 += y * y + z * z;
        n += 1;
    }
    let scale = (s2 / n.max(1) as f64).sqrt();
    if !(scale > 0.0 && scale.is_finite()) {
        return Err(EpdError::Degenerate(
            "the points lie on a line through the sensor".into(),
        ));
    }
    let mut m = Matrix5::<f64>::zeros();
    let mut rhs = Vector5::<f64>::zeros();
    for p in points.iter().step_by(stride) {
        let p = Vector3::from(*p);
        let y = e1.dot(&p) / scale;
        let z = e2.dot(&p) / scale;
        let row = Vector5::new(y * y, y * z, z * z, y, z);
        m += row * row.transpose();
        rhs += row;
    }
    let coef = m
        .cholesky()
        .map(|c| c.solve(&rhs))
        .filter(|c| c.iter().all(|v| v.is_finite()))
        .ok_or_else(|| {
            EpdError::Degenerate(
                "the cross-section of the points is not a curve (a plane or a line?)".into(),
            )
        })?;
    let (a, b, c, dd, e) = (coef[0], coef[1], coef[2], coef[3], coef[4]);
    let q = Matrix2::new(a, 0.5 * b, 0.5 * b, c);
    let centre = q
        .try_inverse()
        .map(|qi| -0.5 * qi * Vector2::new(dd, e))
        .ok_or_else(|| {
            EpdError::Degenerate("the cross-section has no centre (not an ellipse)".into())
        })?;
    // Constant on the right once centred: q(x') = 1 − (d yc + e zc)/2.
    let k = 1.0 + 0.5 * (dd * centre.x + e * centre.y);
    let eig = q.symmetric_eigen();
    let (i_small, i_large) = if eig.eigenvalues[0] <= eig.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let (l_small, l_large) = (eig.eigenvalues[i_small], eig.eigenvalues[i_large]);
    if !(l_small > 0.0 && k > 0.0) {
        return Err(EpdError::NotAPipe(
            "the cross-section of the points is not an ellipse around the sensor".into(),
        ));
    }
    let semi_major = (k / l_small).sqrt() * scale;
    let semi_minor = (k / l_large).sqrt() * scale;
    let v = eig.eigenvectors.column(i_small);
    let major = (e1 * v[0] + e2 * v[1]).normalize();
    Ok(Section {
        centre: (e1 * centre.x + e2 * centre.y) * scale,
        major,
        a: semi_major,
        b: semi_minor,
    })
}

/// The initial guess (see the module doc). `points` are finite, non-zero SCS points.
pub fn initial_guess(points: &[[f64; 3]]) -> Result<Params, EpdError> {
    let n = points.len();
    // Work on at most ~20 000 points: plenty for a starting point.
    let stride = (n / 20_000).max(1);
    let mut mean = Vector3::zeros();
    let mut count = 0usize;
    for p in points.iter().step_by(stride) {
        mean += Vector3::from(*p);
        count += 1;
    }
    mean /= count as f64;
    let mut cov = Matrix3::zeros();
    for p in points.iter().step_by(stride) {
        let dv = Vector3::from(*p) - mean;
        cov += dv * dv.transpose();
    }
    cov /= count as f64;
    let eig = cov.symmetric_eigen();
    let imax = eig.eigenvalues.imax();
    let lmax = eig.eigenvalues[imax];
    if !(lmax > 0.0) {
        return Err(EpdError::Degenerate("all points coincide".into()));
    }
    let mut d: Vector3<f64> = eig.eigenvectors.column(imax).into_owned();
    if d.x < 0.0 {
        d = -d;
    }
    // Spread across the axis, relative to along: a line has none.
    let lmin = eig.eigenvalues.min();
    if lmin <= 1e-12 * lmax {
        return Err(EpdError::Degenerate(
            "the points lie on a plane or a line, not on a cylinder".into(),
        ));
    }
    let mut section = fit_section(points, &d, stride)?;
    // Step 3: refine the axis through the centres of the near and far halves.
    let proj: Vec<f64> = points
        .iter()
        .step_by(stride)
        .map(|p| d.dot(&Vector3::from(*p)))
        .collect();
    let mut sorted = proj.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let halves: Vec<Vec<[f64; 3]>> = [true, false]
        .iter()
        .map(|&near| {
            points
                .iter()
                .step_by(stride)
                .zip(&proj)
                .filter(|(_, t)| (**t < median) == near)
                .map(|(p, _)| *p)
                .collect()
        })
        .collect();
    if halves.iter().all(|h| h.len() >= 20) {
        let near = fit_section(&halves[0], &d, 1);
        let far = fit_section(&halves[1], &d, 1);
        if let (Ok(near), Ok(far)) = (near, far) {
            let tn = halves[0]
                .iter()
                .map(|p| d.dot(&Vector3::from(*p)))
                .sum::<f64>()
                / halves[0].len() as f64;
            let tf = halves[1]
                .iter()
                .map(|p| d.dot(&Vector3::from(*p)))
                .sum::<f64>()
                / halves[1].len() as f64;
            let axis = (far.centre + d * tf) - (near.centre + d * tn);
            if axis.norm() > 0.0 && axis.normalize().dot(&d) > 0.9 {
                let d2 = axis.normalize();
                if let Ok(s2) = fit_section(points, &d2, stride) {
                    d = d2;
                    section = s2;
                }
            }
        }
    }
    // Rotation SCS → PCS with rows (axis, major, axis × major).
    let m = (section.major - d * d.dot(&section.major)).normalize();
    let nz = d.cross(&m);
    let r = Matrix3::from_rows(&[d.transpose(), m.transpose(), nz.transpose()]);
    let base = Params {
        d_max: 2.0 * section.a,
        d_min: 2.0 * section.b,
        roll: 0.0,
        pitch: 0.0,
        yaw: 0.0,
        dy: 0.0,
        dz: 0.0,
    };
    let guess = base.with_rotation(&r, -m.dot(&section.centre), -nz.dot(&section.centre));
    if !guess.is_finite() {
        return Err(EpdError::Degenerate(
            "the initial guess is not finite".into(),
        ));
    }
    if !guess.sensor_inside() {
        return Err(EpdError::NotAPipe(
            "the sensor lies outside the fitted cross-section: the points are not the inside of a pipe seen from within".into(),
        ));
    }
    Ok(guess)
}
