//! A calibration rig: frames recorded in a pipe of known diameter → the depth table
//! (`epd calibrate`): the settings as given and checked ([`RigSettings::check`]), and the
//! table with each frame's fitted pose ([`calibrate_rig`]).

use epd_core::calibration::{CalibrationFrame, CalibrationSettings, calibrate};
use epd_core::{EpdError, Estimate, EstimateOptions, Loss, LossScale};

use crate::config::{ConfigError, DEFAULT_LOSS_SCALE_M};
use crate::table::CalibrationTable;

/// The most bins a table may have: 2²⁰, about 3 000 times the default 30 × 12, so a
/// table stays a few tens of MB in memory whatever its bins are asked to be; the table
/// file's reader accepts as many ([`epd_core::calibration::MAX_TABLE_BINS`]).
pub const MAX_TABLE_BINS: usize = epd_core::calibration::MAX_TABLE_BINS;

/// The fewest points a bin needs to measure a mean and a spread: with n = 5 the spread's
/// relative standard error is 1/√(2(n − 1)) ≈ 35 %, the loosest a weight may be.
pub const MIN_BIN_COUNT: usize = 5;

/// The settings of `epd calibrate` as given (flags), before [`RigSettings::check`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigSettings {
    /// The known inner diameter (mm); the major one when `known_dmin_mm` is given.
    pub known_id_mm: f64,
    /// The known minor inner diameter (mm) of an oval pipe.
    pub known_dmin_mm: Option<f64>,
    /// Use the points whose ray meets the known wall at least this far (m).
    pub min_range: f64,
    /// … and at most this far (m).
    pub max_range: f64,
    /// Range bins of the table.
    pub range_bins: usize,
    /// Intensity bins of the table (even in log-intensity).
    pub intensity_bins: usize,
    /// A bin with fewer points is empty and takes the nearest filled bin's values.
    pub min_count: usize,
    /// Passes of the alternating refinement of the poses and the table.
    pub passes: u32,
}

impl RigSettings {
    /// Check the settings; the error names the flag, its value and the range it must lie in.
    pub fn check(&self) -> Result<CalibrationSettings, ConfigError> {
        let usage = |m: String| Err(ConfigError::Setting(m));
        let d_max = self.known_id_mm * 1e-3;
        let d_min = self.known_dmin_mm.unwrap_or(self.known_id_mm) * 1e-3;
        if !(self.known_id_mm > 0.0 && self.known_id_mm.is_finite()) {
            return usage(format!(
                "--known-id-mm {}: expected the pipe's inner diameter in mm (> 0)",
                self.known_id_mm
            ));
        }
        if !(d_min > 0.0 && d_min <= d_max) {
            return usage(format!(
                "--known-dmin-mm {}: expected the minor inner diameter in mm, > 0 and at most \
                 --known-id-mm {}",
                d_min * 1e3,
                self.known_id_mm
            ));
        }
        if !(self.min_range >= 0.0 && self.max_range > self.min_range && self.max_range.is_finite())
        {
            return usage(format!(
                "--min-range {} and --max-range {}: need 0 ≤ min < max",
                self.min_range, self.max_range
            ));
        }
        let bins = self.range_bins.checked_mul(self.intensity_bins);
        if self.range_bins == 0
            || self.intensity_bins == 0
            || bins.is_none_or(|b| b > MAX_TABLE_BINS)
        {
            return usage(format!(
                "--range-bins {} × --intensity-bins {}: need at least 1 each, at most \
                 {MAX_TABLE_BINS} (2²⁰) bins",
                self.range_bins, self.intensity_bins
            ));
        }
        if self.min_count < MIN_BIN_COUNT {
            return usage(format!(
                "--min-count {}: a bin needs at least {MIN_BIN_COUNT} points to measure a mean \
                 and a spread",
                self.min_count
            ));
        }
        Ok(CalibrationSettings {
            known: (d_max, d_min),
            gate: (self.min_range, self.max_range),
            bins: (self.range_bins, self.intensity_bins),
            min_count: self.min_count,
            passes: self.passes as usize,
        })
    }
}

/// The table of a rig and how each of its frames was fitted.
#[derive(Clone, Debug)]
pub struct RigTable {
    /// The table, with the known diameters and the frames whose fit it used.
    pub table: CalibrationTable,
    /// Each frame's pose fit on the known pipe, in the order given.
    pub fits: Vec<Result<Estimate, EpdError>>,
}

/// The depth table of `frames` (points in the sensor frame, m, with their intensity),
/// the poses and the table refined together (`epd_core::calibration::calibrate`, ML-EPD
/// with the Cauchy loss from [`DEFAULT_LOSS_SCALE_M`], its scale from the residuals).
pub fn calibrate_rig(
    frames: &[CalibrationFrame<'_>],
    settings: &CalibrationSettings,
) -> Result<RigTable, EpdError> {
    let options = EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", DEFAULT_LOSS_SCALE_M)?)?
        .with_loss_scale(LossScale::Auto);
    let cal = calibrate(frames, settings, &options)?;
    let used = cal.fits.iter().filter(|f| f.is_ok()).count();
    Ok(RigTable {
        table: CalibrationTable {
            table: cal.table,
            known: settings.known,
            frames: used,
            n_observations: cal.n_observations as u64,
        },
        fits: cal.fits,
    })
}
