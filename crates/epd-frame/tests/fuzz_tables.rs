//! Depth-table files on random mutations (issue 27): a table or an error, never a panic,
//! an abort or a hang, and a table that reads corrects a frame in bounded time.
//!
//! Seeds: a real table as `epd calibrate` writes it, compact tables, and tables whose
//! bin counts are spliced with huge or negative numbers. Mutations: flipped, inserted and
//! deleted bytes, truncation, numbers spliced in (2⁶³, 2⁶⁴, 1048577, 1e308, -1, NaN…),
//! a byte-order mark.
//!
//! `EPD_FUZZ_CASES=N` runs N cases instead of the default 5000 (about a second);
//! `cargo test --release -p epd-frame --test fuzz_tables -- --ignored` runs 10⁵.

use std::time::{Duration, Instant};

use epd_core::DepthTable;
use epd_core::calibration::{Axis, MAX_TABLE_BINS};
use epd_frame::CalibrationTable;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

/// The time one case may take (read, and a frame's correction when it reads).
const TIME_LIMIT: Duration = Duration::from_secs(3);
/// A case still running after this is a hang.
const HANG: Duration = Duration::from_secs(30);

fn cases(default: u32) -> u32 {
    std::env::var("EPD_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn seeds() -> Vec<String> {
    let (nr, ni) = (30, 12);
    let cells = nr * ni;
    let real = CalibrationTable::plain(
        DepthTable {
            range: Axis::new(0.5, 2.0, nr),
            log_intensity: Axis::new(1.0, 7.0, ni),
            offset_m: (0..cells)
                .map(|k| 0.01 * ((k as f64) * 0.37).sin())
                .collect(),
            spread_m: (0..cells).map(|k| 0.005 + 0.001 * (k % 7) as f64).collect(),
            count: (0..cells as u64).map(|k| 30 + k).collect(),
        },
        (0.5842, 0.5842),
        20,
        2_400_000,
    );
    let small = |nr: &str, ni: &str, rows: usize, cols: usize| {
        let row = |v: &str| format!("[{}]", vec![v; cols].join(","));
        let arr = |v: &str| format!("[{}]", vec![row(v); rows].join(","));
        format!(
            r#"{{"format":"epd-depth-table","version":1,"known_d_max_mm":500,"known_d_min_mm":500,"frames":1,"n_observations":10,"range_m":{{"lo":0.5,"hi":2.0,"bins":{nr}}},"log_intensity":{{"lo":1.0,"hi":7.0,"bins":{ni}}},"empty_bins":"","offset_mm":{},"spread_mm":{},"count":{}}}"#,
            arr("1.5"),
            arr("10"),
            arr("40")
        )
    };
    vec![
        real.to_json(),
        small("3", "2", 3, 2),
        small("1", "200000", 1, 3),
        small("1048576", "1048576", 2, 2),
        small("18446744073709551615", "2", 1, 2),
        small("2", "1", 2, 1),
    ]
}

const SPLICES: &[&str] = &[
    "9223372036854775808",
    "18446744073709551616",
    "1048577",
    "1048576",
    "200000",
    "0",
    "-1",
    "1e308",
    "-1e308",
    "1e-300",
    "NaN",
    "null",
    "[]",
    "[[]]",
    "\"x\"",
    "0.500000001",
];

/// `b` mutated by `kind` at `at` (a fraction of its length) with `byte`.
fn mutate(mut b: Vec<u8>, kind: u8, at: f64, byte: u8) -> Vec<u8> {
    let i = ((b.len() as f64 * at) as usize).min(b.len().saturating_sub(1));
    match kind % 7 {
        0 if !b.is_empty() => b[i] ^= 1 << (byte % 8),
        1 => b.insert(i.min(b.len()), byte),
        2 if !b.is_empty() => {
            b.remove(i);
        }
        3 => b.truncate(i),
        4 => {
            // A number (the next run of digits from i) replaced by a splice.
            let start = (i..b.len())
                .find(|&k| b[k].is_ascii_digit())
                .unwrap_or(b.len());
            let end = (start..b.len())
                .find(|&k| !(b[k].is_ascii_digit() || b[k] == b'.' || b[k] == b'e'))
                .unwrap_or(b.len());
            let s = SPLICES[byte as usize % SPLICES.len()].as_bytes();
            b.splice(start..end, s.iter().copied());
        }
        5 => {
            let mut v = "\u{feff}".as_bytes().to_vec();
            v.extend(b);
            b = v;
        }
        _ => {
            // A `"bins":` value replaced by a splice.
            let key = b"\"bins\":";
            let found: Vec<usize> = b
                .windows(key.len())
                .enumerate()
                .filter(|(_, w)| *w == key)
                .map(|(p, _)| p)
                .collect();
            if let Some(&p) = found.get(byte as usize % 2) {
                let start = p + key.len();
                let end = (start..b.len())
                    .find(|&k| b[k] == b',' || b[k] == b'}')
                    .unwrap_or(b.len());
                let s = SPLICES[(i + byte as usize) % SPLICES.len()].as_bytes();
                b.splice(start..end, s.iter().copied());
            }
        }
    }
    b
}

/// A frame of 2000 points with intensities, on and around the seeds' axes.
fn frame() -> (Vec<[f64; 3]>, Vec<f64>) {
    (0..2000)
        .map(|k| {
            let u = (k as f64 * 0.618_034).fract();
            let r = 0.4 + 1.8 * u;
            (
                [
                    r * 0.8,
                    r * 0.6 * (6.0 * u).cos(),
                    r * 0.6 * (6.0 * u).sin(),
                ],
                (0.5 + 7.0 * u).exp(),
            )
        })
        .unzip()
}

/// Read `bytes` as a table and, when it reads, correct a frame with it: on its own
/// thread, so that a panic, a hang or a slow case fails the test case.
fn one_case(bytes: Vec<u8>) -> Result<(), TestCaseError> {
    let (tx, rx) = std::sync::mpsc::channel();
    let t0 = Instant::now();
    std::thread::spawn(move || {
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let ok = match CalibrationTable::from_json(&text) {
            Err(_) => true,
            Ok(t) => {
                let cells = t.table.range.n * t.table.log_intensity.n;
                let (mut p, i) = frame();
                let _ = t.correct_points(true, &mut p, Some(&i), false);
                let _ = t.correct_points(false, &mut p, Some(&i), false);
                cells <= MAX_TABLE_BINS && t.table.offset_m.len() == cells
            }
        };
        let _ = tx.send(ok);
    });
    match rx.recv_timeout(HANG) {
        Ok(ok) => prop_assert!(ok, "a table beyond the bin limit was read"),
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
            return Err(TestCaseError::fail("a table case hangs"));
        }
        Err(_) => return Err(TestCaseError::fail("a table case panicked")),
    }
    prop_assert!(t0.elapsed() < TIME_LIMIT, "{:?}", t0.elapsed());
    Ok(())
}

fn run(n: u32) {
    let seeds = seeds();
    let mut runner = TestRunner::new(Config {
        cases: n,
        failure_persistence: None,
        ..Config::default()
    });
    let t0 = Instant::now();
    let strategy = (0..seeds.len(), 0u8..7, 0.0..1.0f64, any::<u8>(), 1usize..4);
    runner
        .run(&strategy, |(s, kind, at, byte, times)| {
            let mut bytes = seeds[s].as_bytes().to_vec();
            for k in 0..times {
                let k8 = k as u8;
                bytes = mutate(
                    bytes,
                    kind.wrapping_add(k8.wrapping_mul(3)),
                    (at + k as f64 * 0.37).fract(),
                    byte.wrapping_add(k8),
                );
            }
            one_case(bytes)
        })
        .unwrap();
    eprintln!("{n} mutated tables in {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn mutated_tables_never_panic_abort_or_hang() {
    run(cases(5000));
}

/// The goal's measure: 10⁵ tables (`-- --ignored`).
#[test]
#[ignore]
fn mutated_tables_1e5() {
    run(100_000);
}
