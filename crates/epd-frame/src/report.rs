//! One result per input file, written as text, JSON (one object per line, the keys of
//! the `estimate` example) or CSV (the same names as columns).

use epd_core::Estimate;
use epd_core::report::{ESTIMATE_KEYS, FIRST_RESULT_KEY, Field, estimate_fields};

use crate::scene::GeometryReport;

/// What `epd estimate` found for one file.
#[derive(Clone, Debug)]
pub struct FileReport {
    /// The file as given (lossy where its name is not UTF-8: see `file_bytes`).
    pub file: String,
    /// The name's bytes when they are not UTF-8 (`None` when they are, or for no file):
    /// reported as `file_bytes_hex`, and shown with `\xNN` escapes in text.
    pub file_bytes: Option<Vec<u8>>,
    /// The estimate and its context, or what went wrong.
    pub outcome: Result<FileEstimate, String>,
    /// The bag message the cloud came from (`None` for a file or an array): reported as
    /// `stamp_ns` and `frame_id`, null for a file.
    pub message: Option<MessageSource>,
}

/// Where in a bag a cloud came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MessageSource {
    /// The topic.
    pub topic: String,
    /// The message's index among the topic's messages (0 first).
    pub index: u64,
    /// `header.stamp` (ns), when the message could be decoded.
    pub stamp_ns: Option<i64>,
    /// `header.frame_id`, when the message could be decoded.
    pub frame_id: Option<String>,
}

/// A successful estimate of one file.
#[derive(Clone, Debug)]
pub struct FileEstimate {
    /// The estimate (its `n_dropped` counts the invalid points of the file).
    pub estimate: Estimate,
    /// Points in the file.
    pub n_read: usize,
    /// Valid points outside [min-range, max-range].
    pub n_out_of_range: usize,
    /// RMS range residual at the estimate (mm).
    pub rms_residual_mm: Option<f64>,
    /// Time of the estimate call alone (ms).
    pub elapsed_ms: f64,
    /// Time to read and parse the file (ms).
    pub read_ms: f64,
    /// The robust loss and its scale (m).
    pub loss: (String, f64),
    /// The nominal outer diameter (mm), when given; then the wall thickness is
    /// estimated as (OD − mean inner diameter)/2.
    pub nominal_od_mm: Option<f64>,
    /// Points moved by a depth-calibration table (`None` without one).
    pub n_calibrated: Option<usize>,
    /// Whether each residual was weighted by 1/σᵢ (σᵢ from the calibration table).
    pub weighted: bool,
    /// What lies ahead (`None`: not surveyed).
    pub geometry: Option<GeometryReport>,
    /// With `--max-points`: how many points were chosen and fitted, and how
    /// ([`crate::sampling`]); `None` when the frame was used whole.
    pub sampled: Option<(usize, crate::sampling::SamplingMethod)>,
    /// The input carried a per-point intensity (a ToF camera's frame) and no depth table
    /// was given: the camera's systematic range error is in the diameters (not a key of
    /// the report; `epd estimate` notes it on standard error).
    pub intensity_without_table: bool,
    /// With a depth table: the fraction of the frame's valid points outside the table's
    /// support (`calibration_outside`): uncorrected by an incidence table, corrected by
    /// an edge or neighbour bin's guess by a version-1 table. `None` without a table.
    pub calibration_outside: Option<f64>,
    /// With an incidence table: the rigs' smallest and largest diameters (mm) when the
    /// frame's mean diameter lies outside them (`crate::measure::RIG_SIZE_MARGIN`); said
    /// in `status_reason`.
    pub size_outside_rigs: Option<(f64, f64)>,
    /// With an incidence table: more than half of the frame's points lay outside its
    /// support, and the correction's whole effect on the diameters was added to their
    /// 1-σ; said in `status_reason`.
    pub outside_in_sigma: bool,
    /// With an incidence table: the frame lay too far outside its support to be
    /// corrected, and was fitted on its raw points with the table's largest offset as an
    /// error shared by every point in its 1-σ; said in `status_reason`.
    pub uncorrected: Option<crate::measure::UncorrectedFrame>,
    /// The survey's bend ahead, when it found one: its placement in the pipe frame of the
    /// survey's straight fit (those parameters first) and its angle (rad: the fitted
    /// angle when its end is in view, else the angle seen so far);
    /// not a key of the report (`epd estimate --export-fit` meshes it as a torus).
    pub bend_fit: Option<(epd_core::Params, epd_core::bend::BendGeometry, f64)>,
}

/// The CSV columns, in order: the keys of [`FileReport::fields`].
pub fn columns() -> Vec<&'static str> {
    let failed = FileReport {
        file: String::new(),
        file_bytes: None,
        outcome: Err(String::new()),
        message: None,
    };
    failed.fields().into_iter().map(|(k, _)| k).collect()
}

