//! Simulate one Helios2-like frame in a pipe and write its measured points.
//!
//! ```text
//! cargo run --release -p tof-sim --example frame -- --seed S --trial K --sigma M \
//!     --od-in X --ovality O [--points N] --out frame.csv [--ply frame.ply] [--depth-png depth.png]
//! ```
//! The pose of trial K is drawn from the paper's ranges (SPEC §5) with seed S; the pipe
//! has a 12 mm wall. `--out` gets `x,y,z` (m, sensor frame) with a header line; the true
//! β is printed as one JSON object (mm and degrees), in the canonical form of SPEC §3
//! (Dmax ≥ Dmin, roll in [−90°, 90°)), as estimates are.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use tof_sim::output::{
    PlyFormat, PlyPrecision, save_depth_png, save_ply, write_csv, write_file_atomic,
};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate};

struct Args {
    seed: u64,
    trial: u64,
    sigma: f64,
    od_in: f64,
    ovality: f64,
    points: Option<usize>,
    out: PathBuf,
    ply: Option<PathBuf>,
    png: Option<PathBuf>,
}

fn parse() -> anyhow::Result<Args> {
    let mut a = Args {
        seed: 1,
        trial: 0,
        sigma: 0.03,
        od_in: 20.0,
        ovality: 0.02,
        points: None,
        out: PathBuf::new(),
        ply: None,
        png: None,
    };
    let mut out = None;
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut val = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--seed" => a.seed = val()?.parse().context("--seed must be an integer ≥ 0")?,
            "--trial" => a.trial = val()?.parse().context("--trial must be an integer ≥ 0")?,
            "--sigma" => a.sigma = val()?.parse().context("--sigma must be a number (m)")?,
            "--od-in" => {
                a.od_in = val()?
                    .parse()
                    .context("--od-in must be a number (inches)")?
            }
            "--ovality" => {
                a.ovality = val()?
                    .parse()
                    .context("--ovality must be a number in [0, 1)")?
            }
            "--points" => {
                a.points = Some(val()?.parse().context("--points must be an integer ≥ 1")?)
            }
            "--out" => out = Some(PathBuf::from(val()?)),
            "--ply" => a.ply = Some(PathBuf::from(val()?)),
            "--depth-png" => a.png = Some(PathBuf::from(val()?)),
            other => bail!(
                "unknown argument `{other}`: expected --seed, --trial, --sigma, --od-in, --ovality, --points, --out, --ply, --depth-png"
            ),
        }
    }
    a.out = out.context("--out FILE.csv is required")?;
    if a.points == Some(0) {
        bail!("--points must be at least 1");
    }
    Ok(a)
}

fn run() -> anyhow::Result<()> {
    let a = parse()?;
    let sensor = Sensor::helios2();
    let pipe = Pipe {
        nominal_od_in: a.od_in,
        wall_thickness: 0.012,
        ovality: a.ovality,
    };
    let truth = PoseRanges::default().sample(&pipe, a.seed, a.trial)?;
    let scene = Scene::new(&truth, WallModel::Exact, sensor.max_range)?;
    let sub = a.points.map_or(Subsample::All, Subsample::Points);
    let seeds = FrameSeed {
        seed: a.seed,
        trial: a.trial,
        sweep_index: 0,
    };
    let frame = simulate(&sensor, &scene, &Noise::range(a.sigma), sub, seeds)?;
    write_file_atomic(&a.out, |w| write_csv(w, &frame))?;
    if let Some(p) = &a.ply {
        save_ply(p, &frame, PlyFormat::BinaryLittleEndian, PlyPrecision::F64)?;
    }
    if let Some(p) = &a.png {
        save_depth_png(p, &frame, sensor.max_range)?;
    }
    // The truth in canonical form (SPEC §3), comparable with an estimate as printed.
    let truth = epd_core::canonicalize(&truth);
    let deg = 180.0 / std::f64::consts::PI;
    println!(
        "{}",
        serde_json::json!({
            "d_max_mm": truth.d_max * 1e3,
            "d_min_mm": truth.d_min * 1e3,
            "roll_deg": truth.roll * deg,
            "pitch_deg": truth.pitch * deg,
            "yaw_deg": truth.yaw * deg,
            "dy_mm": truth.dy * 1e3,
            "dz_mm": truth.dz * 1e3,
            "n_points": frame.measured.len(),
        })
    );
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
