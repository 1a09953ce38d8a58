//! What `epd estimate` does with one input, shared by the `epd` binary and the Python
//! package (`crates/epd-py`), so that the two report the same keys and values: the checked
//! settings ([`EstimateConfig`]), the conversion of a cloud to metres in the sensor frame,
//! the depth-table correction and the estimate ([`estimate_points`], [`estimate_file`]).

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use epd_core::{
    EstimateOptions, Loss, LossScale, Method, estimate, estimate_weighted, rms_range_residual,
};

use crate::read::{Format, MAX_INPUT_BYTES, PointCloud, read_from, read_path};
use crate::report::{FileEstimate, FileReport, GeometryReport, bend_table_coverage};
use crate::table::CalibrationTable;
use epd_core::segment::{SegmentOptions, straight_mask};

/// Seed scale of the first robust pass (m) when no loss scale is given.
pub const DEFAULT_LOSS_SCALE_M: f64 = 0.05;

/// A cloud whose median distance from the sensor exceeds this (m) is not in metres.
const MAX_MEDIAN_RANGE_M: f64 = 30.0;
/// A cloud whose median distance from the sensor is below this (m) is not in the unit
/// given (e.g. metres read as millimetres).
const MIN_MEDIAN_RANGE_M: f64 = 0.02;

/// The length unit of the input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Units {
    /// Metres.
    Metres,
    /// Millimetres (the Helios2 SDK's unit).
    Millimetres,
}

/// The coordinate frame of the input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputFrame {
    /// The paper's sensor frame: X forward (optical axis), Y right, Z up.
    Sensor,
    /// A camera's optical frame (Arena SDK, PCL, Open3D, ROS): X right, Y down, Z forward.
    Optical,
}

/// How the inputs are read, checked.
#[derive(Clone, Copy, Debug)]
pub struct InputConfig {
    /// Length unit of the inputs.
    pub units: Units,
    /// Coordinate frame of the inputs.
    pub frame: InputFrame,
    /// Format of standard input (`None`: detected from its first bytes).
    pub format: Option<Format>,
}

/// The settings of `epd estimate` as given (command-line flags, Python arguments),
/// before they are checked by [`EstimateConfig::new`].
#[derive(Clone, Debug)]
pub struct EstimateSettings {
    /// The estimator.
    pub method: Method,
    /// Keep the points whose ray meets the fitted wall at least this far (m).
    pub min_range: Option<f64>,
    /// Keep the points whose ray meets the fitted wall at most this far (m).
    pub max_range: Option<f64>,
    /// Nominal outer diameter (inch): the wall thickness is estimated from it.
    pub nominal_od_in: Option<f64>,
    /// The robust loss by name: `cauchy`, `huber` or `none`.
    pub loss: String,
    /// Fixed loss scale (m of range error); `None`: from the residuals.
    pub loss_scale: Option<f64>,
    /// Depth-calibration table file.
    pub calibration: Option<PathBuf>,
    /// With a table, do not weight each residual by 1/σᵢ.
    pub unweighted: bool,
    /// Look for a bend or a tee ahead and estimate the straight section only
    /// (`epd_core::segment::survey`); `false` fits every point as one straight pipe.
    pub geometry: bool,
    /// How the inputs are read.
    pub input: InputConfig,
}

/// Why the settings cannot be used (the `epd` binary's usage errors, exit code 2).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ConfigError {
    /// A setting out of its range, or two that do not go together.
    #[error("{0}")]
    Setting(String),
    /// The depth-calibration table could not be read or is not one.
    #[error("--calibration {message}")]
    Calibration {
        /// The table file.
        path: PathBuf,
        /// What is wrong (the file name first).
        message: String,
    },
}

/// Checked settings of `epd estimate`.
#[derive(Clone, Debug)]
pub struct EstimateConfig {
    /// The estimator.
    pub method: Method,
    /// Nominal outer diameter (mm), when given.
    pub nominal_od_mm: Option<f64>,
    /// The estimator's options (loss, loss scale, range gate).
    pub options: EstimateOptions,
    /// The loss's name in reports.
    pub loss: String,
    /// How the inputs are read.
    pub input: InputConfig,
    /// The depth-calibration table, when given.
    pub calibration: Option<CalibrationTable>,
    /// Whether each residual is weighted by the table's 1/σᵢ.
    pub weighted: bool,
    /// Whether the geometry ahead is surveyed (see [`EstimateSettings::geometry`]).
    pub geometry: bool,
}

