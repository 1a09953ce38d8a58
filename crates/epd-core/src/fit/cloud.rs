//! Cleaning of measured points before a fit.

use std::borrow::Cow;

use rayon::prelude::*;

use crate::error::EpdError;

/// Measured points (SCS, m) with the unusable ones removed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CleanCloud<'a> {
    /// Finite points away from the origin (the input itself when all are usable).
    pub points: Cow<'a, [[f64; 3]]>,
    /// How many input points were dropped.
    pub dropped: usize,
}

/// The farthest a measured point may lie from the sensor (m): 1 km. A continuous-wave
/// ToF camera measures within its unambiguous range c/(2f), 15 m at the lowest modulation
/// frequency in use (10 MHz); pulsed ones reach tens of metres. A point 70× beyond that
/// is not a return: a damaged file or a unit error (1e30 m, 1e300 m). Such points made
/// the fit fail with "no step lowers the cost" or "points lie on a plane"; they are now
/// refused by name ([`check_ranges`]).
pub const MAX_POINT_RANGE_M: f64 = 1000.0;

/// An error naming the points farther than [`MAX_POINT_RANGE_M`] from the sensor (how
/// many, the first one's index and distance); non-finite points are not looked at (they
/// are dropped as invalid pixels).
pub fn check_ranges(points: &[[f64; 3]]) -> Result<(), EpdError> {
    let count = points.par_iter().filter(|p| far(p)).count();
    if count == 0 {
        return Ok(());
    }
    let index = points.iter().position(far).unwrap_or(0);
    let p = points[index];
    // The norm without overflow: scaled by the largest coordinate.
    let m = p.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let range_m = m * ((p[0] / m).powi(2) + (p[1] / m).powi(2) + (p[2] / m).powi(2)).sqrt();
    Err(EpdError::FarPoints {
        count,
        index,
        range_m,
        limit_m: MAX_POINT_RANGE_M,
    })
}

/// Whether a finite point lies farther than [`MAX_POINT_RANGE_M`] from the sensor (what
/// [`check_ranges`] refuses).
pub fn far(p: &[f64; 3]) -> bool {
    let r2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
    // r² overflows to +inf beyond 1.3e154 m: still far.
    p.iter().all(|v| v.is_finite()) && r2 > MAX_POINT_RANGE_M * MAX_POINT_RANGE_M
}

/// Whether a point is finite and not at the sensor origin (what [`clean`] keeps).
pub fn usable(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0)
}

/// Keep the points that are finite and not at the sensor origin (a ToF camera writes
/// zeros or NaN for invalid pixels); count the others. Borrows the input when every
/// point is usable, so a clean frame is not copied.
pub fn clean(points: &[[f64; 3]]) -> CleanCloud<'_> {
    if points.par_iter().all(usable) {
        return CleanCloud {
            points: Cow::Borrowed(points),
            dropped: 0,
        };
    }
    let mut kept: Vec<[f64; 3]> = Vec::with_capacity(points.len());
    kept.extend(points.iter().copied().filter(usable));
    CleanCloud {
        dropped: points.len() - kept.len(),
        points: Cow::Owned(kept),
    }
}

/// Measured points with their per-point range noise σᵢ, the unusable pairs removed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CleanWeighted {
    /// Finite points away from the origin whose σᵢ is usable.
    pub points: Vec<[f64; 3]>,
    /// σᵢ of each kept point (m): finite and > 0, aligned with `points`.
    pub sigma: Vec<f64>,
    /// How many input pairs were dropped (unusable point or σᵢ).
    pub dropped: usize,
}

/// Keep the pairs (x̂ᵢ, σᵢ) whose point is usable (as in [`clean`]) and whose σᵢ is
/// finite and > 0, in their order; count the others. Pairs by index: `points` and
/// `sigma` should have the same length (the pairs beyond the shorter are dropped and
/// counted).
pub fn clean_weighted(points: &[[f64; 3]], sigma: &[f64]) -> CleanWeighted {
    let (kept_points, kept_sigma): (Vec<[f64; 3]>, Vec<f64>) = points
        .par_iter()
        .zip(sigma)
        .filter(|(p, s)| usable(p) && s.is_finite() && **s > 0.0)
        .map(|(p, s)| (*p, *s))
        .unzip();
    CleanWeighted {
        dropped: points.len().max(sigma.len()) - kept_points.len(),
        points: kept_points,
        sigma: kept_sigma,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drops_and_counts() {
        let pts = [
            [1.0, 0.0, 0.0],
            [f64::NAN, 0.0, 1.0],
            [0.0, 0.0, 0.0],
            [f64::INFINITY, 1.0, 1.0],
            [0.5, 0.2, -0.1],
        ];
        let c = clean(&pts);
        assert_eq!(c.points.len(), 2);
        assert_eq!(c.dropped, 3);
        let good = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];
        assert!(matches!(clean(&good).points, Cow::Borrowed(_)));
    }

    #[test]
    fn drops_pairs_together() {
        let pts = [
            [1.0, 0.0, 0.0],
            [f64::NAN, 0.0, 1.0],
            [0.0, 0.5, 0.0],
            [0.0, 0.0, 0.7],
            [0.5, 0.2, -0.1],
            [0.0, 0.0, 0.0],
        ];
        let sigma = [0.01, 0.02, f64::NAN, 0.0, 0.05, 0.03];
        let c = clean_weighted(&pts, &sigma);
        assert_eq!(c.points, vec![[1.0, 0.0, 0.0], [0.5, 0.2, -0.1]]);
        assert_eq!(c.sigma, vec![0.01, 0.05]);
        assert_eq!(c.dropped, 4);
    }
}
