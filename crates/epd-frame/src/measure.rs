//! One frame measured, the same way for every front end (`epd estimate`, `epd.estimate`,
//! the bench harness's pipeline run): the depth table's correction, the scene ahead
//! ([`crate::scene`]), the fit of the straight section, and the report's context
//! ([`measure_frame`]; [`measure_file`] reads a file first).

use std::borrow::Cow;
use std::path::Path;
use std::time::Instant;

use epd_core::{EstimateOptions, Method, estimate, estimate_weighted, rms_range_residual};

use crate::config::EstimateConfig;
use crate::input::{
    CALIBRATION_NEEDS_INTENSITY, convert_to_sensor_metres, has_intensity, intensity, ranges,
    read_input, to_sensor_metres,
};
use crate::read::PointCloud;
use crate::report::{FileEstimate, FileReport};
use crate::scene::FrameScene;

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
        Some(beta) => cfg.options.with_start(beta).unwrap_or(cfg.options),
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
    let mut n_calibrated = None;
    let mut calibration_outside = None;
    let mut shared: Option<SharedErrors> = None;
    let mut sigmas: Option<Cow<'_, [f64]>> = sigma.map(Cow::Borrowed);
    let failed = |e: epd_core::EpdError| format!("{e} ({n_read} points read)");
    // The scene, when it is surveyed on other points than those fitted (a version-2
    // table's: [`survey_for_incidence`]).
    let mut scene_apart: Option<FrameScene> = None;
    if let Some(cal) = &cfg.calibration {
        match (&cal.incidence, intensity) {
            (Some(inc), Some(i)) => {
                if cfg.weighted && sigma.is_some() {
                    return Err(
                        "per-point σ given with a weighting depth table: give one or \
                                the other (or the table unweighted)"
                            .into(),
                    );
                }
                if cfg.geometry {
                    let raw_r = raw_range_m.as_deref().unwrap_or(&[]);
                    scene_apart = Some(survey_for_incidence(cal, &points, i, raw_r, cfg).map_err(
                        |e| {
                            format!(
                                "{e} (the survey on the plain table's points; {n_read} points read)"
                            )
                        },
                    )?);
                }
                let straight = scene_apart.as_ref().and_then(|s| s.straight.as_deref());
                let (moved, s) = correct_by_incidence(cal, inc, points.to_mut(), i, straight, cfg)?;
                n_calibrated = Some(moved);
                calibration_outside = Some(s.outside_fraction);
                if cfg.weighted {
                    sigmas = Some(Cow::Owned(s.sigma_m.clone()));
                }
                shared = Some(s);
            }
            _ => {
                if let Some(i) = intensity
                    && i.len() == points.len()
                {
                    let (valid, covered) =
                        points.iter().zip(i).fold((0usize, 0usize), |a, (p, &v)| {
                            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                            if !(r.is_finite() && r > 0.0) {
                                return a;
                            }
                            (a.0 + 1, a.1 + usize::from(cal.table.covers(r, v)))
                        });
                    calibration_outside =
                        (valid > 0).then(|| (valid - covered) as f64 / valid as f64);
                }
                let (moved, table_sigmas) =
                    cal.correct_points(cfg.weighted, points.to_mut(), intensity, sigma.is_some())?;
                n_calibrated = Some(moved);
                if let Some(s) = table_sigmas {
                    sigmas = Some(Cow::Owned(s));
                }
                // The bins' standard errors, shared by the points each one corrected.
                if let Some(i) = intensity
                    && i.len() == points.len()
                {
                    shared = Some(SharedErrors {
                        shift: Shares::Interpolated(cal.table.shared_error_terms(&points, i)),
                        n_groups: cal.table.offset_m.len(),
                        outside_fraction: calibration_outside.unwrap_or(0.0),
                        sigma_m: Vec::new(),
                        raw_diameters: None,
                    });
                }
            }
        }
    }
    // Invalid pixels (NaN, inf, zeros) are dropped and counted by the estimator; the
    // range gate keeps points by their model range (see EstimateOptions).
    let kept: &[[f64; 3]] = &points;
    // Between stages, a caller's stop request is honoured (`epd_core::cancel`).
    epd_core::cancel::checkpoint();
    let surveyed_apart = scene_apart.is_some();
    let scene = if let Some(s) = scene_apart {
        Some(s)
    } else if cfg.geometry {
        let table = match (&cfg.calibration, raw_range_m.as_deref(), intensity) {
            (Some(cal), Some(r), Some(i)) => Some((&cal.table, r, i)),
            _ => None,
        };
        Some(FrameScene::survey(kept, cfg.method, &whole, table).map_err(failed)?)
    } else {
        None
    };
    epd_core::cancel::checkpoint();
    let mut est = fit_straight(
        kept,
        sigmas.as_deref(),
        scene.as_ref(),
        !surveyed_apart,
        &whole,
        cfg,
    )
    .map_err(failed)?;
    epd_core::cancel::checkpoint();
    let mask = scene.as_ref().and_then(|s| s.straight.as_deref());
    let mut size_outside_rigs = None;
    if let (Some(s), Some(cal)) = (&shared, &cfg.calibration) {
        add_table_uncertainty(&mut est, kept, mask, s, cfg);
        size_outside_rigs = add_transfer_uncertainty(&mut est, s, cal);
    }
    let elapsed_ms = sampling_ms + t1.elapsed().as_secs_f64() * 1e3;
    let bend_fit = scene.as_ref().and_then(|s| {
        let b = s.survey.bend.as_ref()?;
        Some((
            s.survey.segmentation.straight.params,
            b.geometry,
            b.angle_seen,
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
        size_outside_rigs,
        bend_fit,
    })
}

/// A frame more than this fraction of whose points lie outside the depth table's support
/// is refused: 90 %. The fit then rests on under a tenth of the wall the camera saw —
/// on the Helios2 model a band of ranges near the rig's, where the diameters and the
/// sensor's offset are not told apart: of eight such frames (a 20" table, 30" frames,
/// 93–100 % outside) seven ended `implausible` and the eighth 19.6 mm off.
pub const REFUSE_OUTSIDE: f64 = 0.9;

/// Rounds of fit → incidence → correction → refit at most: the incidence comes from the
/// fitted wall, which moves with the correction. The mean diameter settles within
/// [`INCIDENCE_TOLERANCE_M`] in two rounds on the Helios2 model (a 1 mm change of the
/// diameter changes cos θ by 0.2 % at a 0.5 m pipe, and the correction by far less
/// than a micrometre), so three leave a margin.
pub const INCIDENCE_ROUNDS: usize = 3;

/// The convergence criterion of the rounds: the mean diameter moved by less than 10 µm
/// (a hundredth of the 1 mm resolution the report gives the diameters to).
pub const INCIDENCE_TOLERANCE_M: f64 = 1e-5;

/// A frame more than this fraction of whose points lie outside the depth table's
/// support is said to be (in `status_reason`): the majority of its wall, one half, was
/// left out of the fit (points outside the support are not corrected and not fitted),
/// so its diameters rest on less than half of what the camera saw.
pub const MOSTLY_OUTSIDE: f64 = 0.5;

/// A point's shared range error: its bin and the bin mean's standard error (m).
type Shift = Option<(u32, f64)>;

/// The shared range errors of a frame's points.
#[derive(Clone, Debug)]
enum Shares {
    /// One bin per point (the incidence table: the bin holding the point).
    Home(Vec<Shift>),
    /// The 4 bins a version-1 table's bilinear interpolation read, each with its weight
    /// × its standard error (`epd_core::DepthTable::shared_error_terms`).
    Interpolated(Vec<[(u32, f64); 4]>),
}

/// What the incidence table's correction leaves to the 1-σ: per point the bin whose
/// mean corrected it (its standard error shared by every point of the bin).
#[derive(Clone, Debug)]
struct SharedErrors {
    /// Per point: the bins whose errors it shares, with their standard errors (m).
    shift: Shares,
    /// Groups: the table's bins.
    n_groups: usize,
    /// Of the valid points with an intensity, the fraction outside the support.
    outside_fraction: f64,
    /// The table's spread at each corrected point (m), for a weighted fit.
    sigma_m: Vec<f64>,
    /// The (Dmax, Dmin) of the fit on the raw points (m): the correction's whole effect
    /// on the diameters is the corrected fit's minus these (the incidence table's
    /// rounds fit them; `None` for a version-1 table, which is not checked against the
    /// rig's size).
    raw_diameters: Option<(f64, f64)>,
}

/// The scene of a frame to be corrected by a version-2 (incidence) table, surveyed on
/// its points corrected by the table's plain range × intensity part. The incidence
/// table leaves out (NaN) the points outside its support — a bend's or a tee's wall,
/// whose incidences and ranges straight rigs never showed — so a survey of its points
/// would not see what lies ahead (issue 24: a bend read `straight` with the version-2
/// table of the pipeline run); the plain table corrects every point its range and
/// intensity axes hold. The straight section it finds is then fitted on the incidence
/// table's points ([`correct_by_incidence`]).
fn survey_for_incidence(
    cal: &crate::table::CalibrationTable,
    raw: &[[f64; 3]],
    intensity: &[f64],
    raw_range_m: &[f64],
    cfg: &EstimateConfig,
) -> Result<FrameScene, String> {
    let mut plain = raw.to_vec();
    cal.correct_points(false, &mut plain, Some(intensity), false)?;
    let table = (raw_range_m.len() == raw.len()).then_some((&cal.table, raw_range_m, intensity));
    FrameScene::survey(&plain, cfg.method, &cfg.options, table).map_err(|e| e.to_string())
}

/// The incidence table's correction of a frame's `points` in place: the frame fitted
/// on its raw points, then up to [`INCIDENCE_ROUNDS`] rounds of cos θ of each ray at
/// the fitted wall → the raw points corrected by the table → refit, until the mean
/// diameter moves by less than [`INCIDENCE_TOLERANCE_M`]. Points outside the table's
/// support are left out (NaN) and counted. With `straight` (the scene's straight
/// section, [`survey_for_incidence`]) only its points are fitted and corrected, the
/// others left out (NaN, not counted): a bend's or a tee's wall is no straight
/// cylinder, and the incidences of a fit that included it would be wrong. The points
/// moved and what the 1-σ needs.
fn correct_by_incidence(
    cal: &crate::table::CalibrationTable,
    table: &epd_core::calibration::IncidenceTable,
    points: &mut Vec<[f64; 3]>,
    intensity: &[f64],
    straight: Option<&[bool]>,
    cfg: &EstimateConfig,
) -> Result<(usize, SharedErrors), String> {
    let mut raw = points.clone();
    if let Some(keep) = straight {
        for (p, &k) in raw.iter_mut().zip(keep) {
            if !k {
                *p = [f64::NAN; 3];
            }
        }
    }
    let fit = |p: &[[f64; 3]]| {
        estimate(p, cfg.method, &cfg.options).map_err(|e| format!("{e} (the incidence round)"))
    };
    let mut pose = fit(&raw)?;
    let raw_diameters = (pose.params.d_max, pose.params.d_min);
    let mut out = None;
    for round in 0..INCIDENCE_ROUNDS {
        if round == 0 {
            // Refused before the corrected points are fitted: too few lie in the support.
            let cos = epd_core::calibration::incidences(&raw, &pose.params);
            let mut c = raw.clone();
            let corr = cal.correct_with_incidence(table, &mut c, intensity, &cos)?;
            let total = corr.moved + corr.outside;
            if total > 0 && corr.outside as f64 > REFUSE_OUTSIDE * total as f64 {
                return Err(format!(
                    "{:.0} % of the frame's points lie outside the depth table's support (more \
                     than {:.0} %): the rigs ({}) did not show this pipe's ranges, \
                     intensities and incidences; calibrate with a rig of this pipe's size",
                    100.0 * corr.outside as f64 / total as f64,
                    REFUSE_OUTSIDE * 100.0,
                    cal.rigs
                        .iter()
                        .map(|((d, _), _)| format!("{:.1} mm", d * 1e3))
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
        }
        let cos = epd_core::calibration::incidences(&raw, &pose.params);
        let mut c = raw.clone();
        let corr = cal.correct_with_incidence(table, &mut c, intensity, &cos)?;
        let next = fit(&c)?;
        let moved = (next.d_mean() - pose.d_mean()).abs();
        pose = next;
        out = Some((c, corr));
        if moved < INCIDENCE_TOLERANCE_M {
            break;
        }
    }
    let Some((corrected, corr)) = out else {
        return Err("no incidence round ran".into());
    };
    let shift = Shares::Home(
        corr.bin
            .iter()
            .map(|b| b.map(|b| (b, table.se_m[b as usize])))
            .collect(),
    );
    let total = corr.moved + corr.outside;
    *points = corrected;
    Ok((
        corr.moved,
        SharedErrors {
            shift,
            n_groups: table.cells(),
            outside_fraction: if total == 0 {
                0.0
            } else {
                corr.outside as f64 / total as f64
            },
            sigma_m: corr.sigma_m,
            raw_diameters: Some(raw_diameters),
        },
    ))
}

/// The relative margin around the rigs' diameters within which a pipe counts as one of
/// their sizes: 3 %, the 2 % ovality a pipe may have (API 5L's out-of-roundness limit for
/// line pipe is 1.5 % of the OD at the ends, more along the body) plus the 1 % tolerance
/// of the nominal diameter — nominal sizes 2" apart at 16"–30" differ by 7 % or more.
pub const RIG_SIZE_MARGIN: f64 = 0.03;

/// When the frame's mean diameter lies outside the rigs' sizes (the smallest rig's
/// Dmin to the largest rig's Dmax, widened by [`RIG_SIZE_MARGIN`]), the table's
/// correction is not known to transfer to it (at the same range, intensity and
/// incidence the rigs' poses absorbed a part of the error that depends on the pipe's
/// size): the whole effect of the correction on each diameter, |D_corrected − D_raw|,
/// is added to its variance — a 1-σ that spans the raw and the corrected result. The
/// smallest and largest rig diameters (mm) when so, else `None`.
fn add_transfer_uncertainty(
    est: &mut epd_core::Estimate,
    s: &SharedErrors,
    cal: &crate::table::CalibrationTable,
) -> Option<(f64, f64)> {
    let raw = s.raw_diameters?;
    let lo = cal.rigs.iter().map(|r| r.0.1).fold(f64::INFINITY, f64::min);
    let hi = cal.rigs.iter().map(|r| r.0.0).fold(0.0f64, f64::max);
    let d = est.d_mean();
    if !(lo.is_finite() && hi > 0.0)
        || (lo * (1.0 - RIG_SIZE_MARGIN)..=hi * (1.0 + RIG_SIZE_MARGIN)).contains(&d)
    {
        return None;
    }
    let delta = [est.params.d_max - raw.0, est.params.d_min - raw.1];
    if let Some(mut cov) = est.diameter_cov {
        for k in 0..2 {
            cov[k][k] += delta[k] * delta[k];
        }
        est.diameter_cov = Some(cov);
    }
    for k in 0..2 {
        if let Some(sig) = est.sigma[k] {
            est.sigma[k] = Some(sig.hypot(delta[k]));
        }
    }
    Some((lo * 1e3, hi * 1e3))
}

/// Add the depth table's own uncertainty to the diameters' 1-σ: each bin's standard
/// error, shared by every point the bin corrected (a version-1 table: by every point
/// whose bilinear interpolation read it, times its weight), propagated through the
/// fit's Jacobian ([`epd_core::calibration::shared_error_cov_terms`]) and added to the
/// fit's own covariance. The fitted points: those of the straight
/// section (`mask`) within the range gate.
fn add_table_uncertainty(
    est: &mut epd_core::Estimate,
    points: &[[f64; 3]],
    mask: Option<&[bool]>,
    s: &SharedErrors,
    cfg: &EstimateConfig,
) {
    let Some(mut cov) = est.diameter_cov else {
        return;
    };
    let geom = epd_core::residual::Geometry::new(&est.params);
    let gate = cfg.options.range_gate();
    let fitted = |k: usize, p: &[f64; 3]| {
        mask.is_none_or(|m| m.get(k).copied().unwrap_or(false))
            && match (gate, &geom) {
                (Some((lo, hi)), Some(g)) => {
                    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    (lo..=hi).contains(&(g.line_parameter(p) * r))
                }
                _ => true,
            }
    };
    fn pick<T: Copy>(
        points: &[[f64; 3]],
        terms: &[T],
        keep: impl Fn(usize, &[f64; 3]) -> bool,
    ) -> (Vec<[f64; 3]>, Vec<T>) {
        points
            .iter()
            .zip(terms)
            .enumerate()
            .filter(|(k, (p, _))| keep(*k, p))
            .map(|(_, (p, t))| (*p, *t))
            .unzip()
    }
    let extra = match &s.shift {
        Shares::Home(sh) => {
            let (p, sh) = pick(points, sh, fitted);
            epd_core::calibration::shared_error_cov(&p, &sh, s.n_groups, &est.params)
        }
        Shares::Interpolated(t) => {
            let (p, t) = pick(points, t, fitted);
            epd_core::calibration::shared_error_cov_terms(&p, &t, s.n_groups, &est.params)
        }
    };
    let Some(extra) = extra else {
        return;
    };
    for a in 0..2 {
        for b in 0..2 {
            cov[a][b] += extra[a][b];
        }
    }
    est.diameter_cov = Some(cov);
    for k in 0..2 {
        if let Some(sig) = est.sigma[k] {
            est.sigma[k] = Some((sig * sig + extra[k][k]).sqrt());
        }
    }
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
/// them when nothing lies ahead) within the range gate, about the estimate.
fn straight_rms_mm(
    points: &[[f64; 3]],
    mask: Option<&[bool]>,
    est: &epd_core::Estimate,
    cfg: &EstimateConfig,
) -> Option<f64> {
    let straight: Cow<'_, [[f64; 3]]> = match mask {
        None => Cow::Borrowed(points),
        Some(keep) => points
            .iter()
            .zip(keep)
            .filter(|(_, k)| **k)
            .map(|(p, _)| *p)
            .collect(),
    };
    let fitted: Cow<'_, [[f64; 3]]> = match cfg.options.range_gate() {
        None => straight,
        Some((lo, hi)) => Cow::Owned(epd_core::gate_by_model_range(
            &straight,
            &est.params,
            lo,
            hi,
        )),
    };
    rms_range_residual(&fitted, &est.params).map(|v| v * 1e3)
}
