//! One frame measured, the same way for every front end (`epd estimate`, `epd.estimate`,
//! the bench harness's pipeline run): the depth table's correction, the scene ahead
//! ([`crate::scene`]), the fit of the straight section, and the report's context
//! ([`measure_frame`]; [`measure_file`] reads a file first).

use std::borrow::Cow;
use std::path::Path;
use std::time::Instant;

use epd_core::{EstimateOptions, Method, estimate, estimate_weighted};

use crate::config::EstimateConfig;
use crate::input::{
    CALIBRATION_NEEDS_INTENSITY, convert_to_sensor_metres, has_intensity, intensity, ranges,
    read_input, to_sensor_metres,
};
use crate::read::PointCloud;
use crate::report::{FileEstimate, FileReport};
use crate::scene::FrameScene;

mod calibrated;

pub use calibrated::{
    INCIDENCE_ROUNDS, INCIDENCE_TOLERANCE_M, IncidenceFrame, IncidenceRounds, MOSTLY_OUTSIDE,
    PlainFrame, PlainFrameError, REFUSE_OUTSIDE, RIG_SIZE_MARGIN, UncorrectedFrame,
    incidence_frame, incidence_rounds, plain_frame,
};
use calibrated::{add_table_uncertainty, add_transfer_uncertainty, calibrate};

/// A frame's points and what comes with them, as [`measure_frame`] takes them.
#[derive(Clone, Debug)]
pub struct FrameInput<'a> {
    /// The points, in metres in the sensor frame (invalid pixels as zeros or NaN are
    /// dropped and counted by the estimator). Borrowed points are copied only when a
    /// depth table moves them.
    pub points: Cow<'a, [[f64; 3]]>,
    /// One camera intensity per point, when the input has them (needed by a depth table).
    pub intensity: Option<&'a [f64]>,
    /// One range standard deviation per point (m), when known: the fit is weighted by it.
    pub sigma: Option<&'a [f64]>,
    /// The time taken to get the points (ms), reported as `read_ms`.
    pub read_ms: f64,
}

/// Read one file (or standard input for `-`) and measure it ([`measure_frame`]).
///
/// With `--max-points N` ([`EstimateConfig::sampling`]), a binary PLY or PCD of more
/// than N fixed-size records is not decoded whole: the choice reads the points it looks
/// at, then the chosen records are read with every property ([`measure_records`]), so
/// that `read_ms` falls with N. The estimate is the one of the whole file read and
/// sampled ([`crate::sampling::choose_from`] makes the same choice from either).
pub fn measure_file(path: &Path, cfg: &EstimateConfig) -> FileReport {
    let run = || -> Result<FileEstimate, String> {
        if let Some(s) = &cfg.sampling
            && path.as_os_str() != "-"
            && let Some(e) = measure_records(path, s, cfg)?
        {
            return Ok(e);
        }
        let t0 = Instant::now();
        let cloud = read_input(path, &cfg.input)?;
        measure_cloud(cloud, t0.elapsed().as_secs_f64() * 1e3, cfg)
    };
    FileReport::of_path(path, run())
}

/// A file's fixed-size records as the choice reads them: converted to metres in the
/// sensor frame, the unit checked on the first points read, the time spent reading
/// summed.
struct FileRecords<'a> {
    file: &'a epd_io::records::RecordFile,
    input: crate::config::InputConfig,
    checked: bool,
    read: std::time::Duration,
}

impl crate::sampling::Records for FileRecords<'_> {
    fn len(&self) -> usize {
        self.file.len()
    }

    fn points(&mut self, indices: &[u32]) -> Result<Vec<[f64; 3]>, String> {
        let t = Instant::now();
        let mut p = self.file.points(indices)?;
        if self.checked {
            convert_to_sensor_metres(&mut p, self.input.units, self.input.frame);
        } else {
            to_sensor_metres(&mut p, self.input.units, self.input.frame)?;
            self.checked = true;
        }
        self.read += t.elapsed();
        Ok(p)
    }
}

