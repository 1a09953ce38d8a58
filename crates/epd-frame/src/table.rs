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
//!
//! Version 2 (`epd calibrate` writes it; version 1 is still read, and works as before)
//! adds what the table observed and the incidence axis:
//!
//! ```json
//! { …version 1's keys, "version": 2,
//!   "rigs": [ { "known_d_max_mm": 484.0, "known_d_min_mm": 484.0, "frames": 6 }, … ],
//!   "support": { "range_m": [0.5, 2.0], "intensity": [9.1, 980.0],
//!                "cos_incidence": [0.11, 0.52] },
//!   "incidence": { "log_cos_incidence": { "lo": -2.2, "hi": -0.6, "bins": 16 },
//!                  "offset_mm": [[…]], "spread_mm": [[…]], "se_mm": [[…]],
//!                  "count": [[…]], "support": [[…]] } }
//! ```
//! The incidence table's rows are range bins, each of intensity bins × incidence bins
//! values (incidence fastest); `support` is 0 outside (values written as 0, read as
//! none), 1 observed, 2 bridged (`epd_core::calibration::IncidenceTable`). `se_mm` is
//! each bin mean's standard error, shared by every point the bin corrects.

use std::path::Path;

use epd_core::DepthTable;
use epd_core::calibration::{Axis, IncidenceTable, MAX_TABLE_BINS, Support};
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;

use crate::input::CALIBRATION_NEEDS_INTENSITY;

/// The `format` value of a table file.
pub const FORMAT: &str = "epd-depth-table";
/// The `version` written: 2 (the rigs, the support and the incidence table); this reader
/// also reads version 1.
pub const VERSION: u32 = 2;

/// The largest table file read (bytes): what `epd calibrate` writes for the largest
/// table it makes ([`MAX_TABLE_BINS`] bins, one range bin each, every value of the
/// longest form serde_json writes: 24 characters, indented by 6 and followed by `,\n`,
/// 3 values a bin; 3 rows of 12 bytes of brackets each) and its version-2 incidence table
/// of as many bins again (5 values a bin, 5 rows of brackets), plus 4 KiB for the rest:
/// about 369 MB. Anything larger is not a table `epd calibrate` could have written.
pub const MAX_TABLE_FILE_BYTES: u64 =
    4096 + (MAX_TABLE_BINS as u64) * (BYTES_PER_VALUE * 8 + BYTES_PER_ROW * 8);

/// Bytes of one value in a written table at most (see [`MAX_TABLE_FILE_BYTES`]).
const BYTES_PER_VALUE: u64 = 6 + 24 + 2;
/// Bytes of one row's brackets in a written table at most.
const BYTES_PER_ROW: u64 = 12;

/// One axis of the table as written.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisFile {
    lo: f64,
    hi: f64,
    bins: usize,
}

/// One rig as written.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    known_d_max_mm: f64,
    known_d_min_mm: f64,
    frames: usize,
}

/// The spans observed, as written.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SpansFile {
    range_m: [f64; 2],
    intensity: [f64; 2],
    cos_incidence: [f64; 2],
}

/// The support a version-2 table observed, checked: each span finite with lo ≤ hi, the
/// ranges and intensities ≥ 0 and the incidence cosines within [0, 1] (a reversed span had
/// been read as is, every point then outside it).
fn check_spans(s: SpansFile) -> Result<[(f64, f64); 3], String> {
    let spans = [
        ("range_m", s.range_m, (0.0, f64::INFINITY)),
        ("intensity", s.intensity, (0.0, f64::INFINITY)),
        ("cos_incidence", s.cos_incidence, (0.0, 1.0)),
    ];
    for (name, [lo, hi], (min, max)) in spans {
        if !(lo.is_finite() && hi.is_finite() && min <= lo && lo <= hi && hi <= max) {
            return Err(format!(
                "depth table: support.{name} = [{lo}, {hi}]: need finite {min} ≤ lo ≤ hi ≤ {max}"
            ));
        }
    }
    Ok(spans.map(|(_, [lo, hi], _)| (lo, hi)))
}

