//! The rig frames' poses refined jointly with the table, the table's bins eliminated
//! (variable projection).
//!
//! The alternation of [`super::calibrate_rigs`] fits each frame's pose on points corrected
//! by the current table, then rebuilds the table at the new poses. Its fixed point is not
//! the joint least-squares solution: a pose fitted against a table that already holds part
//! of that pose's error reproduces it (docs/calibration.md, "Why the two-size table is
//! off"). Here the joint cost
//!
//!   C(p, T) = Σₖ wₖ (rₖ(p_f(k)) − T_b(k))²,
//!
//! with rₖ the range residual of point k (measured − model range, [`Residual::Range`]) at
//! its frame's pose p_f and T_b its bin's offset, is minimised over all poses at once. The
//! weight is wₖ = 1/s_b² (s_b the bin's spread, the random error's σ there) for a point
//! within [`CLIP_SPREADS`]·s_b of its bin's offset, 0 beyond: the table's own clip, so
//! C is a χ² of the inliers. For fixed poses the best T_b is the weighted mean of its
//! bin's residuals, which leaves the reduced cost
//!
//!   C(p) = Σₖ wₖ rₖ² − Σ_b E_b²/N_b,   N_b = Σ_{k∈b} wₖ,   E_b = Σ_{k∈b} wₖ rₖ,
//!
//! and its Gauss–Newton normal equations (Golub & Pereyra's variable projection):
//!
//!   [blockdiag_f(Σ_{k∈f} wₖ Jₖ Jₖᵀ) − Σ_b s_b s_bᵀ/N_b] δ = −[Σₖ wₖ Jₖ rₖ − Σ_b (E_b/N_b) s_b],
//!
//! Jₖ the gradient of rₖ over its frame's five pose parameters (roll, pitch, yaw, δy, δz;
//! the diameters are the rig's known ones) and s_b the per-frame sums Σ_{k∈b∩f} wₖ Jₖ
//! stacked. The system is solved with Levenberg damping: a round rig's rotation about its
//! own axis changes no residual, a direction of zero curvature. Bins and weights are taken
//! once, at the starting poses (a point's bin moves only when its pose moves it across a
//! bin edge, millimetres against centimetre bins).

use std::collections::HashMap;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::incidence::{IncidenceTable, Support};
use super::rig::CalibrationFrame;
use super::table::{CLIP_SPREADS, DepthTable, norm, usable};
use crate::error::EpdError;
use crate::params::{N_PARAMS, Params};
use crate::residual::{Geometry, Residual};

/// Pose parameters per frame: β[2..7] = (roll, pitch, yaw, δy, δz).
const POSE: usize = 5;
/// First pose parameter in β.
const POSE_AT: usize = N_PARAMS - POSE;

/// A step is the last one when it lowers the χ² C by less than this: the step then moves
/// the poses by about √0.01 = 0.1 of their joint standard deviation (a Gauss–Newton step
/// δ lowers C by δᵀAδ, its length in standard deviations squared).
pub const JOINT_STOP_CHI2: f64 = 0.01;

/// Most Levenberg–Marquardt steps of the joint refinement. The problem is nearly linear
/// (the poses move by millimetres), so Gauss–Newton needs a few; the bound only stops a
/// run that cannot settle.
pub const JOINT_MAX_STEPS: usize = 30;

/// The first Levenberg damping, a fraction of each diagonal entry of the normal matrix:
/// small, since the poses start within millimetres of the minimum (Nielsen's τ ∈
/// [10⁻⁶, 10⁻³] for a good start).
pub const LAMBDA_START: f64 = 1e-3;

/// A table's bins as the joint refinement sees them.
pub(super) trait ObservedBins: Sync {
    /// The observed bin holding a point at model range `range_m` (m), intensity and
    /// cos θ: its index, its offset and its spread (m); `None` outside the observed bins.
    fn observed(
        &self,
        range_m: f64,
        intensity: f64,
        cos_incidence: f64,
    ) -> Option<(usize, f64, f64)>;
}

