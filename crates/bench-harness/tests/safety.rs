//! Results folders an attacker or an interruption cannot corrupt, limits checked when
//! the scenario is loaded, and the command line users expect.

mod common;

use common::{bin, temp_dir};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use bench_harness::Scenario;
use bench_harness::output::RUN_FILES;

/// A quick scenario: 2 swept values × `trials` trials of ML-EPD on `points` points.
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

/// A scenario that runs for minutes (full frames, one method): to be interrupted.
fn long_scenario(dir: &Path) -> PathBuf {
    let p = dir.join("long.toml");
    std::fs::write(&p, "name = \"s\"\ntrials = 2000\nmethods = [\"ml-epd\"]\n").unwrap();
    p
}

/// Names starting with a dot in `dir` (staging, old runs, temporary files).
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

/// Every entry of a folder with its bytes (links read as their target's path, folders
/// not read).
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| {
            let p = e.path();
            let bytes = match std::fs::read_link(&p) {
                Ok(t) => format!("link to {}", t.display()).into_bytes(),
                Err(_) if p.is_dir() => b"a folder".to_vec(),
                Err(_) => std::fs::read(&p).unwrap(),
            };
            (e.file_name().to_string_lossy().into_owned(), bytes)
        })
        .collect()
}

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Wait until a staging folder not in `known` shows up in `dir` (the run has started
/// writing), and return it.
fn wait_for_staging(dir: &Path, child: &mut Child, known: &[PathBuf]) -> PathBuf {
    let t0 = Instant::now();
    loop {
        let found = hidden(dir)
            .into_iter()
            .filter(|n| n.starts_with(".run-"))
            .map(|n| dir.join(n))
            .find(|p| !known.contains(p));
        if let Some(p) = found {
            // Let the first batch of trials start.
            std::thread::sleep(Duration::from_millis(300));
            return p;
        }
        if let Ok(Some(s)) = child.try_wait() {
            panic!("the run ended before it started writing: {s}");
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "no staging folder");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn kill(signal: &str, child: &Child) {
    let k = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(k.success());
}

/// Make a folder look old (a stale folder is at least 10 s old).
fn backdate(dir: &Path) {
    let then = SystemTime::now() - Duration::from_secs(3600);
    std::fs::File::open(dir)
        .unwrap()
        .set_modified(then)
        .unwrap();
}

#[test]
fn help_version_equals_form_double_dash_and_quiet() {
    for flag in ["--help", "-h"] {
        let o = bin().arg(flag).output().unwrap();
        assert_eq!(o.status.code(), Some(0));
        let help = String::from_utf8_lossy(&o.stdout);
        for w in [
            "--out",
            "--trials",
            "--threads",
            "--quiet",
            "SCENARIO",
            "Exit codes",
            "130",
            "n_failed",
        ] {
            assert!(help.contains(w), "{flag} lacks {w}");
        }
    }
    for flag in ["--version", "-V"] {
        let o = bin().arg(flag).output().unwrap();
        assert_eq!(o.status.code(), Some(0));
        assert_eq!(
            String::from_utf8_lossy(&o.stdout).trim(),
            format!("bench-harness {}", env!("CARGO_PKG_VERSION"))
        );
    }
    let dir = temp_dir("safety-q");
    let s = scenario(&dir, 2, 500);
    let out = dir.join("out");
    let o = bin()
        .arg(&s)
        .args(["--trials=5", "--threads=1", "-q", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(o.stderr.is_empty(), "-q wrote {}", stderr(&o));
    let rows = std::fs::read_to_string(out.join("trials.csv"))
        .unwrap()
        .lines()
        .count();
    assert_eq!(
        rows,
        1 + 2 * 5,
        "--trials=5: 2 values × 5 trials × 1 method"
    );
    // `--` ends the options: a scenario whose name starts with a dash.
    std::fs::copy(&s, dir.join("-s.toml")).unwrap();
    let o = bin()
        .current_dir(&dir)
        .args(["-q", "--out=out2", "--", "-s.toml"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(dir.join("out2/metadata.json").is_file());
    // Without `--`, the same name is an unknown option.
    let o = bin()
        .current_dir(&dir)
        .args(["--out=out3", "-s.toml"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    for bad in [
        &["--threads", "0"][..],
        &["--threads", "5000"],
        &["--threads=x"],
        &["--trials", "-3"],
        &["--trials=1e3"],
    ] {
        let o = bin().arg(&s).args(bad).arg("--out=out4").output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{bad:?}");
    }
    assert!(!dir.join("out3").exists() && !dir.join("out4").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn planted_links_never_redirect_a_write() {
    let dir = temp_dir("safety-links");
    let s = scenario(&dir, 2, 500);
    let out = dir.join("out");
    // A previous run, then links planted at every name a run writes, at the temporary
    // names of earlier versions and at guesses of staging names, all pointing outside:
    // to an existing file, and to files that do not exist yet.
    let o = bin().arg(&s).arg("--out").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    let mut names: Vec<String> = RUN_FILES.iter().map(|f| f.to_string()).collect();
    names.extend(RUN_FILES.iter().map(|f| format!(".{f}.tmp1")));
    for (i, name) in names.iter().enumerate() {
        let p = out.join(name);
        let _ = std::fs::remove_file(&p);
        if i % 2 == 0 {
            std::os::unix::fs::symlink(&victim, &p).unwrap();
        } else {
            std::os::unix::fs::symlink(dir.join(format!("created-{i}")), &p).unwrap();
        }
    }
    for guess in [".run-000000", ".old-000000", ".run-", ".out.tmp"] {
        std::os::unix::fs::symlink(&victim, dir.join(guess)).unwrap();
    }
    let before: Vec<String> = {
        let mut v: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    // The folder holds links at run names only: it is a previous run, replaced whole.
    let o = bin().arg(&s).arg("--out").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    let mut after: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    after.sort();
    assert_eq!(before, after, "something was created beside the output");
    let mut written: Vec<String> = Vec::new();
    for e in std::fs::read_dir(&out).unwrap().flatten() {
        let t = std::fs::symlink_metadata(e.path()).unwrap().file_type();
        assert!(t.is_file(), "{:?} is not a regular file", e.file_name());
        written.push(e.file_name().to_string_lossy().into_owned());
    }
    written.sort();
    let mut expected: Vec<String> = RUN_FILES.iter().map(|f| f.to_string()).collect();
    expected.sort();
    assert_eq!(written, expected);
    // The output folder itself as a link: refused, the target untouched.
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let linked = dir.join("linked");
    std::os::unix::fs::symlink(&elsewhere, &linked).unwrap();
    let o = bin().arg(&s).arg("--out").arg(&linked).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0);
    // A link to a file, too.
    let o = bin()
        .arg(&s)
        .arg("--out")
        .arg(dir.join(".out.tmp"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    let staging: Vec<String> = hidden(&dir)
        .into_iter()
        .filter(|n| std::fs::symlink_metadata(dir.join(n)).is_ok_and(|m| m.is_dir()))
        .collect();
    assert!(staging.is_empty(), "{staging:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn folders_that_are_not_a_run_are_refused() {
    let dir = temp_dir("safety-foreign");
    let s = scenario(&dir, 2, 500);
    // A home-like folder; a previous run with a file of the user's; a previous run with
    // a sub-folder; files of a run without metadata.json.
    let cases: [&[&str]; 4] = [
        &[".bashrc", "notes.txt"],
        &["trials.csv", "metadata.json", "notes.txt"],
        &["trials.csv", "metadata.json", "sub/"],
        &["trials.csv", "summary.csv"],
    ];
    for (i, files) in cases.iter().enumerate() {
        let out = dir.join(format!("out{i}"));
        std::fs::create_dir_all(&out).unwrap();
        for f in *files {
            match f.strip_suffix('/') {
                Some(d) => std::fs::create_dir(out.join(d)).unwrap(),
                None => std::fs::write(out.join(f), "mine").unwrap(),
            }
        }
        let before = snapshot(&out);
        let o = bin().arg(&s).arg("--out").arg(&out).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{files:?}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("not a bench-harness run"),
            "{}",
            stderr(&o)
        );
        assert_eq!(snapshot(&out), before, "{files:?} touched");
    }
    // `.` and `..` name no folder that could be replaced.
    let empty = dir.join("empty");
    std::fs::create_dir(&empty).unwrap();
    for out in [".", ".."] {
        let o = bin()
            .current_dir(&empty)
            .arg(&s)
            .args(["--out", out])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{out}: {}", stderr(&o));
    }
    assert_eq!(std::fs::read_dir(&empty).unwrap().count(), 0);
    assert!(hidden(&dir).is_empty(), "{:?}", hidden(&dir));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_interrupted_run_leaves_the_previous_one_whole() {
    let dir = temp_dir("safety-int");
    let quick = scenario(&dir, 2, 500);
    let out = dir.join("out");
    let o = bin().arg(&quick).arg("--out").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    let before = snapshot(&out);
    let long = long_scenario(&dir);
    for signal in ["-INT", "-TERM"] {
        let mut child = bin()
            .arg(&long)
            .args(["--threads", "1", "--out"])
            .arg(&out)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        wait_for_staging(&dir, &mut child, &[]);
        kill(signal, &child);
        let t0 = Instant::now();
        let o = child.wait_with_output().unwrap();
        assert!(t0.elapsed() < Duration::from_secs(20));
        assert_eq!(o.status.code(), Some(130), "{signal}: {}", stderr(&o));
        assert!(stderr(&o).contains("interrupted"), "{}", stderr(&o));
        // The previous run, every file of it, and nothing else.
        assert_eq!(snapshot(&out), before, "{signal}: the previous run changed");
        assert!(hidden(&dir).is_empty(), "{signal}: left {:?}", hidden(&dir));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_killed_run_is_cleaned_up_by_the_next_but_a_live_one_is_not() {
    let dir = temp_dir("safety-kill");
    let quick = scenario(&dir, 2, 500);
    let long = long_scenario(&dir);
    // SIGKILL cannot be handled: the staging folder stays...
    let mut child = bin()
        .arg(&long)
        .args(["--threads", "1", "--out"])
        .arg(dir.join("a"))
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stale = wait_for_staging(&dir, &mut child, &[]);
    kill("-KILL", &child);
    let _ = child.wait();
    assert!(stale.is_dir());
    // ... next to a live run's, and a hidden folder of the user's with a `.run-` name.
    let mut live = bin()
        .arg(&long)
        .args(["--threads", "1", "--out"])
        .arg(dir.join("b"))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let live_staging = wait_for_staging(&dir, &mut live, std::slice::from_ref(&stale));
    let users = dir.join(".run-mine00");
    std::fs::create_dir(&users).unwrap();
    std::fs::write(users.join("notes.txt"), "mine").unwrap();
    for d in [&stale, &live_staging, &users] {
        backdate(d);
    }
    // The next run in the same parent folder removes only the killed run's folder.
    let o = bin()
        .arg(&quick)
        .arg("--out")
        .arg(dir.join("c"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(!stale.exists(), "the killed run's staging folder stayed");
    assert!(
        live_staging.is_dir(),
        "a live run's staging folder was removed"
    );
    assert_eq!(
        std::fs::read_to_string(users.join("notes.txt")).unwrap(),
        "mine"
    );
    kill("-INT", &live);
    let o = live.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    assert!(!live_staging.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_full_disk_is_an_error_naming_the_file_and_the_previous_run_stays() {
    let dir = temp_dir("safety-full");
    let s = scenario(&dir, 20, 500);
    let out = dir.join("out");
    let o = bin().arg(&s).arg("--out").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    let before = snapshot(&out);
    // A file size limit stands in for a full disk: writes past it fail with EFBIG
    // (SIGXFSZ ignored), as they would with ENOSPC.
    let o = Command::new("sh")
        .arg("-c")
        .arg("trap '' XFSZ; ulimit -f 8; exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_bench-harness"))
        .arg(&s)
        .args(["--trials", "200", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("cannot write") && err.contains("trials.csv"),
        "{err}"
    );
    assert_eq!(snapshot(&out), before);
    assert!(hidden(&dir).is_empty(), "{:?}", hidden(&dir));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_trial_that_cannot_be_made_exits_1_with_the_results_written() {
    // 3 × 2 pixels: too few points for any estimate (status `error`).
    let dir = temp_dir("safety-error");
    let p = dir.join("e.toml");
    std::fs::write(
        &p,
        "name = \"e\"\ntrials = 2\nmethods = [\"ml-epd\"]\n[sensor]\nwidth = 3\nheight = 2\n",
    )
    .unwrap();
    let out = dir.join("out");
    let o = bin()
        .arg(&p)
        .arg("-q")
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("could not be made"), "{}", stderr(&o));
    let trials = std::fs::read_to_string(out.join("trials.csv")).unwrap();
    assert!(
        trials.lines().skip(1).all(|l| l.contains(",error,")),
        "{trials}"
    );
    assert!(out.join("metadata.json").is_file());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn limits_are_checked_before_anything_is_written() {
    let dir = temp_dir("safety-limits");
    let cases = [
        ("trials = 1000001\n", &["`trials` = 1000001", "1000000"][..]),
        ("trials = 1e18\n", &["`trials` = 1e18", "float", "1000000"]),
        ("trials = -1\n", &["`trials` = -1"]),
        (
            "[sensor]\nwidth = 100000\n",
            &["`sensor.width` = 100000", "4096"],
        ),
        ("[sensor]\nheight = 0\n", &["`sensor.height` = 0", "4096"]),
        (
            "points = 100000000\n",
            &["`points` = 100000000", "10000000"],
        ),
        ("points = 3\n", &["`points` = 3", "[9, "]),
        ("points = 3.5\n", &["`points` = 3.5", "float"]),
        (
            "trials = 1000000\nmethods = [\"c-epd\", \"ru-epd\", \"ml-epd\"]\n\
             [sweep]\nvariable = \"pipe.ovality\"\nvalues = [0.0, 0.01, 0.02, 0.03, 0.04, \
             0.05, 0.06, 0.07, 0.08, 0.09, 0.1, 0.11, 0.12, 0.13, 0.14, 0.15, 0.16, 0.17, \
             0.18, 0.19, 0.2, 0.21, 0.22, 0.23, 0.24, 0.25, 0.26, 0.27, 0.28, 0.29, 0.3, \
             0.31, 0.32, 0.33, 0.34]\n",
            &["`trials` = 1000000", "105000000 estimates", "100000000"],
        ),
        (
            "[sweep]\nvariable = \"sensor.width\"\nvalues = [64, 5000]\n",
            &["`sensor.width` = 5000", "swept value 5000"],
        ),
    ];
    for (i, (body, needles)) in cases.iter().enumerate() {
        let p = dir.join(format!("l{i}.toml"));
        std::fs::write(&p, format!("name = \"l{i}\"\n{body}")).unwrap();
        let out = dir.join(format!("out{i}"));
        let o = bin().arg(&p).arg("--out").arg(&out).output().unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{body}: {err}");
        for n in *needles {
            assert!(err.contains(n), "{body}: `{n}` not in {err}");
        }
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists());
    }
    // `--trials` is held to the same limits, after the scenario is read.
    let values: Vec<String> = (0..200)
        .map(|i| format!("{}", 0.01 + i as f64 * 1e-4))
        .collect();
    let p = dir.join("v200.toml");
    std::fs::write(
        &p,
        format!(
            "name = \"v\"\nmethods = [\"ml-epd\"]\n[sweep]\nvariable = \"noise.sigma_m\"\nvalues = [{}]\n",
            values.join(",")
        ),
    )
    .unwrap();
    for (n, needle) in [
        ("1000001", "`--trials` = 1000001"),
        ("600000", "120000000 estimates"),
    ] {
        let o = bin()
            .arg(&p)
            .args(["--trials", n, "--out"])
            .arg(dir.join("outx"))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(stderr(&o).contains(needle), "{}", stderr(&o));
        assert!(!dir.join("outx").exists());
    }
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
    assert!(stderr(&o).contains("sweep.values") && stderr(&o).contains("10001"));
    assert!(!dir.join("outm").exists());
    // A device is refused before anything is read from it (a FIFO would never end).
    let o = bin()
        .args(["/dev/zero", "--out"])
        .arg(dir.join("outz"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("not a regular file"), "{}", stderr(&o));
    // An endless standard input is read no further than the limit.
    let o = bin()
        .args(["-", "--out"])
        .arg(dir.join("outz"))
        .stdin(std::fs::File::open("/dev/zero").unwrap())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("larger than"), "{}", stderr(&o));
    assert!(hidden(&dir).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

/// 10 000 swept values load in linear time and memory (they used to take the square:
/// 3.1 GB and 12 s for a 90 KB file).
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
    assert!(dt < Duration::from_secs(2), "{dt:?}");
}
