//! `epd profile`: a run's frames (a bag's PointCloud2 messages, or point-cloud files in
//! order) measured as `epd estimate` measures them, a few at a time, and written as one row
//! per frame to `profile.csv` as they come (the whole run is never in memory: two clouds
//! per thread at most, `crate::stream`), then drawn as `profile.png` (`epd_io::plot`).
//!
//! The x axis: the distance travelled when `--odometry-topic` (the path length of the
//! odometry's positions, interpolated at each cloud's stamp) or `--speed` is given, else
//! the time since the run's first message, else (files without stamps) the frame number.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use epd_core::report::Field;
use epd_frame::bag::{BagFrames, damage_report, odometry};
use epd_frame::report::FileReport;
use epd_io::plot::{BLUE, Figure, GAP, GREEN, Panel, Point, RED, RGBColor, Series, render};
use epd_io::stderr_line;

use crate::args::ProfileArgs;
use crate::estimate::{Input, Work, fit_config, resolve_inputs};
use crate::{progress, start_threads, usage};

/// The columns of `profile.csv`, in order. `frame` is the frame's number in the run (from
/// 0, over all inputs, as `--shard` counts them); `message_index` its index among its bag
/// topic's messages (empty for a file); `time_s` seconds since the run's first message;
/// `distance_m` the distance travelled (empty without odometry or speed); the values and
/// their 1-σ are those of `epd estimate` under the same names; `flagged` is true for a
/// frame with no result or with a note in `reason`.
pub const PROFILE_COLUMNS: [&str; 19] = [
    "frame",
    "file",
    "message_index",
    "stamp_ns",
    "time_s",
    "distance_m",
    "d_mean_mm",
    "sigma_d_mean_mm",
    "ovality_pct",
    "sigma_ovality_pct",
    "d_max_mm",
    "sigma_d_max_mm",
    "d_min_mm",
    "sigma_d_min_mm",
    "geometry",
    "straight_until_m",
    "status",
    "flagged",
    "reason",
];

/// What the plot keeps of a frame (a few numbers; the clouds are gone).
struct Row {
    x: f64,
    d_mean: Option<(f64, f64)>,
    ovality: Option<(f64, f64)>,
    geometry: Option<String>,
    straight_until: Option<f64>,
    result: bool,
    flagged: bool,
}

/// Cumulative path length (m) of an odometry track at its stamps, for interpolation.
struct Odometer {
    stamps: Vec<i64>,
    distance: Vec<f64>,
}

impl Odometer {
    fn new(positions: &[epd_frame::bag::OdometryPosition]) -> Odometer {
        let mut ps: Vec<_> = positions.to_vec();
        ps.sort_by_key(|p| p.stamp_ns);
        let mut distance = Vec::with_capacity(ps.len());
        let mut total = 0.0;
        for (k, p) in ps.iter().enumerate() {
            if k > 0 {
                let q = ps[k - 1].position;
                let d: f64 = (0..3).map(|i| (p.position[i] - q[i]).powi(2)).sum();
                if d.is_finite() {
                    total += d.sqrt();
                }
            }
            distance.push(total);
        }
        Odometer {
            stamps: ps.iter().map(|p| p.stamp_ns).collect(),
            distance,
        }
    }

    /// The distance at `stamp` (linear between the two odometry stamps around it), `None`
    /// outside the track's span.
    fn at(&self, stamp: i64) -> Option<f64> {
        let (first, last) = (*self.stamps.first()?, *self.stamps.last()?);
        if stamp < first || stamp > last {
            return None;
        }
        let i = self.stamps.partition_point(|&s| s < stamp);
        if self.stamps[i] == stamp {
            return Some(self.distance[i]);
        }
        let (s0, s1) = (self.stamps[i - 1], self.stamps[i]);
        let f = (stamp - s0) as f64 / (s1 - s0) as f64;
        Some(self.distance[i - 1] + f * (self.distance[i] - self.distance[i - 1]))
    }
}

/// The x of each frame.
enum Abscissa {
    Frame,
    Time,
    Speed(f64),
    Odometry(Odometer),
}

