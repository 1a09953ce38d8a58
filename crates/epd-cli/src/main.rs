//! `epd`: pipe diameters and sensor pose from point-cloud files.
//!
//! ```text
//! epd estimate FILE… [--method ml-epd|ru-epd|c-epd] [--min-range M] [--max-range M]
//!                    [--format text|json|csv] [--nominal-od-in X] [--loss cauchy|huber|none]
//!                    [--loss-scale M] [--units m|mm] [--frame sensor|optical]
//!                    [--input-format F] [--calibration LUT.json [--unweighted]]
//!                    [-o FILE] [--threads N] [--shard K/N] [-q]
//! epd calibrate FILE… --known-id-mm D [--known-dmin-mm D2] --out LUT.json
//!               [--min-range M] [--max-range M] [--range-bins N] [--intensity-bins N]
//!               [--min-count N] [--passes N] [--units m|mm] [--frame sensor|optical] [--threads N] [-q]
//! epd simulate --out DIR [--frames K] [--seed S] [--sigma M] [--od-in X] [--ovality O]
//!              [--wall-mm T] [--points N] [--outliers F] [--noise range|isotropic]
//!              [--ply binary|ascii] [--precision f64|f32]
//! ```
//! Exit codes: 0 all files estimated, 1 a file failed or its fit did not converge to a
//! result consistent with its points (the others are still reported), 2 wrong arguments.
//! `calibrate` exits 1 when a frame was skipped (the table is written from the others)
//! or none could be used (no table written).

use std::io::{BufWriter, ErrorKind, Write};
use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, Parser, Subcommand, ValueEnum};
use epd_cli::estimate::{
    DEFAULT_LOSS_SCALE_M, EstimateConfig, EstimateSettings, InputConfig, InputFrame, Units,
    estimate_file, intensity, read_input,
};
use epd_cli::read::{Format, PointCloud};
use epd_cli::report::{FileReport, columns};
use epd_cli::shard::ShardSpec;
use epd_cli::table::CalibrationTable;
use epd_core::calibration::{CalibrationFrame, CalibrationSettings, calibrate};
use epd_core::{EstimateOptions, Loss, LossScale, Method};
use indicatif::ProgressBar;
use rayon::prelude::*;

/// Pipe diameters and sensor pose from 3D time-of-flight point clouds (RU-EPD, ML-EPD).
#[derive(Parser, Debug)]
#[command(
    name = "epd",
    version,
    propagate_version = true,
    subcommand_required = true,
    arg_required_else_help = false
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Estimate the pipe and the pose from point-cloud files, one result per file.
    Estimate(EstimateArgs),
    /// Build a depth-calibration table from frames recorded in a pipe of known diameter.
    Calibrate(CalibrateArgs),
    /// Simulate Helios2-like frames (PLY) with their ground truth (JSON).
    Simulate(SimulateArgs),
}

/// The estimator, by its name in reports.
#[derive(Clone, Copy, Debug, ValueEnum)]
#[allow(clippy::enum_variant_names)] // the paper's names
enum MethodArg {
    /// Range residual along the sensing line (maximum likelihood; unbiased across tilt).
    #[value(name = "ml-epd")]
    MlEpd,
    /// The paper's error-based residual (eqs. 20–23).
    #[value(name = "ru-epd")]
    RuEpd,
    /// The canonical-ellipse residual (eq. 6; biased under noise).
    #[value(name = "c-epd")]
    CEpd,
}

impl From<MethodArg> for Method {
    fn from(m: MethodArg) -> Method {
        match m {
            MethodArg::MlEpd => Method::MlEpd,
            MethodArg::RuEpd => Method::RuEpd,
            MethodArg::CEpd => Method::CEpd,
        }
    }
}

/// How results are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum OutputFormat {
    /// A few lines per file, for people.
    Text,
    /// One JSON object per file and line.
    Json,
    /// A header, then one row per file.
    Csv,
}

/// The robust loss.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum LossArg {
    /// Cauchy (far outliers weigh almost nothing).
    Cauchy,
    /// Huber.
    Huber,
    /// Plain least squares.
    None,
}

/// The length unit of the file.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum UnitsArg {
    /// Metres.
    M,
    /// Millimetres (the Helios2 SDK's unit).
    Mm,
}

