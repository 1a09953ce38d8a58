//! Round trips: simulated noise-free frames written as PLY (binary and ASCII, double and
//! float), PCD (ascii, binary, binary_compressed), CSV and XYZ, read back and estimated:
//! the truth is recovered to 1e-6 (float32 files: to float32 precision), and every
//! double-precision format gives the same estimate.

#[path = "../../epd-io/tests/common/mod.rs"]
mod common;

use epd_core::{EstimateOptions, Method, errors_against, estimate};
use epd_io::ply::{PlyFormat, PlyPrecision, write as write_ply};
use epd_io::read::{Format, read_bytes};

fn files(frame: &tof_sim::Frame) -> Vec<(&'static str, Format, Vec<u8>, f64)> {
    let ply = |f, p| {
        let mut v = Vec::new();
        write_ply(&mut v, &frame.cloud(), f, p).unwrap();
        v
    };
    let mut csv = Vec::new();
    epd_io::csv::write_points(&mut csv, &frame.measured).unwrap();
    vec![
        (
            "ply binary f64",
            Format::Ply,
            ply(PlyFormat::BinaryLittleEndian, PlyPrecision::F64),
            1e-6,
        ),
        (
            "ply ascii f64",
            Format::Ply,
            ply(PlyFormat::Ascii, PlyPrecision::F64),
            1e-6,
        ),
        (
            "ply binary f32",
            Format::Ply,
            ply(PlyFormat::BinaryLittleEndian, PlyPrecision::F32),
            2e-5,
        ),
        (
            "ply ascii f32",
            Format::Ply,
            ply(PlyFormat::Ascii, PlyPrecision::F32),
            2e-5,
        ),
        (
            "pcd ascii",
            Format::Pcd,
            common::pcd(&frame.measured, "ascii"),
            1e-6,
        ),
        (
            "pcd binary",
            Format::Pcd,
            common::pcd(&frame.measured, "binary"),
            1e-6,
        ),
        (
            "pcd binary_compressed",
            Format::Pcd,
            common::pcd(&frame.measured, "binary_compressed"),
            1e-6,
        ),
        ("csv", Format::Text, csv, 1e-6),
        ("xyz", Format::Text, common::xyz(&frame.measured), 1e-6),
    ]
}

#[test]
fn every_format_recovers_the_truth() {
    for k in 0..3 {
        let frame = frame(k, 20_000);
        let mut double_results = Vec::new();
        for (name, format, bytes, tol) in files(&frame) {
            let cloud = read_bytes(format, &bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(cloud.points.len(), frame.measured.len(), "{name}");
            let est = estimate(&cloud.points, Method::RuEpd, &EstimateOptions::default()).unwrap();
            let e = errors_against(&est.params, &frame.truth);
            let worst = [e.d_max, e.d_min, e.dy, e.dz, e.roll, e.pitch, e.yaw]
                .iter()
                .map(|v| v.abs())
                .fold(0.0, f64::max);
            assert!(worst < tol, "{name}: worst error {worst:e}");
            if tol == 1e-6 {
                double_results.push((name, est.params));
            }
            // Extra properties are kept.
            match name {
                n if n.starts_with("ply") => {
                    assert_eq!(
                        cloud
                            .extra
                            .iter()
                            .map(|(n, _)| n.as_str())
                            .collect::<Vec<_>>(),
                        ["u", "v"]
                    );
                    assert_eq!(cloud.extra[0].1[7], frame.pixels[7][0] as f64);
                }
                n if n.starts_with("pcd") => {
                    assert_eq!(cloud.extra[0].0, "intensity");
                    assert_eq!(cloud.extra[0].1[42], 42.0);
                }
                _ => {}
            }
        }
        // Binary and ASCII (and PCD, CSV) in double precision: the same estimate, bit for bit.
        for (name, p) in &double_results[1..] {
            assert_eq!(
                *p, double_results[0].1,
                "{name} differs from {}",
                double_results[0].0
            );
        }
    }
}

#[test]
fn streaming_file_reader_equals_the_in_memory_one() {
    let frame = frame(4, 5000);
    let dir = common::temp_dir("stream");
    for (name, f, p) in [
        (
            "bin64.ply",
            PlyFormat::BinaryLittleEndian,
            PlyPrecision::F64,
        ),
        (
            "bin32.ply",
            PlyFormat::BinaryLittleEndian,
            PlyPrecision::F32,
        ),
        ("ascii.ply", PlyFormat::Ascii, PlyPrecision::F64),
    ] {
        let mut bytes = Vec::new();
        write_ply(&mut bytes, &frame.cloud(), f, p).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, &bytes).unwrap();
        assert_eq!(
            epd_io::read::read_path(&path).unwrap(),
            read_bytes(Format::Ply, &bytes).unwrap(),
            "{name}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ply_big_endian_and_other_elements() {
    // A big-endian file with a face element after the vertices and mixed types.
    let pts = [[1.0f32, 0.5, -0.25], [2.0, -0.5, 0.125]];
    let mut b = b"ply\r\nformat binary_big_endian 1.0\r\ncomment x\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nproperty uchar confidence\r\nelement face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n".to_vec();
    for (i, p) in pts.iter().enumerate() {
        for c in p {
            b.extend(c.to_be_bytes());
        }
        b.push(200 + i as u8);
    }
    b.push(3);
    for i in [0i32, 1, 1] {
        b.extend(i.to_be_bytes());
    }
    let c = read_bytes(Format::Ply, &b).unwrap();
    assert_eq!(c.points, vec![[1.0, 0.5, -0.25], [2.0, -0.5, 0.125]]);
    assert_eq!(
        c.extra,
        vec![("confidence".to_string(), vec![200.0, 201.0])]
    );
}

#[test]
fn lzf_back_references() {
    // "abcabcabc": 3 literals, then a back reference of length 6 at distance 3.
    let comp = [2u8, b'a', b'b', b'c', (4 << 5), 2];
    let out = epd_io::pcd::lzf_decompress(&comp, 9).unwrap();
    assert_eq!(out, b"abcabcabc");
    assert!(epd_io::pcd::lzf_decompress(&[(1 << 5), 9], 3).is_err());
}

/// A noise-free frame of trial `k` (20" pipe, 3 % ovality), `n` points.
fn frame(k: u64, n: usize) -> tof_sim::Frame {
    use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel};
    let pipe = Pipe {
        ovality: 0.03,
        ..Pipe::paper_20in()
    };
    let truth = PoseRanges::default().sample(&pipe, 5, k).unwrap();
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    tof_sim::simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::none(),
        Subsample::Points(n),
        FrameSeed::default(),
    )
    .unwrap()
}