/// The incidence table as written.
#[derive(Clone, Debug, Serialize)]
struct IncidenceFile {
    log_cos_incidence: AxisFile,
    offset_mm: Vec<Vec<f64>>,
    spread_mm: Vec<Vec<f64>>,
    se_mm: Vec<Vec<f64>>,
    count: Vec<Vec<u64>>,
    support: Vec<Vec<u8>>,
}

/// The incidence table as read (values left as JSON text until the axes are checked).
#[derive(Debug, Deserialize)]
struct IncidenceHeader<'a> {
    log_cos_incidence: AxisFile,
    #[serde(borrow)]
    offset_mm: &'a RawValue,
    #[serde(borrow)]
    spread_mm: &'a RawValue,
    #[serde(borrow)]
    se_mm: &'a RawValue,
    #[serde(borrow)]
    count: &'a RawValue,
    #[serde(borrow)]
    support: &'a RawValue,
}

/// The file's contents, as written.
#[derive(Clone, Debug, Serialize)]
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
    rigs: Vec<RigFile>,
    #[serde(skip_serializing_if = "Option::is_none")]
    support: Option<SpansFile>,
    #[serde(skip_serializing_if = "Option::is_none")]
    incidence: Option<IncidenceFile>,
}

/// The file's contents as read: the bins' values are left as JSON text until the axes
/// are checked, so that nothing is allocated for bins beyond [`MAX_TABLE_BINS`].
#[derive(Debug, Deserialize)]
struct TableHeader<'a> {
    format: String,
    version: u32,
    known_d_max_mm: f64,
    known_d_min_mm: f64,
    frames: usize,
    n_observations: u64,
    range_m: AxisFile,
    log_intensity: AxisFile,
    #[allow(dead_code)]
    empty_bins: String,
    #[serde(borrow)]
    offset_mm: &'a RawValue,
    #[serde(borrow)]
    spread_mm: &'a RawValue,
    #[serde(borrow)]
    count: &'a RawValue,
    #[serde(default)]
    rigs: Option<Vec<RigFile>>,
    #[serde(default)]
    support: Option<SpansFile>,
    #[serde(default, borrow)]
    incidence: Option<IncidenceHeader<'a>>,
}

/// A JSON array of at most `rows` arrays of exactly `cols` values each, read into one
/// flat vector (row after row) with no more than `rows × cols` values allocated.
struct Rows<T> {
    name: &'static str,
    rows: usize,
    cols: usize,
    out: Vec<T>,
}

impl<T> Rows<T> {
    fn new(name: &'static str, rows: usize, cols: usize) -> Self {
        Self {
            name,
            rows,
            cols,
            out: Vec::new(),
        }
    }

    /// Parse `raw` (`[[…], …]`): the values, or why not (`name` and its limit).
    fn read(mut self, raw: &RawValue) -> Result<Vec<T>, String>
    where
        T: for<'de> Deserialize<'de>,
    {
        let mut de = serde_json::Deserializer::from_str(raw.get());
        serde::de::DeserializeSeed::deserialize(&mut self, &mut de)
            .map_err(|e| format!("depth table: `{}`: {e}", self.name))?;
        Ok(self.out)
    }
}

impl<'de, T: Deserialize<'de>> serde::de::DeserializeSeed<'de> for &mut Rows<T> {
    type Value = ();

    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_seq(self)
    }
}

impl<'de, T: Deserialize<'de>> serde::de::Visitor<'de> for &mut Rows<T> {
    type Value = ();

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "an array of rows of {} values", self.cols)
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        use serde::de::Error;
        self.out.reserve_exact(self.rows.saturating_mul(self.cols));
        let mut row = 0;
        while seq
            .next_element_seed(Row {
                cols: self.cols,
                out: &mut self.out,
            })?
            .is_some()
        {
            row += 1;
            if row > self.rows {
                return Err(A::Error::custom(format!(
                    "more than {} rows (one per range bin)",
                    self.rows
                )));
            }
        }
        Ok(())
    }
}

