//! Sharded runs: `bench-harness SCENARIO --shard K/N` as separate processes, then
//! `bench-harness merge`, equal an unsharded run apart from timings; every kind of
//! wrong set of shards is refused.

mod common;

use common::{bin, temp_dir};
use std::path::{Path, PathBuf};
use std::process::{Child, Output};

/// Three settings × 5 trials × 3 methods: 15 trials, so 4 shards get 4, 4, 4 and 3,
/// each from every setting.
const SMALL: &str = r#"
name = "small"
seed = 11
trials = 5
methods = ["c-epd", "ru-epd", "ml-epd"]
points = 3000
[noise]
sigma_m = 0.03
[sweep]
variable = "noise.sigma_m"
values = [0.01, 0.03, 0.05]
"#;

/// One setting, two trials: for the refusals.
const TINY: &str = r#"
name = "tiny"
seed = 2
trials = 2
methods = ["ru-epd"]
points = 1000
"#;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn ok(o: Output) -> Output {
    assert!(
        o.status.success(),
        "exit {:?}: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// `trials.csv` without the `time_ms` column (index 7, before any quoted field).
fn trials_without_timings(p: &Path) -> Vec<String> {
    let text = read(p);
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    assert_eq!(header[7], "time_ms");
    text.lines()
        .map(|l| {
            let mut f: Vec<&str> = l.splitn(9, ',').collect();
            f.remove(7);
            f.join(",")
        })
        .collect()
}

/// `summary.csv` with the statistics of the `time_ms` rows left out (their n and
/// n_failed kept).
fn summary_without_timings(p: &Path) -> Vec<String> {
    read(p)
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            if f[3] == "time_ms" {
                f[..7].join(",")
            } else {
                l.to_string()
            }
        })
        .collect()
}

fn spawn_shard(scenario: &Path, shard: &str, out: &Path) -> Child {
    bin()
        .arg(scenario)
        .args(["--shard", shard, "--threads", "1", "-q", "--out"])
        .arg(out)
        .spawn()
        .unwrap()
}

