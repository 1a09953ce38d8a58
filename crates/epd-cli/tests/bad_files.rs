//! Crafted bad inputs, one test each: every reader returns within a second, within a
//! bounded amount of memory, and with an error that names the problem (the caller adds the
//! file name).

mod common;
mod peak_alloc;

use epd_cli::read::{Format, PointCloud, read_bytes, read_path};
use std::path::{Path, PathBuf};
use std::time::Duration;

#[global_allocator]
static ALLOC: peak_alloc::PeakAlloc = peak_alloc::PeakAlloc;

/// A temporary directory removed when dropped.
struct Dir(PathBuf);

impl Dir {
    fn new(tag: &str) -> Self {
        Dir(common::temp_dir(tag))
    }

    fn file(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.0.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }
}

impl Drop for Dir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The most a reader may take for these small inputs.
const MEMORY_LIMIT: usize = 64 << 20;

fn check_cost(what: &str, cost: &peak_alloc::Cost) {
    assert!(
        cost.time < Duration::from_secs(2),
        "{what}: took {:?}",
        cost.time
    );
    assert!(
        cost.peak_bytes < MEMORY_LIMIT,
        "{what}: took {} bytes of memory",
        cost.peak_bytes
    );
}

/// `read_path` on `path`, on its own thread with a time limit, its cost checked.
fn path_result(path: &Path) -> Result<PointCloud, String> {
    let p = path.to_path_buf();
    let (r, cost) = peak_alloc::bounded(Duration::from_secs(10), move || read_path(&p));
    check_cost(&path.display().to_string(), &cost);
    r
}

/// `read_bytes` likewise.
fn bytes_result(format: Format, bytes: &[u8]) -> Result<PointCloud, String> {
    let b = bytes.to_vec();
    let (r, cost) = peak_alloc::bounded(Duration::from_secs(10), move || {
        read_bytes(format, &b).map_err(|e| e.to_string())
    });
    check_cost(&format!("{format:?} bytes"), &cost);
    r
}

/// The file `name` holding `bytes` read through `read_path` (and, when `format` is given,
/// the bytes through `read_bytes`) fails with an error containing every one of `words`.
fn expect_error(name: &str, bytes: &[u8], format: Option<Format>, words: &[&str]) {
    let dir = Dir::new("bad");
    let path = dir.file(name, bytes);
    let mut results = vec![("read_path", path_result(&path))];
    if let Some(f) = format {
        results.push(("read_bytes", bytes_result(f, bytes)));
    }
    for (how, r) in results {
        match r {
            Ok(c) => panic!(
                "{name} ({how}): read {} points, expected an error",
                c.points.len()
            ),
            Err(e) => {
                for w in words {
                    assert!(e.contains(w), "{name} ({how}): `{e}` lacks `{w}`");
                }
            }
        }
    }
}

fn expect_points(name: &str, bytes: &[u8], points: &[[f64; 3]]) -> PointCloud {
    let dir = Dir::new("good");
    let path = dir.file(name, bytes);
    let c = path_result(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(c.points, points, "{name}");
    c
}

const PLY_XYZ_F32: &str = "property float x\nproperty float y\nproperty float z\n";

fn ply_binary(count: &str, body_len: usize) -> Vec<u8> {
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {count}\n{PLY_XYZ_F32}end_header\n"
    )
    .into_bytes();
    b.extend(std::iter::repeat_n(0u8, body_len));
    b
}

// ---------------------------------------------------------------- PLY counts

#[test]
fn ply_vertex_count_1e12_with_a_36_byte_body() {
    expect_error(
        "count.ply",
        &ply_binary("1000000000000", 36),
        Some(Format::Ply),
        &["1000000000000", "too short"],
    );
}

#[test]
fn ply_vertex_count_2_pow_63() {
    expect_error(
        "count.ply",
        &ply_binary("9223372036854775808", 36),
        Some(Format::Ply),
        &["9223372036854775808", "too short"],
    );
}

#[test]
fn ply_vertex_count_2_pow_64_does_not_parse() {
    expect_error(
        "count.ply",
        &ply_binary("18446744073709551616", 36),
        Some(Format::Ply),
        &["element count", "18446744073709551616"],
    );
}

#[test]
fn ply_vertex_count_negative() {
    expect_error(
        "count.ply",
        &ply_binary("-1", 36),
        Some(Format::Ply),
        &["element count", "-1"],
    );
}

#[test]
fn ply_ascii_vertex_count_beyond_the_lines() {
    let b = format!(
        "ply\nformat ascii 1.0\nelement vertex 1000000000000\n{PLY_XYZ_F32}end_header\n1 2 3\n4 5 6\n"
    );
    expect_error(
        "count.ply",
        b.as_bytes(),
        Some(Format::Ply),
        &["1000000000000", "too short"],
    );
}

#[test]
fn ply_element_without_properties_and_a_count_of_2_pow_63_is_skipped() {
    for (enc, body) in [
        ("ascii", b"1 2 3\n4 5 6\n".to_vec()),
        (
            "binary_little_endian",
            [1f32, 2., 3., 4., 5., 6.]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect(),
        ),
    ] {
        let mut b = format!(
            "ply\nformat {enc} 1.0\nelement marker 9223372036854775808\nelement vertex 2\n{PLY_XYZ_F32}end_header\n"
        )
        .into_bytes();
        b.extend(&body);
        expect_points("empty.ply", &b, &[[1., 2., 3.], [4., 5., 6.]]);
        let c = bytes_result(Format::Ply, &b).unwrap();
        assert_eq!(c.points.len(), 2);
    }
}

