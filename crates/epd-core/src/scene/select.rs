//! Which points belong to which part of a frame: the axial coordinate at which each
//! point's ray meets a fitted wall, and the selections the survey refits on (the points
//! before a departure, the near points, the points beyond the straight section).

use crate::params::Params;
use crate::points::{Mask, Points};
use crate::residual::Geometry;

/// The PCS axial coordinate at which a point's ray meets the wall of `beta`: the
/// crossing t·x̂ of eq. (21), which depends on the ray only, so that a cut on it does not
/// select points by their range noise (at a grazing wall the noise moves a point mostly
/// along the axis). `None` when β leaves the model.
pub(crate) fn model_axial(beta: &Params) -> Option<impl Fn(&[f64; 3]) -> f64> {
    let geom = Geometry::new(beta)?;
    let row = beta.rotation().matrix().row(0).into_owned();
    Some(move |p: &[f64; 3]| {
        geom.line_parameter(p) * (row[0] * p[0] + row[1] * p[1] + row[2] * p[2])
    })
}

/// The even sample of at most `max` of the points [`axial_mask`] keeps (every
/// ⌈n/max⌉-th of their n, from the first; [`crate::points::Points::sample`]): the points a
/// reader that strides them to `max` (the bend fit, [`crate::bend::BEND_POINTS`]) would
/// read, without their copy. Empty when β leaves the model.
pub(crate) fn axial_sample(
    points: &[[f64; 3]],
    beta: &Params,
    keep: impl Fn(f64) -> bool,
    max: usize,
) -> Vec<[f64; 3]> {
    let mask = axial_mask(points, beta, keep);
    Points::masked(points, &mask)
        .map(|p| p.sample(max).into_owned())
        .unwrap_or_default()
}

/// The mask of the points (SCS) whose ray meets the wall of `beta` at a PCS axial
/// coordinate that satisfies `keep` ([`model_axial`]): a selection read in place, one bit
/// a point (issue 27: a refit's selection is most of a frame, and its copy held 24 B a
/// point beside the input). Keeps none when β leaves the model.
pub(crate) fn axial_mask(points: &[[f64; 3]], beta: &Params, keep: impl Fn(f64) -> bool) -> Mask {
    match model_axial(beta) {
        Some(axial) => Mask::new(points, |p| keep(axial(p))),
        None => Mask::new(points, |_| false),
    }
}

/// Bins of [`quantile_of`]'s counting pass.
const QUANTILE_BINS: usize = 4096;

/// The q-quantile of `value(p)` over `points`, as [`crate::check::quantile`] gives it of
/// their collected values (nearest rank, total order) — the same value — without holding
/// them: the least and greatest value, a count of the values in [`QUANTILE_BINS`] equal
/// bins between them (a monotone map, so the bins keep the values' order), then the
/// values of the one bin that holds the rank, of which the rank's is selected. Three
/// passes; memory the bins and that bin's values (all of them only if every value falls in
/// one bin). NaN when there are no points or a value is not finite (the points are clean
/// and their coordinates finite).
pub(crate) fn quantile_of(points: &[[f64; 3]], value: impl Fn(&[f64; 3]) -> f64, q: f64) -> f64 {
    let n = points.len();
    if n == 0 {
        return f64::NAN;
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in points {
        let v = value(p);
        if !v.is_finite() {
            return f64::NAN;
        }
        (lo, hi) = (lo.min(v), hi.max(v));
    }
    let k = ((q * (n - 1) as f64).round() as usize).min(n - 1);
    if lo == hi {
        return lo;
    }
    let bins = QUANTILE_BINS as f64;
    let bin = |v: f64| (((v - lo) / (hi - lo) * bins) as usize).min(QUANTILE_BINS - 1);
    let mut counts = vec![0usize; QUANTILE_BINS];
    for p in points {
        counts[bin(value(p))] += 1;
    }
    let (mut b, mut before) = (0, 0);
    while before + counts[b] <= k {
        before += counts[b];
        b += 1;
    }
    let mut inside: Vec<f64> = points.iter().map(&value).filter(|&v| bin(v) == b).collect();
    crate::check::quantile_rank(&mut inside, k - before)
}

/// Which points (SCS) lie outside a ring of range error ([`crate::segment::Ring`]) that
/// the straight estimate leaves out: those whose ray meets the wall of `beta` before
/// `ring.from_m − margin` or from `ring.to_m + margin` on (the margin the survey's refit
/// left on each side, a slice). All `false` when β leaves the model.
pub fn outside_ring_mask(
    points: &[[f64; 3]],
    beta: &Params,
    ring: &crate::segment::Ring,
    margin: f64,
) -> Vec<bool> {
    match model_axial(beta) {
        Some(axial) => points
            .iter()
            .map(|p| {
                let x = axial(p);
                x < ring.from_m - margin || x >= ring.to_m + margin
            })
            .collect(),
        None => vec![false; points.len()],
    }
}

/// Which points (SCS) belong to the straight section that ends at `end` (PCS x of the
/// straight fit `beta`, m): those whose ray meets the fitted wall before `end − margin`
/// (the ray's model crossing, not the noisy point). All `false` when β leaves the model.
pub fn straight_mask(points: &[[f64; 3]], beta: &Params, end: f64, margin: f64) -> Vec<bool> {
    match model_axial(beta) {
        Some(axial) => points.iter().map(|p| axial(p) < end - margin).collect(),
        None => vec![false; points.len()],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_counted_quantile_is_the_collected_one() {
        // A small LCG: values spread, clustered (most in one bin), with ties, all equal.
        let mut state = 12345u64;
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let spread: Vec<f64> = (0..5000).map(|_| 6.0 * next() - 0.5).collect();
        let clustered: Vec<f64> = (0..5000)
            .map(|i| {
                if i % 100 == 0 {
                    1e3 * next()
                } else {
                    1.0 + 1e-9 * next()
                }
            })
            .collect();
        let ties: Vec<f64> = (0..999).map(|i| (i % 7) as f64).collect();
        let equal = vec![2.5; 10];
        let one = vec![-3.0];
        for xs in [spread, clustered, ties, equal, one] {
            let pts: Vec<[f64; 3]> = xs.iter().map(|&x| [x, 0.0, 1.0]).collect();
            for q in [0.0, 0.1, 0.5, 0.6, 0.85, 0.999, 1.0] {
                let mut v = xs.clone();
                let want = crate::check::quantile(&mut v, q);
                assert_eq!(
                    quantile_of(&pts, |p| p[0], q).to_bits(),
                    want.to_bits(),
                    "q {q}"
                );
            }
        }
        assert!(quantile_of(&[], |p| p[0], 0.5).is_nan());
    }
}