impl ObservedBins for IncidenceTable {
    fn observed(&self, r: f64, i: f64, c: f64) -> Option<(usize, f64, f64)> {
        if !(r.is_finite() && i.is_finite() && i > 0.0 && c > 0.0 && c <= 1.0) {
            return None;
        }
        let (li, lc) = (i.ln(), c.ln());
        if !(self.range.holds(r)
            && self.log_intensity.holds(li)
            && self.log_cos_incidence.holds(lc))
        {
            return None;
        }
        let k = (self.range.bin(r) * self.log_intensity.n + self.log_intensity.bin(li))
            * self.log_cos_incidence.n
            + self.log_cos_incidence.bin(lc);
        (self.support[k] == Support::Observed).then(|| (k, self.offset_m[k], self.spread_m[k]))
    }
}

impl ObservedBins for DepthTable {
    fn observed(&self, r: f64, i: f64, _c: f64) -> Option<(usize, f64, f64)> {
        if !(r.is_finite() && i.is_finite() && i > 0.0) {
            return None;
        }
        let li = i.ln();
        if !(self.range.holds(r) && self.log_intensity.holds(li)) {
            return None;
        }
        let k = self.range.bin(r) * self.log_intensity.n + self.log_intensity.bin(li);
        (self.count[k] > 0).then(|| (k, self.offset_m[k], self.spread_m[k]))
    }
}

/// One frame's points in the refinement: each one's index in the frame, its bin among
/// the frame's own bins, and its weight; and each of the frame's bins' index among all
/// frames' bins.
struct Selected {
    point: Vec<u32>,
    bin: Vec<u32>,
    weight: Vec<f64>,
    global: Vec<u32>,
}

/// A frame's sums at a pose: Σ w J Jᵀ, Σ w J r, Σ w r², and per bin it touches
/// (N, E, S₀…S₄), in the order of `global` (the bins' indices among all frames' bins).
struct FrameSums<'a> {
    h: [[f64; POSE]; POSE],
    g: [f64; POSE],
    c: f64,
    bins: Vec<[f64; 2 + POSE]>,
    global: &'a [u32],
}

/// What the refinement did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointOutcome {
    /// Levenberg–Marquardt steps taken (accepted or not).
    pub steps: usize,
    /// The reduced χ² C(p) at the starting poses and at the end.
    pub chi2: (f64, f64),
    /// Points in the refinement (inliers of observed bins, over all frames).
    pub n_points: usize,
}

/// The refinement's fixed part: the frames, each one's selected points, the frames
/// that take part and the number of bins.
struct Joint<'a> {
    frames: &'a [CalibrationFrame<'a>],
    selected: Vec<Option<Selected>>,
    active: Vec<usize>,
    n_bins: usize,
}

