//! `epd estimate`: every file measured by the frame library (`epd_frame::measure_file`),
//! and every PointCloud2 message of a bag's topic (`epd_frame::bag`), a few at a time in
//! parallel (the next few read while they are measured), the results written in input
//! order to standard output or a file replaced whole at the end.

use std::io::{BufWriter, ErrorKind, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use epd_frame::bag::{BagFrame, BagFrames, damage_report, is_bag, measure_message, topics};
use epd_frame::report::{FileReport, columns};
use epd_frame::shard::ShardSpec;
use epd_frame::{EstimateConfig, EstimateSettings, measure_file};

use crate::args::{EstimateArgs, FitArgs, LossArg, OutputFormat};
use epd_io::stderr_line;

use crate::{check_output_path, progress, start_threads, usage};

/// The frame library's settings of the fit flags (a usage error names a wrong value).
pub(crate) fn fit_config(a: &FitArgs) -> anyhow::Result<EstimateConfig> {
    let loss_name = match a.loss {
        LossArg::Cauchy => "cauchy",
        LossArg::Huber => "huber",
        LossArg::None => "none",
    };
    let settings = EstimateSettings {
        method: a.method.into(),
        min_range: a.min_range,
        max_range: a.max_range,
        nominal_od_in: a.nominal_od_in,
        loss: loss_name.into(),
        loss_scale: a.loss_scale,
        calibration: a.calibration.clone(),
        unweighted: a.unweighted,
        geometry: !a.straight_only,
        input: (&a.input).into(),
        max_points: a.max_points,
        sampling: a.sampling.into(),
    };
    EstimateConfig::new(&settings).map_err(|e| usage(e.to_string()))
}

fn estimate_config(a: &EstimateArgs) -> anyhow::Result<EstimateConfig> {
    let cfg = fit_config(&a.fit)?;
    if a.files.iter().filter(|f| f.as_os_str() == "-").count() > 1 {
        return Err(usage("standard input (`-`) may be given only once"));
    }
    Ok(cfg)
}

/// Where results go: standard output, or FILE: a temporary file in its folder that
/// replaces it when the run ends, or FILE itself when it is a device or a pipe
/// (`epd_io::atomic::Output`).
pub(crate) enum Sink {
    Stdout(BufWriter<std::io::StdoutLock<'static>>),
    File(epd_io::atomic::Output, PathBuf),
}

impl Sink {
    pub(crate) fn open(output: Option<&Path>) -> anyhow::Result<Self> {
        let Some(path) = output else {
            return Ok(Sink::Stdout(BufWriter::new(std::io::stdout().lock())));
        };
        // Created exclusively, with an unpredictable name: never a planted link.
        let out = epd_io::atomic::Output::create(path, ".epd-output-")
            .with_context(|| format!("cannot write {}", epd_io::name::shown(path)))?;
        Ok(Sink::File(out, path.to_path_buf()))
    }

    fn name(&self) -> String {
        match self {
            Sink::Stdout(_) => "standard output".into(),
            Sink::File(_, p) => epd_io::name::shown(p),
        }
    }

    pub(crate) fn line(&mut self, text: &str) -> std::io::Result<()> {
        let w: &mut dyn Write = match self {
            Sink::Stdout(w) => w,
            Sink::File(w, _) => w,
        };
        w.write_all(text.as_bytes())?;
        w.write_all(b"\n")
    }

    /// Flush; a file is synced and renamed over FILE (a link there is replaced, not
    /// followed), then its folder synced.
    fn finish(self) -> anyhow::Result<()> {
        match self {
            Sink::Stdout(mut w) => w.flush().context("cannot write to standard output"),
            Sink::File(out, path) => out
                .commit()
                .with_context(|| format!("cannot write {}", epd_io::name::shown(&path))),
        }
    }
}

/// Whether an output error is a closed pipe (a reader such as `head` went away).
fn closed_pipe(e: &std::io::Error) -> bool {
    e.kind() == ErrorKind::BrokenPipe
}

/// The files a run estimates, in output order: all of them as given, or with
/// `--shard K/N` the K-th contiguous block of the list sorted by path bytes.
fn shard_files(files: &[PathBuf], shard: Option<ShardSpec>) -> anyhow::Result<Vec<PathBuf>> {
    let Some(shard) = shard else {
        return Ok(files.to_vec());
    };
    if files.iter().any(|f| f.as_os_str() == "-") {
        return Err(usage(format!(
            "--shard {shard}: standard input (`-`) cannot be split between shards; name files"
        )));
    }
    let mut sorted = files.to_vec();
    sorted.sort_by(|a, b| {
        a.as_os_str()
            .as_encoded_bytes()
            .cmp(b.as_os_str().as_encoded_bytes())
    });
    let block = shard.block(sorted.len());
    Ok(sorted.drain(block).collect())
}

/// Flush the output; a reader that went away before the last flush is not an error of ours.
pub(crate) fn finish_output(sink: Sink) -> anyhow::Result<()> {
    let Err(e) = sink.finish() else {
        return Ok(());
    };
    let pipe = e
        .chain()
        .any(|c| c.downcast_ref::<std::io::Error>().is_some_and(closed_pipe));
    if pipe { Ok(()) } else { Err(e) }
}

/// The note for `n` of `total` files that carried a camera's intensity and were
/// estimated without a depth table.
fn uncalibrated_note(n: usize, total: usize) -> String {
    format!(
        "note: {n} of {total} files carry a per-point intensity (a ToF camera's frame) and were \
         estimated without --calibration: the camera's systematic range error (multipath, \
         wiggling, intensity offset) is in their diameters (tens of mm for a Helios2 in a 20\" \
         pipe: +21 mm in simulation). Build a depth table with `epd calibrate` in a pipe of \
         known diameter and pass it with --calibration"
    )
}

/// Exit 0 if no file failed, else list them (unless `quiet`) and exit 1.
fn failures_exit(failed: &[String], total: usize, quiet: bool) -> ExitCode {
    if failed.is_empty() {
        return ExitCode::SUCCESS;
    }
    if !quiet {
        // One line per file: control characters in names and messages escaped.
        let mut list = format!("{} of {total} files failed:", failed.len());
        for f in failed {
            list.push_str("\n  ");
            list.push_str(&epd_io::name::escape_controls(f));
        }
        stderr_line!("{list}");
    }
    ExitCode::FAILURE
}

/// One input of a run: a point-cloud file, a bag with the topic read from it (and its
/// number of messages there), or an input that failed before it could be read.
pub(crate) enum Input {
    File(PathBuf),
    Bag {
        path: PathBuf,
        topic: String,
        messages: u64,
    },
    Failed(Box<FileReport>),
}

/// The inputs, a bag's topic chosen (`--topic`, or its only PointCloud2 topic): a bag whose
/// topic cannot be chosen is a usage error (nothing is estimated); one that cannot be read
/// is a failed input.
pub(crate) fn resolve_inputs(
    files: Vec<PathBuf>,
    topic: Option<&str>,
) -> anyhow::Result<Vec<Input>> {
    let mut inputs = Vec::with_capacity(files.len());
    let mut any_bag = false;
    for path in files {
        if path.as_os_str() == "-" || !is_bag(&path) {
            inputs.push(Input::File(path));
            continue;
        }
        any_bag = true;
        let found = match topics(&path) {
            Ok(t) => t,
            Err(e) => {
                inputs.push(Input::Failed(Box::new(damage_report(&path, &e))));
                continue;
            }
        };
        let chosen = match (found.choose(topic), &found.damaged) {
            (Ok(c), _) => c,
            // The topic is not among those read before the damage: the damage is what is
            // wrong (the bag is cut or broken before its point clouds), not the command.
            (Err(_), Some(damage)) => {
                inputs.push(Input::Failed(Box::new(damage_report(&path, damage))));
                continue;
            }
            (Err(e), None) => {
                return Err(usage(format!("{}: {e}", epd_io::name::shown(&path))));
            }
        };
        let messages = found
            .topics
            .iter()
            .find(|t| t.topic == chosen)
            .map_or(0, |t| t.count);
        inputs.push(Input::Bag {
            path,
            topic: chosen,
            messages,
        });
    }
    if let Some(t) = topic
        && !any_bag
    {
        return Err(usage(format!(
            "--topic {t}: applies to ROS 2 bags (an .mcap file or a rosbag2 folder), and no \
             input is one"
        )));
    }
    Ok(inputs)
}

/// One thing to measure: a file, a bag's message, or a report already made (an input
/// that failed, a bag's damage).
pub(crate) enum Work {
    File(PathBuf),
    Message(Box<BagFrame>),
    Done(Box<FileReport>),
}

impl Work {
    pub(crate) fn measure(self, cfg: &EstimateConfig) -> FileReport {
        match self {
            Work::File(p) => measure_file(&p, cfg),
            Work::Message(m) => measure_message(*m, cfg),
            Work::Done(r) => *r,
        }
    }
}

/// The work of the inputs in order, a bag's messages read one at a time as they are
/// taken.
struct Queue<'a> {
    inputs: std::slice::Iter<'a, Input>,
    bag: Option<OpenBag<'a>>,
}

/// The bag being read: its path, topic, the messages its summary lists for the topic, those
/// read so far, and the reader.
struct OpenBag<'a> {
    path: &'a Path,
    topic: &'a str,
    listed: u64,
    read: u64,
    frames: BagFrames,
}

