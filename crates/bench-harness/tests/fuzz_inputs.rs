//! Scenario files and shard folders on random mutations (issue 27): an error or a
//! result, never a panic, an abort or a hang; and a shard whose records or scenario were
//! changed is never merged.
//!
//! Scenarios: the committed ones mutated (flipped, inserted, deleted bytes, truncation,
//! numbers spliced in, lines duplicated, sections added), read as the binary reads them
//! (`Kind::of`, then the kind's parser). Shard folders: a real pair of shards with one
//! of `shard.json`, `shard-trials.jsonl` or `scenario.toml` mutated, removed, or
//! replaced by a FIFO, a folder or a link to `/dev/zero`, then merged in-process.
//!
//! `EPD_FUZZ_CASES=N` runs N cases per test instead of the defaults (3000 scenarios, 300
//! shard folders: a few seconds each; a shard case writes a folder of six files);
//! `cargo test -p bench-harness --test fuzz_inputs -- --ignored` runs 10⁵ of each.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use bench_harness::approach::ApproachScenario;
use bench_harness::calibration_transfer::TransferScenario;
use bench_harness::experiment::Kind;
use bench_harness::pipeline::PipelineScenario;
use bench_harness::sweep::merge::{MergeError, MergeOptions, merge};
use bench_harness::sweep::shard::run_shard;
use bench_harness::{RunOptions, Scenario};
use epd_frame::shard::ShardSpec;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

/// The time one case may take.
const TIME_LIMIT: Duration = Duration::from_secs(5);
/// A case still running after this is a hang.
const HANG: Duration = Duration::from_secs(60);

