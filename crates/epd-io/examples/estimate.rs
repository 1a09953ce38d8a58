//! Estimate pipe diameters and sensor pose from a CSV point cloud.
//!
//! ```text
//! cargo run --release -p epd-io --example estimate -- FILE.csv [--method ml-epd|ru-epd|c-epd]
//! ```
//! Exit codes: 0 converged, 1 an error or a fit that did not converge (its status is
//! printed), 2 wrong arguments.
//! FILE holds one point per line, `x,y,z` in metres in the sensor frame (SCS: X forward,
//! Y right, Z up), with an optional header line; NaN, inf and all-zero rows are dropped
//! and counted. Prints one JSON object (mm and degrees).

use std::process::ExitCode;
use std::time::Instant;

use std::io::Write;

use anyhow::Context;
use epd_core::report::{Field, estimate_fields};
use epd_core::{EstimateOptions, Method, estimate, rms_range_residual};

/// Estimate pipe diameters and sensor pose from a CSV point cloud (x,y,z in metres,
/// sensor frame); prints one JSON object.
#[derive(clap::Parser, Debug)]
#[command(name = "estimate", version)]
struct Cli {
    /// The CSV file (`-`: standard input).
    #[arg(value_name = "FILE.csv")]
    file: String,
    /// The estimator: ml-epd, ru-epd or c-epd.
    #[arg(long, default_value = "ml-epd", value_parser = parse_method)]
    method: Method,
}

fn parse_method(s: &str) -> Result<Method, String> {
    s.parse().map_err(|e: epd_core::EpdError| e.to_string())
}

/// Read the points of a CSV/XYZ file (or of standard input) with the `epd` tool's text
/// reader: the first line may be a header.
fn read_csv(path: &str) -> anyhow::Result<Vec<[f64; 3]>> {
    let cloud = if path == "-" {
        epd_io::read_from(
            std::io::stdin().lock(),
            Some(epd_io::Format::Text),
            epd_io::MAX_INPUT_BYTES,
        )
        .map_err(|e| anyhow::anyhow!("cannot read standard input: {e}"))?
    } else {
        epd_io::read_path(std::path::Path::new(path))
            .map_err(|e| anyhow::anyhow!("cannot read `{path}`: {e}"))?
    };
    Ok(cloud.points)
}

fn run(cli: Cli) -> anyhow::Result<bool> {
    let (file, method) = (cli.file, cli.method);
    let points = read_csv(&file)?;
    let start = Instant::now();
    let est = estimate(&points, method, &EstimateOptions::default())
        .with_context(|| format!("cannot estimate from `{file}`"))?;
    let elapsed_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut fields = estimate_fields(&est);
    let rms = rms_range_residual(&points, &est.params).map_or(Field::Null, |v| Field::Num(v * 1e3));
    fields.push(("rms_residual_mm", rms));
    fields.push(("elapsed_ms", Field::Num(elapsed_ms)));
    let json = epd_io::json::object(&fields);
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{json}").and_then(|()| out.flush()) {
        // A closed pipe: the reader went away; not an error of ours.
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            return Err(e).context("cannot write to standard output");
        }
        _ => {}
    }
    Ok(est.status.is_converged())
}

fn main() -> ExitCode {
    // Usage errors exit 2, --help and --version 0 (clap's codes).
    let cli = match <Cli as clap::Parser>::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(2));
        }
    };
    match run(cli) {
        Ok(true) => ExitCode::SUCCESS,
        // Printed with its status and reason, but not a result: exit 1.
        Ok(false) => ExitCode::FAILURE,
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
        let c = Cli::try_parse_from(["estimate", "f.csv", "--method=ru-epd"]).unwrap();
        assert_eq!((c.file.as_str(), c.method), ("f.csv", Method::RuEpd));
        let c = Cli::try_parse_from(["estimate", "--", "-"]).unwrap();
        assert_eq!((c.file.as_str(), c.method), ("-", Method::MlEpd));
        for bad in [
            vec!["estimate"],
            vec!["estimate", "f", "--method", "x"],
            vec!["estimate", "a", "b"],
        ] {
            let e = Cli::try_parse_from(bad).unwrap_err();
            assert_eq!(e.exit_code(), 2);
        }
        assert_eq!(
            Cli::try_parse_from(["estimate", "--version"])
                .unwrap_err()
                .exit_code(),
            0
        );
    }
}
