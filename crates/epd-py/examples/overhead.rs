//! Time of one estimate of a file's points called from Rust: the baseline of the Python
//! overhead figure (`examples/overhead.py` times the same through `epd.estimate`).
//!
//! ```text
//! cargo run --release -p epd-py --example overhead -- FILE [CALLS]
//! ```
//! Prints one JSON object: per-call times (ms) of `epd_core::estimate` alone (`core`)
//! and of what `epd.estimate` runs on an array, the estimate and its report fields
//! (`pipeline`), each after one warm-up call; and the part of `pipeline` outside the fit
//! itself (`outside_fit`: the pipeline's time less the `elapsed_ms` it reports).

use std::borrow::Cow;
use std::path::PathBuf;
use std::time::Instant;

use epd_frame::report::FileReport;
use epd_frame::{EstimateConfig, EstimateSettings, FrameInput, measure_frame};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().ok_or("usage: overhead FILE [CALLS]")?);
    let calls: usize = args.next().map_or(Ok(20), |s| s.parse())?;
    let cloud = epd_frame::read::read_path(&path)?;
    let cfg = EstimateConfig::new(&EstimateSettings::default())?;
    // The fields and the fit's own time (ms).
    let pipeline = || -> Result<(usize, f64), String> {
        let input = FrameInput {
            points: Cow::Borrowed(&cloud.points),
            intensity: None,
            sigma: None,
            read_ms: 0.0,
        };
        let e = measure_frame(input, &cfg)?;
        let fit_ms = e.elapsed_ms;
        let report = FileReport {
            file: String::new(),
            file_bytes: None,
            outcome: Ok(e),
            message: None,
        };
        Ok((report.fields().len(), fit_ms))
    };
    let core = || epd_core::estimate(&cloud.points, cfg.method, &cfg.options);
    pipeline()?;
    core()?;
    let mut t_pipeline = Vec::with_capacity(calls);
    let mut t_core = Vec::with_capacity(calls);
    let mut t_outside = Vec::with_capacity(calls);
    for _ in 0..calls {
        let t = Instant::now();
        core()?;
        t_core.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let (_, fit_ms) = pipeline()?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        t_pipeline.push(ms);
        t_outside.push(ms - fit_ms);
    }
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.4}"))
            .collect::<Vec<_>>()
            .join(",")
    };
    println!(
        "{{\"n_points\":{},\"core\":[{}],\"pipeline\":[{}],\"outside_fit\":[{}]}}",
        cloud.points.len(),
        list(&t_core),
        list(&t_pipeline),
        list(&t_outside)
    );
    Ok(())
}