impl EstimateConfig {
    /// Check the settings and read the depth table; the error is the `epd` binary's usage
    /// message.
    pub fn new(a: &EstimateSettings) -> Result<Self, ConfigError> {
        let usage = |m: String| ConfigError::Setting(m);
        let min_range = a.min_range.unwrap_or(0.0);
        let max_range = a.max_range.unwrap_or(f64::INFINITY);
        if !(min_range >= 0.0 && max_range > min_range) {
            return Err(usage(format!(
                "--min-range {min_range} and --max-range {max_range}: need 0 ≤ min < max"
            )));
        }
        let nominal_od_mm = match a.nominal_od_in {
            None => None,
            Some(x) if x > 0.0 && x.is_finite() => Some(x * 25.4),
            Some(x) => {
                return Err(usage(format!(
                    "--nominal-od-in {x}: expected a diameter in inches > 0"
                )));
            }
        };
        let scale = a.loss_scale.unwrap_or(DEFAULT_LOSS_SCALE_M);
        let loss = Loss::from_name(&a.loss, scale)
            .map_err(|e| usage(format!("--loss/--loss-scale: {e}")))?;
        let mut options = EstimateOptions::default()
            .with_loss(loss)
            .map_err(|e| usage(e.to_string()))?
            .with_loss_scale(if a.loss_scale.is_some() {
                LossScale::Fixed
            } else {
                LossScale::Auto
            });
        if a.min_range.is_some() || a.max_range.is_some() {
            options = options
                .with_range_gate(min_range, max_range)
                .map_err(|e| usage(e.to_string()))?;
        }
        if a.unweighted && a.calibration.is_none() {
            return Err(usage(
                "--unweighted applies to --calibration (without a table every point weighs the same)"
                    .into(),
            ));
        }
        let calibration = match &a.calibration {
            None => None,
            Some(p) => {
                Some(
                    CalibrationTable::read(p).map_err(|message| ConfigError::Calibration {
                        path: p.clone(),
                        message,
                    })?,
                )
            }
        };
        Ok(EstimateConfig {
            method: a.method,
            nominal_od_mm,
            options,
            loss: loss.name().into(),
            input: a.input,
            weighted: calibration.is_some() && !a.unweighted,
            calibration,
            geometry: a.geometry,
        })
    }
}

/// Convert the points to metres in the sensor frame, in place, and check that the
/// unit is plausible for a camera inside a pipe: its points lie between 2 cm and 30 m
/// (median distance) from the sensor.
pub fn to_sensor_metres(
    points: &mut [[f64; 3]],
    units: Units,
    frame: InputFrame,
) -> Result<(), String> {
    let k = match units {
        Units::Metres => 1.0,
        Units::Millimetres => 1e-3,
    };
    for p in points.iter_mut() {
        let [x, y, z] = *p;
        *p = match frame {
            InputFrame::Sensor => [k * x, k * y, k * z],
            // X_sensor = Z_optical, Y_sensor = X_optical, Z_sensor = −Y_optical (a
            // reflection: the sensor frame is left-handed).
            InputFrame::Optical => [k * z, k * x, -k * y],
        };
    }
    check_units(points, units)
}

/// [`to_sensor_metres`] of borrowed points: borrowed back unchanged (no copy) when they
/// are already metres in the sensor frame, else converted in a copy.
pub fn sensor_metres(
    points: &[[f64; 3]],
    units: Units,
    frame: InputFrame,
) -> Result<Cow<'_, [[f64; 3]]>, String> {
    if units == Units::Metres && frame == InputFrame::Sensor {
        check_units(points, units)?;
        return Ok(Cow::Borrowed(points));
    }
    let mut owned = points.to_vec();
    to_sensor_metres(&mut owned, units, frame)?;
    Ok(Cow::Owned(owned))
}