/// [`measure_file`] of a file of fixed-size records (`epd_io::records`) with
/// `--max-points`: the choice reads the points it looks at, the chosen records are read
/// whole (their intensity, pixel and other properties with them), then
/// [`measure_frame`] on them. `read_ms` is the time spent opening and reading, the
/// choice's other work is in `elapsed_ms`. `Ok(None)` when the file is not one of fixed
/// size records or holds no more than `max_points` (valid) points: then it is read whole.
pub fn measure_records(
    path: &Path,
    sampling: &crate::sampling::Sampling,
    cfg: &EstimateConfig,
) -> Result<Option<FileEstimate>, String> {
    let t0 = Instant::now();
    let Some(file) = epd_io::records::RecordFile::open(path)? else {
        return Ok(None);
    };
    if file.len() <= sampling.max_points {
        return Ok(None);
    }
    let opened = t0.elapsed();
    let t1 = Instant::now();
    let mut src = FileRecords {
        file: &file,
        input: cfg.input,
        checked: false,
        read: std::time::Duration::ZERO,
    };
    let Some(chosen) = crate::sampling::choose_from(&mut src, sampling, cfg.method, &cfg.options)?
    else {
        return Ok(None);
    };
    let choice = t1.elapsed().saturating_sub(src.read);
    let measure = |chosen: &crate::sampling::Chosen, read: std::time::Duration, ms: f64| {
        let t2 = Instant::now();
        let idx: Vec<u32> = chosen.indices.iter().map(|&i| i as u32).collect();
        let mut cloud = file.cloud(&idx)?;
        convert_to_sensor_metres(&mut cloud.points, cfg.input.units, cfg.input.frame);
        let read_ms = (read + t2.elapsed()).as_secs_f64() * 1e3;
        let sampled = Presampled {
            n_read: file.len(),
            n: cloud.points.len(),
            method: chosen.method,
            ms,
            pilot: chosen.pilot,
        };
        measure_cloud_as(cloud, read_ms, cfg, Some(sampled))
    };
    let first = measure(&chosen, opened + src.read, choice.as_secs_f64() * 1e3)?;
    if !disagrees_with_pilot(&chosen, &first, cfg) {
        return Ok(Some(first));
    }
    // The informed choice disagrees with its pilot: the frame again, on a uniform sample.
    let t3 = Instant::now();
    src.read = std::time::Duration::ZERO;
    let uniform = uniform_instead(sampling);
    let again = crate::sampling::choose_from(&mut src, &uniform, cfg.method, &cfg.options)?;
    let Some(again) = again else {
        return Ok(Some(first));
    };
    let spent = first.elapsed_ms + t3.elapsed().saturating_sub(src.read).as_secs_f64() * 1e3;
    let mut second = measure(&again, src.read, spent)?;
    second.read_ms += first.read_ms;
    Ok(Some(second))
}

/// Whether the fit of the informed choice's points disagrees with the choice's pilot
/// ([`crate::sampling::Witness::disagrees`]). Not with a depth table: the pilot saw the
/// points before the table moved them, so its diameters differ by the correction.
fn disagrees_with_pilot(
    chosen: &crate::sampling::Chosen,
    fit: &FileEstimate,
    cfg: &EstimateConfig,
) -> bool {
    cfg.calibration.is_none() && chosen.witness.is_some_and(|w| w.disagrees(&fit.estimate))
}

/// The same sampling, uniform: the choice of a frame whose informed choice disagreed
/// with its pilot ([`crate::sampling::Witness`]). A uniform sample holds the frame's
/// parts of the wall in the frame's own proportions, so its fit targets what the full
/// frame's does, whatever part of the wall the model does not fit.
fn uniform_instead(sampling: &crate::sampling::Sampling) -> crate::sampling::Sampling {
    crate::sampling::Sampling {
        method: crate::sampling::SamplingMethod::Uniform,
        ..*sampling
    }
}

/// Points already chosen by [`crate::sampling`] before they were read
/// ([`measure_records`]): of how many, how many, how, and the time the choice took (ms, besides
/// reading).
#[derive(Clone, Copy, Debug)]
struct Presampled {
    /// Points in the file.
    n_read: usize,
    /// Points chosen.
    n: usize,
    /// How they were chosen.
    method: crate::sampling::SamplingMethod,
    /// The choice's time besides reading (ms).
    ms: f64,
    /// The informed choice's pilot fit ([`crate::sampling::Chosen::pilot`]).
    pilot: Option<epd_core::Params>,
}

/// Measure a cloud read from a file or a bag (its points in metres in the sensor frame;
/// `read_ms` the time taken to read it): its `intensity` taken for a depth table, then
/// [`measure_frame`].
pub fn measure_cloud(
    cloud: PointCloud,
    read_ms: f64,
    cfg: &EstimateConfig,
) -> Result<FileEstimate, String> {
    measure_cloud_as(cloud, read_ms, cfg, None)
}

