//! The initial guess of β from the point cloud alone (no ground truth).
//!
//! An elliptic cylinder is the quadric xᵀA x + bᵀx = 1 (SCS) whose symmetric A has one
//! zero eigenvalue (along the axis) and two positive ones (the normalisation "= 1" is
//! safe: the sensor, at the origin, lies strictly inside, where the left side is < 1).
//! The guess is made in three steps, each exact on noise-free points:
//!
//! 1. **Trimmed quadric fit.** Up to 8192 evenly strided points are binned by
//!    direction (32 × 32 bins over the view) and each bin is represented by its point
//!    of median range: an outlier moves a point along its own ray, so a bin's median
//!    is a wall point unless most of the bin is outliers. A linear least-squares fit
//!    of the nine coefficients to the representatives follows, then concentration
//!    steps: the points'
//!    approximate distances to the fitted surface, (q(x) − 1)/‖∇q(x)‖, are computed, the
//!    closest half (then those within 3 robust standard deviations) are kept, and the
//!    quadric is fitted again. Far outliers (stray points anywhere in the view) and
//!    range outliers (multipath) weigh heavily in an algebraic fit and are trimmed
//!    this way; a clean cloud needs no second fit.
//! 2. **The axis.** The eigenvector d of A with the smallest |eigenvalue| whose two
//!    other eigenvalues are positive, turned to look forward (d·X > 0). Noise and tilt
//!    may leave the fitted quadric slightly curved along d (an ellipsoid or a
//!    hyperboloid instead of a cylinder); the axis is then the direction of least
//!    curvature, and the cross-section fit decides. Only a surface that curves the
//!    same way, about equally, in every direction (a sphere) is refused.
//! 3. **The cross-section.** The kept points are projected on the plane ⊥ d and a
//!    conic a u² + 2b uv + c v² + d u + e v = 1 is fitted to them (a 2-D ellipse, the
//!    origin inside): its centre gives the offsets (δy, δz), its eigen-decomposition
//!    the major axis and both diameters.
//!
//! The rotation with rows (d, m, d × m), m the major axis, maps SCS → PCS; its Z-Y-X
//! Euler angles are the pose of eq. (3). A noisy guess that puts the sensor just
//! outside the ellipse is pulled inside (the solver refines it); one that puts it far
//! outside means the points are not a pipe seen from within.

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2, Vector3};

use crate::error::EpdError;
use crate::lm::{LmOptions, minimize};
use crate::params::Params;
use crate::problem::PipeFit;
use crate::residual::{Geometry, Residual};

/// At most this many points (evenly strided) are binned by direction: [`BINS`]² = 1024
/// bins then hold 8 points each on average, so a bin's median stands on enough points to
/// outvote a stray return, and the guess costs O(8192) whatever the frame. A start, not
/// the answer: the solver refines it on every point.
pub(crate) const MAX_SAMPLE: usize = 8192;

/// Bins per side of the direction grid: 32 × 32 representatives (about 1000) over-
/// determine the nine coefficients of the quadric a hundredfold, and each bin spans 1/32
/// of the view, about 2° of a 69° field of view, fine enough that the wall's range
/// changes little across a bin.
const BINS: usize = 32;

/// Smallest |λ_axis|/λ₁ of the fitted quadric refused as a closed surface (a sphere):
/// a cylinder has λ_axis = 0, and noise or tilt leave it a small fraction of λ₁; a surface
/// curved along the axis by more than 0.7 of its least cross-section curvature curves
/// about equally every way, and no pipe seen from inside does. A bound on a start, not a
/// statistic: the solver and the checks decide the answer.
const MAX_AXIAL_CURVATURE: f64 = 0.7;

/// Concentration steps of the trimmed fit: each refits the quadric to the points kept by
/// the last; a concentration step never raises the trimmed cost (Rousseeuw & Van Driessen
/// 1999, Technometrics 41:212), and a clean cloud stops after the first (see
/// [`CLEAN_SIGMAS`]); four bound the work of a start.
const TRIM_STEPS: usize = 4;

/// A kept point lies within this many robust standard deviations of the surface: for
/// normal noise 99.7 % of the wall's points do, so trimming drops 0.3 % of a clean wall
/// and every point further off (stray returns, multipath).
const TRIM_SIGMAS: f64 = 3.0;

