//! `bench-harness` with standard error a pipe whose reader has gone: every path that
//! prints (a bad scenario, a run's summary line, a refused merge, the `--threads` limit)
//! exits with its documented code, not 101 ("failed printing to stderr: Broken pipe"),
//! and a run's files are written.
#![cfg(unix)]

mod common;

use common::{bin, temp_dir};
use std::process::Stdio;

/// A pipe whose reader is already closed: every write to it fails with EPIPE.
fn closed_pipe() -> Stdio {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    Stdio::from(writer)
}

const TINY: &str = r#"
name = "tiny"
seed = 3
trials = 2
methods = ["ru-epd"]
points = 2000
[noise]
sigma_m = 0.03
[sweep]
variable = "pipe.ovality"
values = [0.0]
"#;

#[test]
fn a_closed_stderr_changes_no_exit_code() {
    let dir = temp_dir("streams");
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "name = \"u\"\n[noise]\nsigma = 0.1\n").unwrap();
    let o = bin().arg(&bad).stderr(closed_pipe()).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "bad scenario: {o:?}");
    let good = dir.join("tiny.toml");
    std::fs::write(&good, TINY).unwrap();
    let o = bin()
        .arg(&good)
        .args(["--threads", "5000"])
        .stderr(closed_pipe())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "--threads limit: {o:?}");
    // The summary line ("… in 0.1 s → out") cannot be printed: the run is written, 0.
    let out = dir.join("out");
    let o = bin()
        .arg(&good)
        .arg("--out")
        .arg(&out)
        .stderr(closed_pipe())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "run: {o:?}");
    assert!(out.join("trials.csv").is_file() && out.join("summary.csv").is_file());
    // merge of folders that are not shards: refused, 2.
    let o = bin()
        .arg("merge")
        .arg(&out)
        .arg("--out")
        .arg(dir.join("merged"))
        .stderr(closed_pipe())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "merge: {o:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
