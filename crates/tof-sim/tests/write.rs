//! PLY, CSV and depth-PNG output of tof-sim frames.

use epd_io::ply::{PlyFormat, PlyPrecision};
use std::f64::consts::FRAC_PI_2;

use epd_core::Params;
use tof_sim::{
    Frame, FrameSeed, MeshResolution, Noise, Pipe, Pipeline, PoseRanges, Scene, Segment, Sensor,
    Subsample, ToFPhysics, WallModel, simulate,
};

/// A frame of trial (2, 3) in the paper's 20" pipe.
fn frame_with(sensor: &Sensor, noise: &Noise, sub: Subsample) -> Frame {
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 2, 3)
        .unwrap();
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    simulate(sensor, &scene, noise, sub, FrameSeed::default()).unwrap()
}

/// 500 points with range noise.
fn frame() -> Frame {
    frame_with(
        &Sensor::helios2(),
        &Noise::range(0.03),
        Subsample::Points(500),
    )
}

/// The physical sensor model alone.
fn physics() -> Noise {
    Noise {
        physics: Some(ToFPhysics::helios2()),
        ..Noise::none()
    }
}

/// A frame as PLY bytes.
fn ply(f: &Frame, format: PlyFormat, precision: PlyPrecision) -> Vec<u8> {
    let mut out = Vec::new();
    epd_io::ply::write(&mut out, &f.cloud(), format, precision).unwrap();
    out
}

/// The header (through `end_header\n`) and the body of PLY bytes.
fn split_header(bytes: &[u8]) -> (String, &[u8]) {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    (
        String::from_utf8(bytes[..end].to_vec()).unwrap(),
        &bytes[end..],
    )
}

#[test]
fn ply_binary_and_ascii_hold_the_same_points() {
    let f = frame();
    let bin = ply(&f, PlyFormat::BinaryLittleEndian, PlyPrecision::F64);
    let (h, body) = split_header(&bin);
    assert!(h.starts_with("ply\nformat binary_little_endian 1.0\n"));
    assert!(h.contains("element vertex 500\n") && h.contains("property double x\n"));
    assert_eq!(body.len(), 500 * (3 * 8 + 2 * 4));
    for (i, p) in f.measured.iter().enumerate() {
        let rec = &body[i * 32..(i + 1) * 32];
        for k in 0..3 {
            let v = f64::from_le_bytes(rec[8 * k..8 * k + 8].try_into().unwrap());
            assert_eq!(v, p[k]);
        }
        assert_eq!(
            u32::from_le_bytes(rec[24..28].try_into().unwrap()),
            f.pixels[i][0]
        );
    }
    let asc = ply(&f, PlyFormat::Ascii, PlyPrecision::F64);
    let (h, body) = split_header(&asc);
    assert!(h.contains("format ascii 1.0"));
    let rows: Vec<Vec<f64>> = std::str::from_utf8(body)
        .unwrap()
        .lines()
        .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 500);
    for (r, p) in rows.iter().zip(&f.measured) {
        assert_eq!(&r[..3], &p[..]); // shortest round-trip formatting is exact
    }
    let f32s = ply(&f, PlyFormat::BinaryLittleEndian, PlyPrecision::F32);
    let (h, body) = split_header(&f32s);
    assert!(h.contains("property float x\n"));
    assert_eq!(body.len(), 500 * (3 * 4 + 2 * 4));
}

#[test]
fn csv_has_a_header_and_every_point() {
    let f = frame();
    let mut out = Vec::new();
    epd_io::csv::write_points(&mut out, &f.measured).unwrap();
    let text = String::from_utf8(out).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x,y,z"));
    assert_eq!(lines.count(), 500);
}

#[test]
fn depth_png_decodes_with_the_image_and_a_scale_bar() {
    let f = frame();
    let mut out = Vec::new();
    epd_io::depth_png::write(&mut out, &f.cloud(), 6.0).unwrap();
    let dec = png::Decoder::new(std::io::Cursor::new(out));
    let reader = dec.read_info().unwrap();
    let info = reader.info();
    assert_eq!((info.width, info.height), (640 + 110, 480));
    // The pixels: a measured point is coloured, a pixel without a point is black, and
    // the colour bar's bottom (near) and top (far) differ.
    let (rgb, (w, _)) = epd_io::depth_png::render(&f.cloud(), 6.0).unwrap();
    let at = |x: u32, y: u32| {
        let i = 3 * (y * w + x) as usize;
        [rgb[i], rgb[i + 1], rgb[i + 2]]
    };
    let [u, v] = f.pixels[0];
    assert_ne!(at(u, v), [0, 0, 0]);
    let hit: std::collections::HashSet<_> = f.pixels.iter().copied().collect();
    let empty = (0..640)
        .flat_map(|u| (0..480).map(move |v| [u, v]))
        .find(|p| !hit.contains(p))
        .unwrap();
    assert_eq!(at(empty[0], empty[1]), [0, 0, 0]);
    let column: Vec<[u8; 3]> = (0..480).map(|y| at(640 + 18, y)).collect();
    assert!(column.iter().filter(|c| **c != [0, 0, 0]).count() > 300);
    assert_ne!(column[30], column[450]);
}