/// The fields after the estimate's, without the final `error`.
const CONTEXT_KEYS: [&str; 30] = [
    "n_read",
    "n_out_of_range",
    "n_calibrated",
    "weighted",
    "rms_residual_mm",
    "elapsed_ms",
    "read_ms",
    "loss",
    "loss_scale_m",
    "nominal_od_mm",
    "wall_thickness_est_mm",
    "geometry",
    "geometry_evidence",
    "straight_until_m",
    "sigma_straight_until_m",
    "bend_radius_mm",
    "sigma_bend_radius_mm",
    "bend_angle_deg",
    "sigma_bend_angle_deg",
    "bend_direction_deg",
    "bend_withheld",
    "dent_at_m",
    "dent_clock_deg",
    "dent_depth_mm",
    "ring_from_m",
    "ring_to_m",
    "ring_widening_mm",
    "n_sampled",
    "sampling",
    "calibration_outside",
];

/// Whether a key's value is a result, withheld (null) unless the estimate converged:
/// the estimate's keys from `d_max_mm` on (diameters, pose, `roll_determined`, the 1-σ),
/// the RMS residual and the wall thickness.
fn is_result(key: &str) -> bool {
    ESTIMATE_KEYS[FIRST_RESULT_KEY..].contains(&key)
        || ["rms_residual_mm", "wall_thickness_est_mm"].contains(&key)
}

impl FileReport {
    /// The report of the file at `path` (its name's bytes kept when they are not UTF-8).
    pub fn of_path(path: &std::path::Path, outcome: Result<FileEstimate, String>) -> Self {
        FileReport {
            file: path.display().to_string(),
            file_bytes: path
                .to_str()
                .is_none()
                .then(|| path.as_os_str().as_encoded_bytes().to_vec()),
            outcome,
            message: None,
        }
    }

    /// Why the file gave no result: a read or estimate error, or a fit that did not
    /// converge to something consistent with the points (`implausible`, …).
    pub fn failure(&self) -> Option<String> {
        match &self.outcome {
            Err(msg) => Some(msg.clone()),
            // In a bend the straight fit has no straight section to stand on: that is the
            // reason, whatever the fit did.
            Ok(e) if e.geometry.as_ref().and_then(|g| g.withheld()).is_some() => {
                e.geometry.as_ref().and_then(|g| g.withheld())
            }
            Ok(e) if !e.estimate.status.is_converged() => Some(format!(
                "{} {}: {}",
                e.estimate.method,
                e.estimate.status.name(),
                e.estimate.status.reason()
            )),
            Ok(_) => None,
        }
    }

    /// All fields, in the order of [`columns`]. A fit that did not converge keeps its
    /// status and counts but withholds every result (null), with the reason in `error`:
    /// a number is printed only when it can be believed.
    pub fn fields(&self) -> Vec<(&'static str, Field)> {
        let mut f = self.all_fields();
        let withheld = match &self.outcome {
            Ok(e) => e.geometry.as_ref().and_then(|g| g.withheld()).or_else(|| {
                (!e.estimate.status.is_converged()).then(|| e.estimate.status.reason())
            }),
            Err(_) => None,
        };
        if let Some(why) = withheld {
            for (k, v) in f.iter_mut() {
                if is_result(k) {
                    *v = Field::Null;
                }
                if *k == "error" {
                    *v = Field::Text(why.clone());
                }
            }
        }
        f
    }

    fn all_fields(&self) -> Vec<(&'static str, Field)> {
        let mut f = self.context_and_result_fields();
        f.push((
            "file_bytes_hex",
            self.file_bytes
                .as_deref()
                .map_or(Field::Null, |b| Field::Text(epd_io::name::hex(b))),
        ));
        // A bag message's header; null for a file (the same columns either way).
        let m = self.message.as_ref();
        f.push((
            "stamp_ns",
            m.and_then(|m| m.stamp_ns).map_or(Field::Null, Field::Int64),
        ));
        f.push((
            "frame_id",
            m.and_then(|m| m.frame_id.clone())
                .map_or(Field::Null, Field::Text),
        ));
        f
    }