impl<'a> Joint<'a> {
    /// Select each frame's points at its starting pose (`None`: the frame is left out).
    fn new(
        frames: &'a [CalibrationFrame<'a>],
        poses: &[Option<Params>],
        table: &dyn ObservedBins,
        gate: (f64, f64),
    ) -> Self {
        let mut compact: HashMap<usize, u32> = HashMap::new();
        let mut selected: Vec<Option<Selected>> = Vec::with_capacity(frames.len());
        for (f, pose) in frames.iter().zip(poses.iter()) {
            let Some(pose) = pose else {
                selected.push(None);
                continue;
            };
            let picks = select(f, pose, table, gate);
            let mut s = Selected {
                point: Vec::with_capacity(picks.len()),
                bin: Vec::with_capacity(picks.len()),
                weight: Vec::with_capacity(picks.len()),
                global: Vec::new(),
            };
            let mut local: HashMap<usize, u32> = HashMap::new();
            for (k, b, w) in picks {
                let next = local.len() as u32;
                let l = *local.entry(b).or_insert_with(|| {
                    let g = compact.len() as u32;
                    s.global.push(*compact.entry(b).or_insert(g));
                    next
                });
                s.point.push(k);
                s.bin.push(l);
                s.weight.push(w);
            }
            selected.push(Some(s));
        }
        let active = (0..frames.len())
            .filter(|&f| selected[f].as_ref().is_some_and(|s| !s.point.is_empty()))
            .collect();
        Self {
            frames,
            selected,
            active,
            n_bins: compact.len(),
        }
    }

    /// The reduced χ², its Gauss–Newton normal matrix and half its gradient over the
    /// active frames' poses (module doc), or `None` when a pose leaves the model's domain
    /// or a value is not finite.
    fn system(&self, poses: &[Option<Params>]) -> Option<(f64, DMatrix<f64>, DVector<f64>)> {
        let sums: Vec<Option<FrameSums>> = self
            .active
            .par_iter()
            .with_max_len(1)
            .map(|&f| {
                frame_sums(
                    &self.frames[f],
                    self.selected[f].as_ref()?,
                    poses[f].as_ref()?,
                )
            })
            .collect();
        reduced_system(&sums.into_iter().collect::<Option<Vec<_>>>()?, self.n_bins)
    }

    /// `poses` moved by `delta` (five values per active frame, in order).
    fn step(&self, poses: &[Option<Params>], delta: &DVector<f64>) -> Vec<Option<Params>> {
        let mut out = poses.to_vec();
        for (slot, &f) in self.active.iter().enumerate() {
            if let Some(p) = out[f].as_mut() {
                let mut b = p.to_array();
                for q in 0..POSE {
                    b[POSE_AT + q] += delta[slot * POSE + q];
                }
                *p = Params::from_array(b);
            }
        }
        out
    }
}

