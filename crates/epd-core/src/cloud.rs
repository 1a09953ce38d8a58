//! Cleaning of measured points before a fit.

use std::borrow::Cow;

/// Measured points (SCS, m) with the unusable ones removed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CleanCloud<'a> {
    /// Finite points away from the origin (the input itself when all are usable).
    pub points: Cow<'a, [[f64; 3]]>,
    /// How many input points were dropped.
    pub dropped: usize,
}

fn usable(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0)
}

/// Keep the points that are finite and not at the sensor origin (a ToF camera writes
/// zeros or NaN for invalid pixels); count the others. Borrows the input when every
/// point is usable, so a clean frame is not copied.
pub fn clean(points: &[[f64; 3]]) -> CleanCloud<'_> {
    if points.iter().all(usable) {
        return CleanCloud {
            points: Cow::Borrowed(points),
            dropped: 0,
        };
    }
    let kept: Vec<[f64; 3]> = points.iter().copied().filter(usable).collect();
    CleanCloud {
        dropped: points.len() - kept.len(),
        points: Cow::Owned(kept),
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
}
