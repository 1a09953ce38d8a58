//! The readers on random and mutated bytes, in memory and through real files of every
//! extension: an error or a cloud, never a panic, within a time and memory bound.
//!
//! Mutations of valid PLY (binary, ASCII, big-endian with faces), PCD (ascii, binary,
//! binary_compressed with literal runs and with back references), CSV, XYZ and PTS files:
//! flipped, inserted and deleted bytes, truncation, huge or negative numbers spliced into
//! the header's numbers (2^63, 2^64, 4611686018427387904, 1e12, -1…), overwritten
//! binary_compressed size words, duplicated header lines.
//!
//! `EPD_FUZZ_CASES=N` runs N cases per test instead of the defaults (6000 in memory,
//! 4000 through files: about 3 s in all).

mod common;
mod peak_alloc;

use epd_io::ply::{PlyFormat, PlyPrecision, write as write_ply};
use epd_io::read::{Format, PointCloud, read_bytes, read_path};
use proptest::prelude::*;
use std::path::PathBuf;
use std::time::Duration;

#[global_allocator]
static ALLOC: peak_alloc::PeakAlloc = peak_alloc::PeakAlloc;

/// Cases per test: `EPD_FUZZ_CASES`, else `default`.
fn cases(default: u32) -> u32 {
    std::env::var("EPD_FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn config(default: u32) -> ProptestConfig {
    ProptestConfig {
        cases: cases(default),
        max_shrink_time: 60_000,
        ..ProptestConfig::default()
    }
}

/// The time one read may take (a hang fails the case after `HANG`).
const TIME_LIMIT: Duration = Duration::from_secs(2);
const HANG: Duration = Duration::from_secs(20);

/// The memory one read may take for `len` input bytes: a constant (stream buffers) plus
/// what a binary_compressed PCD can legitimately expand to (LZF: ≤ 88×, then ≤ 8 bytes of
/// cloud per byte of 1-byte coordinates).
fn memory_limit(len: usize) -> usize {
    (8 << 20) + 1024 * len
}

/// `f` on its own thread: no panic, within the time and memory limits; whole clouds.
fn check(
    what: &str,
    len: usize,
    f: impl FnOnce() -> Result<PointCloud, String> + Send + 'static,
) -> Result<(), TestCaseError> {
    let (r, cost) = peak_alloc::bounded(HANG, f);
    prop_assert!(cost.time < TIME_LIMIT, "{what}: {:?}", cost.time);
    prop_assert!(
        cost.peak_bytes <= memory_limit(len),
        "{what}: {} bytes of memory for {len} bytes of input",
        cost.peak_bytes
    );
    if let Ok(cloud) = r {
        prop_assert!(
            cloud
                .extra
                .iter()
                .all(|(_, v)| v.len() == cloud.points.len()),
            "{what}: extra properties of another length than the points"
        );
    }
    Ok(())
}

fn check_bytes(format: Format, bytes: Vec<u8>) -> Result<(), TestCaseError> {
    let len = bytes.len();
    check(&format!("{format:?}"), len, move || {
        read_bytes(format, &bytes).map_err(|e| e.to_string())
    })
}

const EXTENSIONS: [&str; 7] = ["ply", "pcd", "csv", "xyz", "pts", "txt", ""];

/// Write `bytes` to a file with extension `EXTENSIONS[ext]` and read it with `read_path`.
fn check_file(bytes: &[u8], ext: usize) -> Result<(), TestCaseError> {
    // One file per test thread and extension, under the target directory (reused by
    // every run, so nothing piles up in the system's temporary directory).
    thread_local! {
        static DIR: PathBuf = {
            let test = std::thread::current().name().unwrap_or("main").replace("::", "-");
            let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("fuzz-{test}"));
            std::fs::create_dir_all(&d).unwrap();
            d
        };
    }
    let name = match EXTENSIONS[ext] {
        "" => "case".to_string(),
        e => format!("case.{e}"),
    };
    let path = DIR.with(|d| d.join(name));
    std::fs::write(&path, bytes).map_err(|e| TestCaseError::fail(e.to_string()))?;
    let p = path.clone();
    check(&path.display().to_string(), bytes.len(), move || {
        read_path(&p)
    })
}

/// PLY ×3, PCD ×4, text ×3.
const SEED_COUNT: usize = 10;

fn seeds() -> &'static [(Format, Vec<u8>)] {
    static SEEDS: std::sync::OnceLock<Vec<(Format, Vec<u8>)>> = std::sync::OnceLock::new();
    SEEDS.get_or_init(make_seeds)
}

