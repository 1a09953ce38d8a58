//! `epd`: pipe diameters and sensor pose from point-cloud files.
//!
//! ```text
//! epd estimate FILE… [--method ml-epd|ru-epd|c-epd] [--min-range M] [--max-range M]
//!                    [--format text|json|csv] [--nominal-od-in X] [--loss cauchy|huber|none]
//!                    [--loss-scale M] [--units m|mm] [--frame sensor|optical]
//! epd simulate --out DIR [--frames K] [--seed S] [--sigma M] [--od-in X] [--ovality O]
//!              [--wall-mm T] [--points N] [--outliers F] [--noise range|isotropic]
//!              [--ply binary|ascii] [--precision f64|f32]
//! ```
//! Exit codes: 0 all files estimated, 1 a file failed or its fit did not converge to a
//! result consistent with its points (the others are still reported), 2 wrong arguments.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use epd_cli::read::read_path;
use epd_cli::report::{FileEstimate, FileReport, columns};
use epd_core::{EstimateOptions, Loss, LossScale, Method, estimate, rms_range_residual};
use indicatif::ProgressBar;
use rayon::prelude::*;

const USAGE: &str = "usage:
  epd estimate FILE… [--method ml-epd|ru-epd|c-epd] [--min-range M] [--max-range M]
                     [--format text|json|csv] [--nominal-od-in X] [--loss cauchy|huber|none] [--loss-scale M]
                     [--units m|mm] [--frame sensor|optical]
  epd simulate --out DIR [--frames K] [--seed S] [--sigma M] [--od-in X] [--ovality O] [--wall-mm T]
               [--points N] [--outliers F] [--noise range|isotropic] [--ply binary|ascii] [--precision f64|f32]";

/// Default method: ML-EPD, unbiased across tilt for noise along the sensing line (see
/// README, "Tilt").
const DEFAULT_METHOD: &str = "ml-epd";
/// Default robust loss: Cauchy, its scale taken from the residuals (2.3849 × their
/// robust standard deviation) unless --loss-scale sets it (see README, "Outliers").
const DEFAULT_LOSS: &str = "cauchy";
/// The seed scale of the first robust pass (m) when --loss-scale is not given.
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
    format: String,
    nominal_od_mm: Option<f64>,
    options: EstimateOptions,
    loss: String,
    units: Units,
    frame: InputFrame,
}

/// The length unit of the input file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Units {
    Metres,
    Millimetres,
}

/// The coordinate frame of the input file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum InputFrame {
    /// The paper's sensor frame: X forward (optical axis), Y right, Z up.
    Sensor,
    /// A camera's optical frame (Arena SDK, PCL, Open3D, ROS): X right, Y down, Z forward.
    Optical,
}

/// A cloud whose median distance from the sensor exceeds this (m) is not in metres.
const MAX_MEDIAN_RANGE_M: f64 = 30.0;
/// A cloud whose median distance from the sensor is below this (m) is not in the unit
/// given (e.g. metres read as millimetres).
const MIN_MEDIAN_RANGE_M: f64 = 0.02;