/// [`measure_cloud`] of points already chosen (`pre`) or not.
fn measure_cloud_as(
    cloud: PointCloud,
    read_ms: f64,
    cfg: &EstimateConfig,
    pre: Option<Presampled>,
) -> Result<FileEstimate, String> {
    if cloud.points.is_empty() {
        return Err("the file holds no points".into());
    }
    let i = match &cfg.calibration {
        None => None,
        Some(_) => Some(intensity(&cloud, CALIBRATION_NEEDS_INTENSITY)?),
    };
    let camera = has_intensity(&cloud);
    let input = FrameInput {
        points: Cow::Owned(cloud.points),
        intensity: i.as_deref(),
        sigma: None,
        read_ms,
    };
    let mut e = measure_frame_as(input, cfg, pre)?;
    e.intensity_without_table = camera && cfg.calibration.is_none();
    Ok(e)
}

/// Measure one frame, in this order:
/// 0. with `--max-points N` ([`EstimateConfig::sampling`]), the N points that carry the
///    information ([`crate::sampling::choose`]; the rest, with their intensity and σ, are
///    left out of every later step, and the time it takes is in `elapsed_ms`);
/// 1. the depth table's correction, when the configuration has a table
///    ([`crate::table::CalibrationTable::correct_points`]; it needs `intensity`), which
///    may also give each point its σᵢ;
/// 2. the scene ahead, unless the configuration fits every point as one straight pipe
///    ([`FrameScene::survey`]): straight, a bend or a tee ahead, or in a bend, and which points
///    belong to the straight section;
/// 3. the fit of the straight section's points (weighted by the table's σᵢ or by
///    `sigma` when given) with its checks and 1-σ (`epd_core::estimate`);
/// 4. the report's context: the loss scale, the RMS residual, the counts, the times.
///
/// The error is a message for the user (the number of points read appended).
pub fn measure_frame(input: FrameInput<'_>, cfg: &EstimateConfig) -> Result<FileEstimate, String> {
    measure_frame_as(input, cfg, None)
}

/// [`measure_frame`] of points already chosen (`pre`: step 0 done) or not: with
/// `--max-points`, step 0 here, then the chosen points measured
/// ([`measure_chosen`]); an informed choice that disagrees with its pilot
/// ([`crate::sampling::Witness`]) is replaced by a uniform one.
fn measure_frame_as(
    input: FrameInput<'_>,
    cfg: &EstimateConfig,
    pre: Option<Presampled>,
) -> Result<FileEstimate, String> {
    let Some(sampling) = cfg.sampling.as_ref().filter(|_| pre.is_none()) else {
        return measure_chosen(input, cfg, pre);
    };
    let t0 = Instant::now();
    let Some(chosen) = crate::sampling::choose(&input.points, sampling, cfg.method, &cfg.options)
    else {
        return measure_chosen(input, cfg, None);
    };
    let n_read = input.points.len();
    // The time of the choice, and of a first measurement replaced, counts in
    // `elapsed_ms`.
    let measure = |chosen: &crate::sampling::Chosen| {
        // Values of another length than the points are kept whole: the step that uses
        // them names the mismatch.
        let pick = |v: &[f64]| -> Vec<f64> {
            if v.len() != n_read {
                return v.to_vec();
            }
            chosen.indices.iter().map(|&i| v[i]).collect()
        };
        let (intensity, sigma) = (input.intensity.map(pick), input.sigma.map(pick));
        let picked = FrameInput {
            points: Cow::Owned(chosen.indices.iter().map(|&i| input.points[i]).collect()),
            intensity: intensity.as_deref(),
            sigma: sigma.as_deref(),
            read_ms: input.read_ms,
        };
        let sampled = Presampled {
            n_read,
            n: chosen.indices.len(),
            method: chosen.method,
            ms: t0.elapsed().as_secs_f64() * 1e3,
            pilot: chosen.pilot,
        };
        measure_chosen(picked, cfg, Some(sampled))
    };
    let first = measure(&chosen)?;
    if !disagrees_with_pilot(&chosen, &first, cfg) {
        return Ok(first);
    }
    // The informed choice disagrees with its pilot: the frame again, on a uniform sample.
    let uniform = uniform_instead(sampling);
    match crate::sampling::choose(&input.points, &uniform, cfg.method, &cfg.options) {
        Some(again) => measure(&again),
        None => Ok(first),
    }
}