/// The coordinate frame of the file.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum FrameArg {
    /// X forward (optical axis), Y right, Z up: the paper's frame.
    Sensor,
    /// X right, Y down, Z forward: camera SDKs, PCL, Open3D, ROS.
    Optical,
}

#[derive(Args, Debug)]
struct EstimateArgs {
    /// Point-cloud files: PLY, PCD, CSV/XYZ/TXT/PTS; `-` reads standard input.
    #[arg(required = true, value_name = "FILE")]
    files: Vec<PathBuf>,
    /// The estimator.
    #[arg(long, value_enum, default_value_t = MethodArg::MlEpd)]
    method: MethodArg,
    /// Keep the points whose ray meets the fitted wall at least this far (m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    min_range: Option<f64>,
    /// Keep the points whose ray meets the fitted wall at most this far (m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    max_range: Option<f64>,
    /// How results are written.
    #[arg(long, value_enum, default_value_t = OutputFormat::Text)]
    format: OutputFormat,
    /// Nominal outer diameter (inch): the wall thickness is estimated from it.
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    nominal_od_in: Option<f64>,
    /// Robust loss against outliers.
    #[arg(long, value_enum, default_value_t = LossArg::Cauchy)]
    loss: LossArg,
    /// Fixed loss scale (m of range error); without it the scale comes from the residuals.
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    loss_scale: Option<f64>,
    #[command(flatten)]
    input: InputArgs,
    /// Depth-calibration table (JSON from `epd calibrate`): each point is moved along
    /// its ray by the table's offset at its range and intensity before the fit (the
    /// files need a per-point `intensity`).
    #[arg(long, value_name = "LUT.json")]
    calibration: Option<PathBuf>,
    /// With --calibration, do not weight each residual by 1/σᵢ (σᵢ: the table's spread
    /// at the point's range and intensity).
    #[arg(long)]
    unweighted: bool,
    /// Fit every point as one straight pipe, without looking for a bend or a tee ahead.
    /// By default the frame is surveyed first (JSON keys `geometry`, `straight_until_m`,
    /// `bend_radius_mm`, `bend_angle_deg`, `bend_direction_deg`, `bend_withheld`): the estimate then uses
    /// the straight section's points only, and a sensor already in a bend gets no result.
    #[arg(long)]
    straight_only: bool,
    /// Write the results to FILE (atomically) instead of standard output.
    #[arg(short = 'o', long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<NonZeroUsize>,
    /// Process only the K-th of N parts of the files (1 ≤ K ≤ N), e.g. one task of a
    /// job array: the files are sorted by the bytes of their paths (as `LC_ALL=C ls`)
    /// and cut into N contiguous blocks whose sizes differ by at most one; shard K
    /// takes the K-th block (possibly none). Concatenating the outputs of shards 1, 2,
    /// …, N in that order gives the output of one run over the sorted list, timings
    /// (elapsed_ms, read_ms) aside; with --format csv only shard 1 writes the header
    /// line. Standard input (`-`) cannot be sharded.
    #[arg(long, value_name = "K/N")]
    shard: Option<ShardSpec>,
    /// No progress bar and no summary of failures: only the results and the exit code.
    #[arg(short, long)]
    quiet: bool,
}

/// How the files are read.
#[derive(Args, Debug)]
struct InputArgs {
    /// Length unit of the files.
    #[arg(long, value_enum, default_value_t = UnitsArg::M)]
    units: UnitsArg,
    /// Coordinate frame of the files.
    #[arg(long, value_enum, default_value_t = FrameArg::Sensor)]
    frame: FrameArg,
    /// Format of standard input (ply, pcd, csv, xyz, txt, pts, asc); default: from its
    /// first bytes.
    #[arg(long, value_name = "FORMAT")]
    input_format: Option<Format>,
}

