//! The `epd` tool on inputs an attacker or a careless user gives it (issue 27, part A):
//! crafted depth tables, a table of another camera, absurd bin counts, a dangling `--out`.

mod common;

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn epd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_epd"))
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A table file of `nr × ni` bins over range [r0, r1] m and log-intensity [l0, l1],
/// every offset 2 mm, every spread 10 mm.
fn table(nr: usize, ni: usize, (r0, r1): (f64, f64), (l0, l1): (f64, f64)) -> String {
    let row = |v: &str| format!("[{}]", vec![v; ni].join(","));
    let arr = |v: &str| format!("[{}]", vec![row(v); nr].join(","));
    format!(
        r#"{{"format":"epd-depth-table","version":1,"known_d_max_mm":500,"known_d_min_mm":500,
           "frames":1,"n_observations":10,
           "range_m":{{"lo":{r0},"hi":{r1},"bins":{nr}}},
           "log_intensity":{{"lo":{l0},"hi":{l1},"bins":{ni}}},"empty_bins":"",
           "offset_mm":{},"spread_mm":{},"count":{}}}"#,
        arr("2"),
        arr("10"),
        arr("40")
    )
}

/// One simulated Helios2 frame (PLY with intensity) in `dir`.
fn helios_frame(dir: &Path) -> std::path::PathBuf {
    let o = epd()
        .args([
            "simulate", "--frames", "1", "--sensor", "helios2", "--seed", "4", "--out",
        ])
        .arg(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    dir.join("frame_0000.ply")
}

/// A 2 MB table of 200 000 intensity bins (issue 27: "memory allocation of 104859200000
/// bytes failed", SIGABRT, every file of the batch lost) corrects a frame in bounded time.
#[test]
fn a_table_of_200000_intensity_bins_does_not_abort_the_batch() {
    let dir = common::temp_dir("crafted-table");
    let frame = helios_frame(&dir);
    let t = dir.join("crafted.json");
    std::fs::write(&t, table(1, 200_000, (0.1, 10.0), (-5.0, 20.0))).unwrap();
    let t0 = Instant::now();
    let o = epd()
        .arg("estimate")
        .arg(&frame)
        .arg("--calibration")
        .arg(&t)
        .args(["--format", "json"])
        .output()
        .unwrap();
    let dt = t0.elapsed();
    assert!(
        matches!(o.status.code(), Some(0 | 1)),
        "exit {:?}: {}",
        o.status,
        stderr(&o)
    );
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(out.lines().count(), 1, "{out}");
    assert!(dt < Duration::from_secs(60), "{dt:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A table whose axes none of the frame's points fall in (another camera, another rig)
/// is not applied silently: the frame is refused, naming the table's axes.
#[test]
fn a_table_of_another_camera_is_refused_for_the_frame() {
    let dir = common::temp_dir("foreign-table");
    let frame = helios_frame(&dir);
    let t = dir.join("foreign.json");
    std::fs::write(&t, table(4, 3, (50.0, 60.0), (1.0, 7.0))).unwrap();
    let o = epd()
        .arg("estimate")
        .arg(&frame)
        .arg("--calibration")
        .arg(&t)
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let all = format!("{err}{}", String::from_utf8_lossy(&o.stdout));
    assert!(
        all.contains("none of the frame's") && all.contains("another camera or rig"),
        "{all}"
    );
    // Bins beyond 2²⁰: a usage error naming the limit.
    std::fs::write(
        &t,
        table(1, 1, (0.5, 2.0), (1.0, 7.0)).replace("\"bins\":1}", "\"bins\":1048577}"),
    )
    .unwrap();
    let o = epd()
        .arg("estimate")
        .arg(&frame)
        .arg("--calibration")
        .arg(&t)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("at most 1048576 (2²⁰) bins"),
        "{}",
        stderr(&o)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Bin counts that overflow their product are usage errors naming the limit (issue 27:
/// 4294967296 × 4294967296 wrapped and exited 1).
#[test]
fn calibrate_bin_counts_are_checked_as_parsed() {
    let dir = common::temp_dir("cal-bins");
    let f = dir.join("f.ply");
    std::fs::write(&f, b"").unwrap();
    for (r, i) in [
        ("4294967296", "4294967296"),
        ("18446744073709551615", "2"),
        ("0", "12"),
        ("1048577", "1"),
    ] {
        let o = epd()
            .args([
                "calibrate",
                "--known-id-mm",
                "500",
                "--range-bins",
                r,
                "--intensity-bins",
                i,
                "--out",
            ])
            .arg(dir.join("t.json"))
            .arg(&f)
            .output()
            .unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{r} × {i}: {err}");
        assert!(err.contains("1048576"), "{r} × {i}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `simulate --out` on a dangling link or a file (issue 27: "File exists").
#[cfg(unix)]
#[test]
fn simulate_out_names_what_is_in_the_way() {
    let dir = common::temp_dir("sim-out");
    let link = dir.join("link");
    std::os::unix::fs::symlink(dir.join("nowhere"), &link).unwrap();
    let o = epd()
        .args(["simulate", "--frames", "1", "--points", "1000", "--out"])
        .arg(&link)
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("symbolic link")
            && err.contains("does not exist")
            && !err.contains("File exists"),
        "{err}"
    );
    let file = dir.join("file");
    std::fs::write(&file, b"x").unwrap();
    let o = epd()
        .args(["simulate", "--frames", "1", "--points", "1000", "--out"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("is not a folder"), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A FIFO given as a frame is refused by name without waiting for a writer (opening it
/// to sniff a bag's magic bytes had waited forever, the good files after it unread), in
/// `estimate`, `view` and `profile`; the file after it is still estimated.
#[test]
fn a_fifo_among_the_frames_is_refused_not_waited_on() {
    let dir = common::temp_dir("fifo-frame");
    let frame = helios_frame(&dir);
    let fifo = dir.join("pipe.ply");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    // A writer never comes: a reader that opens the FIFO blocking would wait forever.
    let limit = Duration::from_secs(60);
    let mut estimate = epd();
    estimate.arg("estimate").arg(&fifo).arg(&frame);
    let o = common::output_within(estimate, limit).expect("estimate waited on the FIFO");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("not a regular file (a FIFO)"),
        "{}",
        stderr(&o)
    );
    // The frame after it was read and estimated (this uncalibrated Helios2 frame is
    // refused `lack_of_fit`, on stdout with its estimate).
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(out.contains("frame_0000.ply: ml-epd"), "{out}");
    let mut view = epd();
    view.arg("view")
        .arg(&fifo)
        .arg("--out")
        .arg(dir.join("v.png"));
    let o = common::output_within(view, limit).expect("view waited on the FIFO");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("not a regular file (a FIFO)"),
        "{}",
        stderr(&o)
    );
    // `profile` names each frame without a result and why on stderr, not only in its CSV.
    let mut profile = epd();
    profile
        .arg("profile")
        .arg(&fifo)
        .arg("--out")
        .arg(dir.join("prof"));
    let o = common::output_within(profile, limit).expect("profile waited on the FIFO");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("pipe.ply: not a regular file (a FIFO)"),
        "{}",
        stderr(&o)
    );
}
