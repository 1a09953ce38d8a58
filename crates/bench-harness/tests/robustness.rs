//! Trust on hard frames, in CI at a small count (the full counts are the scenarios
//! `init_robustness.toml`, 2000 poses, and `tilt_sweep.toml`):
//! - the initial guess and the whole estimate find every pipe of `init_robustness`
//!   (16"–30", pitch/yaw ±20°, σ 0.05 m, 10 % range and 1 % far outliers);
//! - a 16" pipe tilted up to ±15° at σ = 0.05 m (where C-EPD used to report
//!   "converged" at 10⁹ mm): every row reported converged lies within a sane distance
//!   of the truth, whatever the method.

mod common;

use common::{read_csv, temp_dir, workspace};
use std::path::Path;

use bench_harness::{RunOptions, Scenario, run};

#[test]
fn every_hard_pipe_is_found() {
    let scenario = Scenario::load(&workspace().join("scenarios/init_robustness.toml")).unwrap();
    let out = temp_dir("robust");
    let report = run(
        &scenario,
        &RunOptions {
            out: out.clone(),
            trials: Some(40),
            progress: false,
        },
    )
    .unwrap();
    // 4 pipe sizes × 40 poses: no failure at all (the 2000-pose scenario: 0 of 2000).
    let failed: usize = report
        .summary
        .iter()
        .filter(|r| r.quantity == "dmean")
        .map(|r| r.n_failed)
        .sum();
    let trials: usize = report
        .summary
        .iter()
        .filter(|r| r.quantity == "dmean")
        .map(|r| r.stats.n + r.n_failed)
        .sum();
    assert_eq!(trials, 160);
    assert_eq!(failed, 0, "{failed} of {trials} hard frames failed");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn no_confident_wrong_answer_on_tilted_small_pipes() {
    let source = r#"
name = "tilted16"
seed = 3
trials = 40
methods = ["c-epd", "ru-epd", "ml-epd"]
points = 20000
[pipe]
nominal_od_in = 16.0
[noise]
sigma_m = 0.05
[poses]
pitch_deg = [-15.0, 15.0]
yaw_deg = [-15.0, 15.0]
"#;
    let scenario = Scenario::parse(Path::new("tilted16.toml"), source).unwrap();
    let out = temp_dir("tilted16");
    run(
        &scenario,
        &RunOptions {
            out: out.clone(),
            trials: None,
            progress: false,
        },
    )
    .unwrap();
    let (header, rows) = read_csv(&out.join("trials.csv"));
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (status, method, err) = (col("status"), col("method"), col("err_dmean_mm"));
    let mut converged = [0usize; 3];
    for f in &rows {
        if f[status] != "converged" {
            // A refusal must be one of the honest ones: a fit its points contradict, or
            // a wall its points leave beyond their noise (C-EPD's bias at 15° tilt).
            assert!(
                ["implausible", "lack_of_fit"].contains(&f[status].as_str()),
                "{f:?}"
            );
            continue;
        }
        let e: f64 = f[err].parse().unwrap();
        let m = ["c-epd", "ru-epd", "ml-epd"]
            .iter()
            .position(|m| *m == f[method])
            .unwrap();
        converged[m] += 1;
        // C-EPD's own bias here is ≈ 1.75σ²/ID ≈ 11 mm and grows with tilt; a
        // diverged fit is off by metres. RU-EPD's tilt bias stays within a few mm.
        let bound = [40.0, 10.0, 2.0][m];
        assert!(
            e.abs() < bound,
            "{} converged with a {e} mm error: {f:?}",
            f[method]
        );
    }
    // RU-EPD and ML-EPD converge on every frame; C-EPD's biased fits are refused where
    // its wall leaves the points (measured 19 of 40 converged with the form test).
    assert_eq!(converged[1], 40, "{converged:?}");
    assert_eq!(converged[2], 40, "{converged:?}");
    eprintln!("converged per method (c, ru, ml): {converged:?}");
    let _ = std::fs::remove_dir_all(&out);
}
