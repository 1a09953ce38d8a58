//! Simulate one Helios2-like frame in a pipe and write its measured points.
//!
//! ```text
//! cargo run --release -p tof-sim --example frame -- --seed S --trial K --sigma M \
//!     --od-in X --ovality O [--points N] --out frame.csv [--ply frame.ply] [--depth-png depth.png]
//! ```
//! Exit codes: 0 written, 1 an error (invalid pipe or noise, I/O), 2 wrong arguments.
//! The pose of trial K is drawn from the paper's ranges (README, Conventions) with seed S; the pipe
//! has a 12 mm wall. `--out` gets `x,y,z` (m, sensor frame) with a header line; the true
//! β is printed as one JSON object (mm and degrees), in the canonical form of README's Conventions
//! (Dmax ≥ Dmin, roll in [−90°, 90°)), as estimates are.

use std::path::PathBuf;
use std::process::ExitCode;

use epd_io::ply::{PlyFormat, PlyPrecision};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate};

/// Simulate one Helios2-like frame in a pipe (12 mm wall) and write its points; print
/// the true β.
#[derive(clap::Parser, Debug)]
#[command(name = "frame", version)]
struct Args {
    /// Seed of the pose and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Trial index: the pose is drawn from the paper's ranges with (seed, trial).
    #[arg(long, default_value_t = 0)]
    trial: u64,
    /// Range-noise standard deviation (m).
    #[arg(long, default_value_t = 0.03, allow_negative_numbers = true)]
    sigma: f64,
    /// Nominal outer diameter (inch).
    #[arg(long, default_value_t = 20.0, allow_negative_numbers = true)]
    od_in: f64,
    /// Ovality (Dmax − Dmin)/ID.
    #[arg(long, default_value_t = 0.02, allow_negative_numbers = true)]
    ovality: f64,
    /// A uniform subsample of N points (default: all within 6 m).
    #[arg(long, value_name = "N")]
    points: Option<std::num::NonZeroUsize>,
    /// The CSV file of the measured points (x,y,z in m, sensor frame).
    #[arg(long, short = 'o', value_name = "FILE.csv")]
    out: PathBuf,
    /// Also a binary PLY file.
    #[arg(long, value_name = "FILE.ply")]
    ply: Option<PathBuf>,
    /// Also a depth image.
    #[arg(long, value_name = "FILE.png")]
    depth_png: Option<PathBuf>,
}

fn run(a: Args) -> anyhow::Result<()> {
    let sensor = Sensor::helios2();
    let pipe = Pipe {
        nominal_od_in: a.od_in,
        wall_thickness: 0.012,
        ovality: a.ovality,
    };
    let truth = PoseRanges::default().sample(&pipe, a.seed, a.trial)?;
    let scene = Scene::new(&truth, WallModel::Exact, sensor.max_range)?;
    let sub = a
        .points
        .map_or(Subsample::All, |n| Subsample::Points(n.get()));
    let seeds = FrameSeed {
        seed: a.seed,
        trial: a.trial,
        sweep_index: 0,
    };
    let frame = simulate(&sensor, &scene, &Noise::range(a.sigma), sub, seeds)?;
    epd_io::atomic::write_file_atomic(&a.out, |w| epd_io::csv::write_points(w, &frame.measured))?;
    if let Some(p) = &a.ply {
        epd_io::ply::save(
            p,
            &frame.cloud(),
            PlyFormat::BinaryLittleEndian,
            PlyPrecision::F64,
        )?;
    }
    if let Some(p) = &a.depth_png {
        epd_io::depth_png::save(p, &frame.cloud(), sensor.max_range)?;
    }
    // The truth in canonical form (README, Conventions), comparable with an estimate as printed.
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
    // Usage errors exit 2, --help and --version 0 (clap's codes).
    let args = match <Args as clap::Parser>::try_parse() {
        Ok(a) => a,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[test]
    fn arguments() {
        let a = Args::try_parse_from(["frame", "--out=f.csv", "--sigma", "0.05", "--points", "10"])
            .unwrap();
        assert_eq!((a.sigma, a.points.map(|n| n.get())), (0.05, Some(10)));
        for bad in [
            vec!["frame"],
            vec!["frame", "--out", "f", "--points", "0"],
            vec!["frame", "--out", "f", "--bogus"],
        ] {
            assert_eq!(Args::try_parse_from(bad).unwrap_err().exit_code(), 2);
        }
    }
}
