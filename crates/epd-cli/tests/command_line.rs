//! The `epd` command line as users of other tools expect it: --help and --version,
//! `--opt=value`, `--`, `-` for standard input, `-o FILE`, `--threads`, `-q`, exit
//! codes, and a closed standard output.

mod common;

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};

fn epd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_epd"))
}

/// A small noise-free frame as CSV (m, sensor frame).
fn csv_file(dir: &std::path::Path) -> std::path::PathBuf {
    let frame = common::frame(2, 3000);
    let path = dir.join("f.csv");
    std::fs::write(&path, common::xyz(&frame.measured)).unwrap();
    path
}

/// `o` is a usage error (exit 2) whose standard error says `says`.
fn expect_usage_error(o: &std::process::Output, says: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(says), "{err}");
}

fn without_timings(json: &str) -> serde_json::Value {
    let mut v: serde_json::Value = serde_json::from_str(json).unwrap();
    for k in ["elapsed_ms", "read_ms"] {
        v[k] = serde_json::Value::Null;
    }
    v
}

#[test]
fn help_and_version() {
    for (args, words) in [
        (vec!["--help"], vec!["estimate", "simulate"]),
        (
            vec!["estimate", "--help"],
            vec![
                "--method",
                "--min-range",
                "--max-range",
                "--format",
                "--nominal-od-in",
                "--loss",
                "--loss-scale",
                "--units",
                "--frame",
                "--input-format",
                "--output",
                "--threads",
                "--quiet",
            ],
        ),
        (
            vec!["simulate", "-h"],
            vec![
                "--out",
                "--frames",
                "--sigma",
                "--noise",
                "--ply",
                "--precision",
            ],
        ),
    ] {
        let o = epd().args(&args).output().unwrap();
        assert_eq!(o.status.code(), Some(0), "{args:?}");
        let text = String::from_utf8_lossy(&o.stdout);
        for w in words {
            assert!(text.contains(w), "{args:?} lacks {w}:\n{text}");
        }
    }
    let o = epd().arg("--version").output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).trim(),
        format!("epd {}", env!("CARGO_PKG_VERSION"))
    );
}

