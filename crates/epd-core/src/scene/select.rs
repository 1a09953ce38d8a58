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
