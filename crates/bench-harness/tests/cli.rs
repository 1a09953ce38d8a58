//! The `bench-harness` binary: arguments, exit codes, files, determinism.

mod common;

use common::{bin, read_csv as csv, temp_dir};
use std::path::{Path, PathBuf};

const SMALL: &str = r#"
name = "small"
seed = 3
trials = 5
methods = ["c-epd", "ru-epd", "ml-epd"]
points = 3000
[noise]
sigma_m = 0.03
[sweep]
variable = "pipe.ovality"
values = [0.0, 0.04]
"#;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn bad_scenarios_exit_2_name_the_key_and_write_nothing() {
    let dir = temp_dir("bad");
    let cases = [
        (
            "unknown.toml",
            "name = \"u\"\n[noise]\nsigma = 0.1\n",
            "sigma",
        ),
        (
            "range.toml",
            "name = \"r\"\n[pipe]\novality = 2.0\n",
            "pipe.ovality",
        ),
        (
            "sweep.toml",
            "name = \"s\"\n[sweep]\nvariable = \"noise.sigma_m\"\nvalues = [0.01, -1.0]\n",
            "noise.sigma_m",
        ),
        ("syntax.toml", "name = \n", "line 1"),
    ];
    for (file, text, key) in cases {
        let p = write(&dir, file, text);
        let out = dir.join(format!("out-{file}"));
        let o = bin().arg(&p).arg("--out").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{file}: {err}");
        assert!(err.contains(file) && err.contains(key), "{file}: {err}");
        assert!(!out.exists(), "{file}: wrote {}", out.display());
    }
    let o = bin().arg(dir.join("missing.toml")).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let o = bin().args(["x.toml", "--trials", "0"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let o = bin().args(["x.toml", "--frobnicate"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn run_writes_the_spec_files_and_is_identical_for_1_and_2_threads() {
    let dir = temp_dir("run");
    let scenario = write(&dir, "small.toml", SMALL);
    let mut tables = Vec::new();
    for threads in ["1", "2"] {
        let out = dir.join(format!("out{threads}"));
        // A folder holding someone else's file is refused, and the file left alone.
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let run = || {
            bin()
                .arg(&scenario)
                .args(["--trials=4", "--threads", threads, "--out"])
                .arg(&out)
                .output()
                .unwrap()
        };
        let o = run();
        assert_eq!(
            o.status.code(),
            Some(2),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert_eq!(
            std::fs::read_to_string(out.join("notes.txt")).unwrap(),
            "mine"
        );
        std::fs::remove_file(out.join("notes.txt")).unwrap();
        // An empty folder, then a previous run, are replaced as a whole.
        for _ in 0..2 {
            let o = run();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
        for f in [
            "trials.csv",
            "summary.csv",
            "scenario.toml",
            "metadata.json",
            "diameter_error.png",
            "pose_error.png",
            "time.png",
            "std_vs_crb.png",
            "coverage.png",
        ] {
            assert!(out.join(f).is_file(), "{f} missing");
        }
        // Exactly the run's files: what a later run may replace.
        let mut names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        let mut expected: Vec<&str> = bench_harness::output::RUN_FILES.to_vec();
        expected.sort();
        assert_eq!(names, expected);
        // A file of the user's put beside a previous run: refused, not deleted.
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let o = run();
        assert_eq!(o.status.code(), Some(2));
        assert_eq!(
            std::fs::read_to_string(out.join("notes.txt")).unwrap(),
            "mine"
        );
        std::fs::remove_file(out.join("notes.txt")).unwrap();
        let leftovers: Vec<_> = std::fs::read_dir(&out)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
            .collect();
        assert!(leftovers.is_empty());
        let beside: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .filter(|e| {
                let n = e.file_name().to_string_lossy().into_owned();
                n.starts_with(".run-") || n.starts_with(".old-")
            })
            .collect();
        assert!(beside.is_empty(), "staging folders left: {beside:?}");
        let (h, rows) = csv(&out.join("trials.csv"));
        for col in [
            "sweep_variable",
            "sweep_value",
            "trial",
            "method",
            "n_points",
            "status",
            "iterations",
            "time_ms",
            "dmax_true_mm",
            "dmin_true_mm",
            "dmax_est_mm",
            "dmin_est_mm",
            "err_dmax_mm",
            "err_dmin_mm",
            "err_dmean_mm",
            "err_roll_deg",
            "err_pitch_deg",
            "err_yaw_deg",
            "err_dy_mm",
            "err_dz_mm",
        ] {
            assert!(h.iter().any(|c| c == col), "trials.csv lacks {col}");
        }
        assert_eq!(rows.len(), 2 * 4 * 3, "2 values × 4 trials × 3 methods");
        let (sh, srows) = csv(&out.join("summary.csv"));
        for col in [
            "sweep_variable",
            "sweep_value",
            "method",
            "quantity",
            "unit",
            "n",
            "n_failed",
            "mean",
            "std",
            "rmse",
            "median",
            "min",
            "max",
            "range",
        ] {
            assert!(sh.iter().any(|c| c == col), "summary.csv lacks {col}");
        }
        assert_eq!(
            srows.len(),
            2 * 3 * 9,
            "2 values × 3 methods × 9 quantities"
        );
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("metadata.json")).unwrap())
                .unwrap();
        assert_eq!(meta["threads"].as_u64(), Some(threads.parse().unwrap()));
        assert_eq!(
            std::fs::read_to_string(out.join("scenario.toml")).unwrap(),
            SMALL
        );
        // Everything but the timing column.
        let t = h.iter().position(|c| c == "time_ms").unwrap();
        tables.push(
            rows.into_iter()
                .map(|mut r| {
                    r.remove(t);
                    r
                })
                .collect::<Vec<_>>(),
        );
    }
    assert_eq!(
        tables[0], tables[1],
        "results differ between 1 and 2 threads"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn circular_pipe_rows_are_kept_with_their_status() {
    // Ovality 0: the roll is undetermined, but diameters still converge; nothing is
    // dropped from trials.csv.
    let dir = temp_dir("circ");
    let s = write(
        &dir,
        "c.toml",
        "name = \"c\"\ntrials = 3\npoints = 2000\n[pipe]\novality = 0.0\n",
    );
    let out = dir.join("out");
    let o = bin().arg(&s).arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (h, rows) = csv(&out.join("trials.csv"));
    let st = h.iter().position(|c| c == "status").unwrap();
    assert_eq!(rows.len(), 9);
    assert!(rows.iter().all(|r| !r[st].is_empty()));
    let _ = std::fs::remove_dir_all(&dir);
}