/// The plausibility check of [`to_sensor_metres`] on points already converted.
fn check_units(points: &[[f64; 3]], units: Units) -> Result<(), String> {
    let stride = points.len().div_ceil(4096).max(1);
    let mut r: Vec<f64> = points
        .iter()
        .step_by(stride)
        .filter(|p| p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0))
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .collect();
    if r.is_empty() {
        return Ok(());
    }
    let mid = r.len() / 2;
    let (_, &mut median, _) = r.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    if median > MAX_MEDIAN_RANGE_M {
        return Err(match units {
            Units::Metres if median / 1e3 <= MAX_MEDIAN_RANGE_M => format!(
                "the points lie a median {median:.1} m from the sensor: the cloud looks like millimetres \
                 (the Helios2 SDK writes mm); pass --units mm"
            ),
            Units::Metres => format!(
                "the points lie a median {median:.3e} m from the sensor, too far even for \
                 millimetres: the coordinates are not read as written (a binary file's byte order \
                 or value type, a decimal comma, an extra leading column such as an index?)"
            ),
            Units::Millimetres => format!(
                "the points lie a median {median:.1} m from the sensor even read as millimetres: \
                 not a frame from inside a pipe"
            ),
        });
    }
    if median < MIN_MEDIAN_RANGE_M {
        return Err(match units {
            Units::Millimetres => format!(
                "read as millimetres, the points lie a median {:.1} mm from the sensor: the cloud looks like \
                 metres; drop --units mm",
                median * 1e3
            ),
            Units::Metres => format!(
                "the points lie a median {:.1} mm from the sensor: the cloud is not in metres \
                 (kilometres?) or not a frame from inside a pipe",
                median * 1e3
            ),
        });
    }
    Ok(())
}

/// Read one input (a file, or standard input for `-`) and convert its points to metres
/// in the sensor frame.
pub fn read_input(path: &Path, input: &InputConfig) -> Result<PointCloud, String> {
    let mut cloud = if path.as_os_str() == "-" {
        read_from(std::io::stdin().lock(), input.format, MAX_INPUT_BYTES)?
    } else {
        read_path(path)?
    };
    to_sensor_metres(&mut cloud.points, input.units, input.frame)?;
    Ok(cloud)
}

/// Whether a cloud has a per-point `intensity` (any case).
fn has_intensity(cloud: &PointCloud) -> bool {
    cloud
        .extra
        .iter()
        .any(|(name, _)| name.eq_ignore_ascii_case("intensity"))
}

/// The per-point `intensity` of a cloud (any case), or why there is none.
pub fn intensity(cloud: &PointCloud, why: &str) -> Result<Vec<f64>, String> {
    cloud
        .extra
        .iter()
        .find(|(name, _)| name.eq_ignore_ascii_case("intensity"))
        .map(|(_, v)| v.clone())
        .ok_or_else(|| {
            let have: Vec<&str> = cloud.extra.iter().map(|(n, _)| n.as_str()).collect();
            format!(
                "no per-point `intensity` in the file ({}); {why}",
                if have.is_empty() {
                    "it holds x, y, z only".to_string()
                } else {
                    format!("it holds x, y, z, {}", have.join(", "))
                }
            )
        })
}

/// What `--calibration` says when the input has no intensity.
pub const CALIBRATION_NEEDS_INTENSITY: &str = "--calibration needs one per point";

/// Read, filter and estimate one file.
pub fn estimate_file(path: &Path, cfg: &EstimateConfig) -> FileReport {
    let file = path.display().to_string();
    let run = || -> Result<FileEstimate, String> {
        let t0 = Instant::now();
        let cloud = read_input(path, &cfg.input)?;
        let read_ms = t0.elapsed().as_secs_f64() * 1e3;
        if cloud.points.is_empty() {
            return Err("the file holds no points".into());
        }
        let i = match &cfg.calibration {
            None => None,
            Some(_) => Some(intensity(&cloud, CALIBRATION_NEEDS_INTENSITY)?),
        };
        let camera = has_intensity(&cloud);
        let mut e = estimate_points(Cow::Owned(cloud.points), i.as_deref(), None, cfg, read_ms)?;
        e.intensity_without_table = camera && cfg.calibration.is_none();
        Ok(e)
    };
    FileReport {
        file,
        outcome: run(),
    }
}