/// A cloud is clean — nothing to trim — when no point lies beyond this many robust
/// standard deviations of the surface: for normal noise P(|z| > 5) = 5.7·10⁻⁷, so a
/// clean frame of 10⁵ points passes with probability 0.94, and a frame with one gross
/// outlier is trimmed.
const CLEAN_SIGMAS: f64 = 5.0;

/// Smallest cosine between a point's direction and the axis guess for the point to be
/// projected on the cross-section plane (cos 80° = 0.17): at more grazing angles the
/// projection 1/cos grows past 5.8 and one point's noise moves it across the grid.
const MIN_PROJECTION_COS: f64 = 0.17;

/// Where noise put the sensor just outside the guessed ellipse, it is pulled back to this
/// fraction of the way to the wall (in units of the normalised radius): inside, with a
/// margin of a tenth of the radius for the solver's first steps.
const PULL_INSIDE: f64 = 0.9;

/// The sensor may lie this far outside the guessed ellipse (in units of its normalised
/// radius) and still be pulled inside; beyond, the points are not a pipe around it.
const MAX_OUTSIDE: f64 = 1.5;

/// A direction bin's median range stands for the bin only with at least this many
/// points: three is the fewest whose median outvotes one stray return (one outlier of
/// two would be a coin toss); bins with fewer are left out.
const MIN_BIN_POINTS: usize = 3;

/// The fewest representatives that replace the points: 64, seven times the quadric's
/// nine coefficients, so that the trimmed fit (which may drop a few per step) stays
/// over-determined; fewer filled bins mean the directions do not spread over the grid
/// (a narrow view), and every point is used instead.
const MIN_REPRESENTATIVES: usize = 64;

/// The farthest 1/[`FAR_SHARE_DIVISOR`] of the points (their count rounded up) give a
/// candidate axis of [`multi_start`], their mean direction: a quarter. Seen from inside a
/// pipe the far points crowd toward the vanishing point of the axis, and a quarter of a
/// frame (thousands of points) averages the wall's sides out while staying far along it.
const FAR_SHARE_DIVISOR: usize = 4;

/// Iterations of each candidate's short solver run in [`multi_start`]: 30, against the
/// default 100 of a fit. The runs only rank the candidates by their median residual; the
/// full fit then refines the best from where its run stopped.
const CANDIDATE_ITERATIONS: usize = 30;

/// The quadric fit's normal matrix is near-singular — the points lie on many quadrics
/// (a plane, a line) — when its eigenvalues span more than 10¹³: its entries are
/// products of up to four coordinates scaled to O(1), summed in f64 (ε = 2.2·10⁻¹⁶), so
/// a ratio of 10⁻¹³ is a few hundred roundings, where the least eigenvalue no longer
/// measures anything.
const QUADRIC_CONDITION: f64 = 1e-13;

/// The fewest usable points an estimate takes: the initial guess fits a quadric of nine
/// coefficients to the points (step 1 of the module doc), which needs at least nine;
/// the fit itself needs seven, one per parameter.
pub const MIN_ESTIMATE_POINTS: usize = 9;

