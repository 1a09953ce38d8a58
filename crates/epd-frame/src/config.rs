//! The settings of a frame's measurement as given (command-line flags, Python
//! arguments: [`EstimateSettings`]) and checked ([`EstimateConfig`]), and how the inputs
//! are read ([`InputConfig`]).

use std::path::PathBuf;

use epd_core::{EstimateOptions, Loss, LossScale, Method};

use crate::read::Format;
use crate::sampling::{Sampling, SamplingMethod};
use crate::table::CalibrationTable;

/// Seed scale of the first robust pass (m of range error) when no loss scale is given;
/// the scale is then re-estimated from the residuals (`LossScale::Auto`), so this value
/// only has to exceed the noise of a first fit: 5 cm is above the σ of every ToF camera
/// of the field notes (1–3 cm at their working ranges) and below a pipe's radius.
pub const DEFAULT_LOSS_SCALE_M: f64 = 0.05;

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
    /// The paper's sensor frame: X forward (optical axis), Y right, Z up (left-handed).
    Sensor,
    /// A camera's optical frame (Arena SDK, PCL, Open3D, ROS `*_optical_frame`): X right,
    /// Y down, Z forward.
    Optical,
    /// A ROS body frame, FLU (REP 103: `base_link`, `camera_link`): X forward, Y left, Z up.
    /// Read as [`Sensor`](Self::Sensor) it would mirror the pose (roll, yaw and δy change
    /// sign) while the diameters stay right, so nothing in the data could tell.
    Body,
}

/// How the inputs are read, checked.
#[derive(Clone, Copy, Debug)]
pub struct InputConfig {
    /// Length unit of the inputs.
    pub units: Units,
    /// Coordinate frame of the inputs.
    pub frame: InputFrame,
    /// Whether `frame` was given (`--frame`) rather than the default: when it was not, a
    /// bag's cloud whose `frame_id` ends in `_optical_frame` is read in the optical frame
    /// (REP 103), see [`InputConfig::frame_of`].
    pub frame_given: bool,
    /// Format of standard input (`None`: detected from its first bytes).
    pub format: Option<Format>,
}

/// The `frame_id` suffix of a camera's optical frame (REP 103: `camera_color_optical_frame`).
pub const OPTICAL_FRAME_SUFFIX: &str = "_optical_frame";

impl InputConfig {
    /// The frame of a cloud whose header names `frame_id`: [`InputFrame::Optical`] for a
    /// `frame_id` ending in `_optical_frame` unless a frame was given, else [`Self::frame`].
    pub fn frame_of(&self, frame_id: &str) -> InputFrame {
        if !self.frame_given && frame_id.ends_with(OPTICAL_FRAME_SUFFIX) {
            InputFrame::Optical
        } else {
            self.frame
        }
    }
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
    /// Fit at most this many points of each frame, chosen by `sampling`
    /// ([`crate::sampling`]); `None`: every point.
    pub max_points: Option<usize>,
    /// How the `max_points` points are chosen.
    pub sampling: SamplingMethod,
}

impl Default for EstimateSettings {
    /// `epd estimate`'s defaults: ML-EPD, the Cauchy loss with its scale from the
    /// residuals, no range gate, no table, the scene read; metres in the sensor frame.
    fn default() -> Self {
        Self {
            method: Method::MlEpd,
            min_range: None,
            max_range: None,
            nominal_od_in: None,
            loss: "cauchy".into(),
            loss_scale: None,
            calibration: None,
            unweighted: false,
            geometry: true,
            input: InputConfig {
                units: Units::Metres,
                frame: InputFrame::Sensor,
                frame_given: false,
                format: None,
            },
            max_points: None,
            sampling: SamplingMethod::default(),
        }
    }
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
    /// The choice of the points fitted, with `--max-points` ([`crate::sampling`]).
    pub sampling: Option<Sampling>,
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
            // Finite in millimetres too (1e308 in is not).
            Some(x) if x > 0.0 && (x * 25.4).is_finite() => Some(x * 25.4),
            Some(x) => {
                return Err(usage(format!(
                    "--nominal-od-in {x:e}: expected a diameter in inches > 0 (and finite in \
                     millimetres)"
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
        let sampling = a
            .max_points
            .map(|n| Sampling::new(n, a.sampling))
            .transpose()
            .map_err(|e| usage(e.to_string()))?;
        Ok(EstimateConfig {
            sampling,
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