/// Estimate from points already in metres in the sensor frame, as `epd estimate` does
/// for one file once read: the depth table's correction (which needs `intensity`, one
/// per point; borrowed points are copied then), the estimate, weighted by the table's σᵢ
/// or by `sigma` (one range standard deviation per point, m) when given, and the
/// report's context. `read_ms` is the time taken to get the points.
pub fn estimate_points(
    points: Cow<'_, [[f64; 3]]>,
    intensity: Option<&[f64]>,
    sigma: Option<&[f64]>,
    cfg: &EstimateConfig,
    read_ms: f64,
) -> Result<FileEstimate, String> {
    let n_read = points.len();
    let mut points = points;
    if cfg.calibration.is_some() {
        // The table moves the points: a copy of borrowed ones, before the clock starts.
        points = Cow::Owned(points.into_owned());
    }
    let t1 = Instant::now();
    // The measured ranges before the table moves the points: where the table observed
    // the camera's error is looked up by them (the bend's points, below).
    let raw_range_m: Option<Vec<f64>> =
        (cfg.calibration.is_some() && cfg.geometry).then(|| ranges(&points));
    let mut n_calibrated = None;
    let mut sigmas: Option<Cow<'_, [f64]>> = sigma.map(Cow::Borrowed);
    if let Some(cal) = &cfg.calibration {
        let (moved, table_sigmas) = correct_by_table(
            cal,
            cfg.weighted,
            points.to_mut(),
            intensity,
            sigma.is_some(),
        )?;
        n_calibrated = Some(moved);
        if let Some(s) = table_sigmas {
            sigmas = Some(Cow::Owned(s));
        }
    }
    // Invalid pixels (NaN, inf, zeros) are dropped and counted by the estimator; the
    // range gate keeps points by their model range (see EstimateOptions).
    let kept: &[[f64; 3]] = &points;
    let failed = |e: epd_core::EpdError| format!("{e} ({n_read} points read)");
    let survey = if cfg.geometry {
        Some(
            epd_core::segment::survey(kept, cfg.method, &cfg.options, &SegmentOptions::default())
                .map_err(failed)?,
        )
    } else {
        None
    };
    let mask = survey.as_ref().and_then(|s| straight_points(s, kept));
    let est = fit_straight(
        kept,
        sigmas.as_deref(),
        survey.as_ref(),
        mask.as_deref(),
        cfg,
    )
    .map_err(failed)?;
    let geometry = survey
        .as_ref()
        .map(|s| geometry_report(s, kept, raw_range_m.as_deref(), intensity, cfg));
    let elapsed_ms = t1.elapsed().as_secs_f64() * 1e3;
    Ok(FileEstimate {
        loss: (cfg.loss.clone(), radial_loss_scale_m(&est)),
        rms_residual_mm: straight_rms_mm(kept, mask.as_deref(), &est, cfg),
        n_out_of_range: est.n_out_of_gate,
        estimate: est,
        n_read,
        elapsed_ms,
        read_ms,
        nominal_od_mm: cfg.nominal_od_mm,
        n_calibrated,
        weighted: sigmas.is_some(),
        geometry,
        intensity_without_table: false,
    })
}

/// Which points are the straight section's (`straight_mask`, less the survey's margin),
/// when something lies ahead of it; `None` when nothing does.
fn straight_points(s: &epd_core::segment::Survey, points: &[[f64; 3]]) -> Option<Vec<bool>> {
    let end = s.segmentation.straight_until?;
    let margin = SegmentOptions::default().margin_m;
    Some(straight_mask(
        points,
        &s.segmentation.straight.params,
        end,
        margin,
    ))
}

/// Each point's distance from the sensor (m).
pub fn ranges(points: &[[f64; 3]]) -> Vec<f64> {
    points
        .iter()
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .collect()
}

/// The survey's report; with a depth table, the bend's values withheld where the table
/// did not observe most of its points ([`GeometryReport::check_bend_against_table`]):
/// `points` as surveyed, `raw_range_m` their ranges before the correction.
fn geometry_report(
    s: &epd_core::segment::Survey,
    points: &[[f64; 3]],
    raw_range_m: Option<&[f64]>,
    intensity: Option<&[f64]>,
    cfg: &EstimateConfig,
) -> GeometryReport {
    let mut g = GeometryReport::of(s);
    if let (Some(cal), Some(r), Some(i)) = (&cfg.calibration, raw_range_m, intensity) {
        g.check_bend_against_table(bend_table_coverage(s, points, r, i, &cal.table));
    }
    g
}

