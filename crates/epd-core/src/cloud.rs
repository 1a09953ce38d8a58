//! Cleaning of measured points before a fit.

/// Measured points (SCS, m) with the unusable ones removed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CleanCloud {
    /// Finite points away from the origin.
    pub points: Vec<[f64; 3]>,
    /// How many input points were dropped.
    pub dropped: usize,
}

/// Keep the points that are finite and not at the sensor origin (a ToF camera writes
/// zeros or NaN for invalid pixels); count the others.
pub fn clean<P: Copy + Into<[f64; 3]>>(points: &[P]) -> CleanCloud {
    let mut out = Vec::with_capacity(points.len());
    for &p in points {
        let p: [f64; 3] = p.into();
        if p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0) {
            out.push(p);
        }
    }
    CleanCloud {
        dropped: points.len() - out.len(),
        points: out,
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
    }
}