impl OpenBag<'_> {
    /// When the bag ends: a report for the messages its summary lists that were never read
    /// (none at all: an empty topic, or channel or chunk records the reader could not use),
    /// so that a bag that gives fewer frames than it holds is not passed over in silence.
    fn shortfall(&self) -> Option<FileReport> {
        let why = if self.listed == 0 {
            format!(
                "topic `{}` holds no message: nothing to estimate",
                self.topic
            )
        } else if self.read < self.listed {
            format!(
                "{} of the {} messages the bag lists for topic `{}` were read: the records \
                 holding the others are damaged or unreadable (`epd topics` lists what the \
                 summary says)",
                self.read, self.listed, self.topic
            )
        } else {
            return None;
        };
        Some(FileReport::of_path(self.path, Err(why)))
    }
}

impl Iterator for Queue<'_> {
    type Item = Work;

    fn next(&mut self) -> Option<Work> {
        loop {
            if let Some(bag) = &mut self.bag {
                match bag.frames.next() {
                    Some(Ok(m)) => {
                        bag.read += 1;
                        return Some(Work::Message(Box::new(m)));
                    }
                    Some(Err(e)) => {
                        let r = damage_report(bag.path, &e);
                        self.bag = None;
                        return Some(Work::Done(Box::new(r)));
                    }
                    None => {
                        let short = bag.shortfall();
                        self.bag = None;
                        if let Some(r) = short {
                            return Some(Work::Done(Box::new(r)));
                        }
                    }
                }
            }
            match self.inputs.next()? {
                Input::File(p) => return Some(Work::File(p.clone())),
                Input::Failed(r) => return Some(Work::Done(r.clone())),
                Input::Bag {
                    path,
                    topic,
                    messages,
                } => match BagFrames::open(path, topic) {
                    Ok(frames) => {
                        self.bag = Some(OpenBag {
                            path,
                            topic,
                            listed: *messages,
                            read: 0,
                            frames,
                        })
                    }
                    Err(e) => return Some(Work::Done(Box::new(damage_report(path, &e)))),
                },
            }
        }
    }
}