/// One row of [`Rows`]: exactly `cols` values, appended to `out`.
struct Row<'o, T> {
    cols: usize,
    out: &'o mut Vec<T>,
}

impl<'de, T: Deserialize<'de>> serde::de::DeserializeSeed<'de> for Row<'_, T> {
    type Value = ();

    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_seq(self)
    }
}

impl<'de, T: Deserialize<'de>> serde::de::Visitor<'de> for Row<'_, T> {
    type Value = ();

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "a row of {} values", self.cols)
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        use serde::de::Error;
        let mut n = 0;
        while let Some(v) = seq.next_element::<T>()? {
            n += 1;
            if n > self.cols {
                break;
            }
            self.out.push(v);
        }
        if n != self.cols {
            return Err(A::Error::custom(format!(
                "every row needs {} values (one per intensity bin)",
                self.cols
            )));
        }
        Ok(())
    }
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
    /// The range × intensity × incidence table (version 2), used in place of `table`
    /// to correct a frame when present.
    pub incidence: Option<IncidenceTable>,
    /// Each rig's known (Dmax, Dmin) (m) and frames used (version 1: the one rig of
    /// `known`).
    pub rigs: Vec<((f64, f64), usize)>,
    /// The spans the rigs' observations covered: model range (m), intensity, cos θ,
    /// each (min, max); `None` for a version-1 table.
    pub spans: Option<[(f64, f64); 3]>,
}

/// The incidence table of a version-2 file, its axes (range and intensity the same as
/// the plain table's) checked before its values are read.
fn read_incidence(h: &IncidenceHeader<'_>, plain: &DepthTable) -> Result<IncidenceTable, String> {
    let nr = plain.range.n;
    let nc = h.log_cos_incidence.bins;
    let per = plain
        .log_intensity
        .n
        .checked_mul(nc)
        .filter(|&p| nc > 0 && p.checked_mul(nr).is_some_and(|c| c <= MAX_TABLE_BINS))
        .ok_or_else(|| {
            format!(
                "depth table: incidence table of {nr} × {} × {nc} bins: need at least 1 \
                 incidence bin and at most {MAX_TABLE_BINS} (2²⁰) bins in all",
                plain.log_intensity.n
            )
        })?;
    let mm = |v: Vec<f64>| v.into_iter().map(|x| x * 1e-3).collect::<Vec<_>>();
    let support: Vec<Support> = Rows::<u8>::new("incidence.support", nr, per)
        .read(h.support)?
        .into_iter()
        .map(|c| {
            Support::from_code(c)
                .ok_or_else(|| format!("depth table: incidence support {c}: expected 0, 1 or 2"))
        })
        .collect::<Result<_, _>>()?;
    let outside_nan = |v: Vec<f64>| -> Vec<f64> {
        v.into_iter()
            .zip(&support)
            .map(|(x, s)| if *s == Support::Outside { f64::NAN } else { x })
            .collect()
    };
    let t = IncidenceTable {
        range: plain.range,
        log_intensity: plain.log_intensity,
        log_cos_incidence: Axis {
            lo: h.log_cos_incidence.lo,
            hi: h.log_cos_incidence.hi,
            n: nc,
        },
        offset_m: outside_nan(mm(
            Rows::new("incidence.offset_mm", nr, per).read(h.offset_mm)?
        )),
        spread_m: outside_nan(mm(
            Rows::new("incidence.spread_mm", nr, per).read(h.spread_mm)?
        )),
        se_m: outside_nan(mm(Rows::new("incidence.se_mm", nr, per).read(h.se_mm)?)),
        count: Rows::new("incidence.count", nr, per).read(h.count)?,
        support,
    };
    t.validate()
        .map_err(|e| format!("depth table: incidence table: {e}"))?;
    Ok(t)
}

