//! The depth-calibration table on disk: JSON written by `epd calibrate`, read by
//! `epd estimate --calibration`.
//!
//! ```json
//! { "format": "epd-depth-table", "version": 1,
//!   "known_d_max_mm": 584.2, "known_d_min_mm": 584.2, "frames": 20, "n_observations": 2400000,
//!   "range_m": { "lo": 0.5, "hi": 2.0, "bins": 30 },
//!   "log_intensity": { "lo": 2.1, "hi": 8.3, "bins": 12 },
//!   "empty_bins": "nearest filled bin of the same range row, else the nearest filled row",
//!   "offset_mm": [[…12 values…], …30 rows…], "spread_mm": [[…]], "count": [[…]] }
//! ```
//! Rows are range bins, columns intensity bins (natural log of the camera's intensity).

use std::path::Path;

use epd_core::DepthTable;
use epd_core::calibration::Axis;
use serde::{Deserialize, Serialize};

use crate::input::CALIBRATION_NEEDS_INTENSITY;

/// The `format` value of a table file.
pub const FORMAT: &str = "epd-depth-table";
/// The `version` this reader understands.
pub const VERSION: u32 = 1;

/// One axis of the table as written.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisFile {
    lo: f64,
    hi: f64,
    bins: usize,
}

/// The file's contents.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct TableFile {
    format: String,
    version: u32,
    known_d_max_mm: f64,
    known_d_min_mm: f64,
    frames: usize,
    n_observations: u64,
    range_m: AxisFile,
    log_intensity: AxisFile,
    empty_bins: String,
    offset_mm: Vec<Vec<f64>>,
    spread_mm: Vec<Vec<f64>>,
    count: Vec<Vec<u64>>,
}

/// A table with what it was made from.
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationTable {
    /// The table.
    pub table: DepthTable,
    /// The known diameters of the calibration pipe (m).
    pub known: (f64, f64),
    /// Frames it was made from.
    pub frames: usize,
    /// Point observations behind it.
    pub n_observations: u64,
}

fn rows<T: Copy>(v: &[T], n: usize) -> Vec<Vec<T>> {
    v.chunks(n.max(1)).map(|c| c.to_vec()).collect()
}