/// The depth table's correction in place: each point moved along its ray by the table's
/// offset at its range and `intensity`; with a weighting table also each point's σᵢ
/// (refused when per-point σ are `sigma_given` too). The number of points moved.
fn correct_by_table(
    cal: &CalibrationTable,
    weighted: bool,
    points: &mut [[f64; 3]],
    intensity: Option<&[f64]>,
    sigma_given: bool,
) -> Result<(usize, Option<Vec<f64>>), String> {
    let Some(i) = intensity else {
        return Err(format!(
            "no per-point `intensity` given; {CALIBRATION_NEEDS_INTENSITY}"
        ));
    };
    if !weighted {
        let moved = cal.table.correct(points, i).map_err(|e| e.to_string())?;
        return Ok((moved, None));
    }
    if sigma_given {
        return Err(
            "per-point σ given with a weighting depth table: give one or the other \
             (or the table unweighted)"
                .into(),
        );
    }
    let (moved, s) = cal
        .table
        .correct_with_sigmas(points, i)
        .map_err(|e| e.to_string())?;
    Ok((moved, Some(s)))
}

/// The estimate on the straight section's points (those `mask` keeps; all of them when
/// nothing lies ahead): unweighted, the survey's own straight estimate when there is a
/// survey; weighted by `sigmas` when given.
fn fit_straight(
    points: &[[f64; 3]],
    sigmas: Option<&[f64]>,
    survey: Option<&epd_core::segment::Survey>,
    mask: Option<&[bool]>,
    cfg: &EstimateConfig,
) -> Result<epd_core::Estimate, epd_core::EpdError> {
    match (sigmas, survey, mask) {
        // No straight section to fit on its own (in a bend, or its end too close): the
        // report withholds the estimate and says why; nothing more to fit.
        (_, Some(s), _) if s.segmentation.straight_withheld => Ok(s.segmentation.straight),
        // The survey's straight estimate is the (unweighted) estimate on the straight
        // section's points: all of them when nothing lies ahead.
        (None, Some(s), _) => Ok(s.segmentation.straight),
        (None, None, _) => estimate(points, cfg.method, &cfg.options),
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
        (Some(sig), _, None) => estimate_weighted(points, sig, cfg.method, &cfg.options),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Borrowed points in metres in the sensor frame are not copied; others are
    /// converted like `to_sensor_metres` does in place.
    #[test]
    fn sensor_metres_borrows_only_when_nothing_changes() {
        let pts = vec![[1.0, 0.2, -0.1], [2.0, -0.3, 0.25]];
        let same = sensor_metres(&pts, Units::Metres, InputFrame::Sensor).unwrap();
        assert!(matches!(same, Cow::Borrowed(p) if std::ptr::eq(p, pts.as_slice())));
        let mm: Vec<[f64; 3]> = pts
            .iter()
            .map(|p| [p[1] * 1e3, -p[2] * 1e3, p[0] * 1e3])
            .collect();
        let conv = sensor_metres(&mm, Units::Millimetres, InputFrame::Optical).unwrap();
        assert!(matches!(conv, Cow::Owned(_)));
        let mut inplace = mm.clone();
        to_sensor_metres(&mut inplace, Units::Millimetres, InputFrame::Optical).unwrap();
        assert_eq!(conv.as_ref(), inplace.as_slice());
        let e = sensor_metres(&mm, Units::Metres, InputFrame::Sensor).unwrap_err();
        assert!(e.contains("pass --units mm"), "{e}");
    }

    /// Millimetres are suggested only where they would explain the distances: coordinates
    /// a thousand times too far even for millimetres (a wrong byte order, a decimal comma,
    /// an index column) get the causes that could, not a hint that fails next.
    #[test]
    fn the_millimetre_hint_only_where_millimetres_fit() {
        let far: Vec<[f64; 3]> = (0..100).map(|i| [1e6 + i as f64, 10.0, 5.0]).collect();
        let e = sensor_metres(&far, Units::Metres, InputFrame::Sensor).unwrap_err();
        assert!(!e.contains("--units mm") && e.contains("byte order"), "{e}");
        let mm: Vec<[f64; 3]> = (0..100).map(|i| [1500.0 + i as f64, 10.0, 5.0]).collect();
        let e = sensor_metres(&mm, Units::Metres, InputFrame::Sensor).unwrap_err();
        assert!(e.contains("pass --units mm"), "{e}");
    }
}