#[test]
fn ply_element_before_the_vertices_with_a_huge_count() {
    let b = format!(
        "ply\nformat binary_little_endian 1.0\nelement face 4611686018427387904\nproperty list uchar int vertex_indices\nelement vertex 1\n{PLY_XYZ_F32}end_header\n\x03"
    );
    expect_error(
        "face.ply",
        b.as_bytes(),
        Some(Format::Ply),
        &["face", "4611686018427387904", "too short"],
    );
}

#[test]
fn ply_list_length_beyond_the_file() {
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uint int vertex_indices\nelement vertex 1\n{PLY_XYZ_F32}end_header\n"
    )
    .into_bytes();
    b.extend(u32::MAX.to_le_bytes());
    b.extend([0u8; 12]);
    expect_error(
        "list.ply",
        &b,
        Some(Format::Ply),
        &["list length", "4294967295"],
    );
}

// ---------------------------------------------------------------- PCD counts and sizes

fn pcd(count: &str, points: usize, data: &str, body: &[u8]) -> Vec<u8> {
    let mut b = format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT {count}\nWIDTH {points}\nHEIGHT 1\nPOINTS {points}\nDATA {data}\n"
    )
    .into_bytes();
    b.extend(body);
    b
}

#[test]
fn pcd_count_overflow_binary() {
    expect_error(
        "count.pcd",
        &pcd("1 1 4611686018427387904", 1, "binary", &[0; 12]),
        Some(Format::Pcd),
        &["COUNT", "too large"],
    );
}

#[test]
fn pcd_count_overflow_binary_compressed() {
    let mut body = 12u32.to_le_bytes().to_vec();
    body.extend(12u32.to_le_bytes());
    body.push(11);
    body.extend([0u8; 12]);
    expect_error(
        "count.pcd",
        &pcd("1 1 4611686018427387904", 1, "binary_compressed", &body),
        Some(Format::Pcd),
        &["COUNT", "too large"],
    );
}

#[test]
fn pcd_count_overflow_ascii() {
    for count in [
        "1 9223372036854775808 1",
        "1 9223372036854775808 9223372036854775808",
        "18446744073709551615 18446744073709551615 18446744073709551615",
    ] {
        expect_error(
            "count.pcd",
            &pcd(count, 1, "ascii", b"1 2 3\n"),
            Some(Format::Pcd),
            &["COUNT", "too large"],
        );
    }
}

#[test]
fn pcd_points_beyond_the_data() {
    expect_error(
        "points.pcd",
        &pcd("1 1 1", 1 << 40, "binary", &[0; 12]),
        Some(Format::Pcd),
        &["1099511627776 points", "truncated"],
    );
}

/// A 201-byte binary_compressed file whose header says it decompresses to 1 GiB.
#[test]
fn pcd_compressed_size_bomb() {
    let n = (1usize << 30) / 12;
    let header_len = pcd("1 1 1", n, "binary_compressed", &[]).len();
    let csize = 201 - header_len - 8;
    let mut body = (csize as u32).to_le_bytes().to_vec();
    body.extend(((n * 12) as u32).to_le_bytes());
    // Literal runs of 32 zero bytes.
    while body.len() < 8 + csize {
        body.push(31);
        body.extend([0u8; 32]);
    }
    body.truncate(8 + csize);
    let b = pcd("1 1 1", n, "binary_compressed", &body);
    assert_eq!(b.len(), 201);
    expect_error(
        "bomb.pcd",
        &b,
        Some(Format::Pcd),
        &["binary_compressed", "1073741820"],
    );
}

// ---------------------------------------------------------------- files that are not files

#[test]
fn dev_zero() {
    if !Path::new("/dev/zero").exists() {
        return;
    }
    let e = path_result(Path::new("/dev/zero")).unwrap_err();
    assert!(e.contains("not a regular file"), "{e}");
    assert!(e.contains("device"), "{e}");
}

#[cfg(unix)]
#[test]
fn dev_zero_through_a_ply_symlink() {
    if !Path::new("/dev/zero").exists() {
        return;
    }
    let dir = Dir::new("zero");
    for name in ["zero.ply", "zero.csv", "zero"] {
        let link = dir.0.join(name);
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        let e = path_result(&link).unwrap_err();
        assert!(e.contains("not a regular file"), "{name}: {e}");
    }
}

#[test]
fn fifo() {
    let dir = Dir::new("fifo");
    let path = dir.0.join("pipe.ply");
    match std::process::Command::new("mkfifo").arg(&path).status() {
        Ok(s) if s.success() => {}
        _ => {
            eprintln!("mkfifo unavailable: skipped");
            return;
        }
    }
    let e = path_result(&path).unwrap_err();
    assert!(
        e.contains("not a regular file") && e.contains("FIFO"),
        "{e}"
    );
}

#[test]
fn directory() {
    let dir = Dir::new("dir");
    let sub = dir.0.join("cloud.ply");
    std::fs::create_dir(&sub).unwrap();
    let e = path_result(&sub).unwrap_err();
    assert!(
        e.contains("not a regular file") && e.contains("directory"),
        "{e}"
    );
}