#[test]
fn atomic_writes_replace_a_planted_link_and_leave_nothing_behind() {
    let dir = std::env::temp_dir().join(format!("epd-io-out-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    let path = dir.join("frame.csv");
    let _ = std::fs::remove_file(&path);
    std::os::unix::fs::symlink(&victim, &path).unwrap();
    // The old predictable temporary name, planted too.
    std::os::unix::fs::symlink(
        &victim,
        dir.join(format!(".frame.csv.tmp{}", std::process::id())),
    )
    .unwrap();
    epd_io::atomic::write_file_atomic(&path, |w| epd_io::csv::write_points(w, &frame().measured))
        .unwrap();
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    assert!(
        std::fs::symlink_metadata(&path)
            .unwrap()
            .file_type()
            .is_file()
    );
    let temps = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(".epd-io-"))
        .count();
    assert_eq!(temps, 0);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Invalid pixels of the physical model (dark, far down the pipe within a 0.5–2 m
/// window) are written as x = y = z = 0 with intensity 0.
#[test]
fn invalid_pixels_are_written_as_zeros_with_intensity_zero() {
    let sensor = Sensor {
        min_range: 0.5,
        max_range: 2.0,
        ..Sensor::helios2()
    };
    let f = frame_with(&sensor, &physics(), Subsample::All);
    let invalid = (0..f.len()).filter(|&i| !f.is_valid(i)).count();
    assert!(invalid > 1000, "{invalid}");
    let ply = ply(&f, PlyFormat::Ascii, PlyPrecision::F64);
    let text = String::from_utf8(ply).unwrap();
    let zeros: Vec<&str> = text.lines().filter(|l| l.starts_with("0 0 0 ")).collect();
    assert_eq!(zeros.len(), invalid);
    assert!(zeros.iter().all(|l| l.ends_with(" 0")));
}

#[test]
fn ply_has_an_intensity_property_only_with_the_physical_model() {
    let sensor = Sensor::helios2();
    let f = frame_with(&sensor, &physics(), Subsample::Points(500));
    let bin = ply(&f, PlyFormat::BinaryLittleEndian, PlyPrecision::F64);
    let (h, body) = split_header(&bin);
    assert!(h.ends_with("property uint v\nproperty float intensity\nend_header\n"));
    let rec = 3 * 8 + 2 * 4 + 4;
    assert_eq!(body.len(), 500 * rec);
    for i in 0..500 {
        let at = i * rec + 32;
        let v = f32::from_le_bytes(body[at..at + 4].try_into().unwrap());
        assert_eq!(v.to_bits(), f.intensity[i].to_bits());
    }
    let asc = ply(&f, PlyFormat::Ascii, PlyPrecision::F32);
    let (h, body) = split_header(&asc);
    assert!(h.contains("property float intensity\n"));
    for (line, want) in std::str::from_utf8(body).unwrap().lines().zip(&f.intensity) {
        let cols: Vec<&str> = line.split(' ').collect();
        assert_eq!(cols.len(), 6);
        assert_eq!(cols[5].parse::<f32>().unwrap(), *want);
    }
    // The plain model: NaN intensities, no property.
    let g = frame_with(&sensor, &Noise::range(0.01), Subsample::Points(500));
    assert!(g.intensity.iter().all(|i| i.is_nan()));
    assert!(g.sigma.iter().all(|&s| s == 0.01));
    let plain = ply(&g, PlyFormat::Ascii, PlyPrecision::F64);
    assert!(!split_header(&plain).0.contains("intensity"));
}

/// A labelled frame's PLY carries `segment` and `part` per point, in both encodings.
#[test]
fn ply_of_a_labelled_frame_has_segment_and_part() {
    // A 90° long-radius elbow 1 m ahead of a centred sensor.
    let bend = Segment::Bend {
        radius: 1.5 * 0.508,
        angle: FRAC_PI_2,
        direction: 0.0,
    };
    let p = Pipeline::with_one_bend(0.49, 0.48, -1.0, 1.0, bend, 6.0);
    let truth = Params::from_array([p.d_max, p.d_min, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let res = MeshResolution {
        segments: 256,
        bend_step: 0.02,
        ..MeshResolution::default()
    };
    let scene = Scene::pipeline(&truth, &p, &res).unwrap();
    let f = simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::range(0.01),
        Subsample::Points(300),
        FrameSeed::default(),
    )
    .unwrap();
    let ascii = ply(&f, PlyFormat::Ascii, PlyPrecision::F64);
    let (head, body) = split_header(&ascii);
    assert!(
        head.ends_with(
            "property uint v\nproperty ushort segment\nproperty uchar part\nend_header\n"
        )
    );
    for (line, part) in std::str::from_utf8(body).unwrap().lines().zip(&f.part) {
        let tok: Vec<&str> = line.split(' ').collect();
        let p = part.unwrap();
        assert_eq!(tok[5].parse::<u16>().unwrap(), p.segment);
        assert_eq!(
            tok[6].parse::<u8>().unwrap(),
            tof_sim::export::part_code(p.kind)
        );
    }
    let bin = ply(&f, PlyFormat::BinaryLittleEndian, PlyPrecision::F32);
    let (_, body) = split_header(&bin);
    let rec = 3 * 4 + 2 * 4 + 2 + 1;
    assert_eq!(body.len(), rec * f.len());
    for (i, part) in f.part.iter().enumerate() {
        let r = &body[i * rec..(i + 1) * rec];
        let p = part.unwrap();
        assert_eq!(u16::from_le_bytes([r[20], r[21]]), p.segment);
        assert_eq!(r[22], tof_sim::export::part_code(p.kind));
    }
}