/// Whether two output paths name the same file: the same folder (links resolved) and the
/// same name, whether or not the file exists yet (a link at the path itself is replaced by
/// the output, so it is not followed).
fn same_place(a: &Path, b: &Path) -> bool {
    let place = |p: &Path| {
        let parent = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        (
            parent.canonicalize().ok(),
            p.file_name().map(|n| n.to_os_string()),
        )
    };
    let (pa, pb) = (place(a), place(b));
    a == b || (pa.0.is_some() && pa == pb)
}

/// `--export-fit OUT.ply`: the one input measured, its report written as usual, and its
/// fit written to OUT.ply (`epd_frame::export`).
fn run_export(args: &EstimateArgs, out: &Path, cfg: &EstimateConfig) -> anyhow::Result<ExitCode> {
    let [file] = args.files.as_slice() else {
        return Err(usage(format!(
            "--export-fit: one input file at a time ({} given)",
            args.files.len()
        )));
    };
    if file.as_os_str() == "-" || is_bag(file) {
        return Err(usage(
            "--export-fit: the input must be a point-cloud file (PLY, PCD, CSV…), not standard              input or a bag",
        ));
    }
    check_output_path(out, &args.files, "--export-fit")?;
    if let Some(o) = &args.output {
        check_output_path(o, &args.files, "-o")?;
        if same_place(o, out) {
            return Err(usage(format!(
                "-o and --export-fit name the same file ({}): the fitted wall would replace \
                 the results; give them different names",
                epd_io::name::shown(out)
            )));
        }
    }
    start_threads(args.threads)?;
    let (report, fitted) = epd_frame::export::fit_file(file, cfg);
    let mut sink = Sink::open(args.output.as_deref())?;
    let text = match args.format {
        OutputFormat::Json => report.json(),
        OutputFormat::Csv => format!("{}\n{}", epd_io::csv::line(columns()), report.csv()),
        OutputFormat::Text => report.text(),
    };
    if let Err(e) = sink.line(&text)
        && !closed_pipe(&e)
    {
        return Err(e).with_context(|| format!("cannot write to {}", sink.name()));
    }
    finish_output(sink)?;
    let fitted = fitted.map_err(|e| anyhow::anyhow!("--export-fit: {e}"))?;
    let mut bytes = Vec::new();
    epd_frame::export::write_fit_ply(&mut bytes, &fitted, cfg.input.units, cfg.input.frame)
        .context("--export-fit")?;
    epd_io::atomic::write_bytes_atomic(out, &bytes)
        .with_context(|| format!("cannot write {}", epd_io::name::shown(out)))?;
    if !args.quiet {
        stderr_line!(
            "fit written to {}: {} points with residual_mm, {} mesh vertices, {} triangles",
            epd_io::name::shown(out),
            fitted.points.len(),
            fitted.mesh.vertices.len(),
            fitted.mesh.faces.len()
        );
    }
    Ok(ExitCode::SUCCESS)
}

