//! Estimate pipe diameters and sensor pose from a CSV point cloud.
//!
//! ```text
//! cargo run --release -p epd-core --example estimate -- FILE.csv [--method c-epd|ru-epd|ml-epd]
//! ```
//! FILE holds one point per line, `x,y,z` in metres in the sensor frame (SCS: X forward,
//! Y right, Z up), with an optional header line; NaN, inf and all-zero rows are dropped
//! and counted. Prints one JSON object (mm and degrees).

use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use epd_core::report::{Field, estimate_fields, json_object};
use epd_core::{EstimateOptions, Method, estimate, rms_range_residual};

fn parse_args() -> anyhow::Result<(String, Method)> {
    let mut file = None;
    let mut method = Method::RuEpd;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--method" => {
                let v = args
                    .next()
                    .context("--method needs a value: c-epd, ru-epd or ml-epd")?;
                method = v.parse()?;
            }
            "-h" | "--help" => {
                println!("usage: estimate FILE.csv [--method c-epd|ru-epd|ml-epd]");
                std::process::exit(0);
            }
            s if s.starts_with("--") => bail!("unknown option `{s}` (expected --method)"),
            s => {
                if file.replace(s.to_string()).is_some() {
                    bail!("more than one input file given; pass exactly one FILE.csv");
                }
            }
        }
    }
    let file =
        file.context("no input file: usage: estimate FILE.csv [--method c-epd|ru-epd|ml-epd]")?;
    Ok((file, method))
}

/// Read `x,y,z` rows; the first line may be a header.
fn read_csv(path: &str) -> anyhow::Result<Vec<[f64; 3]>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read `{path}`"))?;
    let mut pts = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let parsed: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
        match parsed {
            Ok(v) if v.len() == 3 => pts.push([v[0], v[1], v[2]]),
            Ok(v) => bail!(
                "{path}:{}: expected 3 values x,y,z, found {}",
                i + 1,
                v.len()
            ),
            Err(_) if i == 0 && pts.is_empty() => continue, // header
            Err(e) => bail!("{path}:{}: `{line}` is not x,y,z numbers ({e})", i + 1),
        }
    }
    Ok(pts)
}

fn run() -> anyhow::Result<()> {
    let (file, method) = parse_args()?;
    let points = read_csv(&file)?;
    let start = Instant::now();
    let est = estimate(&points, method, &EstimateOptions::default())
        .with_context(|| format!("cannot estimate from `{file}`"))?;
    let elapsed_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut fields = estimate_fields(&est);
    let rms = rms_range_residual(&points, &est.params).map_or(Field::Null, |v| Field::Num(v * 1e3));
    fields.push(("rms_residual_mm", rms));
    fields.push(("elapsed_ms", Field::Num(elapsed_ms)));
    let json = json_object(&fields);
    println!("{json}");
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