/// [`measure_frame`] of the points chosen (`pre`) or of every point.
fn measure_chosen(
    input: FrameInput<'_>,
    cfg: &EstimateConfig,
    pre: Option<Presampled>,
) -> Result<FileEstimate, String> {
    let FrameInput {
        mut points,
        intensity,
        sigma,
        read_ms,
    } = input;
    let n_read = pre.map_or(points.len(), |p| p.n_read);
    let t0 = Instant::now();
    let sampled = pre.map(|p| (p.n, p.method));
    let sampling_ms = t0.elapsed().as_secs_f64() * 1e3 + pre.map_or(0.0, |p| p.ms);
    // The fits of every chosen point (the survey's first, or the straight-only fit) start
    // from the informed choice's pilot, a fit of the same frame: that saves the subsample
    // stage. Not with a depth table, which moves the points after the pilot saw them.
    let pilot = pre
        .and_then(|p| p.pilot)
        .filter(|_| cfg.calibration.is_none());
    let whole = match pilot {
        Some(beta) => cfg
            .options
            .with_start_fitted_on(beta, crate::sampling::PILOT_POINTS)
            .unwrap_or(cfg.options),
        None => cfg.options,
    };
    if cfg.calibration.is_some() {
        // The table moves the points: a copy of borrowed ones, before the clock starts.
        points = Cow::Owned(points.into_owned());
    }
    let t1 = Instant::now();
    // The measured ranges before the table moves the points: where the table observed
    // the camera's error is looked up by them (the bend's points, in the scene step).
    let raw_range_m: Option<Vec<f64>> =
        (cfg.calibration.is_some() && cfg.geometry).then(|| ranges(&points));
    let failed = |e: epd_core::EpdError| format!("{e} ({n_read} points read)");
    let calibrated = match &cfg.calibration {
        Some(cal) => Some(calibrate(
            cal,
            points.to_mut(),
            intensity,
            sigma.is_some(),
            raw_range_m.as_deref(),
            cfg,
            n_read,
        )?),
        None => None,
    };
    let (n_calibrated, calibration_outside, uncorrected) =
        calibrated.as_ref().map_or((None, None, None), |c| {
            (Some(c.n_calibrated), c.outside, c.uncorrected)
        });
    let (sigmas, scene, surveyed_here, shared) = match calibrated {
        Some(c) => (
            c.sigma.map(Cow::Owned).or(sigma.map(Cow::Borrowed)),
            c.scene,
            c.surveyed_here,
            c.shared,
        ),
        None => {
            // Invalid pixels (NaN, inf, zeros) are dropped and counted by the estimator; the
            // range gate keeps points by their model range (see EstimateOptions).
            epd_core::cancel::checkpoint();
            let scene = if cfg.geometry {
                Some(FrameScene::survey(&points, cfg.method, &whole, None).map_err(failed)?)
            } else {
                None
            };
            (sigma.map(Cow::Borrowed), scene, true, None)
        }
    };
    let kept: &[[f64; 3]] = &points;
    epd_core::cancel::checkpoint();
    let mut est = fit_straight(
        kept,
        sigmas.as_deref(),
        scene.as_ref(),
        surveyed_here,
        &whole,
        cfg,
    )
    .map_err(failed)?;
    epd_core::cancel::checkpoint();
    let mask = scene.as_ref().and_then(|s| s.straight.as_deref());
    let mut transfer = calibrated::Transfer::default();
    if let (Some(s), Some(cal)) = (&shared, &cfg.calibration) {
        add_table_uncertainty(&mut est, kept, mask, s, cfg);
        transfer = add_transfer_uncertainty(&mut est, s, cal);
    }
    let elapsed_ms = sampling_ms + t1.elapsed().as_secs_f64() * 1e3;
    let bend_fit = scene.as_ref().and_then(|s| {
        let b = s.survey.bend.as_ref()?;
        Some((
            s.survey.segmentation.straight.params,
            b.geometry,
            if b.end_seen {
                b.geometry.angle
            } else {
                b.angle_seen
            },
        ))
    });
    Ok(FileEstimate {
        loss: (cfg.loss.clone(), radial_loss_scale_m(&est)),
        rms_residual_mm: straight_rms_mm(kept, mask, &est, cfg),
        n_out_of_range: est.n_out_of_gate,
        estimate: est,
        n_read,
        elapsed_ms,
        read_ms,
        nominal_od_mm: cfg.nominal_od_mm,
        n_calibrated,
        weighted: sigmas.is_some(),
        geometry: scene.map(|s| s.geometry),
        sampled,
        intensity_without_table: false,
        calibration_outside,
        size_outside_rigs: transfer.size_outside_rigs,
        outside_in_sigma: transfer.mostly_outside,
        uncorrected,
        bend_fit,
    })
}