#[test]
fn equals_form_double_dash_and_standard_input() {
    let dir = common::temp_dir("cmdline");
    let file = csv_file(&dir);
    let by_file = epd()
        .arg("estimate")
        .arg(&file)
        .args(["--format", "json"])
        .output()
        .unwrap();
    assert_eq!(by_file.status.code(), Some(0));
    let reference = without_timings(String::from_utf8_lossy(&by_file.stdout).trim());
    // --opt=value, and a file after `--`.
    let o = epd()
        .args(["estimate", "--format=json", "--"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0));
    assert_eq!(
        without_timings(String::from_utf8_lossy(&o.stdout).trim()),
        {
            let mut r = reference.clone();
            r["file"] = serde_json::Value::String(file.display().to_string());
            r
        }
    );
    // `-`: standard input, with and without a format hint.
    for hint in [vec![], vec!["--input-format", "csv"]] {
        let mut child = epd()
            .args(["estimate", "-", "--format", "json"])
            .args(&hint)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        child
            .stdin
            .take()
            .unwrap()
            .write_all(&std::fs::read(&file).unwrap())
            .unwrap();
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(0), "{hint:?}");
        let mut got = without_timings(String::from_utf8_lossy(&o.stdout).trim());
        assert_eq!(got["file"], "-");
        got["file"] = reference["file"].clone();
        // The same points, the same estimate.
        assert_eq!(got, reference, "{hint:?}");
    }
    // Standard input at most once.
    let o = epd().args(["estimate", "-", "-"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn output_file_threads_and_quiet() {
    let dir = common::temp_dir("cmdline_out");
    let file = csv_file(&dir);
    let files: Vec<_> = (0..6).map(|_| file.clone()).collect();
    // -o FILE onto a planted link: the link is replaced, its target untouched.
    let target = dir.join("precious.txt");
    std::fs::write(&target, "keep").unwrap();
    let out = dir.join("results.json");
    std::os::unix::fs::symlink(&target, &out).unwrap();
    let runs: Vec<String> = ["1", "2"]
        .iter()
        .map(|t| {
            let o = epd()
                .arg("estimate")
                .args(&files)
                .args(["--format", "json", "--threads", t, "-o"])
                .arg(&out)
                .output()
                .unwrap();
            assert_eq!(
                o.status.code(),
                Some(0),
                "{}",
                String::from_utf8_lossy(&o.stderr)
            );
            assert!(o.stdout.is_empty());
            std::fs::read_to_string(&out).unwrap()
        })
        .collect();
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
    assert!(
        !std::fs::symlink_metadata(&out)
            .unwrap()
            .file_type()
            .is_symlink()
    );
    let lines = |s: &str| -> Vec<serde_json::Value> { s.lines().map(without_timings).collect() };
    assert_eq!(lines(&runs[0]).len(), 6);
    assert_eq!(lines(&runs[0]), lines(&runs[1]), "--threads 1 vs 2");
    // No temporary file left behind.
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with(".epd-output"))
        .collect();
    assert!(left.is_empty());
    // -q: a failing file gives exit 1 and nothing on stderr.
    let o = epd()
        .args(["estimate", "-q", "--format", "json"])
        .arg(dir.join("missing.csv"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(
        o.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        without_timings(String::from_utf8_lossy(&o.stdout).trim())["status"],
        "error"
    );
}

/// `epd estimate … | head -1`: the reader goes away after one line. The run's whole
/// output (300 reports of ≈ 1.2 kB) is several times what the pipe (64 KiB on Linux) and
/// the reader's 8 KiB buffer hold, so `epd` must meet the closed pipe before it is done.
/// It then stops without a word on standard error (no "Broken pipe", no `error:` line,
/// no panic) and exits 0: every file it estimated was fine, and a reader that left is
/// not a failure (docs/epd.md, `epd estimate`).
#[test]
fn a_closed_standard_output_ends_quietly() {
    let dir = common::temp_dir("cmdline_pipe");
    let file = csv_file(&dir);
    let files = 300;
    let mut child = epd()
        .arg("estimate")
        .args(std::iter::repeat_n(&file, files))
        .args(["--format", "json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    // The reader goes away (as `| head -1` does).
    let o = child.wait_with_output().unwrap();
    assert!(first.starts_with('{'));
    assert!(
        files * first.len() > 4 * (64 + 8) * 1024,
        "{files} reports of {} bytes fit in the pipe: the closed pipe would not be met",
        first.len()
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert!(!err.to_lowercase().contains("broken pipe"), "{err}");
    assert!(
        !err.lines()
            .any(|l| l.trim_start().to_lowercase().starts_with("error")),
        "{err}"
    );
    assert!(err.trim().is_empty(), "not quiet: {err}");
    assert_eq!(o.status.code(), Some(0), "{err}");
}

/// `--threads` above 1024 is a usage error naming the limit (100 000 workers had taken
/// minutes to start for a 10 ms frame), in every command that takes it; and `-o` and
/// `--export-fit` naming one file (also through another spelling of its folder) is a
/// usage error, where the fitted wall had silently replaced the results.
#[test]
fn threads_are_bounded_and_two_outputs_cannot_share_a_file() {
    let dir = common::temp_dir("cmdline_limits");
    let file = csv_file(&dir);
    for cmd in [
        vec!["estimate"],
        vec!["calibrate", "--known-id-mm", "500", "--out", "t.json"],
        vec!["profile", "--out", "p"],
    ] {
        let o = epd()
            .args(&cmd)
            .arg(&file)
            .args(["--threads", "100000"])
            .current_dir(&dir)
            .output()
            .unwrap();
        expect_usage_error(&o, "at most 1024");
    }
    let sub = dir.join("sub");
    std::fs::create_dir_all(&sub).unwrap();
    let o = epd()
        .arg("estimate")
        .arg(&file)
        .arg("-o")
        .arg(sub.join("out"))
        .arg("--export-fit")
        .arg(dir.join("sub/../sub/out"))
        .output()
        .unwrap();
    expect_usage_error(&o, "name the same file");
    assert!(!sub.join("out").exists());
}

/// A nominal OD below the measured inner diameter names the option to check instead of a
/// negative wall thickness; one that is not finite in millimetres is a usage error.
#[test]
fn a_nominal_od_that_cannot_be_is_named() {
    let dir = common::temp_dir("cmdline_od");
    let file = csv_file(&dir);
    let o = epd()
        .arg("estimate")
        .arg(&file)
        .args(["--nominal-od-in", "1"])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("check --nominal-od-in"), "{out}");
    assert!(!out.contains("wall thickness ≈ -"), "{out}");
    let o = epd()
        .arg("estimate")
        .arg(&file)
        .args(["--nominal-od-in", "1e308"])
        .output()
        .unwrap();
    expect_usage_error(&o, "finite in millimetres");
}

/// `view --limit-mm 1e308` is a usage error naming the largest limit; it had overflowed
/// the colour scale's span and never ended. A limit within it draws.
#[test]
fn view_limits_beyond_the_colour_scale_are_refused() {
    let dir = common::temp_dir("cmdline_view");
    let file = csv_file(&dir);
    let mut view = epd();
    view.arg("view")
        .arg(&file)
        .arg("--out")
        .arg(dir.join("v.png"))
        .args(["--limit-mm", "1e308"]);
    let o = common::output_within(view, std::time::Duration::from_secs(60))
        .expect("view --limit-mm 1e308 still ran after 60 s");
    expect_usage_error(&o, "at most 1e300");
    let o = epd()
        .arg("view")
        .arg(&file)
        .arg("--out")
        .arg(dir.join("v.png"))
        .args(["--limit-mm", "1e300"])
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `simulate` with settings whose frames hold no point (a noise of 1e308 m, a pipe of
/// 1e308 in) is a usage error naming them, not "1 frames written" of empty files.
#[test]
fn simulate_settings_that_give_no_point_are_refused() {
    let dir = common::temp_dir("cmdline_sim");
    for extra in [["--sigma", "1e308"], ["--od-in", "1e308"]] {
        let o = epd()
            .args(["simulate", "--frames", "1", "--out"])
            .arg(dir.join("sim"))
            .args(extra)
            .output()
            .unwrap();
        expect_usage_error(&o, "no point");
        assert!(!dir.join("sim/frame_0000.ply").exists());
    }
}

/// `simulate --frames 10^15` stops after the first frame with a usage error naming the
/// room it needs and the room there is (it had written until the disk filled).
#[test]
fn simulate_frames_beyond_the_disk_are_refused() {
    let dir = common::temp_dir("cmdline_room");
    let o = epd()
        .args([
            "simulate",
            "--points",
            "2000",
            "--frames",
            "1000000000000000",
            "--out",
        ])
        .arg(dir.join("sim"))
        .output()
        .unwrap();
    expect_usage_error(&o, "bytes free");
    assert!(!dir.join("sim/frame_0001.ply").exists());
}
