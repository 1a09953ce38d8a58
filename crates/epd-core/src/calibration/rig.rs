//! A calibration rig: frames in a pipe of known diameter, each frame's pose fitted with the
//! diameters held ([`calibrate`]), and the observations of the error along each sensing
//! line ([`offsets`]) from which the [`DepthTable`] is built.

use rayon::prelude::*;

use super::incidence::{IncidenceBins, IncidenceObservation, IncidenceTable};
use super::joint::{JointOutcome, ObservedBins, refine_poses};
use super::table::{DepthTable, TableBins, norm, usable};
use crate::error::EpdError;
use crate::estimate::{Estimate, EstimateOptions, Method, estimate};
use crate::params::Params;
use crate::residual::Geometry;

/// One observation of the systematic range error: a point of a calibration frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Range where the point's sensing line meets the known wall (m).
    pub model_range_m: f64,
    /// The point's intensity (camera units).
    pub intensity: f64,
    /// Measured range − model range (m): positive when the camera reads long.
    pub offset_m: f64,
}

/// The observations of one calibration frame: every finite, non-zero point with a finite
/// positive intensity whose model range at `beta` (the frame's fit with the diameters
/// held at the known values) lies in `gate` (m).
pub fn offsets(
    points: &[[f64; 3]],
    intensity: &[f64],
    beta: &Params,
    gate: (f64, f64),
) -> Result<Vec<Observation>, EpdError> {
    observe(points, intensity, beta, gate, |_, _, obs| Some(obs))
}

/// The observations of one calibration frame with the incidence at each wall point
/// ([`Geometry::cos_incidence`] at `beta`): as [`offsets`], leaving out the points whose
/// ray meets the wall along the model axis.
pub fn offsets_with_incidence(
    points: &[[f64; 3]],
    intensity: &[f64],
    beta: &Params,
    gate: (f64, f64),
) -> Result<Vec<IncidenceObservation>, EpdError> {
    observe(points, intensity, beta, gate, |geom, p, obs| {
        let c = geom.cos_incidence(p)?;
        (c > 0.0).then_some(IncidenceObservation {
            obs,
            cos_incidence: c,
        })
    })
}

/// The usable points of a frame (finite, non-zero, a finite positive intensity, a model
/// range at `beta` within `gate`) as [`Observation`]s, each passed to `keep` with the
/// wall's geometry and its point.
fn observe<T>(
    points: &[[f64; 3]],
    intensity: &[f64],
    beta: &Params,
    gate: (f64, f64),
    keep: impl Fn(&Geometry, &[f64; 3], Observation) -> Option<T>,
) -> Result<Vec<T>, EpdError> {
    if points.len() != intensity.len() {
        return Err(EpdError::InvalidOption(format!(
            "{} points but {} intensities: one intensity per point is needed",
            points.len(),
            intensity.len()
        )));
    }
    let geom = Geometry::new(beta).ok_or_else(|| {
        EpdError::InvalidOption("the fitted β puts the sensor outside the pipe".into())
    })?;
    Ok(points
        .iter()
        .zip(intensity)
        .filter(|(p, i)| usable(p) && i.is_finite() && **i > 0.0)
        .filter_map(|(p, &i)| {
            let r = norm(p);
            let model = geom.line_parameter(p) * r;
            let obs = Observation {
                model_range_m: model,
                intensity: i,
                offset_m: r - model,
            };
            ((gate.0..=gate.1).contains(&model) && model.is_finite())
                .then(|| keep(&geom, p, obs))
                .flatten()
        })
        .collect())
}

/// The cos θ of each measured point's ray at the wall of `beta` (NaN where none).
pub fn incidences(points: &[[f64; 3]], beta: &Params) -> Vec<f64> {
    let Some(geom) = Geometry::new(beta) else {
        return vec![f64::NAN; points.len()];
    };
    points
        .par_iter()
        .map(|p| {
            if usable(p) {
                geom.cos_incidence(p).unwrap_or(f64::NAN)
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// One calibration frame: measured points (SCS, m; invalid pixels as zeros) and their
/// intensities.
#[derive(Clone, Copy, Debug)]
pub struct CalibrationFrame<'a> {
    /// Measured points.
    pub points: &'a [[f64; 3]],
    /// One intensity per point.
    pub intensity: &'a [f64],
}

/// The frames of one rig: a pipe of known diameters.
#[derive(Clone, Copy, Debug)]
pub struct RigFrames<'a> {
    /// The known (Dmax, Dmin) of the rig's pipe (m).
    pub known: (f64, f64),
    /// Its frames.
    pub frames: &'a [CalibrationFrame<'a>],
}

/// How a table is made from calibration frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationSettings {
    /// The known (Dmax, Dmin) of the calibration pipe (m) ([`calibrate`]; each rig's own
    /// for [`calibrate_rigs`]).
    pub known: (f64, f64),
    /// Range gate on the model range (m): the points used.
    pub gate: (f64, f64),
    /// Range × intensity bins.
    pub bins: (usize, usize),
    /// Bins of the ln cos θ axis of the [`IncidenceTable`]; 0: no incidence table (the
    /// range × intensity table alone, as before it).
    pub incidence_bins: usize,
    /// Least observations of a filled bin.
    pub min_count: usize,
    /// Passes of the alternating refinement (≥ 1; see [`calibrate`]).
    pub passes: usize,
}