#[derive(Args, Debug)]
struct CalibrateArgs {
    /// Frames recorded in a pipe of known diameter (PLY, PCD, CSV… with a per-point
    /// `intensity`).
    #[arg(required = true, value_name = "FILE")]
    files: Vec<PathBuf>,
    /// The known inner diameter (mm); the major one when --known-dmin-mm is given.
    #[arg(long, value_name = "D", allow_negative_numbers = true)]
    known_id_mm: f64,
    /// The known minor inner diameter (mm) of an oval pipe.
    #[arg(long, value_name = "D2", allow_negative_numbers = true)]
    known_dmin_mm: Option<f64>,
    /// Where the table is written (JSON, atomically).
    #[arg(long, value_name = "LUT.json")]
    out: PathBuf,
    /// Use the points whose ray meets the known wall at least this far (m).
    #[arg(
        long,
        value_name = "M",
        default_value_t = 0.5,
        allow_negative_numbers = true
    )]
    min_range: f64,
    /// Use the points whose ray meets the known wall at most this far (m).
    #[arg(
        long,
        value_name = "M",
        default_value_t = 2.0,
        allow_negative_numbers = true
    )]
    max_range: f64,
    /// Range bins of the table.
    #[arg(long, value_name = "N", default_value_t = 30)]
    range_bins: usize,
    /// Intensity bins of the table (even in log-intensity).
    #[arg(long, value_name = "N", default_value_t = 12)]
    intensity_bins: usize,
    /// A bin with fewer points (at least 5) is empty and takes the nearest filled bin's
    /// values.
    #[arg(long, value_name = "N", default_value_t = 30)]
    min_count: usize,
    /// Passes of the alternating refinement of the poses and the table (1: the poses
    /// fitted once on the raw points).
    #[arg(long, value_name = "N", default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=20))]
    passes: u32,
    #[command(flatten)]
    input: InputArgs,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<NonZeroUsize>,
    /// Only errors.
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Args, Debug)]
struct SimulateArgs {
    /// Folder for frame_KKKK.ply and frame_KKKK.json.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 1)]
    frames: u64,
    /// Seed of the poses and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Standard deviation of the depth noise (m).
    #[arg(long, default_value_t = 0.03, allow_negative_numbers = true)]
    sigma: f64,
    /// Nominal outer diameter (inch).
    #[arg(long, default_value_t = 20.0, allow_negative_numbers = true)]
    od_in: f64,
    /// Ovality (Dmax − Dmin)/ID.
    #[arg(long, default_value_t = 0.02, allow_negative_numbers = true)]
    ovality: f64,
    /// Wall thickness (mm).
    #[arg(long, default_value_t = 12.0, allow_negative_numbers = true)]
    wall_mm: f64,
    /// Keep a uniform subsample of N points (default: all).
    #[arg(long, value_name = "N")]
    points: Option<NonZeroUsize>,
    /// Fraction of range outliers.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    outliers: f64,
    /// Noise model.
    #[arg(long, value_enum, default_value_t = NoiseArg::Range)]
    noise: NoiseArg,
    /// Error model of the camera: `plain` (range noise of --sigma) or `helios2` (the
    /// realistic model: amplitude-dependent noise, invalid pixels written as zeros,
    /// wiggling, intensity offset, multipath; the PLY gets an `intensity` property;
    /// --sigma and --noise do not apply).
    #[arg(long, value_enum, default_value_t = SensorArg::Plain)]
    sensor: SensorArg,
    /// PLY encoding.
    #[arg(long, value_enum, default_value_t = PlyArg::Binary)]
    ply: PlyArg,
    /// PLY coordinate precision.
    #[arg(long, value_enum, default_value_t = PrecisionArg::F64)]
    precision: PrecisionArg,
}

/// Depth-noise model of `simulate`.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum NoiseArg {
    /// Along the sensing line.
    Range,
    /// In no particular direction.
    Isotropic,
}

/// Camera error model of `simulate`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum SensorArg {
    /// Range noise of constant σ.
    Plain,
    /// tof_sim's realistic Helios2 (6 m mode) model.
    Helios2,
}

/// PLY encoding of `simulate`.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum PlyArg {
    /// binary_little_endian.
    Binary,
    /// ascii.
    Ascii,
}

/// PLY precision of `simulate`.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum PrecisionArg {
    /// double.
    #[value(alias = "double")]
    F64,
    /// float.
    #[value(alias = "float")]
    F32,
}

