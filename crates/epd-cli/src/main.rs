//! `epd`: pipe diameters and sensor pose from point-cloud files.
//!
//! ```text
//! epd estimate FILE… [--method ru-epd|c-epd|ml-epd] [--min-range M] [--max-range M]
//!                    [--format text|json|csv] [--nominal-od-in X] [--loss cauchy|huber|none]
//!                    [--loss-scale M]
//! epd simulate --out DIR [--frames K] [--seed S] [--sigma M] [--od-in X] [--ovality O]
//!              [--wall-mm T] [--points N] [--outliers F] [--noise range|isotropic]
//!              [--ply binary|ascii] [--precision f64|f32]
//! ```
//! Exit codes: 0 all files estimated, 1 a file failed (the others are still reported),
//! 2 wrong arguments.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use epd_cli::read::read_path;
use epd_cli::report::{FileEstimate, FileReport, columns};
use epd_core::{EstimateOptions, Loss, Method, estimate, rms_range_residual};
use indicatif::ProgressBar;
use rayon::prelude::*;

const USAGE: &str = "usage:
  epd estimate FILE… [--method ru-epd|c-epd|ml-epd] [--min-range M] [--max-range M]
                     [--format text|json|csv] [--nominal-od-in X] [--loss cauchy|huber|none] [--loss-scale M]
  epd simulate --out DIR [--frames K] [--seed S] [--sigma M] [--od-in X] [--ovality O] [--wall-mm T]
               [--points N] [--outliers F] [--noise range|isotropic] [--ply binary|ascii] [--precision f64|f32]";

/// Default robust loss: Cauchy with a 0.05 m scale (see README, "Outliers").
const DEFAULT_LOSS: &str = "cauchy";
const DEFAULT_LOSS_SCALE_M: f64 = 0.05;

/// A usage error (exit code 2).
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

/// Raw flags as (name, value) pairs plus positional arguments.
struct Flags {
    pairs: Vec<(String, String)>,
    positional: Vec<String>,
}

impl Flags {
    fn parse(args: &[String], known: &[&str]) -> anyhow::Result<Self> {
        let mut pairs = Vec::new();
        let mut positional = Vec::new();
        let mut it = args.iter();
        while let Some(a) = it.next() {
            if let Some(name) = a.strip_prefix("--") {
                if !known.contains(&name) {
                    return Err(usage(format!("unknown option `{a}`")));
                }
                let v = it
                    .next()
                    .ok_or_else(|| usage(format!("{a} needs a value")))?;
                pairs.push((name.to_string(), v.clone()));
            } else {
                positional.push(a.clone());
            }
        }
        Ok(Self { pairs, positional })
    }

    fn get(&self, name: &str) -> Option<&str> {
        self.pairs
            .iter()
            .rev()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }

    fn num<T: std::str::FromStr>(&self, name: &str, default: T, what: &str) -> anyhow::Result<T> {
        match self.get(name) {
            None => Ok(default),
            Some(v) => v
                .parse()
                .map_err(|_| usage(format!("--{name} {v}: expected {what}"))),
        }
    }
}

/// Checked settings of `epd estimate`.
struct EstimateConfig {
    files: Vec<PathBuf>,
    method: Method,
    min_range: f64,
    max_range: f64,
    format: String,
    nominal_od_mm: Option<f64>,
    options: EstimateOptions,
    loss: (String, f64),
}

fn estimate_config(args: &[String]) -> anyhow::Result<EstimateConfig> {
    let f = Flags::parse(
        args,
        &[
            "method",
            "min-range",
            "max-range",
            "format",
            "nominal-od-in",
            "loss",
            "loss-scale",
        ],
    )?;
    if f.positional.is_empty() {
        return Err(usage("no input file: epd estimate FILE…"));
    }
    let method: Method = f
        .get("method")
        .unwrap_or("ru-epd")
        .parse()
        .map_err(|e: epd_core::EpdError| usage(e.to_string()))?;
    let min_range = f.num("min-range", 0.0, "a range in metres")?;
    let max_range = f.num("max-range", f64::INFINITY, "a range in metres")?;
    if !(min_range >= 0.0 && max_range > min_range) {
        return Err(usage(format!(
            "--min-range {min_range} and --max-range {max_range}: need 0 ≤ min < max"
        )));
    }
    let format = f.get("format").unwrap_or("text").to_string();
    if !["text", "json", "csv"].contains(&format.as_str()) {
        return Err(usage(format!(
            "--format {format}: expected text, json or csv"
        )));
    }
    let nominal_od_mm = match f.get("nominal-od-in") {
        None => None,
        Some(v) => match v.parse::<f64>() {
            Ok(x) if x > 0.0 && x.is_finite() => Some(x * 25.4),
            _ => {
                return Err(usage(format!(
                    "--nominal-od-in {v}: expected a diameter in inches > 0"
                )));
            }
        },
    };
    let loss_name = f.get("loss").unwrap_or(DEFAULT_LOSS).to_string();
    let scale = f.num("loss-scale", DEFAULT_LOSS_SCALE_M, "a scale in metres")?;
    let loss = Loss::from_name(&loss_name, scale)
        .map_err(|e| usage(format!("--loss/--loss-scale: {e}")))?;
    let options = EstimateOptions::default()
        .with_loss(loss)
        .map_err(|e| usage(e.to_string()))?;
    Ok(EstimateConfig {
        files: f.positional.iter().map(PathBuf::from).collect(),
        method,
        min_range,
        max_range,
        format,
        nominal_od_mm,
        options,
        loss: (
            loss.name().into(),
            if loss == Loss::Squared {
                f64::NAN
            } else {
                scale
            },
        ),
    })
}