#[test]
fn four_shard_processes_merge_into_the_unsharded_run() {
    let dir = temp_dir("shard4");
    let scenario = write(&dir, "small.toml", SMALL);
    let whole = dir.join("whole");
    ok(bin()
        .arg(&scenario)
        .args(["-q", "--out"])
        .arg(&whole)
        .output()
        .unwrap());
    // Four processes at once, as four array tasks would run.
    let shards: Vec<PathBuf> = (1..=4).map(|k| dir.join(format!("part{k}"))).collect();
    let children: Vec<Child> = shards
        .iter()
        .enumerate()
        .map(|(i, d)| spawn_shard(&scenario, &format!("{}/4", i + 1), d))
        .collect();
    for mut c in children {
        assert!(c.wait().unwrap().success());
    }
    let whole_rows = trials_without_timings(&whole.join("trials.csv"));
    let mut rows_seen = 0;
    for (k, d) in shards.iter().enumerate() {
        let mut names: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                "metadata.json",
                "scenario.toml",
                "shard-trials.jsonl",
                "shard.json",
                "trials.csv"
            ]
        );
        // Each shard's rows are the unsharded run's rows of its trials: g mod 4 = k.
        let rows = trials_without_timings(&d.join("trials.csv"));
        assert_eq!(rows[0], whole_rows[0]);
        let expected: Vec<&String> = whole_rows[1..]
            .iter()
            .enumerate()
            .filter(|(i, _)| (i / 3) % 4 == k)
            .map(|(_, r)| r)
            .collect();
        assert_eq!(
            rows[1..].iter().collect::<Vec<_>>(),
            expected,
            "shard {}",
            k + 1
        );
        rows_seen += rows.len() - 1;
    }
    assert_eq!(rows_seen, whole_rows.len() - 1);
    // The shards in any order.
    let merged = dir.join("merged");
    let o = ok(bin()
        .arg("merge")
        .args([&shards[2], &shards[0], &shards[3], &shards[1]])
        .arg("--out")
        .arg(&merged)
        .output()
        .unwrap());
    assert!(String::from_utf8_lossy(&o.stderr).contains("merged 4 shards"));
    assert_eq!(
        trials_without_timings(&merged.join("trials.csv")),
        whole_rows
    );
    assert_eq!(
        summary_without_timings(&merged.join("summary.csv")),
        summary_without_timings(&whole.join("summary.csv"))
    );
    // The time_ms rows are there, from the shards' own timings.
    assert!(read(&merged.join("summary.csv")).contains(",time_ms,ms,5,0,"));
    assert_eq!(read(&merged.join("scenario.toml")), SMALL);
    for f in [
        "diameter_error.png",
        "dmean_error.png",
        "pose_error.png",
        "time.png",
        "std_vs_crb.png",
        "coverage.png",
    ] {
        let bytes = std::fs::read(merged.join(f)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{f}");
    }
    let meta: serde_json::Value =
        serde_json::from_str(&read(&merged.join("metadata.json"))).unwrap();
    assert_eq!(meta["shards"], 4);
    assert_eq!(meta["seed"], 11);
    assert_eq!(meta["trials_per_setting"], 5);
    assert_eq!(meta["merged_from"].as_array().unwrap().len(), 4);
    // A merge replaces a previous merge, like a run.
    ok(bin()
        .arg("merge")
        .args(&shards)
        .args(["-q", "--out"])
        .arg(&merged)
        .output()
        .unwrap());
    assert_eq!(
        trials_without_timings(&merged.join("trials.csv")),
        whole_rows
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A merge that must be refused: exit 2, `needle` in the message, nothing written.
fn refused(dirs: &[&Path], out: &Path, needle: &str) {
    let o = bin()
        .arg("merge")
        .args(dirs)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{needle}: {err}");
    assert!(err.contains(needle), "`{needle}` not in: {err}");
    assert!(!out.exists(), "{needle}: wrote {}", out.display());
}

fn shard(scenario: &Path, spec: &str, out: &Path, extra: &[&str]) {
    ok(bin()
        .arg(scenario)
        .args(["--shard", spec, "-q"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap());
}

#[test]
fn wrong_sets_of_shards_are_refused_and_nothing_is_written() {
    let dir = temp_dir("shardbad");
    let tiny = write(&dir, "tiny.toml", TINY);
    let d = |name: &str| dir.join(name);
    for k in 1..=2 {
        shard(&tiny, &format!("{k}/2"), &d(&format!("a{k}")), &[]);
    }
    let (a1, a2) = (d("a1"), d("a2"));
    let out = d("merged");
    // The good pair merges (and is then removed again for the refusals).
    ok(bin()
        .arg("merge")
        .args([&a1, &a2])
        .args(["-q", "--out"])
        .arg(&out)
        .output()
        .unwrap());
    std::fs::remove_dir_all(&out).unwrap();

    // Missing and duplicate shards, a different count.
    refused(&[&a1], &out, "1 of 2 shards missing: shard 2/2");
    refused(&[&a1, &a1, &a2], &out, "shard 1/2 given twice");
    shard(&tiny, "3/3", &d("b3"), &[]);
    refused(&[&a1, &a2, &d("b3")], &out, "shard counts differ");

    // Another seed, another scenario, another --trials.
    let seed = write(&dir, "seed.toml", &TINY.replace("seed = 2", "seed = 3"));
    shard(&seed, "2/2", &d("seed2"), &[]);
    refused(&[&a1, &d("seed2")], &out, "different seeds");
    let other = write(
        &dir,
        "other.toml",
        &TINY.replace("points = 1000", "points = 1200"),
    );
    shard(&other, "2/2", &d("other2"), &[]);
    refused(&[&a1, &d("other2")], &out, "different scenarios");
    shard(&tiny, "2/2", &d("trials2"), &["--trials", "3"]);
    refused(&[&a1, &d("trials2")], &out, "different trials per setting");

    // Another build: the manifest's code differs.
    let code = d("code2");
    std::fs::create_dir_all(&code).unwrap();
    for e in std::fs::read_dir(&a2).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), code.join(e.file_name())).unwrap();
    }
    let m = read(&code.join("shard.json"));
    let m = m.replacen("\"crate_version\": \"", "\"crate_version\": \"9.", 1);
    std::fs::write(code.join("shard.json"), m).unwrap();
    refused(&[&a1, &code], &out, "different code versions");
    // Both shards from another build: the merge itself is not the code that made them.
    let other_a1 = d("code1");
    std::fs::create_dir_all(&other_a1).unwrap();
    for e in std::fs::read_dir(&a1).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), other_a1.join(e.file_name())).unwrap();
    }
    let m = read(&other_a1.join("shard.json"));
    let m = m.replacen("\"crate_version\": \"", "\"crate_version\": \"9.", 1);
    std::fs::write(other_a1.join("shard.json"), m).unwrap();
    refused(
        &[&other_a1, &code],
        &out,
        "merge with the binary that made the shards",
    );

    // Not a shard: a whole run, an empty folder, a missing one.
    let whole = d("whole");
    ok(bin()
        .arg(&tiny)
        .args(["-q", "--out"])
        .arg(&whole)
        .output()
        .unwrap());
    refused(&[&a1, &whole], &out, "holds a whole run");
    std::fs::create_dir_all(d("empty")).unwrap();
    refused(&[&a1, &d("empty")], &out, "not a shard folder");
    refused(&[&a1, &d("nowhere")], &out, "not a shard folder");

    // A damaged records file: a line cut short, a trial removed.
    let cut = d("cut2");
    std::fs::create_dir_all(&cut).unwrap();
    for e in std::fs::read_dir(&a2).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), cut.join(e.file_name())).unwrap();
    }
    let records = read(&cut.join("shard-trials.jsonl"));
    std::fs::write(
        cut.join("shard-trials.jsonl"),
        &records[..records.len() - 10],
    )
    .unwrap();
    refused(&[&a1, &cut], &out, "damaged shard");
    std::fs::write(cut.join("shard-trials.jsonl"), "").unwrap();
    refused(&[&a1, &cut], &out, "shard-trials.jsonl is 0 bytes");

    // The output folder may not be one of the shards.
    let o = bin()
        .arg("merge")
        .args([&a1, &a2])
        .arg("--out")
        .arg(&a2)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("is one of the shard folders"));
    assert!(a2.join("shard.json").exists());

    // No folders, no --out.
    let o = bin().args(["merge", "--out"]).arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let o = bin().arg("merge").arg(&a1).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(!out.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_shard_values_and_pipeline_scenarios_are_refused() {
    let dir = temp_dir("shardarg");
    let tiny = write(&dir, "tiny.toml", TINY);
    let out = dir.join("out");
    for (spec, needle) in [
        ("0/4", "K = 0"),
        ("5/4", "K = 5 is larger than N = 4"),
        ("a/b", "expected K/N"),
        ("4/0", "N = 0"),
        ("1/", "expected K/N"),
    ] {
        let o = bin()
            .arg(&tiny)
            .arg(format!("--shard={spec}"))
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{spec}: {err}");
        assert!(err.contains(needle), "{spec}: {err}");
        assert!(!out.exists());
    }
    let pipeline = common::workspace().join("scenarios/pipeline_run.toml");
    let o = bin()
        .arg(&pipeline)
        .args(["--shard", "1/2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("cannot be sharded"), "{err}");
    assert!(!out.exists());
    // More shards than trials: the extra shards are empty, and the merge still works.
    let parts: Vec<PathBuf> = (1..=3).map(|k| dir.join(format!("p{k}"))).collect();
    for (k, p) in parts.iter().enumerate() {
        shard(&tiny, &format!("{}/3", k + 1), p, &[]);
    }
    assert_eq!(read(&parts[2].join("shard-trials.jsonl")), "");
    ok(bin()
        .arg("merge")
        .args(&parts)
        .args(["-q", "--out"])
        .arg(&out)
        .output()
        .unwrap());
    assert_eq!(read(&out.join("trials.csv")).lines().count(), 3);
    let _ = std::fs::remove_dir_all(&dir);
}
