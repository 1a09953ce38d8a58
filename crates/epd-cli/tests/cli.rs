//! The `epd` binary: simulate → estimate, output formats, every bad-input case.

mod common;

use std::path::Path;
use std::process::Command;

fn epd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_epd"))
}

fn json_lines(out: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(out)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn simulate_then_estimate_recovers_the_truth() {
    let dir = common::temp_dir("sim");
    let o = epd()
        .args([
            "simulate", "--frames", "3", "--sigma", "0", "--points", "30000", "--seed", "9",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let plys: Vec<_> = (0..3)
        .map(|k| dir.join(format!("frame_{k:04}.ply")))
        .collect();
    let o = epd()
        .arg("estimate")
        .args(&plys)
        .args(["--format", "json", "--loss", "none"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let results = json_lines(&o.stdout);
    assert_eq!(results.len(), 3);
    for (k, r) in results.iter().enumerate() {
        // One result per file, in the given order.
        assert_eq!(r["file"].as_str().unwrap(), plys[k].display().to_string());
        let truth: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(format!("frame_{k:04}.json"))).unwrap(),
        )
        .unwrap();
        for key in common::PARAM_KEYS {
            let (e, t) = (r[key].as_f64().unwrap(), truth[key].as_f64().unwrap());
            assert!((e - t).abs() < 1e-3, "frame {k} {key}: {e} vs {t}");
        }
        for key in [
            "method",
            "status",
            "iterations",
            "n_points",
            "n_dropped",
            "rms_residual_mm",
            "elapsed_ms",
            "sigma_d_max_mm",
        ] {
            assert!(r.get(key).is_some(), "missing {key}");
        }
        assert_eq!(r["status"], "converged");
    }
    // CSV: a header with the same names, one row per file.
    let o = epd()
        .arg("estimate")
        .args(&plys)
        .args(["--format", "csv"])
        .output()
        .unwrap();
    let mut r = csv::Reader::from_reader(&o.stdout[..]);
    let header = r.headers().unwrap().clone();
    let header: Vec<&str> = header.iter().collect();
    assert!(header.contains(&"d_max_mm") && header.contains(&"sigma_dz_mm") && header[0] == "file");
    assert_eq!(r.records().map(Result::unwrap).count(), 3);
    // Text, with the wall thickness from a nominal OD.
    let o = epd()
        .arg("estimate")
        .arg(&plys[0])
        .args(["--nominal-od-in", "20"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("Dmax") && text.contains("wall thickness ≈ 12.00 mm"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn invalid_points_and_the_range_filter_are_counted() {
    let dir = common::temp_dir("invalid");
    let frame = common::frame(1, 5000);
    let mut s = String::from("x,y,z\n");
    for p in &frame.measured {
        s.push_str(&format!("{},{},{}\n", p[0], p[1], p[2]));
    }
    s.push_str("nan,nan,nan\n0,0,0\n0,0,0\ninf,1,2\n");
    let f = dir.join("cam.csv");
    std::fs::write(&f, s).unwrap();
    let o = epd()
        .arg("estimate")
        .arg(&f)
        .args(["--format", "json", "--min-range", "0.5", "--max-range", "2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = &json_lines(&o.stdout)[0];
    assert_eq!(r["n_dropped"], 4);
    assert_eq!(r["n_read"], 5004);
    let in_range = frame
        .measured
        .iter()
        .filter(|p| (0.5..=2.0).contains(&(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()))
        .count();
    assert_eq!(r["n_points"].as_u64().unwrap() as usize, in_range);
    assert_eq!(
        r["n_out_of_range"].as_u64().unwrap() as usize,
        5000 - in_range
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn bad_files_are_named_the_rest_processed_and_the_exit_code_is_1() {
    let dir = common::temp_dir("bad");
    let frame = common::frame(2, 3000);
    let mut good = Vec::new();
    epd_io::ply::write(
        &mut good,
        &frame.cloud(),
        epd_io::ply::PlyFormat::BinaryLittleEndian,
        epd_io::ply::PlyPrecision::F64,
    )
    .unwrap();
    let good_path = write(&dir, "good.ply", &good);
    let truncated = write(&dir, "truncated.ply", &good[..good.len() / 2]);
    let malformed = write(&dir, "malformed.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty quaternion y\nend_header\n");
    let wrong_type = write(&dir, "wrongtype.pcd", b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F Q\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n");
    let empty = write(&dir, "empty.csv", b"x,y,z\n");
    let garbage = write(&dir, "garbage.csv", b"1,2,3\n4,five,6\n");
    let no_pipe = write(
        &dir,
        "plane.csv",
        b"1,0,0\n1,1,0\n1,0,1\n1,1,1\n1,2,0\n1,0,2\n1,2,2\n1,2,1\n1,1,2\n1,3,3\n",
    );
    let missing = dir.join("missing.ply");
    let files = [
        &good_path,
        &truncated,
        &malformed,
        &wrong_type,
        &empty,
        &garbage,
        &no_pipe,
        &missing,
    ];
    let o = epd()
        .arg("estimate")
        .args(files)
        .args(["--format", "json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let results = json_lines(&o.stdout);
    assert_eq!(results.len(), files.len(), "one result per file");
    assert_eq!(results[0]["status"], "converged");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(&format!(
            "{} of {} files failed",
            files.len() - 1,
            files.len()
        )),
        "{err}"
    );
    let expect = [
        ("truncated.ply", "truncated"),
        ("malformed.ply", "unknown property type"),
        ("wrongtype.pcd", "TYPE"),
        ("empty.csv", "no points"),
        ("garbage.csv", "line 2"),
        ("plane.csv", "degenerate"),
        ("missing.ply", "cannot read"),
    ];
    for (i, (name, what)) in expect.iter().enumerate() {
        let r = &results[i + 1];
        assert_eq!(r["status"], "error", "{name}");
        let msg = r["error"].as_str().unwrap();
        assert!(msg.contains(what), "{name}: {msg}");
        assert!(err.contains(name), "summary lacks {name}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn usage_errors_exit_2() {
    for args in [
        vec![],
        vec!["frobnicate"],
        vec!["estimate"],
        vec!["estimate", "x.ply", "--method", "d-epd"],
        vec!["estimate", "x.ply", "--format", "xml"],
        vec!["estimate", "x.ply", "--min-range", "2", "--max-range", "1"],
        vec![
            "estimate",
            "x.ply",
            "--loss",
            "cauchy",
            "--loss-scale",
            "-1",
        ],
        vec!["estimate", "x.ply", "--bogus", "1"],
        vec!["simulate"],
        vec!["simulate", "--out", "/tmp/x", "--sigma", "-1"],
    ] {
        let o = epd().args(&args).output().unwrap();
        assert_eq!(
            o.status.code(),
            Some(2),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(String::from_utf8_lossy(&o.stderr).contains("error"));
    }
}

/// `--max-points N`: N points fitted (`n_sampled`, `sampling`), the file's count kept in
/// `n_read`, the diameters within 2 mm of the truth (their 1-σ at N = 20 000, σ = 0.03 m,
/// is ≈ 0.08 mm: 25 σ of margin); without it `n_sampled` is null. A count below the
/// least, a negative one, or `--sampling` without `--max-points`: exit 2, the limit named.
#[test]
fn max_points_fits_the_chosen_points() {
    let dir = common::temp_dir("max-points");
    let o = epd()
        .args(["simulate", "--frames", "1", "--seed", "4", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ply = dir.join("frame_0000.ply");
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("frame_0000.json")).unwrap())
            .unwrap();
    for (how, expect) in [
        (None, None),
        (Some("informed"), Some("informed")),
        (Some("uniform"), Some("uniform")),
    ] {
        let mut cmd = epd();
        cmd.arg("estimate").arg(&ply).args(["--format", "json"]);
        if let Some(h) = how {
            cmd.args(["--max-points", "20000", "--sampling", h]);
        }
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let r = &json_lines(&o.stdout)[0];
        assert_eq!(r["sampling"].as_str(), expect, "{how:?}");
        let n_read = r["n_read"].as_u64().unwrap();
        assert!(n_read > 200_000, "{n_read}");
        match how {
            None => assert!(r["n_sampled"].is_null()),
            Some(_) => assert_eq!(r["n_sampled"].as_u64(), Some(20_000)),
        }
        for key in ["d_max_mm", "d_min_mm"] {
            let (e, t) = (r[key].as_f64().unwrap(), truth[key].as_f64().unwrap());
            assert!((e - t).abs() < 2.0, "{how:?} {key}: {e} vs {t}");
        }
    }
    for args in [
        vec!["--max-points", "999"],
        vec!["--max-points=-5"],
        vec!["--sampling", "uniform"],
        vec!["--max-points", "20000", "--sampling", "best"],
    ] {
        let o = epd()
            .arg("estimate")
            .arg(&ply)
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains("max-points") || err.contains("sampling"),
            "{args:?}: {err}"
        );
    }
    let o = epd()
        .arg("estimate")
        .arg(&ply)
        .args(["--max-points", "999"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("at least 1000"));
    let _ = std::fs::remove_dir_all(&dir);
}