fn field<'a>(f: &'a [(&'static str, Field)], key: &str) -> &'a Field {
    f.iter()
        .find(|(k, _)| *k == key)
        .map_or(&Field::Null, |(_, v)| v)
}

fn num(f: &Field) -> Option<f64> {
    match f {
        Field::Num(v) => Some(*v),
        Field::Int(v) => Some(*v as f64),
        Field::Int64(v) => Some(*v as f64),
        _ => None,
    }
}

/// The frames without a result whose reason `epd profile` prints on stderr; the others'
/// are in `profile.csv` (its `reason` column), so that a long run's failures do not flood
/// the terminal.
const FAILURES_SHOWN: usize = 5;

/// One frame's row of `profile.csv`, and what the plot keeps of it.
fn row(frame: u64, r: &FileReport, t0: Option<i64>, x_of: &Abscissa) -> (Vec<Field>, Row) {
    let f = r.fields();
    let stamp = r.message.as_ref().and_then(|m| m.stamp_ns);
    let time_s = stamp.zip(t0).map(|(s, t)| (s - t) as f64 * 1e-9);
    let distance_m = match x_of {
        Abscissa::Speed(v) => time_s.map(|t| v * t),
        Abscissa::Odometry(o) => stamp.and_then(|s| o.at(s)),
        _ => None,
    };
    let failure = r.failure();
    let note = r.outcome.as_ref().is_ok_and(|e| {
        e.size_outside_rigs.is_some()
            || e.calibration_outside
                .is_some_and(|o| o > epd_frame::measure::MOSTLY_OUTSIDE)
    });
    let flagged = failure.is_some() || note;
    let reason = failure.or_else(|| {
        note.then(|| match field(&f, "status_reason") {
            Field::Text(t) => t.clone(),
            _ => String::new(),
        })
    });
    let opt = |v: Option<f64>| v.map_or(Field::Null, Field::Num);
    let mut out = vec![
        Field::Int(frame),
        Field::Text(r.file.clone()),
        r.message
            .as_ref()
            .map_or(Field::Null, |m| Field::Int(m.index)),
        stamp.map_or(Field::Null, Field::Int64),
        opt(time_s),
        opt(distance_m),
    ];
    for k in &PROFILE_COLUMNS[6..16] {
        out.push(field(&f, k).clone());
    }
    out.push(field(&f, "status").clone());
    out.push(Field::Bool(flagged));
    out.push(reason.map_or(Field::Null, Field::Text));
    let pair = |a: &str, b: &str| Some((num(field(&f, a))?, num(field(&f, b)).unwrap_or(0.0)));
    let x = match x_of {
        Abscissa::Frame => Some(frame as f64),
        Abscissa::Time => time_s,
        _ => distance_m,
    };
    let keep = Row {
        x: x.unwrap_or(f64::NAN),
        d_mean: pair("d_mean_mm", "sigma_d_mean_mm"),
        ovality: pair("ovality_pct", "sigma_ovality_pct"),
        geometry: match field(&f, "geometry") {
            Field::Text(t) => Some(t.clone()),
            _ => None,
        },
        straight_until: num(field(&f, "straight_until_m")),
        result: num(field(&f, "d_mean_mm")).is_some(),
        flagged,
    };
    (out, keep)
}

/// The frames of the run, in order, with their number: a bag's messages (only those of
/// the shard's block decoded), then the next input.
struct Frames<'a> {
    inputs: std::slice::Iter<'a, Input>,
    /// The run's frame number of the next input's first frame.
    next_frame: u64,
    keep: std::ops::Range<u64>,
    /// The bag being read: its path, the run's frame number of its first message, the
    /// reader, and the messages of the block its summary lists and those read so far.
    bag: Option<(&'a Path, u64, BagFrames, u64, u64)>,
    /// The frame number after the last message of the current bag.
    after: u64,
}

impl Iterator for Frames<'_> {
    type Item = (u64, Work);

    fn next(&mut self) -> Option<(u64, Work)> {
        loop {
            if let Some((path, at, frames, listed, read)) = &mut self.bag {
                match frames.next() {
                    Some(Ok(m)) => {
                        *read += 1;
                        let k = *at + m.message.index;
                        self.after = k + 1;
                        return Some((k, Work::Message(Box::new(m))));
                    }
                    Some(Err(e)) => {
                        // The damage is the row after the last message read.
                        let k = self.after;
                        let r = damage_report(path, &e);
                        self.bag = None;
                        return Some((k, Work::Done(Box::new(r))));
                    }
                    None => {
                        // Fewer messages than the summary lists for the block: a row saying
                        // so, after the last one read, rather than a silent gap.
                        let short = (*read < *listed).then(|| {
                            let why = format!(
                                "{read} of the {listed} messages the bag lists here were read: \
                                 the records holding the others are damaged or unreadable"
                            );
                            FileReport::of_path(path, Err(why))
                        });
                        self.bag = None;
                        if let Some(r) = short {
                            return Some((self.after, Work::Done(Box::new(r))));
                        }
                    }
                }
            }
            if self.next_frame >= self.keep.end {
                return None;
            }
            let input = self.inputs.next()?;
            let first = self.next_frame;
            match input {
                Input::Bag {
                    path,
                    topic,
                    messages,
                } => {
                    self.next_frame += messages;
                    let lo = self.keep.start.saturating_sub(first);
                    // A bag's last messages beyond its count (a damaged bag) belong to the run's
                    // end: read them when the block runs to the end.
                    let hi = if self.keep.end == u64::MAX {
                        u64::MAX
                    } else {
                        self.keep.end.saturating_sub(first).min(*messages)
                    };
                    if lo >= hi {
                        continue;
                    }
                    self.after = first + lo;
                    match BagFrames::open(path, topic) {
                        Ok(f) => {
                            let listed = hi.min(*messages).saturating_sub(lo);
                            self.bag = Some((path, first, f.only(lo..hi), listed, 0));
                        }
                        Err(e) => {
                            return Some((first, Work::Done(Box::new(damage_report(path, &e)))));
                        }
                    }
                }
                other => {
                    self.next_frame += 1;
                    if !self.keep.contains(&first) {
                        continue;
                    }
                    return Some((
                        first,
                        match other {
                            Input::File(p) => Work::File(p.clone()),
                            Input::Failed(r) => Work::Done(r.clone()),
                            Input::Bag { .. } => return None,
                        },
                    ));
                }
            }
        }
    }
}

/// The stamp of the first message of the run's first bag (the origin of `time_s`).
fn first_stamp(inputs: &[Input]) -> Option<i64> {
    let Input::Bag { path, topic, .. } = inputs.first()? else {
        return None;
    };
    let m = BagFrames::open(path, topic).ok()?.only(0..1).next()?.ok()?;
    m.message.cloud.ok().map(|c| c.stamp_ns)
}

pub fn run_profile(a: &ProfileArgs) -> anyhow::Result<ExitCode> {
    let cfg = fit_config(&a.fit)?;
    if let Some(v) = a.speed
        && !(v.is_finite() && v > 0.0)
    {
        return Err(usage(format!(
            "--speed {v}: expected a speed in m/s above 0"
        )));
    }
    if a.files.iter().any(|f| f.as_os_str() == "-") {
        return Err(usage("epd profile reads files, not standard input (`-`)"));
    }
    let inputs = resolve_inputs(a.files.clone(), a.topic.as_deref())?;
    let all_bags = inputs.iter().all(|i| matches!(i, Input::Bag { .. }));
    if (a.speed.is_some() || a.odometry_topic.is_some()) && !all_bags {
        return Err(usage(
            "--speed and --odometry-topic need stamped frames: give ROS 2 bags (point-cloud \
             files carry no time)",
        ));
    }
    let x_of = if let Some(t) = &a.odometry_topic {
        let mut positions = Vec::new();
        for i in &inputs {
            if let Input::Bag { path, .. } = i {
                let track =
                    odometry(path, t).map_err(|e| usage(format!("--odometry-topic: {e}")))?;
                if let Some(d) = &track.damaged {
                    stderr_line!("warning: odometry: {d}");
                }
                if !track.undecoded.is_empty() {
                    stderr_line!(
                        "warning: odometry: {} messages could not be decoded (first: #{} {})",
                        track.undecoded.len(),
                        track.undecoded[0].0,
                        track.undecoded[0].1
                    );
                }
                positions.extend(track.positions);
            }
        }
        if positions.len() < 2 {
            return Err(usage(format!(
                "--odometry-topic {t}: {} positions; at least 2 are needed for a distance",
                positions.len()
            )));
        }
        Abscissa::Odometry(Odometer::new(&positions))
    } else if let Some(v) = a.speed {
        Abscissa::Speed(v)
    } else if all_bags {
        Abscissa::Time
    } else {
        Abscissa::Frame
    };
    let total: u64 = inputs
        .iter()
        .map(|i| match i {
            Input::Bag { messages, .. } => *messages,
            _ => 1,
        })
        .sum();
    // The last shard (or an unsharded run) reads to the end of the last bag, past the
    // count of its messages (a damaged bag's count stops at the damage, which is then
    // reported as its last row).
    let keep = match a.shard {
        Some(s) if s.k() < s.n() => {
            let b = s.block(usize::try_from(total).unwrap_or(usize::MAX));
            b.start as u64..b.end as u64
        }
        Some(s) => s.block(usize::try_from(total).unwrap_or(usize::MAX)).start as u64..u64::MAX,
        None => 0..u64::MAX,
    };
    let t0 = if all_bags { first_stamp(&inputs) } else { None };
    start_threads(a.threads)?;
    crate::simulate::check_out_folder(&a.out)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", epd_io::name::shown(&a.out)))?;
    let csv_path = a.out.join("profile.csv");
    let mut csv = epd_io::atomic::Output::create(&csv_path, ".epd-output-")
        .with_context(|| format!("cannot write {}", epd_io::name::shown(&csv_path)))?;
    let write = |csv: &mut epd_io::atomic::Output, line: &str| -> anyhow::Result<()> {
        use std::io::Write;
        csv.write_all(line.as_bytes())
            .and_then(|()| csv.write_all(b"\n"))
            .with_context(|| format!("cannot write {}", epd_io::name::shown(&csv_path)))
    };
    if a.shard.is_none_or(|s| s.k() == 1) {
        write(&mut csv, &epd_io::csv::line(PROFILE_COLUMNS))?;
    }
    let bar = progress(a.quiet, (keep.end.min(total) - keep.start) as usize);
    let frames = Frames {
        inputs: inputs.iter(),
        next_frame: 0,
        keep: keep.clone(),
        bag: None,
        after: 0,
    };
    let mut rows = Vec::new();
    let mut failed = 0usize;
    // As `epd estimate` measures its inputs (`crate::stream`).
    let measure = |(k, w): (u64, Work)| {
        let r = w.measure(&cfg);
        bar.inc(1);
        (k, r)
    };
    crate::stream::in_order(frames, measure, |(k, r): (u64, FileReport)| {
        let (fields, keep) = row(k, &r, t0, &x_of);
        failed += usize::from(!keep.result);
        if !keep.result && failed <= FAILURES_SHOWN && !a.quiet {
            let why = r.failure().unwrap_or_else(|| "no result".into());
            let shown = match &r.file_bytes {
                Some(b) => epd_io::name::shown_bytes(b),
                None => epd_io::name::escape_controls(&r.file).into_owned(),
            };
            bar.suspend(|| stderr_line!("{shown}: {}", epd_io::name::escape_controls(&why)));
        }
        let named: Vec<(&str, Field)> = PROFILE_COLUMNS.iter().copied().zip(fields).collect();
        write(&mut csv, &epd_io::csv::fields_line(&named))?;
        rows.push(keep);
        Ok(true)
    })?;
    bar.finish_and_clear();
    csv.commit()
        .with_context(|| format!("cannot write {}", epd_io::name::shown(&csv_path)))?;
    let x_label = match x_of {
        Abscissa::Frame => "frame",
        Abscissa::Time => "time since the first message (s)",
        Abscissa::Speed(_) => "distance at the given speed (m)",
        Abscissa::Odometry(_) => "distance travelled (odometry path length, m)",
    };
    let name = a
        .files
        .first()
        .map(|f| epd_io::name::shown(f))
        .unwrap_or_default();
    let png = plot_profile(&rows, x_label, &name)?;
    let png_path: PathBuf = a.out.join(&png.name);
    epd_io::atomic::write_bytes_atomic(&png_path, &png.bytes)
        .with_context(|| format!("cannot write {}", epd_io::name::shown(&png_path)))?;
    if !a.quiet {
        let unplaced = rows.iter().filter(|r| !r.x.is_finite()).count();
        stderr_line!(
            "{} frames: profile.csv and profile.png written to {} ({failed} without a result{})",
            rows.len(),
            epd_io::name::shown(&a.out),
            match (unplaced, &x_of) {
                (0, _) => String::new(),
                (n, Abscissa::Odometry(_)) => {
                    format!(", {n} outside the odometry's time span or without a time: not drawn")
                }
                (n, _) => format!(", {n} without a time: not drawn"),
            }
        );
    }
    if rows.is_empty() && a.shard.is_none() {
        // Nothing at all to profile (a bag whose topic holds no message): not a success.
        stderr_line!("error: no frame to profile: the inputs hold no point cloud");
        return Ok(ExitCode::FAILURE);
    }
    Ok(if failed > 0 {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}

/// `profile.png`: the mean diameter and the ovality with their 1-σ band, flagged frames
/// marked, and the geometry ahead, against `x_label`.
fn plot_profile(rows: &[Row], x_label: &str, name: &str) -> anyhow::Result<epd_io::plot::Png> {
    let mut sorted: Vec<&Row> = rows.iter().filter(|r| r.x.is_finite()).collect();
    sorted.sort_by(|a, b| a.x.total_cmp(&b.x));
    let band = |v: fn(&Row) -> Option<(f64, f64)>| -> Vec<Point> {
        sorted
            .iter()
            .map(|r| v(r).map_or(GAP, |(m, s)| (r.x, m, m - s, m + s)))
            .collect()
    };
    let flagged = |v: fn(&Row) -> Option<(f64, f64)>| -> Vec<Point> {
        sorted
            .iter()
            .filter(|r| r.flagged)
            .filter_map(|r| v(r).map(|(m, _)| (r.x, m, m, m)))
            .collect()
    };
    let line = |n: &str, c: RGBColor, p: Vec<Point>| {
        let mut s = Series::line(n, c, p, false);
        s.band = true;
        s
    };
    let marks = |n: &str, c: RGBColor, p: Vec<Point>| {
        let mut s = Series::line(n, c, p, false);
        s.markers_only = true;
        s
    };
    let d_mean = vec![
        line("mean inner diameter ± 1-σ", GREEN, band(|r| r.d_mean)),
        marks("flagged (a note)", RED, flagged(|r| r.d_mean)),
    ];
    let ovality = vec![
        line("ovality ± 1-σ", BLUE, band(|r| r.ovality)),
        marks("flagged (a note)", RED, flagged(|r| r.ovality)),
    ];
    let at = |layout: &str, y: fn(&Row) -> Option<f64>| -> Vec<Point> {
        sorted
            .iter()
            .filter(|r| r.geometry.as_deref() == Some(layout))
            .filter_map(|r| y(r).map(|v| (r.x, v, v, v)))
            .collect()
    };
    let geometry = vec![
        marks("bend ahead", BLUE, at("bend_ahead", |r| r.straight_until)),
        marks("tee ahead", RED, at("tee_ahead", |r| r.straight_until)),
        marks("in a bend (0)", GREEN, at("in_bend", |_| Some(0.0))),
        marks(
            "no result (−0.2)",
            RGBColor(0, 0, 0),
            sorted
                .iter()
                .filter(|r| !r.result)
                .map(|r| (r.x, -0.2, -0.2, -0.2))
                .collect(),
        ),
    ];
    let mut panels = vec![
        Panel {
            title: "mean inner diameter (band: 1-σ)".into(),
            y_label: "mm".into(),
            series: &d_mean,
        },
        Panel {
            title: "ovality (Dmax − Dmin)/D, D the mean diameter (band: 1-σ)".into(),
            y_label: "%".into(),
            series: &ovality,
        },
    ];
    // The geometry panel only when a frame has something ahead or no result.
    if geometry.iter().any(|s| !s.points.is_empty()) {
        panels.push(Panel {
            title: "geometry ahead: where the straight section ends; frames without a result"
                .into(),
            y_label: "m ahead".into(),
            series: &geometry,
        });
    }
    let n = panels.len();
    Ok(render(
        Figure::linear(
            "profile.png",
            format!("{name}: profile of the run ({} frames)", rows.len()),
            (n, 1),
            (1440, 460 * n as u32 + 20),
            x_label,
        ),
        &panels,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use epd_frame::bag::OdometryPosition;

    /// The odometer's distance is the path length (not the straight-line distance), linear
    /// between stamps, and unknown outside the track.
    #[test]
    fn odometer_integrates_the_path_length() {
        let p = |s: i64, x: f64, y: f64| OdometryPosition {
            stamp_ns: s,
            position: [x, y, 0.0],
        };
        // Out 3 m along x, then 4 m along y: 7 m travelled, 5 m from the start.
        let o = Odometer::new(&[p(0, 0.0, 0.0), p(20, 3.0, 4.0), p(10, 3.0, 0.0)]);
        assert_eq!(o.at(0), Some(0.0));
        assert_eq!(o.at(10), Some(3.0));
        assert_eq!(o.at(20), Some(7.0));
        assert_eq!(o.at(15), Some(5.0));
        assert_eq!(o.at(-1), None);
        assert_eq!(o.at(21), None);
    }
}