impl CalibrationTable {
    /// The table's correction in place: each point (SCS, m) moved along its ray by the
    /// table's offset at its range and `intensity`; when `weighted`, also each point's σᵢ
    /// (refused when per-point σ are `sigma_given` too). The number of points moved.
    pub fn correct_points(
        &self,
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
            let moved = self.table.correct(points, i).map_err(|e| e.to_string())?;
            return Ok((moved, None));
        }
        if sigma_given {
            return Err(
                "per-point σ given with a weighting depth table: give one or the other \
                 (or the table unweighted)"
                    .into(),
            );
        }
        let (moved, s) = self
            .table
            .correct_with_sigmas(points, i)
            .map_err(|e| e.to_string())?;
        Ok((moved, Some(s)))
    }

    /// The JSON text (pretty-printed).
    pub fn to_json(&self) -> String {
        let ni = self.table.log_intensity.n;
        let axis = |a: &Axis| AxisFile {
            lo: a.lo,
            hi: a.hi,
            bins: a.n,
        };
        let mm = |v: &[f64]| rows(&v.iter().map(|x| x * 1e3).collect::<Vec<_>>(), ni);
        let f = TableFile {
            format: FORMAT.into(),
            version: VERSION,
            known_d_max_mm: self.known.0 * 1e3,
            known_d_min_mm: self.known.1 * 1e3,
            frames: self.frames,
            n_observations: self.n_observations,
            range_m: axis(&self.table.range),
            log_intensity: axis(&self.table.log_intensity),
            empty_bins: "nearest filled bin of the same range row, else the nearest filled row"
                .into(),
            offset_mm: mm(&self.table.offset_m),
            spread_mm: mm(&self.table.spread_m),
            count: rows(&self.table.count, ni),
        };
        // Serialising plain numbers and strings cannot fail; non-finite values would be
        // written as null and refused on reading.
        serde_json::to_string_pretty(&f).unwrap_or_default()
    }

    /// Parse and check a table file's text.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let f: TableFile =
            serde_json::from_str(text).map_err(|e| format!("not a depth table: {e}"))?;
        if f.format != FORMAT {
            return Err(format!(
                "not a depth table: `format` is {:?}, expected {FORMAT:?}",
                f.format
            ));
        }
        if f.version != VERSION {
            return Err(format!(
                "depth table version {} is not supported (this epd reads version {VERSION})",
                f.version
            ));
        }
        let axis = |a: AxisFile| Axis {
            lo: a.lo,
            hi: a.hi,
            n: a.bins,
        };
        let ni = f.log_intensity.bins;
        let flat = |name: &str, v: &[Vec<f64>]| -> Result<Vec<f64>, String> {
            if v.iter().any(|r| r.len() != ni) {
                return Err(format!(
                    "depth table: every row of `{name}` needs {ni} values (one per intensity bin)"
                ));
            }
            Ok(v.iter().flatten().map(|x| x * 1e-3).collect())
        };
        if f.count.iter().any(|r| r.len() != ni) {
            return Err(format!(
                "depth table: every row of `count` needs {ni} values (one per intensity bin)"
            ));
        }
        let table = DepthTable {
            range: axis(f.range_m),
            log_intensity: axis(f.log_intensity),
            offset_m: flat("offset_mm", &f.offset_mm)?,
            spread_m: flat("spread_mm", &f.spread_mm)?,
            count: f.count.into_iter().flatten().collect(),
        };
        table.validate().map_err(|e| format!("depth table: {e}"))?;
        let ok = |d: f64| d.is_finite() && d > 0.0;
        if !(ok(f.known_d_max_mm) && ok(f.known_d_min_mm) && f.known_d_min_mm <= f.known_d_max_mm) {
            return Err(format!(
                "depth table: known diameters {} / {} mm: need 0 < Dmin ≤ Dmax",
                f.known_d_max_mm, f.known_d_min_mm
            ));
        }
        Ok(Self {
            table,
            known: (f.known_d_max_mm * 1e-3, f.known_d_min_mm * 1e-3),
            frames: f.frames,
            n_observations: f.n_observations,
        })
    }

    /// Read a table file: a regular file of at most 64 MiB.
    pub fn read(path: &Path) -> Result<Self, String> {
        use std::io::Read;
        const MAX: u64 = 64 << 20;
        let name = path.display();
        let meta = std::fs::metadata(path).map_err(|e| format!("{name}: {e}"))?;
        if !meta.is_file() {
            return Err(format!("{name}: not a regular file"));
        }
        let mut text = String::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX + 1).read_to_string(&mut text))
            .map_err(|e| format!("{name}: {e}"))?;
        if text.len() as u64 > MAX {
            return Err(format!("{name}: larger than 64 MiB: not a depth table"));
        }
        Self::from_json(&text).map_err(|e| format!("{name}: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use epd_core::calibration::{Observation, TableBins};

    fn table() -> CalibrationTable {
        let obs: Vec<Observation> = (0..4000)
            .map(|k| Observation {
                model_range_m: 0.5 + 1.5 * (k % 100) as f64 / 100.0,
                intensity: 1.0 + (k / 100) as f64,
                offset_m: 0.001 * (k % 7) as f64,
            })
            .collect();
        let bins = TableBins::spanning(&obs, 5, 3).unwrap();
        CalibrationTable {
            table: DepthTable::build(&obs, &bins).unwrap(),
            known: (0.5842, 0.5842),
            frames: 3,
            n_observations: 4000,
        }
    }

    #[test]
    fn round_trip() {
        let t = table();
        let back = CalibrationTable::from_json(&t.to_json()).unwrap();
        assert_eq!(back.table.count, t.table.count);
        assert_eq!(back.frames, 3);
        for (a, b) in back.table.offset_m.iter().zip(&t.table.offset_m) {
            assert!((a - b).abs() < 1e-15);
        }
    }

    #[test]
    fn damaged_files_are_refused_with_a_reason() {
        let text = table().to_json();
        for (from, to, says) in [
            ("epd-depth-table", "something-else", "`format`"),
            ("\"version\": 1", "\"version\": 7", "version 7"),
            ("\"bins\": 3", "\"bins\": 4", "needs 4 values"),
            ("\"bins\": 5", "\"bins\": 6", "offsets"),
        ] {
            let bad = text.replacen(from, to, 1);
            let e = CalibrationTable::from_json(&bad).unwrap_err();
            assert!(e.contains(says), "{from} → {to}: {e}");
        }
        assert!(
            CalibrationTable::from_json("{")
                .unwrap_err()
                .contains("not a depth table")
        );
        assert!(
            CalibrationTable::from_json(&text.replacen(
                "\"offset_mm\": [",
                "\"offset_mm\": [[null],",
                1
            ))
            .is_err()
        );
    }
}