/// LZF compression with back references (greedy, for the seeds only).
fn lzf_compress(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut lit: Vec<u8> = Vec::new();
    let flush = |lit: &mut Vec<u8>, out: &mut Vec<u8>| {
        for run in lit.chunks(32) {
            out.push(run.len() as u8 - 1);
            out.extend_from_slice(run);
        }
        lit.clear();
    };
    let mut i = 0;
    while i < data.len() {
        let (mut best_len, mut best_dist) = (0, 0);
        for dist in 1..=i.min(8192) {
            let mut l = 0;
            while l < 264 && i + l < data.len() && data[i + l] == data[i + l - dist] {
                l += 1;
            }
            if l > best_len {
                (best_len, best_dist) = (l, dist);
            }
        }
        if best_len >= 3 {
            flush(&mut lit, &mut out);
            let (len, off) = (best_len - 2, best_dist - 1);
            if len < 7 {
                out.push(((len << 5) | (off >> 8)) as u8);
            } else {
                out.push(((7 << 5) | (off >> 8)) as u8);
                out.push((len - 7) as u8);
            }
            out.push((off & 0xff) as u8);
            i += best_len;
        } else {
            lit.push(data[i]);
            i += 1;
        }
    }
    flush(&mut lit, &mut out);
    out
}

fn make_seeds() -> Vec<(Format, Vec<u8>)> {
    let (points, pixels) = common::wall_points(50);
    let cloud = epd_io::cloud::SensorCloud {
        points: &points,
        pixels: &pixels,
        image_size: [64, 48],
        comments: vec!["an analytic frame".into()],
        properties: vec![epd_io::cloud::Property {
            name: "intensity".into(),
            values: epd_io::cloud::Values::F32((0..50).map(|i| i as f32).collect()),
        }],
    };
    let mut v = Vec::new();
    for (f, p) in [
        (PlyFormat::BinaryLittleEndian, PlyPrecision::F64),
        (PlyFormat::Ascii, PlyPrecision::F32),
    ] {
        let mut b = Vec::new();
        write_ply(&mut b, &cloud, f, p).unwrap();
        v.push((Format::Ply, b));
    }
    // Big-endian with an element before the vertices and one after.
    let mut b = b"ply\r\nformat binary_big_endian 1.0\r\nelement face 2\r\nproperty list uchar int vertex_indices\r\nelement vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nproperty uchar confidence\r\nelement edge 1\r\nproperty int a\r\nend_header\r\n".to_vec();
    let face: Vec<u8> = std::iter::once(3u8)
        .chain([0i32, 1, 2].iter().flat_map(|i| i.to_be_bytes()))
        .collect();
    b.extend(face.repeat(2));
    for p in points.iter().take(3) {
        for c in p {
            b.extend((*c as f32).to_be_bytes());
        }
        b.push(7);
    }
    b.extend(5i32.to_be_bytes());
    v.push((Format::Ply, b));
    for d in ["ascii", "binary", "binary_compressed"] {
        v.push((Format::Pcd, common::pcd(&points, d)));
    }
    // binary_compressed with back references: repeated values compress.
    let n = 40;
    let mut raw = Vec::new();
    for k in 0..3 {
        for i in 0..n {
            raw.extend(((i / 4 + k) as f32).to_le_bytes());
        }
    }
    let comp = lzf_compress(&raw);
    assert_eq!(epd_io::pcd::lzf_decompress(&comp, raw.len()).unwrap(), raw);
    let mut b = format!("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA binary_compressed\n").into_bytes();
    b.extend((comp.len() as u32).to_le_bytes());
    b.extend((raw.len() as u32).to_le_bytes());
    b.extend(comp);
    assert_eq!(read_bytes(Format::Pcd, &b).unwrap().points.len(), n);
    v.push((Format::Pcd, b));
    let mut csv = Vec::new();
    epd_io::csv::write_points(&mut csv, &points).unwrap();
    v.push((Format::Text, csv));
    v.push((Format::Text, common::xyz(&points)));
    let mut pts = format!("{}\n", points.len());
    for (i, p) in points.iter().enumerate() {
        pts.push_str(&format!(
            "{} {} {} {} 255 {} 0\n",
            p[0],
            p[1],
            p[2],
            -1000 + i as i32,
            i % 256
        ));
    }
    v.push((Format::Text, pts.into_bytes()));
    for (f, b) in &v {
        read_bytes(*f, b).unwrap();
    }
    assert_eq!(v.len(), SEED_COUNT);
    v
}

/// Numbers spliced into header fields.
const HUGE: [&str; 12] = [
    "9223372036854775808",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "4611686018427387904",
    "1000000000000",
    "1e12",
    "-1",
    "0",
    "4294967295",
    "2147483648",
    "3",
];

/// Words written over binary_compressed size fields.
const WORDS: [u32; 6] = [0, 1, u32::MAX, 1 << 30, 12, 0x7fff_ffff];

/// The length of the header: up to the end of the `end_header` or `DATA` line (PLY, PCD),
/// else the first line.
fn header_len(b: &[u8]) -> usize {
    let find = |pat: &[u8]| {
        b.windows(pat.len())
            .position(|w| w == pat)
            .map(|i| i + pat.len())
    };
    let line_end = |from: usize| {
        b[from..]
            .iter()
            .position(|&c| c == b'\n')
            .map_or(b.len(), |i| from + i + 1)
    };
    match find(b"end_header").or_else(|| find(b"\nDATA")) {
        Some(i) => line_end(i),
        None => line_end(0),
    }
}