fn cases(default: u32) -> u32 {
    std::env::var("EPD_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

const SPLICES: &[&str] = &[
    "9223372036854775808",
    "18446744073709551616",
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "-1",
    "0",
    "1e-300",
    "90",
    "7",
    "10000001",
    "\"all\"",
    "[]",
    "[1, 2, 3]",
    "{}",
    "\"\"",
    "true",
];

/// `b` mutated by `kind` at `at` (a fraction of its length) with `byte`.
fn mutate(mut b: Vec<u8>, kind: u8, at: f64, byte: u8) -> Vec<u8> {
    let i = ((b.len() as f64 * at) as usize).min(b.len().saturating_sub(1));
    match kind % 8 {
        0 if !b.is_empty() => b[i] ^= 1 << (byte % 8),
        1 => b.insert(i.min(b.len()), byte),
        2 if !b.is_empty() => {
            b.remove(i);
        }
        3 => b.truncate(i),
        4 | 5 => {
            let start = (i..b.len())
                .find(|&k| b[k].is_ascii_digit())
                .unwrap_or(b.len());
            let end = (start..b.len())
                .find(|&k| !(b[k].is_ascii_digit() || b".eE+-".contains(&b[k])))
                .unwrap_or(b.len());
            let s = SPLICES[byte as usize % SPLICES.len()].as_bytes();
            b.splice(start..end, s.iter().copied());
        }
        6 => {
            // A line duplicated.
            let start = b[..i]
                .iter()
                .rposition(|&c| c == b'\n')
                .map_or(0, |p| p + 1);
            let end = b[i..]
                .iter()
                .position(|&c| c == b'\n')
                .map_or(b.len(), |p| i + p + 1);
            let line = b[start..end].to_vec();
            b.splice(end..end, line);
        }
        _ => {
            let sections: &[&[u8]] = &[
                b"\n[sweep]\n",
                b"\n[pipeline]\n",
                b"\n[approach]\n",
                b"\n[poses]\ntilt_deg = 90\n",
            ];
            b.extend_from_slice(sections[byte as usize % sections.len()]);
        }
    }
    b
}

fn apply(seed: &[u8], (kind, at, byte, times): (u8, f64, u8, usize)) -> Vec<u8> {
    let mut b = seed.to_vec();
    for k in 0..times {
        let k8 = k as u8;
        b = mutate(
            b,
            kind.wrapping_add(k8.wrapping_mul(3)),
            (at + k as f64 * 0.37).fract(),
            byte.wrapping_add(k8),
        );
    }
    b
}

/// `f` on its own thread within HANG; its panics and hangs fail the case.
fn bounded<T: Send + 'static>(
    what: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, TestCaseError> {
    let (tx, rx) = std::sync::mpsc::channel();
    let t0 = Instant::now();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    let r = match rx.recv_timeout(HANG) {
        Ok(r) => r,
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
            return Err(TestCaseError::fail(format!("{what}: hangs")));
        }
        Err(_) => return Err(TestCaseError::fail(format!("{what}: panicked"))),
    };
    prop_assert!(t0.elapsed() < TIME_LIMIT, "{what}: {:?}", t0.elapsed());
    Ok(r)
}

fn scenario_seeds() -> Vec<Vec<u8>> {
    let dir = common::workspace().join("scenarios");
    let mut seeds: Vec<Vec<u8>> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    seeds.sort();
    assert!(seeds.len() >= 10);
    seeds
}

fn run_scenarios(n: u32) {
    let seeds = scenario_seeds();
    let mut runner = TestRunner::new(Config {
        cases: n,
        failure_persistence: None,
        ..Config::default()
    });
    let t0 = Instant::now();
    let strategy = (
        0..seeds.len(),
        (0u8..8, 0.0..1.0f64, any::<u8>(), 1usize..4),
    );
    runner
        .run(&strategy, |(s, m)| {
            let bytes = apply(&seeds[s], m);
            bounded("scenario", move || {
                let text = String::from_utf8_lossy(&bytes).into_owned();
                let path = Path::new("fuzz.toml");
                let message = match Kind::of(&text) {
                    Kind::Sweep => Scenario::parse(path, &text).err().map(|e| e.to_string()),
                    Kind::Pipeline => PipelineScenario::parse(path, &text)
                        .err()
                        .map(|e| e.to_string()),
                    Kind::Approach => ApproachScenario::parse(path, &text)
                        .err()
                        .map(|e| e.to_string()),
                    Kind::CalibrationTransfer => TransferScenario::parse(path, &text)
                        .err()
                        .map(|e| e.to_string()),
                };
                message.map_or(0, |m| m.len())
            })
            .and_then(|len| {
                prop_assert!(len < 8192, "a message of {len} bytes");
                Ok(())
            })
        })
        .unwrap();
    eprintln!(
        "{n} mutated scenarios in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
}

#[test]
fn mutated_scenarios_never_panic_or_hang() {
    run_scenarios(cases(3000));
}

/// The goal's measure: 10⁵ scenarios (`-- --ignored`).
#[test]
#[ignore]
fn mutated_scenarios_1e5() {
    run_scenarios(100_000);
}

/// One setting, four trials, one method: a pair of shards made in this process (the merge
/// checks that the shards are its own code).
const TINY: &str = "name = \"fz\"\nseed = 5\ntrials = 4\nmethods = [\"ru-epd\"]\npoints = 400\n";

/// The pair of shards, made once: each file's bytes.
struct Shards {
    files: Vec<(usize, &'static str, Vec<u8>)>,
}

const MERGED_FILES: [&str; 3] = ["shard.json", "shard-trials.jsonl", "scenario.toml"];

fn shards() -> &'static Shards {
    static SHARDS: OnceLock<Shards> = OnceLock::new();
    SHARDS.get_or_init(|| {
        let dir = common::temp_dir("fuzz-shards");
        let scenario = Scenario::parse(Path::new("fz.toml"), TINY).unwrap();
        let mut files = Vec::new();
        for k in 1..=2u64 {
            let out = dir.join(format!("s{k}"));
            let options = RunOptions {
                out: out.clone(),
                trials: None,
                progress: false,
            };
            run_shard(&scenario, &options, ShardSpec::new(k, 2).unwrap()).unwrap();
            for f in MERGED_FILES {
                files.push((k as usize - 1, f, std::fs::read(out.join(f)).unwrap()));
            }
        }
        Shards { files }
    })
}

/// What is done to the file of a case.
#[derive(Clone, Copy, Debug)]
enum Damage {
    /// Its bytes mutated.
    Bytes(u8, f64, u8, usize),
    /// Removed.
    Missing,
    /// A FIFO in its place.
    Fifo,
    /// A folder in its place.
    Folder,
    /// A link to /dev/zero in its place.
    DevZero,
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        8 => (0u8..8, 0.0..1.0f64, any::<u8>(), 1usize..4)
            .prop_map(|(k, a, b, t)| Damage::Bytes(k, a, b, t)),
        1 => Just(Damage::Missing),
        1 => Just(Damage::Fifo),
        1 => Just(Damage::Folder),
        1 => Just(Damage::DevZero),
    ]
}

fn run_shards(n: u32) {
    let s = shards();
    let cases = common::temp_dir("fuzz-shard-cases");
    let mut runner = TestRunner::new(Config {
        cases: n,
        failure_persistence: None,
        ..Config::default()
    });
    // The merge's output goes below a regular file: a merge that passes every check
    // fails at once creating it, so that a case costs no plots.
    let blocker = cases.join("blocker");
    std::fs::write(&blocker, b"").unwrap();
    let t0 = Instant::now();
    let case = std::sync::atomic::AtomicU64::new(0);
    let strategy = (0..s.files.len(), damage());
    runner
        .run(&strategy, |(f, how)| {
            let n = case.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let d = cases.join(format!("case{n}"));
            let parts: Vec<PathBuf> = (0..2).map(|k| d.join(format!("s{}", k + 1))).collect();
            for (k, name, bytes) in &s.files {
                std::fs::create_dir_all(&parts[*k]).unwrap();
                std::fs::write(parts[*k].join(name), bytes).unwrap();
            }
            let (k, name, original) = &s.files[f];
            let path = parts[*k].join(name);
            let changed = match how {
                Damage::Bytes(a, b, c, t) => {
                    let bytes = apply(original, (a, b, c, t));
                    std::fs::write(&path, &bytes).unwrap();
                    bytes != *original
                }
                Damage::Missing => {
                    std::fs::remove_file(&path).unwrap();
                    true
                }
                Damage::Fifo => {
                    std::fs::remove_file(&path).unwrap();
                    let o = std::process::Command::new("mkfifo")
                        .arg(&path)
                        .output()
                        .unwrap();
                    assert!(o.status.success());
                    true
                }
                Damage::Folder => {
                    std::fs::remove_file(&path).unwrap();
                    std::fs::create_dir(&path).unwrap();
                    true
                }
                Damage::DevZero => {
                    std::fs::remove_file(&path).unwrap();
                    std::os::unix::fs::symlink("/dev/zero", &path).unwrap();
                    true
                }
            };
            let out = blocker.join("merged");
            let dirs = parts.clone();
            let r = bounded("merge", move || {
                merge(&dirs, &MergeOptions { out })
                    .map_err(|e| (e.is::<MergeError>(), e.to_string()))
            });
            let _ = std::fs::remove_dir_all(&d);
            let r = r?;
            // A changed records or scenario file is refused as such (a usage error), never
            // merged; a changed manifest may still describe the same shard.
            if changed && *name != "shard.json" {
                match &r {
                    Ok(_) => prop_assert!(false, "{name} changed ({how:?}) and merged"),
                    Err((refusal, e)) => prop_assert!(*refusal, "{name} ({how:?}): {e}"),
                }
            }
            if let Err((_, e)) = &r {
                prop_assert!(e.len() < 8192, "a message of {} bytes", e.len());
            }
            Ok(())
        })
        .unwrap();
    eprintln!(
        "{n} damaged shard folders in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
}

#[cfg(unix)]
#[test]
fn damaged_shard_folders_never_panic_hang_or_merge() {
    run_shards(cases(300));
}

/// The goal's measure: 10⁵ shard folders (`-- --ignored`).
#[cfg(unix)]
#[test]
#[ignore]
fn damaged_shard_folders_1e5() {
    run_shards(100_000);
}
