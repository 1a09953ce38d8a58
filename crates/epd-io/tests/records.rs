//! `epd_io::records`: the records read by index are exactly those the full reader gives
//! at those indices (binary PLY little- and big-endian, padding and extra properties,
//! binary PCD), files without fixed-size records are left to the full reader, and a
//! truncated or shrunk file is an error that says so.

use epd_io::read::{PointCloud, read_path};
use epd_io::records::RecordFile;
use std::path::PathBuf;

/// A PLY property: its type name and the bytes of one value.
type Prop = (&'static str, &'static str, fn(f64, bool) -> Vec<u8>);

fn f32b(v: f64, little: bool) -> Vec<u8> {
    let v = v as f32;
    if little {
        v.to_le_bytes()
    } else {
        v.to_be_bytes()
    }
    .to_vec()
}
fn f64b(v: f64, little: bool) -> Vec<u8> {
    if little {
        v.to_le_bytes()
    } else {
        v.to_be_bytes()
    }
    .to_vec()
}
fn u8b(v: f64, _little: bool) -> Vec<u8> {
    vec![v as u8]
}
fn u32b(v: f64, little: bool) -> Vec<u8> {
    let v = v as u32;
    if little {
        v.to_le_bytes()
    } else {
        v.to_be_bytes()
    }
    .to_vec()
}
fn i16b(v: f64, little: bool) -> Vec<u8> {
    let v = v as i16;
    if little {
        v.to_le_bytes()
    } else {
        v.to_be_bytes()
    }
    .to_vec()
}

/// The value of property `p` of point `i`: distinct per point and property, with some
/// invalid points (zeros, NaN) as cameras write them.
fn value(i: usize, p: usize) -> f64 {
    if i % 17 == 5 {
        return 0.0;
    }
    if i % 29 == 3 && p < 3 {
        return f64::NAN;
    }
    ((i * 7 + p * 13) % 251) as f64 + 0.25 * p as f64
}

/// A binary PLY of `n` points with `props` (x, y, z among them).
fn ply(n: usize, props: &[Prop], little: bool) -> Vec<u8> {
    let mut h = format!(
        "ply\nformat binary_{}_endian 1.0\ncomment made by the records test\nelement vertex {n}\n",
        if little { "little" } else { "big" }
    );
    for (ty, name, _) in props {
        h += &format!("property {ty} {name}\n");
    }
    h += "end_header\n";
    let mut b = h.into_bytes();
    for i in 0..n {
        for (p, (_, _, enc)) in props.iter().enumerate() {
            b.extend(enc(value(i, p), little));
        }
    }
    b
}

struct Dir(tempfile::TempDir);

impl Dir {
    fn new() -> Self {
        Dir(tempfile::tempdir().expect("temp dir"))
    }
    fn file(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.0.path().join(name);
        std::fs::write(&p, bytes).expect("write");
        p
    }
}

/// Bitwise equality of values (NaN equal to NaN).
fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits()
}

/// The records `idx` read by index equal the full read's at those indices, property by
/// property, and `points` gives the same x, y, z as `cloud`.
fn check_against_full(path: &std::path::Path, idx: &[u32]) {
    let full: PointCloud = read_path(path).expect("full read");
    let rec = RecordFile::open(path)
        .expect("open")
        .expect("fixed-size records");
    assert_eq!(rec.len(), full.points.len());
    let part = rec.cloud(idx).expect("records");
    let pts = rec.points(idx).expect("points");
    assert_eq!(part.points.len(), idx.len());
    for (k, &i) in idx.iter().enumerate() {
        let (a, b) = (part.points[k], full.points[i as usize]);
        assert!(
            (0..3).all(|c| same(a[c], b[c]) && same(pts[k][c], b[c])),
            "point {i}: {a:?} against {b:?}"
        );
    }
    let names: Vec<&str> = full.extra.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(rec.extra_names(), names);
    for ((na, va), (nb, vb)) in part.extra.iter().zip(&full.extra) {
        assert_eq!(na, nb);
        for (k, &i) in idx.iter().enumerate() {
            assert!(same(va[k], vb[i as usize]), "{na} of point {i}");
        }
    }
}

/// Index sets: sparse, dense runs, first and last, a single point, none.
fn index_sets(n: usize) -> Vec<Vec<u32>> {
    let n = n as u32;
    vec![
        (0..n).step_by(97).collect(),
        (0..n).filter(|i| i % 1000 < 40).collect(),
        vec![0, n - 1],
        vec![n / 2],
        vec![],
        (0..n).collect(),
    ]
}

