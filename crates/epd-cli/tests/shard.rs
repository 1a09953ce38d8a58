//! `epd estimate --shard K/N`: the shards' outputs, concatenated in order, are the
//! output of one run over the sorted file list (timings aside); bad K/N are refused.

mod common;

use std::path::PathBuf;
use std::process::{Command, Output};

fn epd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_epd"))
}

fn ok(o: Output) -> String {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// The timing keys of a report, which differ between any two runs.
const TIMINGS: [&str; 2] = ["elapsed_ms", "read_ms"];

/// JSON lines without their timings.
fn json_without_timings(text: &str) -> Vec<serde_json::Value> {
    text.lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let o = v.as_object_mut().unwrap();
            for k in TIMINGS {
                assert!(o.remove(k).is_some(), "no {k} in {l}");
            }
            v
        })
        .collect()
}

/// CSV records (the header first) without the timing columns, read with the `csv` crate.
fn csv_without_timings(text: &str) -> Vec<Vec<String>> {
    let mut r = csv::Reader::from_reader(text.as_bytes());
    let header = r.headers().unwrap().clone();
    let drop: Vec<usize> = TIMINGS
        .iter()
        .map(|k| header.iter().position(|h| h == *k).unwrap())
        .collect();
    std::iter::once(header)
        .chain(r.records().map(Result::unwrap))
        .map(|rec| {
            rec.iter()
                .enumerate()
                .filter(|(i, _)| !drop.contains(i))
                .map(|(_, f)| f.to_string())
                .collect()
        })
        .collect()
}

#[test]
fn shards_concatenate_into_the_run_over_the_sorted_files() {
    let dir = common::temp_dir("shard");
    let o = epd()
        .args([
            "simulate", "--frames", "7", "--points", "3000", "--seed", "4", "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sorted: Vec<PathBuf> = (0..7)
        .map(|k| dir.join(format!("frame_{k:04}.ply")))
        .collect();
    // Given in another order: each shard sorts the list before taking its block.
    let shuffled: Vec<PathBuf> = [4, 1, 6, 0, 3, 5, 2]
        .iter()
        .map(|&i| sorted[i].clone())
        .collect();
    for format in ["json", "csv"] {
        let whole = ok(epd()
            .arg("estimate")
            .args(&sorted)
            .args(["--format", format, "-q"])
            .output()
            .unwrap());
        for n in [1u32, 3, 4, 10] {
            let mut cat = String::new();
            let mut files = 0;
            for k in 1..=n {
                let part = ok(epd()
                    .arg("estimate")
                    .args(&shuffled)
                    .args(["--format", format, "-q", "--shard", &format!("{k}/{n}")])
                    .output()
                    .unwrap());
                let rows = part.lines().count() - usize::from(format == "csv" && k == 1);
                // Contiguous blocks of 7 files whose sizes differ by at most one.
                assert!(
                    rows == 7 / n as usize || rows == 7usize.div_ceil(n as usize),
                    "{format} {k}/{n}: {rows} files"
                );
                if format == "csv" && k > 1 {
                    assert!(!part.starts_with("file,"), "{k}/{n} repeats the header");
                }
                files += rows;
                cat.push_str(&part);
            }
            assert_eq!(files, 7, "{format} N = {n}");
            if format == "json" {
                assert_eq!(
                    json_without_timings(&cat),
                    json_without_timings(&whole),
                    "N = {n}"
                );
            } else {
                assert_eq!(
                    csv_without_timings(&cat),
                    csv_without_timings(&whole),
                    "N = {n}"
                );
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_shards_and_standard_input_are_refused() {
    for (shard, needle) in [
        ("0/4", "K = 0"),
        ("5/4", "K = 5 is larger than N = 4"),
        ("a/b", "expected K/N"),
        ("1/0", "N = 0"),
        ("2", "expected K/N"),
        ("-1/4", "expected K/N"),
    ] {
        let o = epd()
            .args(["estimate", "x.ply", &format!("--shard={shard}")])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{shard}: {err}");
        assert!(err.contains(needle), "{shard}: {err}");
        assert!(o.stdout.is_empty());
    }
    let o = epd()
        .args(["estimate", "-", "x.ply", "--shard", "1/2"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("standard input"), "{err}");
}