/// The estimate on the straight section's points (those the scene keeps; all of them
/// when nothing lies ahead): unweighted, the survey's own straight estimate when the
/// scene was surveyed on these `points` (`surveyed_here`); weighted by `sigmas` when
/// given. A fit of every point takes the `whole` frame's options (with the pilot's start,
/// if any); a fit of the straight section's alone, the configuration's.
fn fit_straight(
    points: &[[f64; 3]],
    sigmas: Option<&[f64]>,
    scene: Option<&FrameScene>,
    surveyed_here: bool,
    whole: &EstimateOptions,
    cfg: &EstimateConfig,
) -> Result<epd_core::Estimate, epd_core::EpdError> {
    let survey = scene.map(|s| &s.survey);
    let mask = scene.and_then(|s| s.straight.as_deref());
    match (sigmas, survey, mask) {
        // No straight section to fit on its own (in a bend, or its end too close): the
        // report withholds the estimate and says why; nothing more to fit.
        (_, Some(s), _) if s.segmentation.straight_withheld => Ok(s.segmentation.straight),
        // The survey's straight estimate is the (unweighted) estimate on the straight
        // section's points: all of them when nothing lies ahead.
        (None, Some(s), _) if surveyed_here => Ok(s.segmentation.straight),
        (None, _, None) => estimate(points, cfg.method, whole),
        (None, _, Some(keep)) => {
            let p: Vec<[f64; 3]> = points
                .iter()
                .zip(keep)
                .filter(|(_, k)| **k)
                .map(|(p, _)| *p)
                .collect();
            estimate(&p, cfg.method, &cfg.options)
        }
        (Some(sig), _, Some(keep)) => {
            let (p, w): (Vec<[f64; 3]>, Vec<f64>) = points
                .iter()
                .zip(sig)
                .zip(keep)
                .filter(|(_, k)| **k)
                .map(|((p, w), _)| (*p, *w))
                .unzip();
            estimate_weighted(&p, &w, cfg.method, &cfg.options)
        }
        (Some(sig), _, None) => estimate_weighted(points, sig, cfg.method, whole),
    }
}

/// The loss's scale in metres of radial error (NaN without a loss). C-EPD's residual
/// r_c ≈ 2δ/R: its scale k is k·(D_max + D_min)/8 m.
fn radial_loss_scale_m(est: &epd_core::Estimate) -> f64 {
    match (est.method, est.loss.scale()) {
        (_, None) => f64::NAN,
        (Method::CEpd, Some(k)) => k * (est.params.d_max + est.params.d_min) / 8.0,
        (_, Some(k)) => k,
    }
}

/// RMS range residual (mm) of the straight section's points (those `mask` keeps; all of
/// them when nothing lies ahead) within the range gate, about the estimate; the points
/// are not copied (`epd_core::rms_range_residual_of`).
fn straight_rms_mm(
    points: &[[f64; 3]],
    mask: Option<&[bool]>,
    est: &epd_core::Estimate,
    cfg: &EstimateConfig,
) -> Option<f64> {
    let gate = match cfg.options.range_gate() {
        None => None,
        Some((lo, hi)) => Some(epd_core::model_range_gate(&est.params, lo, hi)?),
    };
    if mask.is_none() && gate.is_none() {
        // Every point: read in place, on all cores.
        return epd_core::rms_range_residual(points, &est.params).map(|v| v * 1e3);
    }
    let straight = points
        .iter()
        .enumerate()
        .filter(|(i, _)| mask.is_none_or(|m| m.get(*i).copied().unwrap_or(false)))
        .filter(|(_, p)| gate.as_ref().is_none_or(|g| g(p)))
        .map(|(_, p)| *p);
    epd_core::rms_range_residual_of(straight, &est.params).map(|v| v * 1e3)
}