/// Refine `poses` (one per frame; `None`: the frame is left out) jointly with `table`'s
/// bins over the frames' points whose model range lies in `gate` (module doc), by
/// Levenberg–Marquardt with Marquardt's diagonal scaling: the damping starts at
/// [`LAMBDA_START`] of each diagonal entry, falls tenfold after an accepted step and
/// rises tenfold after a rejected one. The damping shapes the path, not the minimum.
/// The diameters in each pose stay as they are (the rig's known ones).
pub(super) fn refine_poses(
    frames: &[CalibrationFrame<'_>],
    poses: &mut [Option<Params>],
    table: &dyn ObservedBins,
    gate: (f64, f64),
) -> Result<JointOutcome, EpdError> {
    let joint = Joint::new(frames, poses, table, gate);
    let n_points = joint.selected.iter().flatten().map(|s| s.point.len()).sum();
    let Some((mut chi2, mut a, mut rhs)) = joint.system(poses) else {
        return Err(EpdError::Degenerate(
            "the joint refinement of the rig's poses started outside the model".into(),
        ));
    };
    let start = chi2;
    let mut lambda = LAMBDA_START;
    let mut steps = 0;
    // No frame with points in an observed bin: nothing to refine.
    while steps < JOINT_MAX_STEPS && a.nrows() > 0 {
        steps += 1;
        let dim = a.nrows();
        let top = (0..dim).map(|i| a[(i, i)]).fold(0.0, f64::max);
        let mut damped = a.clone();
        for i in 0..dim {
            damped[(i, i)] += lambda * a[(i, i)].max(f64::EPSILON * top);
        }
        let Some(chol) = damped.cholesky() else {
            lambda *= 10.0;
            continue;
        };
        let trial = joint.step(poses, &chol.solve(&(-&rhs)));
        match joint.system(&trial) {
            Some((c, a2, r2)) if c < chi2 => {
                let gain = chi2 - c;
                poses.copy_from_slice(&trial);
                (chi2, a, rhs) = (c, a2, r2);
                lambda = (lambda * 0.1).max(f64::EPSILON);
                if gain < JOINT_STOP_CHI2 {
                    break;
                }
            }
            _ => lambda *= 10.0,
        }
    }
    Ok(JointOutcome {
        steps,
        chi2: (start, chi2),
        n_points,
    })
}

/// A frame's points in the refinement at `pose`: (index, table bin, weight) of each usable
/// point (finite, non-zero, a finite positive intensity) whose model range lies in `gate`,
/// in an observed bin, within [`CLIP_SPREADS`] spreads of the bin's offset.
fn select(
    f: &CalibrationFrame<'_>,
    pose: &Params,
    table: &dyn ObservedBins,
    gate: (f64, f64),
) -> Vec<(u32, usize, f64)> {
    let Some(geom) = Geometry::new(pose) else {
        return Vec::new();
    };
    f.points
        .par_iter()
        .zip(f.intensity.par_iter())
        .enumerate()
        .filter_map(|(k, (p, &i))| {
            if !(usable(p) && i.is_finite() && i > 0.0) {
                return None;
            }
            let r = norm(p);
            let model = geom.line_parameter(p) * r;
            if !(model.is_finite() && (gate.0..=gate.1).contains(&model)) {
                return None;
            }
            let c = geom.cos_incidence(p)?;
            let (b, offset, spread) = table.observed(model, i, c)?;
            let inlier = spread > 0.0 && (r - model - offset).abs() <= CLIP_SPREADS * spread;
            inlier.then(|| (k as u32, b, 1.0 / (spread * spread)))
        })
        .collect()
}

/// The sums of one frame at `pose` (`None` when the pose leaves the model's domain).
fn frame_sums<'a>(
    f: &CalibrationFrame<'_>,
    s: &'a Selected,
    pose: &Params,
) -> Option<FrameSums<'a>> {
    let geom = Geometry::new(pose)?;
    let mut out = FrameSums {
        h: [[0.0; POSE]; POSE],
        g: [0.0; POSE],
        c: 0.0,
        bins: vec![[0.0; 2 + POSE]; s.global.len()],
        global: &s.global,
    };
    for ((&k, &b), &w) in s.point.iter().zip(&s.bin).zip(&s.weight) {
        let (r, grad) = geom.residual_and_gradient(Residual::Range, &f.points[k as usize]);
        let j: [f64; POSE] = std::array::from_fn(|q| grad[POSE_AT + q]);
        for a in 0..POSE {
            out.g[a] += w * j[a] * r;
            for c in a..POSE {
                out.h[a][c] += w * j[a] * j[c];
            }
        }
        out.c += w * r * r;
        let acc = &mut out.bins[b as usize];
        acc[0] += w;
        acc[1] += w * r;
        for q in 0..POSE {
            acc[2 + q] += w * j[q];
        }
    }
    for a in 0..POSE {
        for c in 0..a {
            out.h[a][c] = out.h[c][a];
        }
    }
    Some(out)
}