/// A usage error found after parsing (exit code 2).
#[derive(Debug)]
struct Usage(String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for Usage {}

fn usage(msg: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(Usage(msg.into()))
}

/// Refuse an output path that exists but is not a regular file or a link (a device, a
/// pipe, a folder: the atomic write would replace it), or that names one of the inputs.
fn check_output_path(out: &Path, inputs: &[PathBuf], flag: &str) -> anyhow::Result<()> {
    let shown = out.display();
    // A link is replaced, never followed (a planted link cannot redirect the write).
    match std::fs::symlink_metadata(out) {
        Ok(m) if !m.file_type().is_file() && !m.file_type().is_symlink() => {
            return Err(usage(format!(
                "{flag} {shown}: exists and is not a regular file (a device, pipe or folder); \
                 the result replaces the file at that path, so name a new or regular file"
            )));
        }
        _ => {}
    }
    if let Ok(o) = out.canonicalize() {
        for i in inputs {
            if i.canonicalize().is_ok_and(|c| c == o) {
                return Err(usage(format!(
                    "{flag} {shown}: is also an input file; it would be overwritten"
                )));
            }
        }
    }
    Ok(())
}

/// The input settings as the library takes them.
impl From<&InputArgs> for InputConfig {
    fn from(a: &InputArgs) -> Self {
        Self {
            units: match a.units {
                UnitsArg::M => Units::Metres,
                UnitsArg::Mm => Units::Millimetres,
            },
            frame: match a.frame {
                FrameArg::Sensor => InputFrame::Sensor,
                FrameArg::Optical => InputFrame::Optical,
            },
            format: a.input_format,
        }
    }
}

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
    };
    let cfg = EstimateConfig::new(&settings).map_err(|e| usage(e.to_string()))?;
    if a.files.iter().filter(|f| f.as_os_str() == "-").count() > 1 {
        return Err(usage("standard input (`-`) may be given only once"));
    }
    Ok(cfg)
}

/// Where results go: standard output, or a temporary file in the target folder that
/// replaces FILE when the run ends.
enum Sink {
    Stdout(BufWriter<std::io::StdoutLock<'static>>),
    File(BufWriter<tempfile::NamedTempFile>, PathBuf),
}

impl Sink {
    fn open(output: Option<&Path>) -> anyhow::Result<Self> {
        let Some(path) = output else {
            return Ok(Sink::Stdout(BufWriter::new(std::io::stdout().lock())));
        };
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        // Created exclusively, with an unpredictable name: never a planted link.
        let mut builder = tempfile::Builder::new();
        builder.prefix(".epd-output-");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            // A results file for the user, not a secret: rw-r--r-- (umask applies).
            builder.permissions(std::fs::Permissions::from_mode(0o644));
        }
        let tmp = builder
            .tempfile_in(dir)
            .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
        Ok(Sink::File(BufWriter::new(tmp), path.to_path_buf()))
    }

    fn name(&self) -> String {
        match self {
            Sink::Stdout(_) => "standard output".into(),
            Sink::File(_, p) => p.display().to_string(),
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
    /// followed).
    fn finish(self) -> anyhow::Result<()> {
        match self {
            Sink::Stdout(mut w) => w.flush().context("cannot write to standard output"),
            Sink::File(w, path) => {
                let name = path.display().to_string();
                let tmp = w
                    .into_inner()
                    .map_err(|e| e.into_error())
                    .with_context(|| format!("cannot write {name}"))?;
                tmp.as_file()
                    .sync_all()
                    .with_context(|| format!("cannot write {name}"))?;
                tmp.persist(&path)
                    .map_err(|e| e.error)
                    .with_context(|| format!("cannot write {name}"))?;
                Ok(())
            }
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

/// Start rayon's global pool with `threads` workers (unset: one per core).
fn start_threads(threads: Option<NonZeroUsize>) -> anyhow::Result<()> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n.get())
            .build_global()
            .context("cannot start the worker threads")?;
    }
    Ok(())
}

/// A progress bar over `n` files on standard error, hidden with `--quiet`.
fn progress(quiet: bool, n: usize) -> ProgressBar {
    if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(n as u64)
    }
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
        eprintln!("{} of {total} files failed:", failed.len());
        for f in failed {
            eprintln!("  {f}");
        }
    }
    ExitCode::FAILURE
}

fn run_estimate(args: &EstimateArgs) -> anyhow::Result<ExitCode> {
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
                let r = estimate_file(p, &cfg);
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
                    failed.push(format!("{}: {e}", r.file));
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
        eprintln!("{}", uncalibrated_note(uncalibrated, files.len()));
    }
    Ok(failures_exit(&failed, files.len(), args.quiet))
}