    /// The fields up to `error`.
    fn context_and_result_fields(&self) -> Vec<(&'static str, Field)> {
        let mut f = vec![("file", Field::Text(self.file.clone()))];
        let num = |v: f64| {
            if v.is_finite() {
                Field::Num(v)
            } else {
                Field::Null
            }
        };
        match &self.outcome {
            Ok(e) => {
                f.extend(estimate_fields(&e.estimate));
                let mut notes = Vec::new();
                if let Some(u) = e.uncorrected {
                    notes.push(format!(
                        "{:.0} % of the points lie outside the depth table's support (more than \
                         {:.0} %): the frame is not corrected, and its 1-σ holds the camera's \
                         error as one error shared by every point, of the largest offset its \
                         rigs showed ({:.1} mm); calibrate with a rig of this pipe's size",
                        u.outside_fraction * 100.0,
                        crate::measure::REFUSE_OUTSIDE * 100.0,
                        u.shared_error_m * 1e3
                    ));
                } else if let Some(out) = e.calibration_outside
                    && out > crate::measure::MOSTLY_OUTSIDE
                {
                    // An incidence table leaves them out of the fit; a version-1 table
                    // corrects them from its edge or neighbouring bins.
                    let what = if e.outside_in_sigma {
                        "they are left out of the fit, and the correction's whole effect on \
                         the diameters is in their 1-σ"
                    } else {
                        "the table corrects them with the values of its edge or nearest filled \
                         bins, which its rigs did not show there"
                    };
                    notes.push(format!(
                        "{:.0} % of the points lie outside the depth table's support (more than \
                         {:.0} %): {what}",
                        out * 100.0,
                        crate::measure::MOSTLY_OUTSIDE * 100.0
                    ));
                }
                if let Some((lo, hi)) = e.size_outside_rigs {
                    notes.push(format!(
                        "the mean diameter {:.1} mm lies outside the depth table's rig sizes \
                         ({lo:.1} to {hi:.1} mm, ± {:.0} %): the correction is not known to \
                         transfer, and its whole effect on the diameters is in their 1-σ; \
                         calibrate with a rig of this size",
                        e.estimate.d_mean() * 1e3,
                        crate::measure::RIG_SIZE_MARGIN * 100.0
                    ));
                }
                if !notes.is_empty()
                    && let Some((_, Field::Text(r))) =
                        f.iter_mut().find(|(k, _)| *k == "status_reason")
                {
                    let note = notes.join("; ");
                    *r = if r.is_empty() {
                        note
                    } else {
                        format!("{r}; {note}")
                    };
                }
                let p = e.estimate.params;
                f.push(("n_read", Field::Int(e.n_read as u64)));
                f.push(("n_out_of_range", Field::Int(e.n_out_of_range as u64)));
                f.push((
                    "n_calibrated",
                    e.n_calibrated.map_or(Field::Null, |n| Field::Int(n as u64)),
                ));
                f.push(("weighted", Field::Bool(e.weighted)));
                f.push((
                    "rms_residual_mm",
                    e.rms_residual_mm.map_or(Field::Null, num),
                ));
                f.push(("elapsed_ms", num(e.elapsed_ms)));
                f.push(("read_ms", num(e.read_ms)));
                f.push(("loss", Field::Text(e.loss.0.clone())));
                f.push(("loss_scale_m", num(e.loss.1)));
                f.push(("nominal_od_mm", e.nominal_od_mm.map_or(Field::Null, num)));
                let wall = e
                    .nominal_od_mm
                    .map(|od| (od - 0.5 * (p.d_max + p.d_min) * 1e3) / 2.0);
                f.push(("wall_thickness_est_mm", wall.map_or(Field::Null, num)));
                let g = e.geometry.as_ref();
                f.push((
                    "geometry",
                    g.map_or(Field::Null, |g| Field::Text(g.layout.into())),
                ));
                let opt = |v: Option<f64>| v.map_or(Field::Null, num);
                f.push(("geometry_evidence", opt(g.map(|g| g.evidence))));
                f.push(("straight_until_m", opt(g.and_then(|g| g.straight_until_m))));
                f.push((
                    "sigma_straight_until_m",
                    opt(g.and_then(|g| g.sigma_straight_until_m)),
                ));
                f.push(("bend_radius_mm", opt(g.and_then(|g| g.bend_radius_mm))));
                f.push((
                    "sigma_bend_radius_mm",
                    opt(g.and_then(|g| g.sigma_bend_radius_mm)),
                ));
                f.push(("bend_angle_deg", opt(g.and_then(|g| g.bend_angle_deg))));
                f.push((
                    "sigma_bend_angle_deg",
                    opt(g.and_then(|g| g.sigma_bend_angle_deg)),
                ));
                f.push((
                    "bend_direction_deg",
                    opt(g.and_then(|g| g.bend_direction_deg)),
                ));
                f.push((
                    "bend_withheld",
                    g.and_then(|g| g.bend_withheld.clone())
                        .map_or(Field::Null, Field::Text),
                ));
                let dent = g.and_then(|g| g.dent);
                f.push(("dent_at_m", opt(dent.map(|d| d.at_m))));
                f.push(("dent_clock_deg", opt(dent.map(|d| d.clock_deg))));
                f.push(("dent_depth_mm", opt(dent.map(|d| d.depth_mm))));
                let ring = g.and_then(|g| g.ring);
                f.push(("ring_from_m", opt(ring.map(|r| r.from_m))));
                f.push(("ring_to_m", opt(ring.map(|r| r.to_m))));
                f.push(("ring_widening_mm", opt(ring.map(|r| r.widening_mm))));
                f.push((
                    "n_sampled",
                    e.sampled.map_or(Field::Null, |(n, _)| Field::Int(n as u64)),
                ));
                f.push((
                    "sampling",
                    e.sampled
                        .map_or(Field::Null, |(_, m)| Field::Text(m.name().into())),
                ));
                f.push((
                    "calibration_outside",
                    e.calibration_outside.map_or(Field::Null, num),
                ));
                f.push(("error", Field::Null));
            }
            Err(msg) => {
                for k in ESTIMATE_KEYS {
                    f.push((
                        k,
                        if k == "status" {
                            Field::Text("error".into())
                        } else {
                            Field::Null
                        },
                    ));
                }
                for k in CONTEXT_KEYS {
                    f.push((k, Field::Null));
                }
                f.push(("error", Field::Text(msg.clone())));
            }
        }
        f
    }