/// Read, filter and estimate one file.
fn estimate_file(path: &Path, cfg: &EstimateConfig) -> FileReport {
    let file = path.display().to_string();
    let run = || -> Result<FileEstimate, String> {
        let t0 = Instant::now();
        let cloud = read_path(path)?;
        let read_ms = t0.elapsed().as_secs_f64() * 1e3;
        let n_read = cloud.points.len();
        if n_read == 0 {
            return Err("the file holds no points".into());
        }
        // Invalid pixels (NaN, inf, zeros) are dropped and counted; then the range filter.
        let valid = |p: &[f64; 3]| p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0);
        let n_invalid = cloud.points.iter().filter(|p| !valid(p)).count();
        let mut kept = cloud.points;
        kept.retain(|p| {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            valid(p) && r >= cfg.min_range && r <= cfg.max_range
        });
        let n_out_of_range = n_read - n_invalid - kept.len();
        let t1 = Instant::now();
        let mut est = estimate(&kept, cfg.method, &cfg.options).map_err(|e| {
            format!(
                "{e} ({n_read} points read, {n_invalid} invalid, {n_out_of_range} out of range)"
            )
        })?;
        let elapsed_ms = t1.elapsed().as_secs_f64() * 1e3;
        est.n_dropped = n_invalid;
        Ok(FileEstimate {
            rms_residual_mm: rms_range_residual(&kept, &est.params).map(|v| v * 1e3),
            estimate: est,
            n_read,
            n_out_of_range,
            elapsed_ms,
            read_ms,
            loss: cfg.loss.clone(),
            nominal_od_mm: cfg.nominal_od_mm,
        })
    };
    FileReport {
        file,
        outcome: run(),
    }
}

fn run_estimate(args: &[String]) -> anyhow::Result<ExitCode> {
    let cfg = estimate_config(args)?;
    let bar = ProgressBar::new(cfg.files.len() as u64);
    if cfg.format == "csv" {
        println!("{}", columns().join(","));
    }
    let batch = 2 * rayon::current_num_threads().max(1);
    let mut failed = Vec::new();
    for chunk in cfg.files.chunks(batch) {
        let reports: Vec<FileReport> = chunk
            .par_iter()
            .map(|p| {
                let r = estimate_file(p, &cfg);
                bar.inc(1);
                r
            })
            .collect();
        bar.suspend(|| {
            for r in &reports {
                match cfg.format.as_str() {
                    "json" => println!("{}", r.json()),
                    "csv" => println!("{}", r.csv()),
                    _ => println!("{}", r.text()),
                }
                if let Err(e) = &r.outcome {
                    failed.push(format!("{}: {e}", r.file));
                }
            }
        });
    }
    bar.finish_and_clear();
    if failed.is_empty() {
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!("{} of {} files failed:", failed.len(), cfg.files.len());
        for f in &failed {
            eprintln!("  {f}");
        }
        Ok(ExitCode::FAILURE)
    }
}