/// Apply one edit: `kind` chooses it, `idx` where, `byte` what.
fn edit(b: &mut Vec<u8>, kind: u8, idx: prop::sample::Index, byte: u8) {
    if b.is_empty() {
        b.push(byte);
        return;
    }
    let i = idx.index(b.len());
    match kind {
        0 => b[i] ^= byte.max(1),
        1 => b.truncate(i),
        2 => b.insert(i, byte),
        3 => {
            // A huge number over one of the header's numbers.
            let h = header_len(b);
            let mut runs = Vec::new();
            let mut k = 0;
            while k < h {
                if b[k].is_ascii_digit() {
                    let s = k;
                    while k < h && b[k].is_ascii_digit() {
                        k += 1;
                    }
                    runs.push((s, k));
                }
                k += 1;
            }
            if !runs.is_empty() {
                let (s, e) = runs[idx.index(runs.len())];
                let n = HUGE[byte as usize % HUGE.len()].as_bytes();
                b.splice(s..e, n.iter().copied());
            }
        }
        4 => {
            // A 32-bit word over a binary_compressed size (or anywhere after the header).
            let h = header_len(b);
            let at = if byte & 1 == 0 { h } else { h + 4 };
            let at = if byte & 2 == 0 { at } else { i };
            let w = WORDS[(byte as usize >> 2) % WORDS.len()].to_le_bytes();
            for (k, c) in w.iter().enumerate() {
                if let Some(x) = b.get_mut(at + k) {
                    *x = *c;
                }
            }
        }
        _ => {
            // A header line twice (e.g. `property float x`).
            let h = header_len(b);
            let starts: Vec<usize> = std::iter::once(0)
                .chain((0..h).filter(|&k| b[k] == b'\n').map(|k| k + 1))
                .filter(|&k| k < h)
                .collect();
            let s = starts[idx.index(starts.len())];
            let e = b[s..h]
                .iter()
                .position(|&c| c == b'\n')
                .map_or(h, |p| s + p + 1);
            let line = b[s..e].to_vec();
            b.splice(s..s, line);
        }
    }
}

/// Prefixes that steer random bytes into each reader and the format detection.
const PREFIXES: [&[u8]; 10] = [
    b"",
    b"ply\nformat binary_little_endian 1.0\nelement vertex 20\nproperty double x\nproperty double y\nproperty double z\nend_header\n",
    b"ply\nformat ascii 1.0\nelement vertex 9223372036854775808\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 20\nHEIGHT 1\nPOINTS 20\nDATA binary_compressed\n",
    b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 20\nHEIGHT 1\nPOINTS 20\nDATA binary\n",
    b"x y z\n",
    b"\xef\xbb\xbf",
    b"3\n",
    b"LASF",
    b"\xff\xfe",
];

proptest! {
    #![proptest_config(config(6000))]

    #[test]
    fn random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..600), f in 0usize..3) {
        let format = [Format::Ply, Format::Pcd, Format::Text][f];
        check_bytes(format, bytes.clone())?;
        // Random bytes behind a valid-looking header too.
        let mut b = PREFIXES[[1, 3, 5][f]].to_vec();
        b.extend(&bytes);
        check_bytes(format, b)?;
    }

    #[test]
    fn mutated_bytes(
        which in 0usize..SEED_COUNT,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..6), 1..8),
    ) {
        let (format, mut b) = seeds()[which].clone();
        for (idx, byte, kind) in edits {
            edit(&mut b, kind, idx, byte);
        }
        check_bytes(format, b)?;
    }
}

proptest! {
    #![proptest_config(config(4000))]

    #[test]
    fn random_files(
        prefix in 0usize..PREFIXES.len(),
        bytes in prop::collection::vec(any::<u8>(), 0..600),
        ext in 0usize..EXTENSIONS.len(),
    ) {
        let mut b = PREFIXES[prefix].to_vec();
        b.extend(bytes);
        check_file(&b, ext)?;
    }

    #[test]
    fn mutated_files(
        which in 0usize..SEED_COUNT,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..6), 1..6),
        ext in 0usize..EXTENSIONS.len(),
    ) {
        let (_, mut b) = seeds()[which].clone();
        for (idx, byte, kind) in edits {
            edit(&mut b, kind, idx, byte);
        }
        check_file(&b, ext)?;
    }
}

/// Every seed reads, whatever its extension, unless the extension contradicts the
/// contents (text named .ply or .pcd).
#[test]
fn seeds_read_through_files_of_every_extension() {
    for (k, (format, b)) in seeds().iter().enumerate() {
        for ext in EXTENSIONS {
            let text_as_binary = *format == Format::Text && (ext == "ply" || ext == "pcd");
            let dir = common::temp_dir("seeds");
            let path = dir.join(format!("seed.{ext}"));
            std::fs::write(&path, b).unwrap();
            let r = read_path(&path);
            let _ = std::fs::remove_dir_all(&dir);
            assert_eq!(r.is_ok(), !text_as_binary, "seed {k} as .{ext}: {r:?}");
        }
    }
}