    /// One JSON object: [`FileReport::fields`], without `file_bytes_hex` when the name
    /// is UTF-8 ([`FileReport::keyed_fields`]).
    pub fn json(&self) -> String {
        epd_io::json::object(&self.keyed_fields())
    }

    /// [`FileReport::fields`] as a JSON object or a Python dict has them: the key
    /// `file_bytes_hex` only where the name is not UTF-8 (a CSV row has every column).
    pub fn keyed_fields(&self) -> Vec<(&'static str, Field)> {
        let mut f = self.fields();
        f.retain(|(k, v)| *k != "file_bytes_hex" || *v != Field::Null);
        f
    }

    /// The file's name as shown to people: control characters escaped, bytes that are not
    /// UTF-8 as `\xNN` (`epd_io::name`).
    /// A bag message is shown as `BAG TOPIC #INDEX`.
    pub fn shown_file(&self) -> String {
        let file = match &self.file_bytes {
            Some(b) => epd_io::name::shown_bytes(b),
            None => epd_io::name::escape_controls(&self.file).into_owned(),
        };
        match &self.message {
            None => file,
            Some(m) => format!(
                "{file} {} #{}",
                epd_io::name::escape_controls(&m.topic),
                m.index
            ),
        }
    }

    /// One CSV row (no final newline), in the order of [`columns`]. A CSV file is read by
    /// people as well as programs, and printed to a terminal: every text cell shows its
    /// control characters escaped as text output does (`epd_io::name::escape_controls`),
    /// so a name cannot rewrite the screen or fake a row. A file name that this changes
    /// keeps its exact bytes in `file_bytes_hex`, as a name that is not UTF-8 does. (JSON
    /// escapes control characters by its own rules and keeps every string exactly.)
    pub fn csv(&self) -> String {
        let mut f = self.fields();
        let renamed = self.file_bytes.is_none()
            && matches!(
                epd_io::name::escape_controls(&self.file),
                std::borrow::Cow::Owned(_)
            );
        for (k, v) in &mut f {
            match (*k, &*v) {
                ("file_bytes_hex", Field::Null) if renamed => {
                    *v = Field::Text(epd_io::name::hex(self.file.as_bytes()));
                }
                (_, Field::Text(t)) => {
                    if let std::borrow::Cow::Owned(e) = epd_io::name::escape_controls(t) {
                        *v = Field::Text(e);
                    }
                }
                _ => {}
            }
        }
        epd_io::csv::fields_line(&f)
    }

    /// A few readable lines (the name and the messages with their control characters
    /// escaped).
    pub fn text(&self) -> String {
        // Names and messages are data: a crafted name cannot start a line of its own.
        let file = self.shown_file();
        match &self.outcome {
            Err(msg) => format!("{file}: error: {}", epd_io::name::escape_controls(msg)),
            Ok(e) if e.geometry.as_ref().and_then(|g| g.withheld()).is_some() => format!(
                "{}: {} — no result",
                file,
                e.geometry
                    .as_ref()
                    .and_then(|g| g.withheld())
                    .unwrap_or_default()
            ),
            Ok(e) if !e.estimate.status.is_converged() => format!(
                "{}: {} {} after {} iterations, {} points: {} — no result",
                file,
                e.estimate.method,
                e.estimate.status.name(),
                e.estimate.iterations,
                e.estimate.n_points,
                e.estimate.status.reason()
            ),
            Ok(e) => e.text(&file),
        }
    }
}