fn run_simulate(args: &[String]) -> anyhow::Result<ExitCode> {
    use tof_sim::output::{PlyFormat, PlyPrecision, save_ply, write_file_atomic};
    use tof_sim::{
        FrameSeed, Noise, NoiseModel, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel,
        simulate_into,
    };
    let f = Flags::parse(
        args,
        &[
            "out",
            "frames",
            "seed",
            "sigma",
            "od-in",
            "ovality",
            "wall-mm",
            "points",
            "outliers",
            "noise",
            "ply",
            "precision",
        ],
    )?;
    if let Some(p) = f.positional.first() {
        return Err(usage(format!("unexpected argument `{p}`")));
    }
    let out = PathBuf::from(f.get("out").ok_or_else(|| usage("--out DIR is required"))?);
    let frames: u64 = f.num("frames", 1, "a whole number of frames")?;
    let seed: u64 = f.num("seed", 1, "a whole number")?;
    let pipe = Pipe {
        nominal_od_in: f.num("od-in", 20.0, "a diameter in inches")?,
        wall_thickness: f.num("wall-mm", 12.0, "a thickness in mm")? * 1e-3,
        ovality: f.num("ovality", 0.02, "a number in [0, 1)")?,
    };
    let noise = Noise {
        model: match f.get("noise").unwrap_or("range") {
            "range" => NoiseModel::Range,
            "isotropic" => NoiseModel::Isotropic,
            other => {
                return Err(usage(format!(
                    "--noise {other}: expected range or isotropic"
                )));
            }
        },
        sigma: f.num("sigma", 0.03, "a standard deviation in metres")?,
        outlier_fraction: f.num("outliers", 0.0, "a fraction in [0, 1]")?,
        far_outlier_fraction: 0.0,
        bias_b0: 0.0,
        bias_b1: 0.0,
    };
    let sub = match f.get("points") {
        None => Subsample::All,
        Some(v) => Subsample::Points(
            v.parse()
                .ok()
                .filter(|&n: &usize| n > 0)
                .ok_or_else(|| usage(format!("--points {v}: expected a whole number ≥ 1")))?,
        ),
    };
    let format = match f.get("ply").unwrap_or("binary") {
        "binary" => PlyFormat::BinaryLittleEndian,
        "ascii" => PlyFormat::Ascii,
        other => return Err(usage(format!("--ply {other}: expected binary or ascii"))),
    };
    let precision = match f.get("precision").unwrap_or("f64") {
        "f64" | "double" => PlyPrecision::F64,
        "f32" | "float" => PlyPrecision::F32,
        other => return Err(usage(format!("--precision {other}: expected f64 or f32"))),
    };
    let sensor = Sensor::helios2();
    sensor.validate()?;
    noise.validate().map_err(|e| usage(e.to_string()))?;
    pipe.validate().map_err(|e| usage(e.to_string()))?;
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut frame = tof_sim::Frame::empty();
    let bar = ProgressBar::new(frames);
    for k in 0..frames {
        let truth = PoseRanges::default().sample(&pipe, seed, k)?;
        let scene = Scene::new(&truth, WallModel::Exact, sensor.max_range)?;
        simulate_into(
            &sensor,
            &scene,
            &noise,
            sub,
            FrameSeed {
                seed,
                trial: k,
                sweep_index: 0,
            },
            &mut frame,
        )?;
        let stem = format!("frame_{k:04}");
        save_ply(&out.join(format!("{stem}.ply")), &frame, format, precision)?;
        let t = epd_core::canonicalize(&truth);
        let deg = 180.0 / std::f64::consts::PI;
        let json = format!(
            "{{\"d_max_mm\":{},\"d_min_mm\":{},\"roll_deg\":{},\"pitch_deg\":{},\"yaw_deg\":{},\"dy_mm\":{},\"dz_mm\":{},\
             \"n_points\":{},\"seed\":{seed},\"trial\":{k},\"sigma_m\":{},\"outlier_fraction\":{}}}\n",
            t.d_max * 1e3,
            t.d_min * 1e3,
            t.roll * deg,
            t.pitch * deg,
            t.yaw * deg,
            t.dy * 1e3,
            t.dz * 1e3,
            frame.len(),
            noise.sigma,
            noise.outlier_fraction
        );
        write_file_atomic(&out.join(format!("{stem}.json")), |w| {
            std::io::Write::write_all(w, json.as_bytes())
        })?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    eprintln!(
        "{frames} frames written to {} (PLY + ground-truth JSON)",
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn run() -> anyhow::Result<ExitCode> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("estimate") => run_estimate(&args[1..]),
        Some("simulate") => run_simulate(&args[1..]),
        Some("-h" | "--help" | "help") => {
            println!("{USAGE}");
            Ok(ExitCode::SUCCESS)
        }
        Some(other) => bail!(Usage(format!(
            "unknown command `{other}`: expected estimate or simulate"
        ))),
        None => bail!(Usage("no command given".into())),
    }
}

fn main() -> ExitCode {
    match run() {
        Ok(code) => code,
        Err(e) if e.downcast_ref::<Usage>().is_some() => {
            eprintln!("error: {e}\n{USAGE}");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
