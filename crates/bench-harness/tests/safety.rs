//! Results folders an attacker or an interruption cannot corrupt, limits checked when
//! the scenario is loaded, and the command line users expect.

mod common;

use common::{bin, temp_dir};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use bench_harness::Scenario;

fn scenario(dir: &Path, trials: usize, points: usize) -> PathBuf {
    let p = dir.join("s.toml");
    std::fs::write(
        &p,
        format!(
            "name = \"s\"\nseed = 1\ntrials = {trials}\nmethods = [\"ml-epd\"]\npoints = {points}\n\
             [sweep]\nvariable = \"noise.sigma_m\"\nvalues = [0.01, 0.03]\n"
        ),
    )
    .unwrap();
    p
}

/// Names starting with a dot beside or inside the output folder (staging, old runs,
/// temporary files).
fn hidden(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|r| {
            r.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with('.'))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn help_version_and_equals_form() {
    let o = bin().arg("--help").output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    let help = String::from_utf8_lossy(&o.stdout);
    for w in ["--out", "--trials", "--threads", "--quiet", "SCENARIO"] {
        assert!(help.contains(w), "--help lacks {w}");
    }
    let o = bin().arg("--version").output().unwrap();
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).trim(),
        format!("bench-harness {}", env!("CARGO_PKG_VERSION"))
    );
    let dir = temp_dir("safety-q");
    let s = scenario(&dir, 2, 500);
    let o = bin()
        .arg(&s)
        .args(["--trials=2", "-q", "--out"])
        .arg(dir.join("out"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0));
    assert!(
        o.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn planted_links_never_redirect_a_write() {
    let dir = temp_dir("safety-links");
    let s = scenario(&dir, 2, 500);
    let out = dir.join("out");
    // A previous run, then links planted at every name a run writes and at the old
    // predictable temporary names, all pointing outside.
    let o = bin().arg(&s).arg("--out").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    for name in [
        "trials.csv",
        "summary.csv",
        "metadata.json",
        "scenario.toml",
        "diameter_error.png",
        ".trials.csv.tmp1",
        ".summary.csv.tmp1",
    ] {
        let p = out.join(name);
        let _ = std::fs::remove_file(&p);
        std::os::unix::fs::symlink(&victim, &p).unwrap();
    }
    // The folder now holds links, still with no foreign regular file: the run replaces
    // the folder as a whole.
    let o = bin().arg(&s).arg("--out").arg(&out).output().unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    for e in std::fs::read_dir(&out).unwrap().flatten() {
        let t = e.file_type().unwrap();
        assert!(t.is_file(), "{:?} is not a regular file", e.file_name());
    }
    // The output folder itself as a link: refused, the target untouched.
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let linked = dir.join("linked");
    std::os::unix::fs::symlink(&elsewhere, &linked).unwrap();
    let o = bin().arg(&s).arg("--out").arg(&linked).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0);
    assert!(hidden(&dir).is_empty(), "{:?}", hidden(&dir));
}

#[test]
fn an_interrupted_run_leaves_the_previous_one_whole() {
    let dir = temp_dir("safety-int");
    let quick = scenario(&dir, 2, 500);
    let out = dir.join("out");
    let o = bin().arg(&quick).arg("--out").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    let before = std::fs::read(out.join("trials.csv")).unwrap();
    let meta_before = std::fs::read(out.join("metadata.json")).unwrap();
    // A long run (full frames), interrupted by SIGINT once it has started.
    let long = dir.join("long.toml");
    std::fs::write(
        &long,
        "name = \"s\"\ntrials = 2000\nmethods = [\"ml-epd\"]\n",
    )
    .unwrap();
    for signal in ["-INT", "-TERM"] {
        let child = bin()
            .arg(&long)
            .args(["--threads", "1", "--out"])
            .arg(&out)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(800));
        let k = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(k.success());
        let t0 = Instant::now();
        let o = child.wait_with_output().unwrap();
        assert!(t0.elapsed() < Duration::from_secs(20));
        assert_eq!(
            o.status.code(),
            Some(130),
            "{signal}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert_eq!(std::fs::read(out.join("trials.csv")).unwrap(), before);
        assert_eq!(
            std::fs::read(out.join("metadata.json")).unwrap(),
            meta_before
        );
        assert!(hidden(&dir).is_empty(), "{signal}: left {:?}", hidden(&dir));
    }
}

#[test]
fn limits_are_checked_before_anything_is_written() {
    let dir = temp_dir("safety-limits");
    let cases = [
        ("trials = 1000000000\n", "trials"),
        ("trials = 1e18\n", "trials"),
        (
            "trials = 10\n[sensor]\nwidth = 100000\nheight = 100000\n",
            "sensor.width",
        ),
        ("points = 100000000\n", "points"),
        ("points = 3\n", "points"),
    ];
    for (i, (body, key)) in cases.iter().enumerate() {
        let p = dir.join(format!("l{i}.toml"));
        std::fs::write(&p, format!("name = \"l{i}\"\n{body}")).unwrap();
        let out = dir.join(format!("out{i}"));
        let o = bin().arg(&p).arg("--out").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{body}: {err}");
        assert!(err.contains(key), "{body}: {err}");
        assert!(!out.exists());
    }
    let o = bin()
        .arg(dir.join("l0.toml"))
        .args(["--trials", "100000000", "--out"])
        .arg(dir.join("outx"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(!dir.join("outx").exists());
    // More sweep values than allowed.
    let values: Vec<String> = (0..10_001)
        .map(|i| format!("{}", 0.01 + i as f64 * 1e-6))
        .collect();
    let p = dir.join("many.toml");
    std::fs::write(
        &p,
        format!(
            "name = \"m\"\n[sweep]\nvariable = \"noise.sigma_m\"\nvalues = [{}]\n",
            values.join(",")
        ),
    )
    .unwrap();
    let o = bin()
        .arg(&p)
        .arg("--out")
        .arg(dir.join("outm"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("sweep.values"));
}

/// 10 000 swept values load in linear time and memory (they used to take the square:
/// > 3 GB for a 60 KB file).
#[test]
fn ten_thousand_sweep_values_load_fast() {
    let values: Vec<String> = (0..10_000)
        .map(|i| format!("{}", 0.01 + i as f64 * 1e-6))
        .collect();
    let src = format!(
        "name = \"m\"\ntrials = 1\n[sweep]\nvariable = \"noise.sigma_m\"\nvalues = [{}]\n",
        values.join(",")
    );
    let t0 = Instant::now();
    let s = Scenario::parse(Path::new("many.toml"), &src).unwrap();
    let dt = t0.elapsed();
    assert_eq!(s.sweeps.len(), 10_000);
    eprintln!("10 000 sweep values loaded in {dt:?}");
    assert!(dt < Duration::from_secs(5), "{dt:?}");
}