/// The initial guess (see the module doc). `points` are finite, non-zero SCS points.
pub fn initial_guess(points: &[[f64; 3]]) -> Result<Params, EpdError> {
    if points.len() < MIN_ESTIMATE_POINTS {
        return Err(EpdError::TooFewPoints {
            usable: points.len(),
            dropped: 0,
            needed: MIN_ESTIMATE_POINTS,
        });
    }
    let stride = points.len().div_ceil(MAX_SAMPLE).max(1);
    let strided: Vec<[f64; 3]> = points.iter().step_by(stride).copied().collect();
    let sample = bin_medians(&strided);
    // Scale for conditioning: RMS distance from the sensor.
    let s2: f64 = sample
        .iter()
        .map(|p| p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        .sum();
    let scale = (s2 / sample.len() as f64).sqrt();
    if !(scale > 0.0 && scale.is_finite()) {
        return Err(EpdError::Degenerate(
            "all points are at the sensor origin".into(),
        ));
    }
    let scaled: Vec<Vector3<f64>> = sample
        .iter()
        .map(|p| Vector3::new(p[0], p[1], p[2]) / scale)
        .collect();
    let (a, kept) = trimmed_quadric(&scaled)?;
    let (axis, cylinder_like) = cylinder_axis(&a)?;
    // Back to metres for the cross-section.
    let kept_m: Vec<Vector3<f64>> = kept.iter().map(|&i| scaled[i] * scale).collect();
    if cylinder_like && let Ok(g) = section_guess(&kept_m, &axis) {
        return Ok(g);
    }
    multi_start(&kept_m, &a)
}

/// The fallback when the quadric is no cylinder (a saddle fitted to a noisy pipe seen
/// at a steep tilt, when the far end of the pipe leaves the view): candidate axes (the
/// quadric's three eigenvectors, the mean direction of the farthest quarter of the
/// points, the sensor's X axis), a cross-section guess on each, a short solver run
/// with the RU-EPD residual on the kept points from each, and the candidate whose
/// range residuals have the smallest median magnitude.
fn multi_start(pts: &[Vector3<f64>], a: &Matrix3<f64>) -> Result<Params, EpdError> {
    let eig = a.symmetric_eigen();
    let mut axes: Vec<Vector3<f64>> = (0..3)
        .map(|i| eig.eigenvectors.column(i).into_owned())
        .collect();
    let mut by_range: Vec<&Vector3<f64>> = pts.iter().collect();
    by_range.sort_by(|p, q| p.norm_squared().total_cmp(&q.norm_squared()));
    let first_far = by_range.len() - by_range.len().div_ceil(FAR_SHARE_DIVISOR);
    let far: Vector3<f64> = by_range[first_far..].iter().map(|p| p.normalize()).sum();
    axes.push(far);
    axes.push(Vector3::x());
    let raw: Vec<[f64; 3]> = pts.iter().map(|p| [p.x, p.y, p.z]).collect();
    let lm = LmOptions::default()
        .with_max_iterations(CANDIDATE_ITERATIONS)
        .unwrap_or_default();
    let mut best: Option<(f64, Params)> = None;
    let mut last_err = None;
    for axis in axes {
        let Some(mut axis) = axis.try_normalize(1e-12) else {
            continue;
        };
        if axis.x < 0.0 {
            axis = -axis;
        }
        let guess = match section_guess(pts, &axis) {
            Ok(g) => g,
            Err(e) => {
                last_err = Some(e);
                continue;
            }
        };
        let fit = PipeFit::new(&raw, Residual::ErrorBased);
        let rep = minimize(&fit, SVector::from(guess.to_array()), &lm);
        let refined = Params::from_array(rep.x.into());
        let Some(geom) = Geometry::new(&refined) else {
            continue;
        };
        let mut r: Vec<f64> = raw
            .iter()
            .map(|p| geom.residual(Residual::Range, p).abs())
            .collect();
        let mid = r.len() / 2;
        let (_, med, _) = r.select_nth_unstable_by(mid, |x, y| x.total_cmp(y));
        let score = *med;
        if score.is_finite() && best.as_ref().is_none_or(|(s, _)| score < *s) {
            best = Some((score, refined));
        }
    }
    best.map(|(_, p)| p).ok_or_else(|| {
        last_err.unwrap_or_else(|| {
            EpdError::NotAPipe(
                "the points do not lie on an elliptic cylinder around the sensor".into(),
            )
        })
    })
}

/// One representative per direction bin: the point of median range among the points
/// whose directions (gnomonic coordinates about their mean direction) fall in the bin.
/// A ToF outlier moves a point along its own ray, so the median range of a bin is a
/// wall point unless most of the bin is outliers. Falls back to all points when the
/// directions do not spread over enough bins.
fn bin_medians(points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let unit = |p: &[f64; 3]| {
        let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        Vector3::new(p[0] / n, p[1] / n, p[2] / n)
    };
    let mean: Vector3<f64> = points.iter().map(unit).sum();
    let Some(m) = mean.try_normalize(1e-12) else {
        return points.to_vec();
    };
    let helper = if m.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = (helper - m * m.dot(&helper)).normalize();
    let e2 = m.cross(&e1);
    // Gnomonic coordinates of the points in front (within 80° of the mean direction).
    let coords: Vec<Option<(f64, f64)>> = points
        .iter()
        .map(|p| {
            let u = unit(p);
            let c = u.dot(&m);
            (c > MIN_PROJECTION_COS).then(|| (u.dot(&e1) / c, u.dot(&e2) / c))
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for &(a, b) in coords.iter().flatten() {
        lo = [lo[0].min(a), lo[1].min(b)];
        hi = [hi[0].max(a), hi[1].max(b)];
    }
    if !(hi[0] > lo[0] && hi[1] > lo[1]) {
        return points.to_vec();
    }
    let cell =
        |v: f64, k: usize| (((v - lo[k]) / (hi[k] - lo[k]) * BINS as f64) as usize).min(BINS - 1);
    let mut bins: Vec<Vec<(f64, usize)>> = vec![Vec::new(); BINS * BINS];
    for (i, (p, c)) in points.iter().zip(&coords).enumerate() {
        if let Some((a, b)) = c {
            let r2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
            bins[cell(*a, 0) * BINS + cell(*b, 1)].push((r2, i));
        }
    }
    let reps: Vec<[f64; 3]> = bins
        .iter_mut()
        .filter(|b| b.len() >= MIN_BIN_POINTS)
        .map(|b| {
            let mid = b.len() / 2;
            let (_, med, _) = b.select_nth_unstable_by(mid, |x, y| x.0.total_cmp(&y.0));
            points[med.1]
        })
        .collect();
    if reps.len() < MIN_REPRESENTATIVES {
        return points.to_vec();
    }
    reps
}

/// The quadric xᵀA x + bᵀx = 1 fitted to `pts` with concentration steps (module doc,
/// step 1). Returns A and the indices of the points kept.
fn trimmed_quadric(pts: &[Vector3<f64>]) -> Result<(Matrix3<f64>, Vec<usize>), EpdError> {
    let mut kept: Vec<usize> = (0..pts.len()).collect();
    let mut fit = fit_quadric(pts, &kept)?;
    let mut dist = vec![0.0; pts.len()];
    for step in 0..TRIM_STEPS {
        let (a, b) = fit;
        for (d, p) in dist.iter_mut().zip(pts) {
            let q = p.dot(&(a * p)) + b.dot(p) - 1.0;
            let g = (2.0 * a * p + b).norm();
            *d = if g > 0.0 {
                (q / g).abs()
            } else {
                f64::INFINITY
            };
        }
        let mut sorted: Vec<f64> = kept.iter().map(|&i| dist[i]).collect();
        // `kept` is never empty: fit_quadric refuses fewer than 9 points.
        let sigma = crate::loss::mad_sigma(&mut sorted);
        let limit = TRIM_SIGMAS * sigma;
        let max = dist.iter().fold(0.0f64, |m, &d| m.max(d));
        // A clean cloud: every point within the limit, nothing to trim.
        if step == 0 && max <= limit * CLEAN_SIGMAS / TRIM_SIGMAS {
            break;
        }
        let next: Vec<usize> = if step == 0 {
            // The first fit is pulled by the outliers: keep the closer half.
            let mut idx: Vec<usize> = (0..pts.len()).collect();
            let half = idx.len() / 2;
            idx.select_nth_unstable_by(half, |&i, &j| dist[i].total_cmp(&dist[j]));
            idx.truncate(half.max(9));
            idx.sort_unstable();
            idx
        } else {
            (0..pts.len()).filter(|&i| dist[i] <= limit).collect()
        };
        if next.len() < 9 || next == kept {
            break;
        }
        kept = next;
        fit = fit_quadric(pts, &kept)?;
    }
    Ok((fit.0, kept))
}

/// Linear least squares for xᵀA x + bᵀx = 1 over the points `idx` of `pts`.
fn fit_quadric(
    pts: &[Vector3<f64>],
    idx: &[usize],
) -> Result<(Matrix3<f64>, Vector3<f64>), EpdError> {
    let mut m = SMatrix::<f64, 9, 9>::zeros();
    let mut rhs = SVector::<f64, 9>::zeros();
    for &i in idx {
        let (x, y, z) = (pts[i].x, pts[i].y, pts[i].z);
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
        m.syger(1.0, &row, &row, 1.0);
        rhs += row;
    }
    m.fill_upper_triangle_with_lower_triangle();
    // Reject near-singular fits, where the points lie on many quadrics (a plane, a line).
    let eig_m = m.symmetric_eigen();
    let (mmin, mmax) = (eig_m.eigenvalues.min(), eig_m.eigenvalues.max());
    if !(mmin > QUADRIC_CONDITION * mmax) {
        return Err(EpdError::Degenerate(
            "the points lie on a plane, a line or a few lines, not on a cylinder".into(),
        ));
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
    let a = Matrix3::new(
        coef[0], coef[3], coef[4], //
        coef[3], coef[1], coef[5], //
        coef[4], coef[5], coef[2],
    );
    Ok((a, Vector3::new(coef[6], coef[7], coef[8])))
}

/// The pipe axis of a fitted quadric (module doc, step 2), looking forward, and whether
/// the quadric is (nearly) an elliptic cylinder.
fn cylinder_axis(a: &Matrix3<f64>) -> Result<(Vector3<f64>, bool), EpdError> {
    let eig = a.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| {
        eig.eigenvalues[i]
            .abs()
            .total_cmp(&eig.eigenvalues[j].abs())
    });
    let l = |i: usize| eig.eigenvalues[i];
    // The least curved direction whose two others curve the same way (an elliptic
    // cylinder, or nearly one).
    let cylinder_like = idx.iter().copied().find(|&i| {
        let others: Vec<f64> = idx.iter().filter(|&&j| j != i).map(|&j| l(j)).collect();
        others.iter().all(|&o| o > 0.0)
            && l(i).abs()
                <= MAX_AXIAL_CURVATURE * others.iter().copied().fold(f64::INFINITY, f64::min)
    });
    let axis = match cylinder_like {
        Some(i) => i,
        // Curved about equally in every direction: a closed surface.
        None if idx.iter().all(|&i| l(i) > 0.0) => {
            return Err(EpdError::NotAPipe(format!(
                "the points curve along every direction (quadric eigenvalues {:.3e}, {:.3e}, {:.3e}): \
                 a closed surface, not a cylinder",
                l(idx[0]),
                l(idx[1]),
                l(idx[2])
            )));
        }
        // A saddle fitted to a noisy, tilted pipe: its least curved direction is still
        // the best axis; the cross-section fit decides whether it is a pipe.
        None => idx[0],
    };
    let like = cylinder_like.is_some();
    let mut d: Vector3<f64> = eig.eigenvectors.column(axis).into_owned();
    if d.x < 0.0 {
        d = -d;
    }
    Ok((d.normalize(), like))
}

/// The guess from the cross-section of `pts` (SCS, m) ⊥ `axis` (module doc, step 3).
fn section_guess(pts: &[Vector3<f64>], axis: &Vector3<f64>) -> Result<Params, EpdError> {
    // An orthonormal basis (e1, e2) of the plane ⊥ axis.
    let helper = if axis.y.abs() < 0.9 {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let e1 = (helper - axis * axis.dot(&helper)).normalize();
    let e2 = axis.cross(&e1);
    let scale = (pts.iter().map(|p| p.norm_squared()).sum::<f64>() / pts.len() as f64).sqrt();
    // Conic a u² + 2b uv + c v² + d u + e v = 1 by least squares (scaled coordinates).
    let mut m = SMatrix::<f64, 5, 5>::zeros();
    let mut rhs = SVector::<f64, 5>::zeros();
    for p in pts {
        let (u, v) = (p.dot(&e1) / scale, p.dot(&e2) / scale);
        let row = SVector::<f64, 5>::from([u * u, 2.0 * u * v, v * v, u, v]);
        m.syger(1.0, &row, &row, 1.0);
        rhs += row;
    }
    m.fill_upper_triangle_with_lower_triangle();
    let not_a_pipe = || {
        EpdError::NotAPipe("the points do not lie on an elliptic cylinder around the sensor".into())
    };
    let c = m
        .cholesky()
        .map(|ch| ch.solve(&rhs))
        .filter(|c| c.iter().all(|v| v.is_finite()))
        .ok_or_else(|| {
            EpdError::Degenerate("the points do not determine the pipe's cross-section".into())
        })?;
    let q = Matrix2::new(c[0], c[1], c[1], c[2]) / (scale * scale);
    let lin = Vector2::new(c[3], c[4]) / scale;
    let (m1, centre, semi_major, semi_minor) = match ellipse(&q, &lin) {
        Some(e) => e,
        // Not an ellipse (a rough axis smears the section): a circle through the points,
        // u² + v² + d u + e v = f (Kåsa), which always exists; the solver finds the rest.
        None => circle(pts, &e1, &e2).ok_or_else(not_a_pipe)?,
    };
    let major = (e1 * m1.x + e2 * m1.y).normalize();
    let minor = axis.cross(&major);
    let c3 = e1 * centre.x + e2 * centre.y;
    let r = Matrix3::from_rows(&[axis.transpose(), major.transpose(), minor.transpose()]);
    let base = Params {
        d_max: 2.0 * semi_major,
        d_min: 2.0 * semi_minor,
        roll: 0.0,
        pitch: 0.0,
        yaw: 0.0,
        dy: 0.0,
        dz: 0.0,
    };
    let mut guess = base.with_rotation(&r, -major.dot(&c3), -minor.dot(&c3));
    if !guess.is_finite() {
        return Err(EpdError::Degenerate(
            "the initial guess is not finite".into(),
        ));
    }
    let outside = ((guess.dy / semi_major).powi(2) + (guess.dz / semi_minor).powi(2)).sqrt();
    if outside >= 1.0 {
        if outside > MAX_OUTSIDE {
            return Err(EpdError::NotAPipe(
                "the sensor lies outside the fitted cylinder: the points are not the inside of a pipe seen from within"
                    .into(),
            ));
        }
        // Noise put the sensor just outside: start from inside; the solver refines.
        guess.dy *= PULL_INSIDE / outside;
        guess.dz *= PULL_INSIDE / outside;
    }
    Ok(guess)
}

/// Major-axis direction, centre and semi-axes of the conic wᵀQw + linᵀw = 1, when it
/// is an ellipse around the origin.
fn ellipse(q: &Matrix2<f64>, lin: &Vector2<f64>) -> Option<(Vector2<f64>, Vector2<f64>, f64, f64)> {
    let eig = q.symmetric_eigen();
    let (i1, i2) = if eig.eigenvalues[0] <= eig.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let (l1, l2) = (eig.eigenvalues[i1], eig.eigenvalues[i2]);
    if !(l1 > 0.0 && l2 > 0.0) {
        return None;
    }
    let m1: Vector2<f64> = eig.eigenvectors.column(i1).into_owned();
    let m2: Vector2<f64> = eig.eigenvectors.column(i2).into_owned();
    // Centre c = −½ Q⁻¹ lin; the ellipse (w − c)ᵀQ(w − c) = k with k = 1 + cᵀQc.
    let centre = -0.5 * (m1 * (lin.dot(&m1) / l1) + m2 * (lin.dot(&m2) / l2));
    let k = 1.0 + l1 * centre.dot(&m1).powi(2) + l2 * centre.dot(&m2).powi(2);
    let (a, b) = ((k / l1).sqrt(), (k / l2).sqrt());
    (a.is_finite() && b.is_finite()).then_some((m1, centre, a, b))
}

/// The least-squares circle (Kåsa) through the points projected on (e1, e2): major
/// direction e1, centre, radius twice.
fn circle(
    pts: &[Vector3<f64>],
    e1: &Vector3<f64>,
    e2: &Vector3<f64>,
) -> Option<(Vector2<f64>, Vector2<f64>, f64, f64)> {
    // u² + v² = d u + e v + f, linear in (d, e, f).
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut rhs = Vector3::zeros();
    for p in pts {
        let (u, v) = (p.dot(e1), p.dot(e2));
        let row = Vector3::new(u, v, 1.0);
        m += row * row.transpose();
        rhs += row * (u * u + v * v);
    }
    let c = m.cholesky()?.solve(&rhs);
    let centre = Vector2::new(0.5 * c[0], 0.5 * c[1]);
    let r = (c[2] + centre.norm_squared()).sqrt();
    (r.is_finite() && r > 0.0).then_some((Vector2::x(), centre, r, r))
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