/// Check `epd calibrate`'s arguments (exit 2 on a bad one); the known inner diameters
/// (D_max, D_min) in m.
fn calibrate_known(a: &CalibrateArgs) -> anyhow::Result<(f64, f64)> {
    let d_max = a.known_id_mm * 1e-3;
    let d_min = a.known_dmin_mm.unwrap_or(a.known_id_mm) * 1e-3;
    if !(a.known_id_mm > 0.0 && a.known_id_mm.is_finite()) {
        return Err(usage(format!(
            "--known-id-mm {}: expected the pipe's inner diameter in mm (> 0)",
            a.known_id_mm
        )));
    }
    if !(d_min > 0.0 && d_min <= d_max) {
        return Err(usage(format!(
            "--known-dmin-mm {}: expected the minor inner diameter in mm, > 0 and at most \
             --known-id-mm {}",
            d_min * 1e3,
            a.known_id_mm
        )));
    }
    if !(a.min_range >= 0.0 && a.max_range > a.min_range && a.max_range.is_finite()) {
        return Err(usage(format!(
            "--min-range {} and --max-range {}: need 0 ≤ min < max",
            a.min_range, a.max_range
        )));
    }
    if a.range_bins == 0 || a.intensity_bins == 0 || a.range_bins * a.intensity_bins > 1 << 20 {
        return Err(usage(format!(
            "--range-bins {} × --intensity-bins {}: need at least 1 each, at most 2²⁰ bins",
            a.range_bins, a.intensity_bins
        )));
    }
    if a.files.iter().any(|f| f.as_os_str() == "-") {
        return Err(usage("calibrate reads files only (no `-`)"));
    }
    if a.min_count < 5 {
        return Err(usage(format!(
            "--min-count {}: a bin needs at least 5 points to measure a mean and a spread",
            a.min_count
        )));
    }
    check_output_path(&a.out, &a.files, "--out")?;
    Ok((d_max, d_min))
}

/// Every calibration file's points and intensities (the table is binned by intensity),
/// read in parallel, or why not.
fn read_calibration_files(a: &CalibrateArgs) -> Vec<Result<(PointCloud, Vec<f64>), String>> {
    let input: InputConfig = (&a.input).into();
    let bar = progress(a.quiet, a.files.len());
    let read = a
        .files
        .par_iter()
        .with_max_len(1)
        .map(|p| {
            let r = read_input(p, &input).and_then(|c| {
                let i = intensity(&c, "the table is binned by intensity")?;
                Ok((c, i))
            });
            bar.inc(1);
            r
        })
        .collect();
    bar.finish_and_clear();
    read
}

/// Print each frame's fitted pose (unless `quiet`) and add the frames whose fit failed
/// to `failed`; the number of frames used.
fn report_calibration_fits(
    names: &[String],
    fits: &[Result<epd_core::Estimate, epd_core::EpdError>],
    quiet: bool,
    failed: &mut Vec<String>,
) -> usize {
    let deg = 180.0 / std::f64::consts::PI;
    let mut used = 0;
    for (name, fit) in names.iter().zip(fits) {
        match fit {
            Ok(est) => {
                used += 1;
                if !quiet {
                    let p = est.params;
                    eprintln!(
                        "{name}: pose roll {:.2}° pitch {:.3}° yaw {:.3}° δy {:.1} mm δz {:.1} mm, \
                         {} points",
                        p.roll * deg,
                        p.pitch * deg,
                        p.yaw * deg,
                        p.dy * 1e3,
                        p.dz * 1e3,
                        est.n_points,
                    );
                }
            }
            Err(e) => failed.push(format!("{name}: {e}")),
        }
    }
    used
}

/// One line on the written table: its bins, how many hold data, what it was made from and
/// the range of its offsets.
fn print_table_summary(out: &Path, cal: &CalibrationTable) {
    let t = &cal.table;
    let filled = t.count.iter().filter(|&&c| c > 0).count();
    let (lo, hi) = t
        .offset_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    eprintln!(
        "{}: {} × {} bins ({filled} filled) from {} frames and {} points; offsets \
         {:.1} to {:.1} mm",
        out.display(),
        t.range.n,
        t.log_intensity.n,
        cal.frames,
        cal.n_observations,
        lo * 1e3,
        hi * 1e3
    );
}

