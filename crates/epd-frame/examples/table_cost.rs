//! What a depth table costs a frame: `epd estimate --calibration`'s whole measurement
//! ([`measure_frame`]: the table's correction, the scene, the weighted fit, gated to
//! [0.5, 2] m) of one full
//! 640×480 Helios2 frame, with a real table (`epd calibrate`'s default 30 × 12 bins from
//! three rig frames) and with the largest tables the reader accepts (2²⁰ bins in five
//! shapes, their values the real table's at their bin centres). Prints the median time per
//! frame of each, and of its correction alone, and their ratio to the real table's; the
//! goal of issue 27 is at most 2×. Also the time to read each table file (once per batch).
//!
//! `cargo run --release -p epd-frame --example table_cost [FRAMES]` (default 15 frames each)

use std::borrow::Cow;
use std::time::Instant;

use epd_core::DepthTable;
use epd_core::calibration::Axis;
use epd_core::{EstimateOptions, Loss, LossScale};
use epd_frame::{CalibrationTable, EstimateConfig, EstimateSettings, FrameInput, measure_frame};

#[path = "../benches/helios2_rig/mod.rs"]
mod helios2_rig;

use helios2_rig::{helios2_frame as frame, inspection_pipe, rig, rig_table};

/// `real`'s values resampled onto `nr × ni` bins over the same axes.
fn resampled(real: &DepthTable, nr: usize, ni: usize) -> DepthTable {
    let range = Axis {
        n: nr,
        ..real.range
    };
    let log_intensity = Axis {
        n: ni,
        ..real.log_intensity
    };
    let centre = |a: &Axis, k: usize| a.lo + (k as f64 + 0.5) * (a.hi - a.lo) / a.n as f64;
    let cells = nr * ni;
    let mut offset_m = Vec::with_capacity(cells);
    let mut spread_m = Vec::with_capacity(cells);
    for i in 0..nr {
        for j in 0..ni {
            let (r, li) = (centre(&range, i), centre(&log_intensity, j));
            offset_m.push(real.offset_at(r, li.exp()));
            spread_m.push(real.sigma_at(r, li.exp()));
        }
    }
    DepthTable {
        range,
        log_intensity,
        offset_m,
        spread_m,
        count: vec![40; cells],
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    epd_frame::keep_freed_memory();
    let frames: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(15);
    let options = EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", 0.05).expect("loss"))
        .expect("loss")
        .with_loss_scale(LossScale::Auto);
    let rig = rig();
    let real = rig_table(&rig, &options);
    let pipe = inspection_pipe();
    let inspection = frame(&pipe, 10);
    let intensity: Vec<f64> = inspection.intensity.iter().map(|&v| v as f64).collect();
    let dir = tempfile::tempdir().expect("temp dir");
    let max = epd_core::calibration::MAX_TABLE_BINS;
    let tables = [
        ("real 30 × 12", real.clone()),
        // The same values on as few bins: what the fit costs on a frame corrected by a
        // table without a range dependence (other data, not the table's size).
        ("1 × 12", resampled(&real, 1, 12)),
        ("1024 × 1024", resampled(&real, 1024, 1024)),
        ("30 × 34952", resampled(&real, 30, max / 30)),
        ("34952 × 30", resampled(&real, max / 30, 30)),
        ("1 × 2^20", resampled(&real, 1, max)),
        ("2^20 × 1", resampled(&real, max, 1)),
    ];
    println!(
        "one 640×480 frame ({} points), measure_frame with the table (median of {frames})",
        inspection.measured.len()
    );
    let mut configs = Vec::new();
    for (name, table) in tables {
        let file = CalibrationTable::plain(table, (rig.d_max(), rig.d_min()), 3, 1);
        let path = dir.path().join("table.json");
        let text = file.to_json();
        std::fs::write(&path, &text).expect("write");
        let t0 = Instant::now();
        let cfg = EstimateConfig::new(&EstimateSettings {
            calibration: Some(path),
            min_range: Some(0.5),
            max_range: Some(2.0),
            ..EstimateSettings::default()
        })
        .expect("the table reads");
        let read_ms = t0.elapsed().as_secs_f64() * 1e3;
        configs.push((name, cfg, read_ms, text.len()));
    }
    // Round robin over the tables, so that the machine's load weighs on each alike.
    let mut times = vec![Vec::new(); configs.len()];
    let mut corrections = vec![Vec::new(); configs.len()];
    for _ in 0..frames {
        for (((_, cfg, _, _), t), c) in configs.iter().zip(&mut times).zip(&mut corrections) {
            let table = cfg.calibration.as_ref().expect("a table");
            let mut points = inspection.measured.clone();
            let t0 = Instant::now();
            std::hint::black_box(
                table
                    .correct_points(true, &mut points, Some(&intensity), false)
                    .expect("corrected"),
            );
            c.push(t0.elapsed().as_secs_f64() * 1e3);
            let t0 = Instant::now();
            let input = FrameInput {
                points: Cow::Borrowed(&inspection.measured),
                intensity: Some(&intensity),
                sigma: None,
                read_ms: 0.0,
            };
            std::hint::black_box(measure_frame(input, cfg).expect("measured"));
            t.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    let base = median(times[0].clone());
    let base_c = median(corrections[0].clone());
    println!(
        "{:>14}  {:>22}  {:>22}  {:>8}  {:>8}",
        "table", "measure_frame ms", "its correction ms", "file MB", "read ms"
    );
    for (((name, _, read_ms, bytes), t), c) in configs.iter().zip(times).zip(corrections) {
        let (ms, cms) = (median(t), median(c));
        println!(
            "{name:>14}  {ms:9.1} ({:5.2}× real)  {cms:9.1} ({:5.2}× real)  {:8.1}  {read_ms:8.0}",
            ms / base,
            cms / base_c,
            *bytes as f64 / 1e6
        );
    }
    println!(
        "(measure_frame includes the fit, whose path depends on the corrected points: a \
         table of other values is other data; the correction is the table's own cost. The \
         file is read once a batch.)"
    );
}
