//! Real-camera input: millimetres, the optical frame, the range gate, and fits that
//! must be refused rather than printed.

mod common;

use std::process::Command;

fn epd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_epd"))
}

/// One JSON result of `epd estimate FILE ARGS… --format json`, and the exit code.
fn estimate(file: &std::path::Path, args: &[&str]) -> (serde_json::Value, i32) {
    let o = epd()
        .arg("estimate")
        .arg(file)
        .args(args)
        .args(["--format", "json"])
        .output()
        .unwrap();
    let line = String::from_utf8_lossy(&o.stdout)
        .lines()
        .next()
        .unwrap()
        .to_string();
    (
        serde_json::from_str(&line).unwrap(),
        o.status.code().unwrap(),
    )
}

/// The frame's points as CSV, mapped by `f` (sensor frame, m → the file's frame).
fn csv(dir: &std::path::Path, name: &str, f: impl Fn([f64; 3]) -> [f64; 3]) -> std::path::PathBuf {
    let frame = common::frame(4, 20_000);
    let mut s = String::from("x,y,z\n");
    for p in &frame.measured {
        let q = f(*p);
        s.push_str(&format!("{},{},{}\n", q[0], q[1], q[2]));
    }
    let path = dir.join(name);
    std::fs::write(&path, s).unwrap();
    path
}

#[test]
fn millimetres_and_the_optical_frame_give_the_sensor_frame_result() {
    let dir = common::temp_dir("camera");
    let metres = csv(&dir, "m.csv", |p| p);
    let mm = csv(&dir, "mm.csv", |p| p.map(|v| v * 1e3));
    // Optical frame: X right = Y, Y down = −Z, Z forward = X.
    let optical_mm = csv(&dir, "opt.csv", |p| [p[1] * 1e3, -p[2] * 1e3, p[0] * 1e3]);
    // ROS body frame (REP 103): X forward = X, Y left = −Y, Z up = Z.
    let body = csv(&dir, "body.csv", |p| [p[0], -p[1], p[2]]);
    let (base, code) = estimate(&metres, &[]);
    assert_eq!(code, 0, "{base}");
    assert_eq!(base["status"], "converged");
    for (file, args) in [
        (&mm, vec!["--units", "mm"]),
        (&optical_mm, vec!["--units", "mm", "--frame", "optical"]),
        (&body, vec!["--frame", "body"]),
        (&body, vec!["--frame", "ros-body"]),
    ] {
        let (r, code) = estimate(file, &args);
        assert_eq!(code, 0, "{args:?}: {r}");
        for k in common::PARAM_KEYS {
            let (a, b) = (r[k].as_f64().unwrap(), base[k].as_f64().unwrap());
            // The same points up to the 1e-3 mm of the text (and rounding).
            assert!((a - b).abs() < 1e-3, "{args:?} {k}: {a} vs {b}");
        }
    }
}

#[test]
fn a_wrong_unit_or_frame_is_refused_with_the_flag_to_use() {
    let dir = common::temp_dir("camera_bad");
    let mm = csv(&dir, "mm.csv", |p| p.map(|v| v * 1e3));
    let (r, code) = estimate(&mm, &[]);
    assert_eq!(code, 1);
    assert_eq!(r["status"], "error");
    assert!(r["d_max_mm"].is_null());
    assert!(r["error"].as_str().unwrap().contains("--units mm"), "{r}");
    let metres = csv(&dir, "m.csv", |p| p);
    let (r, code) = estimate(&metres, &["--units", "mm"]);
    assert_eq!(code, 1);
    assert!(
        r["error"].as_str().unwrap().contains("drop --units mm"),
        "{r}"
    );
    // An optical-frame cloud read as the sensor frame: the right diameters would come
    // with a wrong pose, so nothing is printed.
    let optical = csv(&dir, "opt.csv", |p| [p[1], -p[2], p[0]]);
    let (r, code) = estimate(&optical, &[]);
    assert_eq!(code, 1, "{r}");
    assert_eq!(r["status"], "implausible");
    for k in common::PARAM_KEYS {
        assert!(r[k].is_null(), "{k}: {r}");
    }
    assert!(
        r["error"].as_str().unwrap().contains("optical frame"),
        "{r}"
    );
    let o = epd()
        .arg("estimate")
        .arg(&metres)
        .args(["--units", "km"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn the_range_gate_counts_by_model_range() {
    let dir = common::temp_dir("camera_gate");
    let metres = csv(&dir, "m.csv", |p| p);
    let (r, code) = estimate(&metres, &["--min-range", "0.5", "--max-range", "2"]);
    assert_eq!(code, 0, "{r}");
    let (n, out) = (
        r["n_points"].as_u64().unwrap(),
        r["n_out_of_range"].as_u64().unwrap(),
    );
    assert!(out > 0 && n > 1000, "{r}");
    assert_eq!(n + out, r["n_read"].as_u64().unwrap(), "{r}");
}