fn run_calibrate(a: &CalibrateArgs) -> anyhow::Result<ExitCode> {
    let (d_max, d_min) = calibrate_known(a)?;
    start_threads(a.threads)?;
    let options = EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", DEFAULT_LOSS_SCALE_M)?)?
        .with_loss_scale(LossScale::Auto);
    // Every frame is read first: the table and the poses are refined together.
    let read = read_calibration_files(a);
    let mut failed = Vec::new();
    let mut names = Vec::new();
    let mut frames = Vec::new();
    for (path, r) in a.files.iter().zip(&read) {
        match r {
            Ok((c, i)) => {
                names.push(path.display().to_string());
                frames.push(CalibrationFrame {
                    points: &c.points,
                    intensity: i,
                });
            }
            Err(e) => failed.push(format!("{}: {e}", path.display())),
        }
    }
    if frames.is_empty() {
        for f in &failed {
            eprintln!("skipped {f}");
        }
        anyhow::bail!(
            "no frame could be read: no table written to {}",
            a.out.display()
        );
    }
    let settings = CalibrationSettings {
        known: (d_max, d_min),
        gate: (a.min_range, a.max_range),
        bins: (a.range_bins, a.intensity_bins),
        min_count: a.min_count.max(1),
        passes: a.passes as usize,
    };
    let cal = calibrate(&frames, &settings, &options)
        .with_context(|| format!("no table written to {}", a.out.display()))?;
    let used = report_calibration_fits(&names, &cal.fits, a.quiet, &mut failed);
    for f in &failed {
        eprintln!("skipped {f}");
    }
    let cal = CalibrationTable {
        table: cal.table,
        known: (d_max, d_min),
        frames: used,
        n_observations: cal.n_observations as u64,
    };
    epd_io::atomic::write_bytes_atomic(&a.out, cal.to_json().as_bytes())?;
    if !a.quiet {
        print_table_summary(&a.out, &cal);
    }
    Ok(if failed.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

fn run_simulate(a: &SimulateArgs) -> anyhow::Result<ExitCode> {
    use epd_cli::simulate::{PoseOverride, SimulateError, SimulateSettings, Simulator};
    use epd_io::ply::{PlyFormat, PlyPrecision};
    use tof_sim::NoiseModel;
    let (out, frames) = (a.out.clone(), a.frames);
    let format = match a.ply {
        PlyArg::Binary => PlyFormat::BinaryLittleEndian,
        PlyArg::Ascii => PlyFormat::Ascii,
    };
    let precision = match a.precision {
        PrecisionArg::F64 => PlyPrecision::F64,
        PrecisionArg::F32 => PlyPrecision::F32,
    };
    let sim = Simulator::new(&SimulateSettings {
        seed: a.seed,
        sigma: a.sigma,
        od_in: a.od_in,
        ovality: a.ovality,
        wall_mm: a.wall_mm,
        points: a.points,
        outliers: a.outliers,
        noise: match a.noise {
            NoiseArg::Range => NoiseModel::Range,
            NoiseArg::Isotropic => NoiseModel::Isotropic,
        },
        helios2: a.sensor == SensorArg::Helios2,
        pose: PoseOverride::default(),
    })
    .map_err(|e| match e {
        SimulateError::Setting(m) => usage(m),
        SimulateError::Sim(e) => e.into(),
    })?;
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut frame = tof_sim::Frame::empty();
    let bar = ProgressBar::new(frames);
    for k in 0..frames {
        sim.frame(k, &mut frame)?;
        let stem = format!("frame_{k:04}");
        epd_io::ply::save(&out.join(format!("{stem}.ply")), &frame, format, precision)?;
        let json = format!("{}\n", epd_io::json::object(&sim.truth(k, &frame)));
        epd_io::atomic::write_bytes_atomic(&out.join(format!("{stem}.json")), json.as_bytes())?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    eprintln!(
        "{frames} frames written to {} (PLY + ground-truth JSON)",
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    epd_cli::keep_freed_memory();
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        // Help and version exit 0, usage errors 2 (clap's codes); a closed stdout while
        // printing help is ignored.
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    let result = match &cli.command {
        Command::Estimate(a) => run_estimate(a),
        Command::Calibrate(a) => run_calibrate(a),
        Command::Simulate(a) => run_simulate(a),
    };
    match result {
        Ok(code) => code,
        Err(e) if e.downcast_ref::<Usage>().is_some() => {
            eprintln!("error: {e}\n\nFor more information, try '--help'.");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
