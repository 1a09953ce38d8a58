//! `epd estimate`: every file measured by the frame library (`epd_frame::measure_file`),
//! in parallel, the results written in input order to standard output or a file replaced
//! whole at the end.

use std::io::{BufWriter, ErrorKind, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use epd_frame::report::{FileReport, columns};
use epd_frame::shard::ShardSpec;
use epd_frame::{EstimateConfig, EstimateSettings, measure_file};
use rayon::prelude::*;

use crate::args::{EstimateArgs, LossArg, OutputFormat};
use epd_io::stderr_line;

use crate::{check_output_path, progress, start_threads, usage};

fn estimate_config(a: &EstimateArgs) -> anyhow::Result<EstimateConfig> {
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
    let cfg = EstimateConfig::new(&settings).map_err(|e| usage(e.to_string()))?;
    if a.files.iter().filter(|f| f.as_os_str() == "-").count() > 1 {
        return Err(usage("standard input (`-`) may be given only once"));
    }
    Ok(cfg)
}

/// Where results go: standard output, or FILE: a temporary file in its folder that
/// replaces it when the run ends, or FILE itself when it is a device or a pipe
/// (`epd_io::atomic::Output`).
enum Sink {
    Stdout(BufWriter<std::io::StdoutLock<'static>>),
    File(epd_io::atomic::Output, PathBuf),
}

impl Sink {
    fn open(output: Option<&Path>) -> anyhow::Result<Self> {
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

    fn line(&mut self, text: &str) -> std::io::Result<()> {
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
fn finish_output(sink: Sink) -> anyhow::Result<()> {
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

pub fn run_estimate(args: &EstimateArgs) -> anyhow::Result<ExitCode> {
    let cfg = estimate_config(args)?;
    let files = shard_files(&args.files, args.shard)?;
    start_threads(args.threads)?;
    let bar = progress(args.quiet, files.len());
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
    let batch = 2 * rayon::current_num_threads().max(1);
    for chunk in files.chunks(batch) {
        if !open {
            break;
        }
        let reports: Vec<FileReport> = chunk
            .par_iter()
            .map(|p| {
                let r = measure_file(p, &cfg);
                bar.inc(1);
                r
            })
            .collect();
        let mut result = Ok(());
        bar.suspend(|| {
            for r in &reports {
                let text = match args.format {
                    OutputFormat::Json => r.json(),
                    OutputFormat::Csv => r.csv(),
                    OutputFormat::Text => r.text(),
                };
                if let Some(e) = r.failure() {
                    failed.push(format!("{}: {e}", r.shown_file()));
                }
                uncalibrated +=
                    usize::from(r.outcome.as_ref().is_ok_and(|e| e.intensity_without_table));
                match write(&mut sink, &text) {
                    Ok(true) => {}
                    Ok(false) => {
                        open = false;
                        break;
                    }
                    Err(e) => {
                        result = Err(e);
                        break;
                    }
                }
            }
        });
        result?;
    }
    bar.finish_and_clear();
    if open {
        finish_output(sink)?;
    }
    if uncalibrated > 0 && !args.quiet {
        stderr_line!("{}", uncalibrated_note(uncalibrated, files.len()));
    }
    Ok(failures_exit(&failed, files.len(), args.quiet))
}