impl FileEstimate {
    /// The readable lines of a converged estimate of `file`: the parameters with their
    /// standard deviations, the fit's figures, the wall thickness and the geometry ahead.
    fn text(&self, file: &str) -> String {
        let est = &self.estimate;
        let p = est.params;
        let s = |i: usize, k: f64| {
            est.sigma[i].map_or("undetermined".to_string(), |v| format!("±{:.3}", v * k))
        };
        let deg = 180.0 / std::f64::consts::PI;
        let mut t = format!(
            "{}: {} {} after {} iterations, {} points ({} invalid dropped, {} out of range)\n  \
             Dmax {:.2} mm {}  Dmin {:.2} mm {}\n  \
             roll {:.2}° {}  pitch {:.3}° {}  yaw {:.3}° {}\n  \
             δy {:.2} mm {}  δz {:.2} mm {}\n  \
             rms range residual {} mm, estimate {:.1} ms, read {:.1} ms\n  \
             ± is one standard deviation (1-σ); {}",
            file,
            est.method,
            est.status.name(),
            est.iterations,
            est.n_points,
            est.n_dropped,
            self.n_out_of_range,
            p.d_max * 1e3,
            s(0, 1e3),
            p.d_min * 1e3,
            s(1, 1e3),
            p.roll * deg,
            s(2, deg),
            p.pitch * deg,
            s(3, deg),
            p.yaw * deg,
            s(4, deg),
            p.dy * 1e3,
            s(5, 1e3),
            p.dz * 1e3,
            s(6, 1e3),
            self.rms_residual_mm
                .map_or("-".into(), |v| format!("{v:.2}")),
            self.elapsed_ms,
            self.read_ms,
            self.applied(),
        );
        if let Some(od) = self.nominal_od_mm {
            let id = 0.5 * (p.d_max + p.d_min) * 1e3;
            if id < od {
                t.push_str(&format!(
                    "\n  wall thickness ≈ {:.2} mm (nominal OD {od:.1} mm − mean ID)/2",
                    (od - id) / 2.0
                ));
            } else {
                t.push_str(&format!(
                    "\n  wall thickness: none, the mean inner diameter {id:.1} mm is not below \
                     the nominal OD {od:.1} mm: check --nominal-od-in (the outer diameter in \
                     inches)"
                ));
            }
        }
        if let Some(g) = &self.geometry {
            t.push_str(&g.text());
        }
        t
    }
}

impl FileEstimate {
    /// What was applied to the points before the fit, in words.
    fn applied(&self) -> String {
        match self.n_calibrated {
            Some(n) => format!(
                "depth table applied ({n} points corrected{})",
                if self.weighted {
                    ", each weighted by the table's 1/σᵢ"
                } else {
                    ", unweighted"
                }
            ),
            None if self.weighted => "each point weighted by its given σᵢ".into(),
            None => "no depth table applied".into(),
        }
    }
}

