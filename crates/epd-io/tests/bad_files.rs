//! Crafted bad inputs, one test each: every reader returns within a second, within a
//! bounded amount of memory, and with an error that names the problem (the caller adds the
//! file name).

mod common;
mod peak_alloc;

use epd_io::read::{Format, PointCloud, read_bytes, read_path};
use std::path::{Path, PathBuf};
use std::time::Duration;

#[global_allocator]
static ALLOC: peak_alloc::PeakAlloc = peak_alloc::PeakAlloc;

/// A temporary directory removed when dropped (`common::TempDir`).
struct Dir(common::TempDir);

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

/// 200 000 properties (issue 27: "header never ends (truncated?)"): the limit is named.
#[test]
fn ply_header_of_200000_properties_names_the_line_limit() {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n".to_vec();
    for k in 0..200_000 {
        b.extend_from_slice(format!("property float p{k}\n").as_bytes());
    }
    b.extend_from_slice(b"end_header\n");
    expect_error(
        "props.ply",
        &b,
        Some(Format::Ply),
        &["more than 10000 lines", "the most the readers accept"],
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

/// An ASCII record per line: a line with a column more or less than the header's
/// properties is an error naming the record (the values had been read as one stream, every
/// record after it shifted, and the fit "settled in a wrong pose"); CR LF line ends and
/// blank lines between records are fine. A second `format` line is an error.
#[test]
fn ply_ascii_lines_must_hold_one_record() {
    let head = format!("ply\nformat ascii 1.0\nelement vertex 2\n{PLY_XYZ_F32}end_header\n");
    for (body, says) in [
        ("1 2 3 9\n4 5 6 9\n", "more values"),
        ("1 2\n3 4 5\n6\n", "its line ends before"),
    ] {
        expect_error(
            "lines.ply",
            format!("{head}{body}").as_bytes(),
            Some(Format::Ply),
            &["`vertex` record 1", says],
        );
    }
    expect_error(
        "format.ply",
        format!("ply\nformat ascii 1.0\nformat binary_little_endian 1.0\nelement vertex 2\n{PLY_XYZ_F32}end_header\n1 2 3\n4 5 6\n").as_bytes(),
        Some(Format::Ply),
        &["header line 3", "a second `format` line"],
    );
    expect_points(
        "crlf.ply",
        format!("{head}1 2 3\r\n\r\n4 5 6 \r\n").as_bytes(),
        &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
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

/// POINTS must be WIDTH × HEIGHT (PCL's rule): a file where they disagree is refused
/// rather than read by one of them without a word.
/// A header key given twice is an error naming both lines (a second FIELDS or POINTS
/// had replaced the first); a key in lower case is named as such.
#[test]
fn pcd_header_keys_once_and_in_upper_case() {
    let head =
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\n";
    for (text, says) in [
        (
            format!("{head}FIELDS a b c\nPOINTS 1\nDATA ascii\n1 2 3\n"),
            "`FIELDS` again (first on header line 2)",
        ),
        (
            format!("{head}POINTS 1\nPOINTS 5\nDATA ascii\n1 2 3\n"),
            "`POINTS` again",
        ),
        (format!("{head}POINTS 1\ndata ascii\n1 2 3\n"), "upper case"),
    ] {
        expect_error("keys.pcd", text.as_bytes(), Some(Format::Pcd), &[says]);
    }
}

#[test]
fn pcd_points_that_are_not_width_times_height() {
    let b = with_width(&pcd("1 1 1", 2, "binary", &[0; 24]), 3);
    expect_error(
        "points.pcd",
        &b,
        Some(Format::Pcd),
        &["POINTS 2", "WIDTH × HEIGHT = 3 × 1"],
    );
}

/// The same PCD file with its WIDTH line set to `w`.
fn with_width(b: &[u8], w: usize) -> Vec<u8> {
    let text = String::from_utf8_lossy(b);
    let i = text.find("WIDTH ").expect("a WIDTH line");
    let j = i + text[i..].find('\n').expect("its end");
    let mut out = b[..i].to_vec();
    out.extend(format!("WIDTH {w}").bytes());
    out.extend(&b[j..]);
    out
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

/// A stream of zeros (`epd estimate - < /dev/zero`) is refused as not text from its first
/// bytes, within the readers' time and memory bounds (it had been read to the 4 GiB cap).
#[test]
fn a_stream_of_zeros_is_not_text_from_its_first_bytes() {
    let (r, cost) = peak_alloc::bounded(Duration::from_secs(10), || {
        epd_io::read::read_from(std::io::repeat(0), None, epd_io::read::MAX_INPUT_BYTES)
            .map(|c| c.points.len())
    });
    check_cost("zeros", &cost);
    let e = r.unwrap_err();
    assert!(e.contains("not text: byte 0x00 at offset 0"), "{e}");
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

/// A file larger than the cap is refused from its size, before anything is read (a
/// sparse file: no disk space taken).
#[test]
fn file_larger_than_the_cap() {
    let dir = Dir::new("big");
    let path = dir.0.join("big.ply");
    let f = std::fs::File::create(&path).unwrap();
    if f.set_len(epd_io::read::MAX_INPUT_BYTES + 1).is_err() {
        eprintln!("no sparse files here: skipped");
        return;
    }
    drop(f);
    let e = path_result(&path).unwrap_err();
    assert!(e.contains("4294967297 bytes") && e.contains("4 GiB"), "{e}");
}

// ---------------------------------------------------------------- standard input

#[test]
fn endless_stream_stops_at_the_cap() {
    let (r, cost) = peak_alloc::bounded(Duration::from_secs(10), || {
        epd_io::read::read_from(std::io::repeat(b'1'), None, 1 << 20)
    });
    check_cost("endless stream", &cost);
    let e = r.unwrap_err();
    assert!(e.contains("longer than 1 MiB"), "{e}");
}

#[test]
fn stream_with_a_huge_ply_count() {
    for (count, cap) in [("1000000000000", 1u64 << 32), ("100000000", 1 << 32)] {
        let b = ply_binary(count, 36);
        let (r, cost) = peak_alloc::bounded(Duration::from_secs(10), move || {
            epd_io::read::read_from(&b[..], None, cap)
        });
        check_cost("stream", &cost);
        let e = r.unwrap_err();
        assert!(e.contains(count) && e.contains("too short"), "{e}");
    }
}

#[test]
fn stream_formats_by_first_bytes_or_hint() {
    let read = |b: &[u8], hint| epd_io::read::read_from(b, hint, 1 << 20);
    let ply = format!("ply\nformat ascii 1.0\nelement vertex 1\n{PLY_XYZ_F32}end_header\n1 2 3\n");
    assert_eq!(read(ply.as_bytes(), None).unwrap().points, [[1., 2., 3.]]);
    assert_eq!(read(b"1,2,3\n", None).unwrap().points, [[1., 2., 3.]]);
    assert_eq!(
        read(b"1,2,3\n", Some(Format::Text)).unwrap().points,
        [[1., 2., 3.]]
    );
    let e = read(b"1,2,3\n", Some(Format::Pcd)).unwrap_err();
    assert!(e.starts_with("PCD:"), "{e}");
    let e = read(b"LASF\x00\x01", Some(Format::Ply)).unwrap_err();
    assert!(e.contains("unsupported format: LAS"), "{e}");
}

// ---------------------------------------------------------------- byte-order marks

const BOM: &[u8] = b"\xef\xbb\xbf";

fn with_bom(b: &[u8]) -> Vec<u8> {
    [BOM, b].concat()
}

#[test]
fn utf8_bom_before_csv() {
    // Without a header: the first row must not be taken for one.
    expect_points(
        "bom.csv",
        &with_bom(b"1,2,3\n4,5,6\n"),
        &[[1., 2., 3.], [4., 5., 6.]],
    );
    let c = expect_points(
        "bom.csv",
        &with_bom(b"\"X\",\"Y\",\"Z\",\"Intensity\"\n1,2,3,9\n"),
        &[[1., 2., 3.]],
    );
    assert_eq!(c.extra, [("intensity".to_string(), vec![9.0])]);
}

#[test]
fn utf8_bom_before_ply() {
    let b = format!("ply\nformat ascii 1.0\nelement vertex 1\n{PLY_XYZ_F32}end_header\n1 2 3\n");
    // Any extension: the header is recognised after the mark.
    for name in ["bom.ply", "bom.txt", "bom"] {
        expect_points(name, &with_bom(b.as_bytes()), &[[1., 2., 3.]]);
    }
    let mut bin = with_bom(&ply_binary("1", 0));
    bin.extend([1f32, 2., 3.].iter().flat_map(|v| v.to_le_bytes()));
    expect_points("bom_bin.ply", &bin, &[[1., 2., 3.]]);
}

#[test]
fn utf8_bom_before_pcd() {
    let b = with_bom(&pcd("1 1 1", 1, "ascii", b"1 2 3\n"));
    for name in ["bom.pcd", "bom"] {
        expect_points(name, &b, &[[1., 2., 3.]]);
    }
}

#[test]
fn utf16_text() {
    let b: Vec<u8> = "\u{feff}x;y;z\r\n1;2;3\r\n"
        .encode_utf16()
        .flat_map(|u| u.to_le_bytes())
        .collect();
    expect_points("utf16.csv", &b, &[[1., 2., 3.]]);
}

// ---------------------------------------------------------------- PTS and ASC

#[test]
fn pts_count_line() {
    expect_points(
        "scan.pts",
        b"3\n1 2 3\n4 5 6\n7 8 9\n",
        &[[1., 2., 3.], [4., 5., 6.], [7., 8., 9.]],
    );
    // CloudCompare ASC: the count, then its header comment.
    expect_points(
        "scan.asc",
        b"2\n//X Y Z\n1 2 3\n4 5 6\n",
        &[[1., 2., 3.], [4., 5., 6.]],
    );
}

#[test]
fn pts_seven_columns() {
    let c = expect_points(
        "scan.pts",
        b"2\n1.5 2 3 -1200 255 0 0\n4 5 6 -800 0 255 0\n",
        &[[1.5, 2., 3.], [4., 5., 6.]],
    );
    let names: Vec<&str> = c.extra.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["intensity", "r", "g", "b"]);
    assert_eq!(c.extra[0].1, [-1200.0, -800.0]);
}

#[test]
fn pts_two_scans() {
    expect_points(
        "two.pts",
        b"1\n1 2 3 5\n2\n4 5 6 5\n7 8 9 5\n",
        &[[1., 2., 3.], [4., 5., 6.], [7., 8., 9.]],
    );
}

// ---------------------------------------------------------------- duplicated properties

#[test]
fn ply_duplicated_property() {
    let b = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float x\nproperty float z\nend_header\n1 2 3 4\n";
    expect_error(
        "dup.ply",
        b.as_bytes(),
        Some(Format::Ply),
        &["`x`", "twice"],
    );
}

#[test]
fn pcd_duplicated_field() {
    let b = b"VERSION 0.7\nFIELDS x y z y\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nPOINTS 1\nDATA ascii\n1 2 3 4\n";
    expect_error("dup.pcd", b, Some(Format::Pcd), &["`y`", "twice"]);
    // PCL's padding fields `_` may repeat.
    let b = b"VERSION 0.7\nFIELDS x _ y z _\nSIZE 4 4 4 4 4\nTYPE F F F F F\nCOUNT 1 1 1 1 1\nPOINTS 1\nDATA ascii\n1 0 2 3 0\n";
    let c = expect_points("pad.pcd", b, &[[1., 2., 3.]]);
    assert!(c.extra.is_empty());
}

#[test]
fn csv_duplicated_column() {
    expect_error(
        "dup.csv",
        b"x,y,z,X\n1,2,3,4\n",
        Some(Format::Text),
        &["`x`", "twice"],
    );
}

// ---------------------------------------------------------------- formats not read

#[test]
fn las_magic() {
    let mut b = b"LASF".to_vec();
    b.extend([0u8; 300]);
    for name in ["cloud.las", "cloud.csv", "cloud.ply", "cloud"] {
        expect_error(
            name,
            &b,
            None,
            &[
                "unsupported format: LAS (convert to PLY, PCD or CSV, e.g. with PDAL or CloudCompare)",
            ],
        );
    }
    expect_error("cloud.laz", &b, None, &["unsupported format: LAZ", "PDAL"]);
}

#[test]
fn e57_magic() {
    let mut b = b"ASTM-E57".to_vec();
    b.extend([0u8; 100]);
    expect_error("scan.txt", &b, None, &["unsupported format: E57"]);
}

#[test]
fn vtk_magic() {
    expect_error(
        "cloud.txt",
        b"# vtk DataFile Version 3.0\nvtk output\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n1 2 3\n",
        None,
        &["unsupported format: VTK"],
    );
    expect_error(
        "cloud.xml",
        b"<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\">\n",
        None,
        &["unsupported format: VTK (XML)"],
    );
}

#[test]
fn compressed_magic() {
    expect_error(
        "cloud.csv",
        b"\x1f\x8b\x08\x00\x00\x00\x00\x00",
        None,
        &["unsupported format: gzip", "decompress"],
    );
    expect_error(
        "cloud.ply",
        b"PK\x03\x04\x14\x00\x00\x00",
        None,
        &["unsupported format: zip"],
    );
}

#[test]
fn unsupported_extensions() {
    for (name, what) in [
        ("mesh.obj", "OBJ"),
        ("mesh.stl", "STL"),
        ("scan.e57", "E57"),
        ("cloud.vtp", "VTK"),
        ("velodyne.bin", "raw binary"),
        ("cloud.npy", "NumPy"),
        ("run.bag", "ROS bag"),
    ] {
        expect_error(name, b"1 2 3\n", None, &["unsupported format", what]);
    }
}

// ---------------------------------------------------------------- binary as text

#[test]
fn binary_garbage_as_csv() {
    let mut b = b"1,2,3\n".to_vec();
    b.extend((0..100_000u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8));
    for name in ["garbage.csv", "garbage.txt", "garbage.xyz", "garbage"] {
        expect_error(
            name,
            &b,
            Some(Format::Text),
            &["not text: byte 0x", "at offset"],
        );
    }
    expect_error(
        "nul.csv",
        b"1,2,3\n4,5\x006\n",
        Some(Format::Text),
        &["not text: byte 0x00 at offset 9"],
    );
    expect_error(
        "latin1.csv",
        b"x,y,z\n1,2,3 \xb5m\n",
        Some(Format::Text),
        &["not text: byte 0xb5 at offset 12 is not UTF-8"],
    );
}

#[test]
fn long_lines_are_quoted_short() {
    let mut b = b"1,2,3\n".to_vec();
    b.extend(std::iter::repeat_n(b'a', 1 << 20));
    let e = bytes_result(Format::Text, &b).unwrap_err();
    assert!(
        e.contains("line 2") && e.len() < 200,
        "{}",
        &e[..e.len().min(300)]
    );
}
