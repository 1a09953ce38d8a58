//! A calibration rig: frames recorded in a pipe of known diameter → the depth table
//! (`epd calibrate`): the settings as given and checked ([`RigSettings::check`]), and the
//! table with each frame's fitted pose ([`calibrate_rig`]).

use epd_core::calibration::{CalibrationFrame, CalibrationSettings, RigFrames, calibrate_rigs};
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

/// Passes of the alternating refinement of the rig's poses and the table by default
/// (`epd calibrate --passes`): the first fits the poses on the raw points, the others
/// refit them on the corrected points; the joint refinement follows. Measured where it
/// matters, the two-size table's transfer (`scenarios/calibration_transfer.toml` with
/// `passes` = 3, 8, 16: the 24" frames' mean-diameter error −0.49, −0.33, −0.32 mm,
/// 26" −0.15, −0.04, −0.04 mm): settled by 8, within 0.01 mm of 16.
pub const DEFAULT_PASSES: u32 = 8;

/// Most passes: each refits every rig frame, and the refinement has settled long before
/// 20 (docs/calibration.md measured up to 10), so more is a typing error.
pub const MAX_PASSES: u32 = 20;

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
    /// Incidence bins of the table (even in ln cos θ); 0: no incidence axis.
    pub incidence_bins: usize,
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
        let bins = self
            .range_bins
            .checked_mul(self.intensity_bins)
            .and_then(|b| b.checked_mul(self.incidence_bins.max(1)));
        if self.range_bins == 0
            || self.intensity_bins == 0
            || bins.is_none_or(|b| b > MAX_TABLE_BINS)
        {
            return usage(format!(
                "--range-bins {} × --intensity-bins {} × --incidence-bins {}: need at least 1 \
                 range and intensity bin, at most {MAX_TABLE_BINS} (2²⁰) bins",
                self.range_bins, self.intensity_bins, self.incidence_bins
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
            incidence_bins: self.incidence_bins,
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
    /// Each frame's pose fit on the known pipe, in the order given (its β the pose
    /// after the joint refinement).
    pub fits: Vec<Result<Estimate, EpdError>>,
    /// What the joint refinement of the poses did.
    pub joint: epd_core::calibration::JointOutcome,
}

/// The depth table of `frames` (points in the sensor frame, m, with their intensity),
/// the poses and the table refined together (`epd_core::calibration::calibrate`, ML-EPD
/// with the Cauchy loss from [`DEFAULT_LOSS_SCALE_M`], its scale from the residuals).
pub fn calibrate_rig(
    frames: &[CalibrationFrame<'_>],
    settings: &CalibrationSettings,
) -> Result<RigTable, EpdError> {
    calibrate_rig_sizes(
        &[RigFrames {
            known: settings.known,
            frames,
        }],
        settings,
    )
}

/// The depth table of rigs of several sizes ([`epd_core::calibration::calibrate_rigs`]):
/// each rig's frames fitted with its own known diameters, one table from all of them.
/// `settings.known` is ignored; the table's `known` is the first rig's.
pub fn calibrate_rig_sizes(
    rigs: &[RigFrames<'_>],
    settings: &CalibrationSettings,
) -> Result<RigTable, EpdError> {
    let options = EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", DEFAULT_LOSS_SCALE_M)?)?
        .with_loss_scale(LossScale::Auto);
    let cal = calibrate_rigs(rigs, settings, &options)?;
    let used = cal.fits.iter().filter(|f| f.is_ok()).count();
    let mut at = 0;
    let mut rig_list = Vec::with_capacity(rigs.len());
    for r in rigs {
        let n = cal.fits[at..at + r.frames.len()]
            .iter()
            .filter(|f| f.is_ok())
            .count();
        at += r.frames.len();
        rig_list.push((r.known, n));
    }
    let known = rigs.first().map_or(settings.known, |r| r.known);
    Ok(RigTable {
        table: CalibrationTable {
            table: cal.table,
            known,
            frames: used,
            n_observations: cal.n_observations as u64,
            incidence: cal.incidence,
            rigs: rig_list,
            spans: Some(cal.spans),
        },
        fits: cal.fits,
        joint: cal.joint,
    })
}

/// The most rigs a RIGS.toml may list: every rig's frames are held in memory together,
/// and 64 pipe sizes are more than a pipe schedule has between 2" and 48".
pub const MAX_RIGS: usize = 64;

/// One rig of a RIGS.toml as given.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RigEntry {
    known_id_mm: f64,
    #[serde(default)]
    known_dmin_mm: Option<f64>,
    files: Vec<std::path::PathBuf>,
}

/// A RIGS.toml as given.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RigsFile {
    rig: Vec<RigEntry>,
}

/// One rig of a RIGS.toml, checked: its known (Dmax, Dmin) (m) and its frame files
/// (resolved against the TOML file's folder).
#[derive(Clone, Debug, PartialEq)]
pub struct RigSpec {
    /// Known (Dmax, Dmin) (m).
    pub known: (f64, f64),
    /// The frame files.
    pub files: Vec<std::path::PathBuf>,
}

/// Parse a RIGS.toml's text: `[[rig]]` tables with `known_id_mm` (mm, > 0), optionally
/// `known_dmin_mm` (0 < Dmin ≤ Dmax), and `files` (at least one; relative paths taken
/// from `base`, the TOML file's folder); 1 to [`MAX_RIGS`] rigs. The error names the
/// rig (1 first), the key and what it must be.
pub fn parse_rigs(text: &str, base: &std::path::Path) -> Result<Vec<RigSpec>, ConfigError> {
    let bad = |m: String| ConfigError::Setting(m);
    let f: RigsFile = toml::from_str(text).map_err(|e| {
        bad(format!(
            "not a rigs file: {e}; expected [[rig]] tables with known_id_mm = D and files = \
             [\"frame.ply\", …]"
        ))
    })?;
    if f.rig.is_empty() || f.rig.len() > MAX_RIGS {
        return Err(bad(format!(
            "{} rigs: list 1 to {MAX_RIGS} [[rig]] tables",
            f.rig.len()
        )));
    }
    // A frame listed twice would count twice in the table (and be held twice in memory: a
    // 60 kB file listing one frame 5000 times had grown to 6.6 GB).
    let mut seen: std::collections::HashMap<std::path::PathBuf, usize> =
        std::collections::HashMap::new();
    for (k, r) in f.rig.iter().enumerate() {
        for p in &r.files {
            let p = if p.is_absolute() {
                p.clone()
            } else {
                base.join(p)
            };
            let key = p.canonicalize().unwrap_or(p);
            if let Some(first) = seen.insert(key.clone(), k + 1) {
                return Err(bad(format!(
                    "rig {}: `{}` is listed twice (also in rig {first}): list each frame once",
                    k + 1,
                    epd_io::name::shown(&key)
                )));
            }
        }
    }
    f.rig
        .into_iter()
        .enumerate()
        .map(|(k, r)| {
            let n = k + 1;
            let d_max = r.known_id_mm;
            let d_min = r.known_dmin_mm.unwrap_or(d_max);
            if !(d_max.is_finite() && d_max > 0.0) {
                return Err(bad(format!(
                    "rig {n}: known_id_mm = {d_max}: expected the pipe's inner diameter in mm \
                     (> 0)"
                )));
            }
            if !(d_min > 0.0 && d_min <= d_max) {
                return Err(bad(format!(
                    "rig {n}: known_dmin_mm = {d_min}: expected the minor inner diameter in \
                     mm, > 0 and at most known_id_mm = {d_max}"
                )));
            }
            if r.files.is_empty() {
                return Err(bad(format!("rig {n}: files = []: list at least one frame")));
            }
            Ok(RigSpec {
                known: (d_max * 1e-3, d_min * 1e-3),
                files: r
                    .files
                    .into_iter()
                    .map(|p| if p.is_absolute() { p } else { base.join(p) })
                    .collect(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rigs_files_are_read_relative_to_the_toml() {
        let r = parse_rigs(
            "[[rig]]\nknown_id_mm = 484\nfiles = [\"a.ply\", \"/x/b.ply\"]\n\
             [[rig]]\nknown_id_mm = 730\nknown_dmin_mm = 720\nfiles = [\"c/d.ply\"]\n",
            std::path::Path::new("/rigs"),
        )
        .unwrap();
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].known, (0.484, 0.484));
        assert_eq!(
            r[0].files,
            vec![
                std::path::PathBuf::from("/rigs/a.ply"),
                std::path::PathBuf::from("/x/b.ply")
            ]
        );
        assert_eq!(r[1].known, (0.73, 0.72));
        assert_eq!(r[1].files, vec![std::path::PathBuf::from("/rigs/c/d.ply")]);
    }

    #[test]
    fn bad_rigs_files_name_what_is_wrong() {
        let base = std::path::Path::new(".");
        for (text, says) in [
            ("", "not a rigs file"),
            ("[[rig]]\nfiles = [\"a.ply\"]\n", "known_id_mm"),
            (
                "[[rig]]\nknown_id_mm = -3\nfiles = [\"a\"]\n",
                "rig 1: known_id_mm = -3",
            ),
            (
                "[[rig]]\nknown_id_mm = 400\nfiles = [\"a\"]\n[[rig]]\nknown_id_mm = 500\nfiles = []\n",
                "rig 2: files = []",
            ),
            (
                "[[rig]]\nknown_id_mm = 400\nknown_dmin_mm = 500\nfiles = [\"a\"]\n",
                "at most known_id_mm",
            ),
            (
                "[[rig]]\nknown_id_mm = 400\nfiles = [\"a\"]\ncolour = 1\n",
                "colour",
            ),
            ("rig = []\n", "0 rigs"),
            (
                "[[rig]]\nknown_id_mm = 400\nfiles = [\"a\"]\n[[rig]]\nknown_id_mm = 500\nfiles = [\"./b\", \"a\"]\n",
                "rig 2: `./a` is listed twice (also in rig 1)",
            ),
        ] {
            let e = parse_rigs(text, base).unwrap_err().to_string();
            assert!(e.contains(says), "{text:?}: {e}");
        }
    }
}