/// Convert the points to metres in the sensor frame, in place, and check that the
/// unit is plausible for a camera inside a pipe: its points lie between 2 cm and 30 m
/// (median distance) from the sensor.
fn to_sensor_metres(
    points: &mut [[f64; 3]],
    units: Units,
    frame: InputFrame,
) -> Result<(), String> {
    let k = match units {
        Units::Metres => 1.0,
        Units::Millimetres => 1e-3,
    };
    for p in points.iter_mut() {
        let [x, y, z] = *p;
        *p = match frame {
            InputFrame::Sensor => [k * x, k * y, k * z],
            // X_sensor = Z_optical, Y_sensor = X_optical, Z_sensor = −Y_optical (a
            // reflection: the sensor frame is left-handed).
            InputFrame::Optical => [k * z, k * x, -k * y],
        };
    }
    let stride = points.len().div_ceil(4096).max(1);
    let mut r: Vec<f64> = points
        .iter()
        .step_by(stride)
        .filter(|p| p.iter().all(|v| v.is_finite()) && p.iter().any(|&v| v != 0.0))
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .collect();
    if r.is_empty() {
        return Ok(());
    }
    let mid = r.len() / 2;
    let (_, &mut median, _) = r.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    if median > MAX_MEDIAN_RANGE_M {
        return Err(match units {
            Units::Metres => format!(
                "the points lie a median {median:.1} m from the sensor: the cloud looks like millimetres \
                 (the Helios2 SDK writes mm); pass --units mm"
            ),
            Units::Millimetres => format!(
                "the points lie a median {median:.1} m from the sensor even read as millimetres: \
                 not a frame from inside a pipe"
            ),
        });
    }
    if median < MIN_MEDIAN_RANGE_M {
        return Err(match units {
            Units::Millimetres => format!(
                "read as millimetres, the points lie a median {:.1} mm from the sensor: the cloud looks like \
                 metres; drop --units mm",
                median * 1e3
            ),
            Units::Metres => format!(
                "the points lie a median {:.1} mm from the sensor: the cloud is not in metres \
                 (kilometres?) or not a frame from inside a pipe",
                median * 1e3
            ),
        });
    }
    Ok(())
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
            "units",
            "frame",
        ],
    )?;
    if f.positional.is_empty() {
        return Err(usage("no input file: epd estimate FILE…"));
    }
    let method: Method = f
        .get("method")
        .unwrap_or(DEFAULT_METHOD)
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
    let mut options = EstimateOptions::default()
        .with_loss(loss)
        .map_err(|e| usage(e.to_string()))?
        .with_loss_scale(if f.get("loss-scale").is_some() {
            LossScale::Fixed
        } else {
            LossScale::Auto
        });
    if min_range > 0.0 || max_range.is_finite() {
        options = options
            .with_range_gate(min_range, max_range)
            .map_err(|e| usage(e.to_string()))?;
    }
    let units = match f.get("units").unwrap_or("m") {
        "m" => Units::Metres,
        "mm" => Units::Millimetres,
        other => return Err(usage(format!("--units {other}: expected m or mm"))),
    };
    let frame = match f.get("frame").unwrap_or("sensor") {
        "sensor" => InputFrame::Sensor,
        "optical" => InputFrame::Optical,
        other => {
            return Err(usage(format!(
                "--frame {other}: expected sensor (X forward, Y right, Z up) or optical (X right, Y down, Z forward)"
            )));
        }
    };
    Ok(EstimateConfig {
        files: f.positional.iter().map(PathBuf::from).collect(),
        method,
        format,
        nominal_od_mm,
        options,
        loss: loss.name().into(),
        units,
        frame,
    })
}

/// Read, filter and estimate one file.
fn estimate_file(path: &Path, cfg: &EstimateConfig) -> FileReport {
    let file = path.display().to_string();
    let run = || -> Result<FileEstimate, String> {
        let t0 = Instant::now();
        let mut cloud = read_path(path)?;
        let read_ms = t0.elapsed().as_secs_f64() * 1e3;
        to_sensor_metres(&mut cloud.points, cfg.units, cfg.frame)?;
        let n_read = cloud.points.len();
        if n_read == 0 {
            return Err("the file holds no points".into());
        }
        // Invalid pixels (NaN, inf, zeros) are dropped and counted by the estimator; the
        // range gate keeps points by their model range (see EstimateOptions).
        let kept = cloud.points;
        let t1 = Instant::now();
        let est = estimate(&kept, cfg.method, &cfg.options)
            .map_err(|e| format!("{e} ({n_read} points read)"))?;
        let elapsed_ms = t1.elapsed().as_secs_f64() * 1e3;
        let n_out_of_range = est.n_out_of_gate;
        let loss_scale_m = match (est.method, est.loss.scale()) {
            (_, None) => f64::NAN,
            // C-EPD's residual r_c ≈ 2δ/R: back to metres of radial error.
            (Method::CEpd, Some(k)) => k * (est.params.d_max + est.params.d_min) / 8.0,
            (_, Some(k)) => k,
        };
        let gated: Vec<[f64; 3]>;
        let fitted: &[[f64; 3]] = match cfg.options.range_gate() {
            None => &kept,
            Some((lo, hi)) => {
                gated = epd_core::gate_by_model_range(&kept, &est.params, lo, hi);
                &gated
            }
        };
        Ok(FileEstimate {
            loss: (cfg.loss.clone(), loss_scale_m),
            rms_residual_mm: rms_range_residual(fitted, &est.params).map(|v| v * 1e3),
            estimate: est,
            n_read,
            n_out_of_range,
            elapsed_ms,
            read_ms,
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
                if let Some(e) = r.failure() {
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