/// A depth table with the frames' fitted poses.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The range × intensity table.
    pub table: DepthTable,
    /// The range × intensity × incidence table, when asked for.
    pub incidence: Option<IncidenceTable>,
    /// Per frame (the rigs' frames in order): its fit with the diameters held, or why
    /// it failed (the frame is then left out).
    pub fits: Vec<Result<Estimate, EpdError>>,
    /// Observations behind the table.
    pub n_observations: usize,
    /// The spans the observations covered: model range (m), intensity, cos θ, each
    /// (min, max).
    pub spans: [(f64, f64); 3],
    /// What the joint refinement of the poses did.
    pub joint: JointOutcome,
}

/// The (min, max) of the observations' model range, intensity and cos θ.
fn spans_of(obs: &[IncidenceObservation]) -> [(f64, f64); 3] {
    let fold = |f: &dyn Fn(&IncidenceObservation) -> f64| {
        obs.iter()
            .map(f)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            })
    };
    [
        fold(&|o| o.obs.model_range_m),
        fold(&|o| o.obs.intensity),
        fold(&|o| o.cos_incidence),
    ]
}

/// The depth table of frames recorded in a pipe of known diameter: [`calibrate_rigs`]
/// with one rig of diameters `settings.known`.
pub fn calibrate(
    frames: &[CalibrationFrame<'_>],
    settings: &CalibrationSettings,
    options: &EstimateOptions,
) -> Result<Calibration, EpdError> {
    calibrate_rigs(
        &[RigFrames {
            known: settings.known,
            frames,
        }],
        settings,
        options,
    )
}

/// The depth table of frames recorded in pipes of known diameters (one or more rigs).
///
/// The systematic error and the pose are found together: a frame's pose, fitted with
/// the diameters held, absorbs the part of the error that looks like a pose change (a
/// range error larger on one side shifts δy, δz), and the table built on that pose
/// inherits the pose's error. So the fit alternates, like the joint least squares of
/// one table and one pose per frame: pass 1 fits each frame's pose on its measured
/// points and builds the table from their offsets (measured − model range); each
/// further pass fits the poses again on the points corrected by the current table (the
/// incidence table where there is one, its incidences from the frame's previous pose)
/// and rebuilds the table from the raw points' offsets to the new poses. The table's
/// bins span the observations of the first pass (range clipped to the gate). Frames
/// whose fit does not converge are left out; fails when none is left.
pub fn calibrate_rigs(
    rigs: &[RigFrames<'_>],
    settings: &CalibrationSettings,
    options: &EstimateOptions,
) -> Result<Calibration, EpdError> {
    let (lo, hi) = settings.gate;
    let mut jobs: Vec<(CalibrationFrame<'_>, EstimateOptions)> = Vec::new();
    for rig in rigs {
        let (d_max, d_min) = rig.known;
        let o = options
            .with_fixed_diameters(d_max, d_min)?
            .with_range_gate(lo, hi)?;
        jobs.extend(rig.frames.iter().map(|f| (*f, o)));
    }
    let mut table: Option<DepthTable> = None;
    let mut inc_table: Option<IncidenceTable> = None;
    let mut bins: Option<TableBins> = None;
    let mut inc_bins: Option<IncidenceBins> = None;
    let mut poses: Vec<Option<Params>> = vec![None; jobs.len()];
    let mut last = None;
    for _ in 0..settings.passes.max(1) {
        type PerFrame = Result<(Estimate, Vec<IncidenceObservation>), EpdError>;
        let per_frame: Vec<PerFrame> = jobs
            .par_iter()
            .zip(poses.par_iter())
            .with_max_len(1)
            .map(|((f, options), pose)| {
                let corrected;
                let pts = match (&table, &inc_table, pose) {
                    (None, _, _) => f.points,
                    (Some(_), Some(it), Some(pose)) => {
                        let mut c = f.points.to_vec();
                        let cos = incidences(f.points, pose);
                        it.correct(&mut c, f.intensity, &cos)?;
                        corrected = c;
                        &corrected
                    }
                    (Some(t), _, _) => {
                        let mut c = f.points.to_vec();
                        t.correct(&mut c, f.intensity)?;
                        corrected = c;
                        &corrected
                    }
                };
                let est = estimate(pts, Method::MlEpd, options)?;
                // A rig's raw frames carry the camera's systematic error — what the table
                // is made to measure — so the form test may well find regions off the
                // known pipe (`lack_of_fit`): the pose is still the one to measure from.
                let usable = est.status.is_converged()
                    || matches!(est.status, crate::check::FitStatus::LackOfFit(_));
                if !usable {
                    return Err(EpdError::Degenerate(format!(
                        "the pose fit with the known diameters ended {}: {}",
                        est.status.name(),
                        est.status.reason()
                    )));
                }
                let obs =
                    offsets_with_incidence(f.points, f.intensity, &est.params, settings.gate)?;
                Ok((est, obs))
            })
            .collect();
        for (pose, r) in poses.iter_mut().zip(&per_frame) {
            *pose = r.as_ref().ok().map(|(e, _)| e.params);
        }
        let iobs: Vec<IncidenceObservation> = per_frame
            .iter()
            .filter_map(|r| r.as_ref().ok())
            .flat_map(|(_, o)| o.iter().copied())
            .collect();
        let obs: Vec<Observation> = iobs.iter().map(|o| o.obs).collect();
        if obs.is_empty() {
            let why = per_frame
                .iter()
                .find_map(|r| r.as_ref().err().map(|e| e.to_string()))
                .unwrap_or_else(|| "no point lies in the range gate".into());
            return Err(EpdError::InvalidOption(format!(
                "no calibration frame could be used: {why}"
            )));
        }
        let b = match bins {
            Some(b) => b,
            None => {
                let mut b = TableBins::spanning(&obs, settings.bins.0, settings.bins.1)?;
                b.range.lo = b.range.lo.max(lo);
                b.range.hi = b.range.hi.min(hi);
                if !(b.range.hi > b.range.lo) {
                    (b.range.lo, b.range.hi) = (lo, hi);
                }
                b.min_count = settings.min_count.max(1);
                bins = Some(b);
                b
            }
        };
        table = Some(DepthTable::build(&obs, &b)?);
        if settings.incidence_bins > 0 {
            let ib = match inc_bins {
                Some(ib) => ib,
                None => {
                    let ib = IncidenceBins::spanning(
                        &iobs,
                        (settings.bins.0, settings.bins.1, settings.incidence_bins),
                        settings.gate,
                        settings.min_count,
                    )?;
                    inc_bins = Some(ib);
                    ib
                }
            };
            inc_table = Some(IncidenceTable::build(&iobs, &ib)?);
        }
        last = Some((per_frame, obs.len()));
    }
    let (Some(mut table), Some((mut per_frame, _))) = (table, last) else {
        return Err(EpdError::InvalidOption("no calibration pass ran".into()));
    };
    // The passes' fixed point is not the joint least squares of the poses and the table
    // (crate::calibration::joint): refine the poses jointly, then rebuild the tables at
    // the refined poses.
    let frames: Vec<CalibrationFrame<'_>> = jobs.iter().map(|j| j.0).collect();
    let binned: &dyn ObservedBins = match &inc_table {
        Some(t) => t,
        None => &table,
    };
    let joint = refine_poses(&frames, &mut poses, binned, settings.gate)?;
    let iobs: Vec<IncidenceObservation> = frames
        .iter()
        .zip(&poses)
        .filter_map(|(f, p)| p.as_ref().map(|p| (f, p)))
        .map(|(f, p)| offsets_with_incidence(f.points, f.intensity, p, settings.gate))
        .collect::<Result<Vec<_>, _>>()?
        .into_iter()
        .flatten()
        .collect();
    let obs: Vec<Observation> = iobs.iter().map(|o| o.obs).collect();
    if let Some(b) = bins {
        table = DepthTable::build(&obs, &b)?;
    }
    if let Some(ib) = inc_bins {
        inc_table = Some(IncidenceTable::build(&iobs, &ib)?);
    }
    for (r, p) in per_frame.iter_mut().zip(&poses) {
        if let (Ok((e, _)), Some(p)) = (r, p) {
            e.params = *p;
        }
    }
    Ok(Calibration {
        table,
        incidence: inc_table,
        fits: per_frame.into_iter().map(|r| r.map(|(e, _)| e)).collect(),
        n_observations: obs.len(),
        spans: spans_of(&iobs),
        joint,
    })
}