pub fn run_estimate(args: &EstimateArgs) -> anyhow::Result<ExitCode> {
    let cfg = estimate_config(args)?;
    if let Some(out) = &args.export_fit {
        return run_export(args, out, &cfg);
    }
    let files = shard_files(&args.files, args.shard)?;
    let inputs = resolve_inputs(files, args.topic.as_deref())?;
    let total: u64 = inputs
        .iter()
        .map(|i| match i {
            Input::Bag { messages, .. } => *messages,
            _ => 1,
        })
        .sum();
    start_threads(args.threads)?;
    let bar = progress(args.quiet, usize::try_from(total).unwrap_or(usize::MAX));
    if let Some(out) = &args.output {
        check_output_path(out, &args.files, "-o")?;
    }
    let mut sink = Sink::open(args.output.as_deref())?;
    let mut failed = Vec::new();
    let mut uncalibrated = 0usize;
    let write = |sink: &mut Sink, text: &str| -> anyhow::Result<bool> {
        match sink.line(text) {
            Ok(()) => Ok(true),
            Err(e) if closed_pipe(&e) => Ok(false),
            Err(e) => Err(e).with_context(|| format!("cannot write to {}", sink.name())),
        }
    };
    let mut open = true;
    // Shards 2..N leave the header out: their outputs concatenate into one table.
    if args.format == OutputFormat::Csv && args.shard.is_none_or(|s| s.k() == 1) {
        open = write(&mut sink, &epd_io::csv::line(columns()))?;
    }
    // A few inputs (or bag messages) measured at a time, the next read as one finishes:
    // memory holds a few frames, whatever the length of a bag (`crate::stream`).
    let queue = Queue {
        inputs: inputs.iter(),
        bag: None,
    };
    let mut n_reports = 0usize;
    let measure = |w: Work| {
        let r = w.measure(&cfg);
        bar.inc(1);
        r
    };
    crate::stream::in_order(queue, measure, |r: FileReport| {
        n_reports += 1;
        let text = match args.format {
            OutputFormat::Json => r.json(),
            OutputFormat::Csv => r.csv(),
            OutputFormat::Text => r.text(),
        };
        if let Some(e) = r.failure() {
            failed.push(format!("{}: {e}", r.shown_file()));
        }
        uncalibrated += usize::from(r.outcome.as_ref().is_ok_and(|e| e.intensity_without_table));
        open = bar.suspend(|| write(&mut sink, &text))?;
        Ok(open)
    })?;
    bar.finish_and_clear();
    if open {
        finish_output(sink)?;
    }
    if uncalibrated > 0 && !args.quiet {
        stderr_line!("{}", uncalibrated_note(uncalibrated, n_reports));
    }
    Ok(failures_exit(&failed, n_reports, args.quiet))
}