fn rows<T: Copy>(v: &[T], n: usize) -> Vec<Vec<T>> {
    v.chunks(n.max(1)).map(|c| c.to_vec()).collect()
}

impl CalibrationTable {
    /// A range × intensity table alone, as version 1 held it: `table` made from `frames`
    /// frames and `n_observations` points of a rig of known (Dmax, Dmin) `known` (m),
    /// without an incidence table, a list of rigs or the spans they covered.
    pub fn plain(table: DepthTable, known: (f64, f64), frames: usize, n_observations: u64) -> Self {
        Self {
            table,
            known,
            frames,
            n_observations,
            incidence: None,
            rigs: Vec::new(),
            spans: None,
        }
    }

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
        if points.len() == i.len() {
            self.check_axes(points, i)?;
        }
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

    /// The incidence table's correction in place ([`IncidenceTable::correct`]): `cos` the
    /// cos θ of each point's ray at the fitted wall. Refused as [`Self::correct_points`]
    /// for a frame of another camera.
    pub fn correct_with_incidence(
        &self,
        table: &IncidenceTable,
        points: &mut [[f64; 3]],
        intensity: &[f64],
        cos: &[f64],
    ) -> Result<epd_core::calibration::Correction, String> {
        if points.len() == intensity.len() {
            self.check_axes(points, intensity)?;
        }
        table
            .correct(points, intensity, cos)
            .map_err(|e| e.to_string())
    }