/// The reduced χ², normal matrix and gradient of the module doc from the frames' sums
/// (frame `slot` owns rows `slot·5 .. slot·5 + 5`); `None` when a value is not finite.
fn reduced_system(sums: &[FrameSums], n_bins: usize) -> Option<(f64, DMatrix<f64>, DVector<f64>)> {
    let dim = sums.len() * POSE;
    let mut a = DMatrix::<f64>::zeros(dim, dim);
    let mut rhs = DVector::<f64>::zeros(dim);
    let mut chi2 = 0.0;
    let mut per_bin: Vec<Vec<(usize, [f64; 2 + POSE])>> = vec![Vec::new(); n_bins];
    for (slot, s) in sums.iter().enumerate() {
        chi2 += s.c;
        for p in 0..POSE {
            rhs[slot * POSE + p] = s.g[p];
            for q in 0..POSE {
                a[(slot * POSE + p, slot * POSE + q)] = s.h[p][q];
            }
        }
        for (&b, acc) in s.global.iter().zip(&s.bins) {
            per_bin[b as usize].push((slot, *acc));
        }
    }
    for members in &per_bin {
        let n: f64 = members.iter().map(|m| m.1[0]).sum();
        if !(n > 0.0) {
            continue;
        }
        let e: f64 = members.iter().map(|m| m.1[1]).sum();
        chi2 -= e * e / n;
        for (f1, s1) in members {
            for p in 0..POSE {
                rhs[f1 * POSE + p] -= e / n * s1[2 + p];
            }
            for (f2, s2) in members {
                for p in 0..POSE {
                    for q in 0..POSE {
                        a[(f1 * POSE + p, f2 * POSE + q)] -= s1[2 + p] * s2[2 + q] / n;
                    }
                }
            }
        }
    }
    (chi2.is_finite() && a.iter().all(|v| v.is_finite())).then_some((chi2, a, rhs))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::{IncidenceBins, offsets_with_incidence};

    /// A rig frame cast analytically at `pose`: wall points along a cone of rays around
    /// the sensor's X axis, read long by `error(k, range)` along each ray, with a
    /// Lambertian intensity 500·cos θ/r².
    fn frame(pose: &Params, error: impl Fn(usize, f64) -> f64) -> Cast {
        let geom = Geometry::new(pose).expect("pose inside the pipe");
        let (mut pts, mut int) = (vec![], vec![]);
        for a in 0..90 {
            for b in 0..40 {
                let phi = std::f64::consts::TAU * a as f64 / 90.0;
                let tilt = 0.2 + 1.2 * b as f64 / 40.0;
                let u = [1.0, tilt * phi.cos(), tilt * phi.sin()];
                let wall = u.map(|v| v * geom.line_parameter(&u));
                let r = norm(&wall);
                let Some(c) = geom.cos_incidence(&wall) else {
                    continue;
                };
                let k = pts.len();
                pts.push(wall.map(|v| v * (r + error(k, r)) / r));
                int.push(500.0 * c / (r * r));
            }
        }
        (pts, int)
    }

    fn pose(dy: f64, dz: f64, pitch: f64, yaw: f64) -> Params {
        Params {
            d_max: 0.49,
            d_min: 0.48,
            roll: 0.1,
            pitch,
            yaw,
            dy,
            dz,
        }
    }

    /// A frame's points and intensities.
    type Cast = (Vec<[f64; 3]>, Vec<f64>);

    /// A bounded, zero-mean stand-in for the random range error (m).
    fn wobble(k: usize) -> f64 {
        0.002 * ((k as f64) * 1.7).sin()
    }

    fn rig(
        truth: &[Params],
        error: impl Fn(usize, f64) -> f64 + Copy,
    ) -> (Vec<Cast>, IncidenceTable) {
        let data: Vec<_> = truth.iter().map(|p| frame(p, error)).collect();
        let gate = (0.1, 3.0);
        let obs: Vec<_> = data
            .iter()
            .zip(truth)
            .flat_map(|((p, i), t)| offsets_with_incidence(p, i, t, gate).unwrap())
            .collect();
        let bins = IncidenceBins::spanning(&obs, (12, 6, 6), gate, 10).unwrap();
        (data, IncidenceTable::build(&obs, &bins).unwrap())
    }

    /// Three rig frames' poses in the sensor's working range.
    fn three_poses() -> [Params; 3] {
        [
            pose(0.03, -0.02, 0.02, -0.03),
            pose(-0.05, 0.01, -0.04, 0.01),
            pose(0.0, 0.06, 0.01, 0.05),
        ]
    }

    fn calibration_frames(data: &[Cast]) -> Vec<CalibrationFrame<'_>> {
        data.iter()
            .map(|(p, i)| CalibrationFrame {
                points: p,
                intensity: i,
            })
            .collect()
    }

    #[test]
    fn the_normal_equations_are_the_reduced_chi2s_derivatives() {
        let truth = three_poses();
        let (data, table) = rig(&truth, |k, r| 0.02 + 0.01 * r * r + wobble(k));
        let frames = calibration_frames(&data);
        // Away from the minimum, where the gradient is not small.
        let start: Vec<Option<Params>> = truth
            .iter()
            .map(|p| {
                Some(Params {
                    dy: p.dy + 0.004,
                    yaw: p.yaw - 0.01,
                    ..*p
                })
            })
            .collect();
        let joint = Joint::new(&frames, &start, &table, (0.1, 3.0));
        let (chi2, a, rhs) = joint.system(&start).unwrap();
        let chi2_at = |delta: &DVector<f64>| joint.system(&joint.step(&start, delta)).unwrap().0;
        let h = 1e-5;
        for i in 0..rhs.len() {
            let mut e = DVector::zeros(rhs.len());
            e[i] = h;
            let (up, down) = (chi2_at(&e), chi2_at(&-&e));
            // Central differences: truncation h²/6·χ²''' and rounding ε·χ²/h, both far
            // below 10⁻⁴ of a gradient entry here.
            let fd = (up - down) / (2.0 * h);
            let tol = 1e-4 * fd.abs().max(1.0) + 1e3 * f64::EPSILON * chi2 / h;
            assert!(
                (fd - 2.0 * rhs[i]).abs() <= tol,
                "entry {i}: finite difference {fd}, normal equations {}",
                2.0 * rhs[i]
            );
            // The Gauss–Newton matrix is half the curvature up to the residuals' own
            // second derivatives: positive on the diagonal and within a factor of the
            // finite-difference curvature.
            let curv = (up - 2.0 * chi2 + down) / (h * h);
            assert!(
                a[(i, i)] > 0.0 && (0.5..2.0).contains(&(curv / (2.0 * a[(i, i)]))),
                "entry {i}: curvature {curv}, Gauss–Newton {}",
                2.0 * a[(i, i)]
            );
        }
    }

    #[test]
    fn frames_left_out_leave_nothing_to_refine() {
        let truth = three_poses();
        let (data, table) = rig(&truth, |k, _| 0.02 + wobble(k));
        let frames = calibration_frames(&data);
        let mut poses = vec![None; frames.len()];
        let out = refine_poses(&frames, &mut poses, &table, (0.1, 3.0)).unwrap();
        assert_eq!((out.steps, out.n_points), (0, 0));
        assert!(poses.iter().all(Option::is_none));
    }

    #[test]
    fn a_pose_moved_off_its_frame_comes_back() {
        let truth = three_poses();
        let (data, table) = rig(&truth, |k, _| 0.02 + wobble(k));
        let frames = calibration_frames(&data);
        let mut poses: Vec<Option<Params>> = truth.iter().copied().map(Some).collect();
        let moved = poses[1].as_mut().unwrap();
        moved.dz += 0.005;
        moved.pitch += 0.01;
        let out = refine_poses(&frames, &mut poses, &table, (0.1, 3.0)).unwrap();
        assert!(out.chi2.1 < out.chi2.0, "{out:?}");
        // The poses' standard deviations at the end: A⁻¹ of the χ² in the table's own
        // σ units (module doc); the frame must come back within 5 of them.
        let joint = Joint::new(&frames, &poses, &table, (0.1, 3.0));
        let (_, a, _) = joint.system(&poses).unwrap();
        let cov = a.clone().try_inverse().unwrap();
        let p = poses[1].unwrap();
        for (i, err) in [(3, p.pitch - truth[1].pitch), (6, p.dz - truth[1].dz)] {
            let sd = cov[(POSE + i - POSE_AT, POSE + i - POSE_AT)].sqrt();
            assert!(
                err.abs() <= 5.0 * sd,
                "β[{i}] off by {err} (sd {sd}) after {out:?}"
            );
        }
    }
}