impl GeometryReport {
    /// The text report's geometry lines (each begins with a newline).
    fn text(&self) -> String {
        let mut t = format!("\n  geometry: {}", self.layout);
        match (self.straight_until_m, self.dent) {
            (Some(x), Some(d)) => t.push_str(&format!(
                " — a dent, debris or an obstacle {:.0} mm inside the wall at {:.0}° \
                 (clock angle from the sensor: 0 up, 90 right), deepest {:.3} m ahead; \
                 the estimate uses the points before it, up to {x:.3} m",
                d.depth_mm, d.clock_deg, d.at_m
            )),
            (Some(x), None) => t.push_str(&format!(
                " — the straight section ends {x:.3} m ahead{}; the estimate uses \
                 its points only",
                self.sigma_straight_until_m
                    .map_or(String::new(), |s| format!(" (±{s:.3} m, 1-σ)"))
            )),
            _ => {}
        }
        if let Some(r) = self.ring {
            t.push_str(&format!(
                "\n  ring: the wall from {:.3} to {:.3} m ahead reads {:.1} mm out all around \
                 (multipath over a band of ranges, a calibration error or a wider stretch \
                 of pipe); the estimate leaves its points out",
                r.from_m, r.to_m, r.widening_mm
            ));
        }
        if let (Some(r), Some(a), Some(c)) = (
            self.bend_radius_mm,
            self.bend_angle_deg,
            self.bend_direction_deg,
        ) {
            let sd = self
                .sigma_bend_radius_mm
                .map_or(String::new(), |s| format!(" (±{s:.0} mm, 1-σ)"));
            let angle = self
                .sigma_bend_angle_deg
                .map_or(format!("{a:.0}° seen so far"), |s| {
                    format!("{a:.1}° (±{s:.1}°, 1-σ) to its end")
                });
            t.push_str(&format!(
                "\n  bend: radius {r:.0} mm{sd}, {angle}, toward {c:.0}° \
                 (clock angle from the sensor: 0 up, 90 right)"
            ));
        }
        if let Some(why) = &self.bend_withheld {
            t.push_str(&format!("\n  bend: {why}"));
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The withheld results start at the diameters and take in every 1-σ.
    #[test]
    fn results_are_the_diameters_pose_and_uncertainties() {
        for k in [
            "d_max_mm",
            "dz_mm",
            "sigma_dz_mm",
            "roll_determined",
            "wall_thickness_est_mm",
        ] {
            assert!(is_result(k), "{k}");
        }
        for k in [
            "method",
            "status",
            "status_reason",
            "n_points",
            "n_dropped",
            "error",
        ] {
            assert!(!is_result(k), "{k}");
        }
    }

    /// A converged report of a synthetic cloud, without a survey.
    fn ok_report() -> FileReport {
        let pts: Vec<[f64; 3]> = (0..400)
            .map(|i| {
                let phi = i as f64 * 0.37;
                [
                    0.5 + (i % 41) as f64 * 0.1,
                    0.24 * phi.cos(),
                    0.23 * phi.sin(),
                ]
            })
            .collect();
        let est = epd_core::estimate(&pts, epd_core::Method::RuEpd, &Default::default()).unwrap();
        FileReport {
            file: "a".into(),
            file_bytes: None,
            message: None,
            outcome: Ok(FileEstimate {
                estimate: est,
                n_read: 400,
                n_out_of_range: 0,
                n_calibrated: None,
                weighted: false,
                rms_residual_mm: None,
                elapsed_ms: 1.0,
                read_ms: 1.0,
                loss: ("none".into(), f64::NAN),
                nominal_od_mm: None,
                geometry: None,
                sampled: None,
                intensity_without_table: false,
                calibration_outside: None,
                size_outside_rigs: None,
                outside_in_sigma: false,
                uncorrected: None,
                bend_fit: None,
            }),
        }
    }

    /// A name with control characters (an escape sequence, a newline that would fake a
    /// row) is shown escaped in CSV, every character of the row printable, and its exact
    /// bytes are in `file_bytes_hex`; a plain name leaves that column empty; JSON keeps the
    /// name exactly (escaped by JSON's rules).
    #[test]
    fn csv_shows_control_characters_escaped_and_keeps_the_bytes() {
        let mut r = ok_report();
        let raw = "x\u{1b}[2Jy.ply\ngood.ply,converged";
        r.file = raw.into();
        let line = r.csv();
        assert!(line.chars().all(|c| !c.is_control()), "{line:?}");
        let cols = columns();
        let row = csv_cells(&line);
        assert_eq!(row.len(), cols.len(), "{line}");
        let cell = |k: &str| row[cols.iter().position(|c| *c == k).unwrap()].clone();
        assert_eq!(cell("file"), epd_io::name::escape_controls(raw));
        assert_eq!(cell("file_bytes_hex"), epd_io::name::hex(raw.as_bytes()));
        assert!(
            r.json().contains("\\u001b[2Jy.ply\\ngood.ply"),
            "{}",
            r.json()
        );
        let plain = ok_report();
        let row = csv_cells(&plain.csv());
        assert_eq!(
            row[cols.iter().position(|c| *c == "file_bytes_hex").unwrap()],
            ""
        );
    }

    /// The cells of one CSV line (quotes as `epd_io::csv` writes them).
    fn csv_cells(line: &str) -> Vec<String> {
        let mut cells = vec![String::new()];
        let mut quoted = false;
        let mut chars = line.chars().peekable();
        while let Some(c) = chars.next() {
            match c {
                '"' if quoted && chars.peek() == Some(&'"') => {
                    chars.next();
                    cells.last_mut().unwrap().push('"');
                }
                '"' => quoted = !quoted,
                ',' if !quoted => cells.push(String::new()),
                c => cells.last_mut().unwrap().push(c),
            }
        }
        cells
    }

    /// The text says what ± means and what was applied to the points; a bag message is
    /// named by its topic and index, and its header fills `stamp_ns` and `frame_id` (null
    /// for a file).
    #[test]
    fn text_says_what_the_uncertainty_is_and_json_has_the_stamp() {
        let mut r = ok_report();
        assert!(
            r.text()
                .contains("± is one standard deviation (1-σ); no depth table applied")
        );
        let get =
            |r: &FileReport, k: &str| r.fields().into_iter().find(|(n, _)| *n == k).unwrap().1;
        assert_eq!(get(&r, "stamp_ns"), Field::Null);
        if let Ok(e) = &mut r.outcome {
            e.n_calibrated = Some(12);
            e.weighted = true;
        }
        r.message = Some(MessageSource {
            topic: "/cam".into(),
            index: 4,
            stamp_ns: Some(-5),
            frame_id: Some("cam_optical_frame".into()),
        });
        let t = r.text();
        assert!(t.starts_with("a /cam #4: "), "{t}");
        assert!(
            t.contains("depth table applied (12 points corrected, each weighted"),
            "{t}"
        );
        assert_eq!(get(&r, "stamp_ns"), Field::Int64(-5));
        assert_eq!(get(&r, "frame_id"), Field::Text("cam_optical_frame".into()));
        assert!(
            r.json()
                .ends_with(r#""stamp_ns":-5,"frame_id":"cam_optical_frame"}"#)
        );
    }

    /// A bend 1 m ahead, as a survey reports it.
    fn bend_ahead() -> GeometryReport {
        GeometryReport {
            layout: "bend_ahead",
            straight_until_m: Some(1.0),
            sigma_straight_until_m: Some(0.004),
            evidence: 307.0,
            bend_radius_mm: Some(762.0),
            sigma_bend_radius_mm: Some(3.5),
            bend_angle_deg: Some(60.0),
            sigma_bend_angle_deg: Some(2.5),
            bend_direction_deg: Some(90.0),
            straight_withheld: false,
            bend_withheld: None,
            dent: None,
            ring: None,
        }
    }

    /// Asserts that each of `expected`'s keys holds its number in the report's fields.
    fn assert_numbers(fields: &[(&str, Field)], expected: &[(&str, f64)]) {
        for &(key, value) in expected {
            let got = fields.iter().find(|(n, _)| *n == key).map(|(_, v)| v);
            assert!(
                matches!(got, Some(Field::Num(v)) if *v == value),
                "{key}: {got:?}"
            );
        }
    }

    /// The scene's uncertainty and evidence reach the report: the keys carry the
    /// survey's values, the text gives the ± as 1-σ, and a withheld bend withholds its
    /// radius's 1-σ too (tested in `a_bend_the_table_did_not_observe_is_withheld`).
    #[test]
    fn the_scene_uncertainty_is_reported() {
        let mut r = ok_report();
        if let Ok(e) = &mut r.outcome {
            e.geometry = Some(bend_ahead());
        }
        let f = r.fields();
        assert_numbers(
            &f,
            &[
                ("geometry_evidence", 307.0),
                ("sigma_straight_until_m", 0.004),
                ("sigma_bend_radius_mm", 3.5),
                ("sigma_bend_angle_deg", 2.5),
            ],
        );
        let text = r.text();
        assert!(
            text.contains("(±0.004 m, 1-σ)")
                && text.contains("(±4 mm, 1-σ)")
                && text.contains("60.0° (±2.5°, 1-σ) to its end"),
            "{text}"
        );
    }

    /// A dent on a straight pipe: its three keys carry where, at which clock angle and how
    /// deep, and the text says the estimate stops before it.
    #[test]
    fn a_dent_is_reported_with_where_and_how_deep() {
        let mut r = ok_report();
        if let Ok(e) = &mut r.outcome {
            e.geometry = Some(GeometryReport {
                layout: "straight",
                straight_until_m: Some(0.7),
                dent: Some(crate::scene::DentReport {
                    at_m: 1.05,
                    clock_deg: 180.0,
                    depth_mm: 21.5,
                }),
                ..bend_ahead()
            });
        }
        let f = r.fields();
        let get = |k: &str| f.iter().find(|(n, _)| *n == k).unwrap().1.clone();
        assert_eq!(get("geometry"), Field::Text("straight".into()));
        assert_numbers(
            &f,
            &[
                ("dent_at_m", 1.05),
                ("dent_clock_deg", 180.0),
                ("dent_depth_mm", 21.5),
            ],
        );
        let text = r.text();
        assert!(text.contains("22 mm inside the wall at 180°"), "{text}");
        assert!(text.contains("up to 0.700 m"), "{text}");
        // Without a dent the keys are null.
        let plain = ok_report().fields();
        assert!(
            plain
                .iter()
                .any(|(k, v)| *k == "dent_depth_mm" && *v == Field::Null)
        );
    }

    /// A ring left out of the straight estimate: its three keys and a text line that says
    /// its points were left out; null keys without one.
    #[test]
    fn a_ring_is_reported_where_and_how_far_out() {
        let mut r = ok_report();
        if let Ok(e) = &mut r.outcome {
            e.geometry = Some(GeometryReport {
                layout: "straight",
                straight_until_m: None,
                ring: Some(crate::scene::RingReport {
                    from_m: 0.825,
                    to_m: 1.975,
                    widening_mm: 11.5,
                }),
                ..bend_ahead()
            });
        }
        let f = r.fields();
        assert_numbers(
            &f,
            &[
                ("ring_from_m", 0.825),
                ("ring_to_m", 1.975),
                ("ring_widening_mm", 11.5),
            ],
        );
        let text = r.text();
        assert!(
            text.contains("from 0.825 to 1.975 m ahead reads 11.5 mm out all around"),
            "{text}"
        );
        let plain = ok_report().fields();
        assert!(
            plain
                .iter()
                .any(|(k, v)| *k == "ring_widening_mm" && *v == Field::Null)
        );
    }

    /// A successful report and a failed one have the same columns, in the same order.
    #[test]
    fn success_and_failure_share_the_columns() {
        let ok = ok_report();
        let keys: Vec<&str> = ok.fields().into_iter().map(|(k, _)| k).collect();
        assert_eq!(keys, columns());
        // epd-core's fields of an estimate follow its key list, after `file`.
        assert_eq!(keys[1..=ESTIMATE_KEYS.len()], ESTIMATE_KEYS);
        // With a survey: the same keys.
        let mut surveyed = ok.clone();
        if let Ok(e) = &mut surveyed.outcome {
            e.geometry = Some(bend_ahead());
        }
        let keys: Vec<&str> = surveyed.fields().into_iter().map(|(k, _)| k).collect();
        assert_eq!(keys, columns());
        // In a bend: every result withheld, with the reason.
        if let Ok(e) = &mut surveyed.outcome {
            e.geometry.as_mut().unwrap().layout = "in_bend";
        }
        let f = surveyed.fields();
        let get = |k: &str| f.iter().find(|(n, _)| *n == k).unwrap().1.clone();
        assert_eq!(get("d_max_mm"), Field::Null);
        assert!(matches!(get("error"), Field::Text(t) if t.contains("in a bend")));
        // In a bend, a straight fit that did not converge either: the bend is the reason
        // given everywhere (the fit on a few centimetres of straight wall means nothing).
        let converged = ok.outcome.as_ref().map(|e| e.estimate.status).unwrap();
        if let Ok(e) = &mut surveyed.outcome {
            e.estimate.status = epd_core::FitStatus::IterationLimit;
        }
        let f = surveyed.fields();
        let get = |k: &str| f.iter().find(|(n, _)| *n == k).unwrap().1.clone();
        assert!(matches!(get("error"), Field::Text(t) if t.contains("in a bend")));
        assert!(surveyed.failure().is_some_and(|t| t.contains("in a bend")));
        assert!(surveyed.text().contains("in a bend"));
        // A tee 0.35 m ahead, too close for the straight pipe before it: withheld, with
        // where the opening starts.
        if let Ok(e) = &mut surveyed.outcome {
            e.estimate.status = converged;
            let g = e.geometry.as_mut().unwrap();
            (g.layout, g.straight_until_m, g.straight_withheld) = ("tee_ahead", Some(0.35), true);
        }
        let f = surveyed.fields();
        let get = |k: &str| f.iter().find(|(n, _)| *n == k).unwrap().1.clone();
        assert_eq!(get("d_min_mm"), Field::Null);
        let why = "a tee's branch opening starts 0.35 m ahead: too little straight pipe";
        assert!(matches!(get("error"), Field::Text(t) if t.contains(why)));
        assert!(surveyed.failure().is_some_and(|t| t.contains(why)));
        assert!(surveyed.text().contains(why));
    }

    /// With a depth table, a bend whose points the table mostly did not observe has its
    /// radius, angle and direction withheld with the reason, in every output; the straight
    /// estimate stays. Enough coverage, or none measured (no table), keeps them.
    #[test]
    fn a_bend_the_table_did_not_observe_is_withheld() {
        let mut g = bend_ahead();
        for keep in [None, Some(0.5), Some(0.9)] {
            let mut h = g.clone();
            h.check_bend_against_table(keep);
            assert_eq!(h, g, "coverage {keep:?}");
        }
        g.check_bend_against_table(Some(0.12));
        assert_eq!(
            (g.bend_radius_mm, g.bend_angle_deg, g.bend_direction_deg),
            (None, None, None)
        );
        assert_eq!(g.sigma_bend_radius_mm, None);
        assert_eq!(g.sigma_bend_angle_deg, None);
        let why = "only 12 % of the bend's points lie where the depth table observed";
        assert!(g.bend_withheld.as_ref().is_some_and(|t| t.contains(why)));
        let mut flagged = ok_report();
        if let Ok(e) = &mut flagged.outcome {
            e.geometry = Some(g);
        }
        let f = flagged.fields();
        let get = |k: &str| f.iter().find(|(n, _)| *n == k).unwrap().1.clone();
        assert_eq!(get("bend_radius_mm"), Field::Null);
        assert!(matches!(get("bend_withheld"), Field::Text(t) if t.contains(why)));
        assert!(matches!(get("d_max_mm"), Field::Num(_)));
        assert!(flagged.text().contains(why));
    }
}
