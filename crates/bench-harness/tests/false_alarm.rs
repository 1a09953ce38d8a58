//! `scenarios/straight_false_alarm.toml` in small: every straight frame measured as
//! `epd estimate` measures a file (the scene surveyed), its reading in `trials.csv`'s
//! `geometry`, and `summary.csv`'s false-alarm columns counted from those readings.

mod common;

use std::collections::HashMap;

use common::{read_csv, temp_dir, workspace};

use bench_harness::stats::FalseAlarms;
use bench_harness::{RunOptions, Scenario, run};

#[test]
fn a_small_false_alarm_run_counts_its_readings() {
    let scenario =
        Scenario::load(&workspace().join("scenarios/straight_false_alarm.toml")).unwrap();
    assert_eq!(scenario.sweep_variable, "pipe+noise");
    assert!(scenario.sweeps.iter().all(|(_, s)| s.geometry));
    assert!(scenario.sweeps.len() * scenario.trials >= 1000);
    let out = temp_dir("false-alarm");
    run(
        &scenario,
        &RunOptions {
            out: out.clone(),
            trials: Some(1),
            progress: false,
        },
    )
    .unwrap();
    let (header, rows) = read_csv(&out.join("trials.csv"));
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (value, status, geometry) = (col("sweep_value"), col("status"), col("geometry"));
    assert_eq!(rows.len(), scenario.sweeps.len());
    // (frames with a reading, alarms) per swept value, from the trials.
    let mut counted: HashMap<String, (usize, usize)> = HashMap::new();
    for r in &rows {
        let g = r[geometry].as_str();
        if r[status] == "error" {
            assert_eq!(g, "", "{r:?}");
            continue;
        }
        assert!(
            ["straight", "bend_ahead", "tee_ahead", "in_bend"].contains(&g),
            "{r:?}"
        );
        let c = counted.entry(r[value].clone()).or_default();
        c.0 += 1;
        c.1 += usize::from(g != "straight");
    }
    assert!(!counted.is_empty());
    let (header, rows) = read_csv(&out.join("summary.csv"));
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    for r in &rows {
        let (frames, alarms) = counted
            .get(&r[col("sweep_value")])
            .copied()
            .unwrap_or((0, 0));
        if frames == 0 {
            assert_eq!(r[col("geometry_frames")], "", "{r:?}");
            continue;
        }
        let want = FalseAlarms::of(alarms, frames);
        let num = |name: &str| r[col(name)].parse::<f64>().unwrap();
        assert_eq!(r[col("geometry_frames")], frames.to_string());
        assert_eq!(r[col("false_alarms")], alarms.to_string());
        assert_eq!(num("false_alarm_rate"), want.rate);
        assert_eq!(num("false_alarm_se"), want.se);
        assert_eq!(num("false_alarm_upper95"), want.upper95);
    }
    let _ = std::fs::remove_dir_all(&out);
}