#[test]
fn ply_records_are_those_of_the_full_read() {
    let d = Dir::new();
    let xyz_f32: [Prop; 3] = [
        ("float", "x", f32b),
        ("float", "y", f32b),
        ("float", "z", f32b),
    ];
    let camera: [Prop; 5] = [
        ("float", "x", f32b),
        ("float", "y", f32b),
        ("float", "z", f32b),
        ("uint", "u", u32b),
        ("uint", "v", u32b),
    ];
    // Padding and properties before, between and after x, y, z; mixed types.
    let padded: [Prop; 7] = [
        ("uchar", "flags", u8b),
        ("double", "z", f64b),
        ("short", "pad", i16b),
        ("double", "x", f64b),
        ("float", "intensity", f32b),
        ("double", "y", f64b),
        ("uchar", "confidence", u8b),
    ];
    // More points than one read takes (1 MiB), so runs are split.
    let n = 70_000;
    for (name, props) in [
        ("xyz", &xyz_f32[..]),
        ("camera", &camera[..]),
        ("padded", &padded[..]),
    ] {
        for little in [true, false] {
            let path = d.file(&format!("{name}_{little}.ply"), &ply(n, props, little));
            for idx in index_sets(n) {
                check_against_full(&path, &idx);
            }
        }
    }
}

#[test]
fn pcd_binary_records_are_those_of_the_full_read() {
    let d = Dir::new();
    let n = 5000;
    let mut b = format!(
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x _ y z intensity\nSIZE 4 4 4 4 2\nTYPE F U F F U\n\
         COUNT 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    .into_bytes();
    for i in 0..n {
        b.extend((value(i, 0) as f32).to_le_bytes());
        b.extend([0xAB; 4]);
        b.extend((value(i, 1) as f32).to_le_bytes());
        b.extend((value(i, 2) as f32).to_le_bytes());
        b.extend((value(i, 3) as u16).to_le_bytes());
    }
    let path = d.file("cloud.pcd", &b);
    for idx in index_sets(n) {
        check_against_full(&path, &idx);
    }
}

/// Files without fixed-size records at a known place are left to the full reader.
#[test]
fn other_files_are_read_whole() {
    let d = Dir::new();
    let ascii = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
        property float z\nend_header\n1 2 3\n4 5 6\n";
    let face_first = b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty uchar n\n\
        element vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n\
        \x01\x00\x00\x80\x3f\x00\x00\x80\x3f\x00\x00\x80\x3f";
    let pcd_ascii = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\n\
        HEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n";
    for (name, bytes) in [
        ("ascii.ply", &ascii[..]),
        ("face.ply", &face_first[..]),
        ("a.pcd", &pcd_ascii[..]),
        ("a.csv", &b"x,y,z\n1,2,3\n"[..]),
        (
            "bad.ply",
            &b"ply\nformat binary_little_endian 1.0\nend_header\n"[..],
        ),
    ] {
        let p = d.file(name, bytes);
        assert!(RecordFile::open(&p).expect("open").is_none(), "{name}");
    }
}

/// A file shorter than its header's records: an error naming the records and saying
/// truncated, as the full reader's; one that shrinks after it was opened: an error when
/// the records read reach beyond its end. Never a panic.
#[test]
fn a_truncated_file_is_an_error() {
    let d = Dir::new();
    let props: [Prop; 3] = [
        ("float", "x", f32b),
        ("float", "y", f32b),
        ("float", "z", f32b),
    ];
    let whole = ply(1000, &props, true);
    let cut = d.file("cut.ply", &whole[..whole.len() - 5]);
    let e = RecordFile::open(&cut).expect_err("too short");
    assert!(
        e.contains("1000 records of 12 bytes") && e.contains("truncated"),
        "{e}"
    );
    assert!(read_path(&cut).expect_err("full").contains("truncated"));

    let path = d.file("shrinks.ply", &whole);
    let rec = RecordFile::open(&path).expect("open").expect("records");
    std::fs::write(&path, &whole[..whole.len() / 2]).expect("shrink");
    assert!(rec.points(&[1, 2]).is_ok(), "the first half is still there");
    let e = rec.points(&[10, 999]).expect_err("beyond the end");
    assert!(e.contains("truncated") && e.contains("shrank"), "{e}");

    // Indices out of order or beyond the records: an error, not a panic.
    let rec = RecordFile::open(&d.file("ok.ply", &whole))
        .expect("open")
        .expect("records");
    assert!(rec.points(&[5, 5]).expect_err("repeat").contains("ascend"));
    assert!(rec.cloud(&[3, 1]).expect_err("order").contains("ascend"));
    assert!(
        rec.points(&[1000])
            .expect_err("beyond")
            .contains("1000 records")
    );
}

/// A header longer than the first piece read (comments of 20 KiB): still found.
#[test]
fn a_long_header_is_read_in_pieces() {
    let d = Dir::new();
    let props: [Prop; 3] = [
        ("float", "x", f32b),
        ("float", "y", f32b),
        ("float", "z", f32b),
    ];
    let body = ply(300, &props, true);
    let comments = "comment a long header line of forty bytes\n".repeat(500);
    let at = body
        .windows(8)
        .position(|w| w == b"element ")
        .expect("element line");
    let bytes = [&body[..at], comments.as_bytes(), &body[at..]].concat();
    let path = d.file("long.ply", &bytes);
    check_against_full(&path, &[0, 7, 299]);
}