    /// An error when the frame has valid points but none of them lies within the
    /// table's axes ([`DepthTable::within_axes`]): the table was made for another camera
    /// or rig, and its correction there would be its edge bins' guess for every point.
    fn check_axes(&self, points: &[[f64; 3]], intensity: &[f64]) -> Result<(), String> {
        let (valid, inside) = self.table.within_axes(points, intensity);
        if valid == 0 || inside > 0 {
            return Ok(());
        }
        let (r, li) = (&self.table.range, &self.table.log_intensity);
        Err(format!(
            "none of the frame's {valid} valid points lies within the depth table's axes \
             (range {:.3} to {:.3} m, intensity {:.4e} to {:.4e}): the table was made with \
             another camera or rig; make one for this camera with `epd calibrate`",
            r.lo,
            r.hi,
            li.lo.exp(),
            li.hi.exp()
        ))
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
            rigs: self
                .rigs
                .iter()
                .map(|&((a, b), frames)| RigFile {
                    known_d_max_mm: a * 1e3,
                    known_d_min_mm: b * 1e3,
                    frames,
                })
                .collect(),
            support: self.spans.map(|s| SpansFile {
                range_m: [s[0].0, s[0].1],
                intensity: [s[1].0, s[1].1],
                cos_incidence: [s[2].0, s[2].1],
            }),
            incidence: self.incidence.as_ref().map(|t| {
                let per = t.log_intensity.n * t.log_cos_incidence.n;
                let inside = |v: &[f64], scale: f64| {
                    let vals: Vec<f64> = v
                        .iter()
                        .zip(&t.support)
                        .map(|(x, s)| {
                            if *s == Support::Outside {
                                0.0
                            } else {
                                x * scale
                            }
                        })
                        .collect();
                    rows(&vals, per)
                };
                IncidenceFile {
                    log_cos_incidence: axis(&t.log_cos_incidence),
                    offset_mm: inside(&t.offset_m, 1e3),
                    spread_mm: inside(&t.spread_m, 1e3),
                    se_mm: inside(&t.se_m, 1e3),
                    count: rows(&t.count, per),
                    support: rows(&t.support.iter().map(|s| *s as u8).collect::<Vec<_>>(), per),
                }
            }),
        };
        // Serialising plain numbers and strings cannot fail; non-finite values would be
        // written as null and refused on reading.
        serde_json::to_string_pretty(&f).unwrap_or_default()
    }

    /// Parse and check a table file's text (a UTF-8 byte-order mark first is skipped).
    /// The axes are checked before any bin's value is read: at most [`MAX_TABLE_BINS`]
    /// bins.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let f: TableHeader<'_> =
            serde_json::from_str(text).map_err(|e| format!("not a depth table: {e}"))?;
        if f.format != FORMAT {
            return Err(format!(
                "not a depth table: `format` is {:?}, expected {FORMAT:?}",
                f.format.chars().take(64).collect::<String>()
            ));
        }
        if f.version != 1 && f.version != VERSION {
            return Err(format!(
                "depth table version {} is not supported (this epd reads versions 1 and \
                 {VERSION})",
                f.version
            ));
        }
        let axis = |a: AxisFile| Axis {
            lo: a.lo,
            hi: a.hi,
            n: a.bins,
        };
        let (nr, ni) = (f.range_m.bins, f.log_intensity.bins);
        if nr == 0 || ni == 0 || nr.checked_mul(ni).is_none_or(|c| c > MAX_TABLE_BINS) {
            return Err(format!(
                "depth table: {nr} range × {ni} intensity bins: need at least 1 each and at \
                 most {MAX_TABLE_BINS} (2²⁰) bins in all (as `epd calibrate` makes)"
            ));
        }
        let mm = |v: Vec<f64>| v.into_iter().map(|x| x * 1e-3).collect::<Vec<_>>();
        let table = DepthTable {
            range: axis(f.range_m),
            log_intensity: axis(f.log_intensity),
            offset_m: mm(Rows::new("offset_mm", nr, ni).read(f.offset_mm)?),
            spread_m: mm(Rows::new("spread_mm", nr, ni).read(f.spread_mm)?),
            count: Rows::new("count", nr, ni).read(f.count)?,
        };
        table.validate().map_err(|e| format!("depth table: {e}"))?;
        let ok = |d: f64| d.is_finite() && d > 0.0;
        if !(ok(f.known_d_max_mm) && ok(f.known_d_min_mm) && f.known_d_min_mm <= f.known_d_max_mm) {
            return Err(format!(
                "depth table: known diameters {} / {} mm: need 0 < Dmin ≤ Dmax",
                f.known_d_max_mm, f.known_d_min_mm
            ));
        }
        let known = (f.known_d_max_mm * 1e-3, f.known_d_min_mm * 1e-3);
        let rigs = match &f.rigs {
            None => vec![(known, f.frames)],
            Some(r) => {
                let mut v = Vec::with_capacity(r.len().min(1024));
                for g in r {
                    let (a, b) = (g.known_d_max_mm, g.known_d_min_mm);
                    if !(ok(a) && ok(b) && b <= a) {
                        return Err(format!(
                            "depth table: a rig's known diameters {a} / {b} mm: need 0 < Dmin \
                             ≤ Dmax"
                        ));
                    }
                    v.push(((a * 1e-3, b * 1e-3), g.frames));
                }
                v
            }
        };
        let incidence = match &f.incidence {
            None => None,
            Some(h) => Some(read_incidence(h, &table)?),
        };
        Ok(Self {
            table,
            known,
            frames: f.frames,
            n_observations: f.n_observations,
            incidence,
            rigs,
            spans: f.support.map(check_spans).transpose()?,
        })
    }

    /// Read a table file: a regular file (a FIFO is refused, not waited on:
    /// [`epd_io::read::open_regular`]) of at most [`MAX_TABLE_FILE_BYTES`].
    pub fn read(path: &Path) -> Result<Self, String> {
        use std::io::Read;
        let name = path.display();
        let (file, len) = epd_io::read::open_regular(path).map_err(|e| format!("{name}: {e}"))?;
        let too_large = || {
            format!(
                "{name}: larger than {MAX_TABLE_FILE_BYTES} bytes, the largest table `epd \
                 calibrate` writes: not a depth table"
            )
        };
        if len > MAX_TABLE_FILE_BYTES {
            return Err(too_large());
        }
        let mut bytes = Vec::new();
        file.take(MAX_TABLE_FILE_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| format!("{name}: cannot read: {e}"))?;
        if bytes.len() as u64 > MAX_TABLE_FILE_BYTES {
            return Err(too_large());
        }
        let text = String::from_utf8(bytes)
            .map_err(|e| format!("{name}: not a depth table: not UTF-8 text ({e})"))?;
        Self::from_json(&text).map_err(|e| format!("{name}: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use epd_core::calibration::Axis;
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
        CalibrationTable::plain(
            DepthTable::build(&obs, &bins).unwrap(),
            (0.5842, 0.5842),
            3,
            4000,
        )
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

    /// A version-2 table's support is read back as written; a reversed span, or cosines
    /// outside [0, 1], are refused naming the span.
    #[test]
    fn the_support_must_be_spans() {
        let mut t = table();
        t.spans = Some([(0.5, 2.0), (1.0, 40.0), (0.25, 1.0)]);
        let text = t.to_json();
        assert_eq!(CalibrationTable::from_json(&text).unwrap().spans, t.spans);
        // The spans as written (pretty-printed: one number per line).
        let span = |a: &str, b: &str| format!("[\n      {a},\n      {b}\n    ]");
        for (from, to, says) in [
            (
                span("0.5", "2.0"),
                span("2.0", "0.5"),
                "support.range_m = [2, 0.5]",
            ),
            (
                span("0.25", "1.0"),
                span("-0.5", "1.0"),
                "support.cos_incidence = [-0.5, 1]",
            ),
        ] {
            assert!(text.contains(&from), "{text}");
            let e = CalibrationTable::from_json(&text.replacen(&from, &to, 1)).unwrap_err();
            assert!(e.contains(says), "{e}");
        }
    }

    #[test]
    fn damaged_files_are_refused_with_a_reason() {
        let text = table().to_json();
        for (from, to, says) in [
            ("epd-depth-table", "something-else", "`format`"),
            ("\"version\": 2", "\"version\": 7", "version 7"),
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

    /// A table file's text with the given axes' bins and rows of values (no other check).
    fn file_with(nr: usize, ni: usize, rows: usize, cols: usize) -> String {
        let row = |v: &str| format!("[{}]", vec![v; cols].join(","));
        let arr = |v: &str| format!("[{}]", vec![row(v); rows].join(","));
        format!(
            r#"{{"format":"epd-depth-table","version":1,"known_d_max_mm":500,"known_d_min_mm":500,
               "frames":1,"n_observations":10,
               "range_m":{{"lo":0.5,"hi":2.0,"bins":{nr}}},
               "log_intensity":{{"lo":1.0,"hi":7.0,"bins":{ni}}},"empty_bins":"",
               "offset_mm":{},"spread_mm":{},"count":{}}}"#,
            arr("1.5"),
            arr("10"),
            arr("40")
        )
    }

    /// Bin counts beyond MAX_TABLE_BINS are refused from the axes alone, with the limit
    /// in the message, before any value is read (issue 27: `log_intensity.bins = 200000`
    /// aborted the process once a frame was corrected).
    #[test]
    fn bin_counts_beyond_the_limit_are_refused_before_reading_the_values() {
        assert!(CalibrationTable::from_json(&file_with(3, 2, 3, 2)).is_ok());
        for (nr, ni) in [
            (MAX_TABLE_BINS, 2),
            (2, MAX_TABLE_BINS),
            (usize::MAX, 2),
            (1 << 32, 1 << 32),
            (0, 5),
        ] {
            let e = CalibrationTable::from_json(&file_with(nr, ni, 1, 1)).unwrap_err();
            assert!(e.contains("at most 1048576 (2²⁰) bins"), "{nr} × {ni}: {e}");
        }
        // More rows or values than the axes say: refused as they are read.
        let e = CalibrationTable::from_json(&file_with(3, 2, 4, 2)).unwrap_err();
        assert!(e.contains("more than 3 rows"), "{e}");
        let e = CalibrationTable::from_json(&file_with(3, 2, 3, 3)).unwrap_err();
        assert!(e.contains("needs 2 values"), "{e}");
        // A range axis 1e-9 m wide.
        let thin = file_with(3, 2, 3, 2).replace("\"hi\":2.0", "\"hi\":0.500000001");
        let e = CalibrationTable::from_json(&thin).unwrap_err();
        assert!(e.contains("at least 0.001"), "{e}");
    }

    /// A table saved by an editor that writes a UTF-8 byte-order mark (issue 27:
    /// "expected value at line 1 column 1").
    #[test]
    fn a_byte_order_mark_is_accepted() {
        let t = table();
        let plain = CalibrationTable::from_json(&t.to_json()).unwrap();
        let back = CalibrationTable::from_json(&format!("\u{feff}{}", t.to_json())).unwrap();
        assert!(back == plain);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.json");
        std::fs::write(&p, format!("\u{feff}{}", t.to_json())).unwrap();
        assert!(CalibrationTable::read(&p).unwrap() == plain);
    }

    /// The file-size limit holds the largest table `epd calibrate` makes, its values of
    /// the longest form serde_json writes.
    #[test]
    fn the_largest_table_calibrate_makes_fits_the_file_limit() {
        for (nr, ni) in [(MAX_TABLE_BINS, 1), (1, MAX_TABLE_BINS)] {
            let cells = nr * ni;
            let t = CalibrationTable::plain(
                DepthTable {
                    range: Axis::new(0.5, 2.0, nr),
                    log_intensity: Axis::new(1.0, 7.0, ni),
                    offset_m: vec![-1.234_567_890_123_456_7e-301; cells],
                    spread_m: vec![1.234_567_890_123_456_7e-301; cells],
                    count: vec![u64::MAX; cells],
                },
                (0.5, 0.5),
                usize::MAX,
                u64::MAX,
            );
            let text = t.to_json();
            assert!(text.contains("-1.2345678901234567e-298"));
            assert!(
                text.len() as u64 <= MAX_TABLE_FILE_BYTES,
                "{nr} × {ni}: {} bytes",
                text.len()
            );
            let back = CalibrationTable::from_json(&text).map_err(|e| e.len());
            assert!(back.is_ok_and(|b| b.table.count.len() == cells));
        }
    }

    /// A FIFO in place of the table is refused at once, not waited on.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.json");
        let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = CalibrationTable::read(&p).unwrap_err();
        assert!(e.contains("a FIFO"), "{e}");
    }

    /// A frame none of whose points lies within the table's axes (another camera, another
    /// rig) is refused, not corrected by the table's edge bins.
    #[test]
    fn a_table_of_another_camera_is_not_applied_silently() {
        let t = table();
        let (r, li) = (&t.table.range, &t.table.log_intensity);
        let inside_i = ((li.lo + li.hi) / 2.0).exp();
        let inside_r = (r.lo + r.hi) / 2.0;
        let far = r.hi + 5.0;
        let mut pts = vec![[inside_r, 0.0, 0.0], [far, 0.0, 0.0]];
        // One point inside: corrected.
        assert!(
            t.correct_points(false, &mut pts, Some(&[inside_i, inside_i]), false)
                .is_ok()
        );
        // Ranges beyond the table's axis, or intensities 1000× brighter: refused.
        for (p, i) in [
            ([far, 0.0, 0.0], inside_i),
            ([inside_r, 0.0, 0.0], inside_i * (li.hi - li.lo).exp() * 1e3),
        ] {
            let mut pts = vec![p; 10];
            let e = t
                .correct_points(true, &mut pts, Some(&[i; 10]), false)
                .unwrap_err();
            assert!(
                e.contains("none of the frame's 10 valid points") && e.contains("epd calibrate"),
                "{e}"
            );
        }
        // No valid point: the estimator says so, not the table.
        let mut pts = vec![[0.0; 3]; 3];
        assert!(
            t.correct_points(false, &mut pts, Some(&[1.0; 3]), false)
                .is_ok()
        );
    }
}
