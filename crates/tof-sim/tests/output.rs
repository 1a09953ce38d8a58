//! PLY, CSV and depth-PNG output.

use tof_sim::output::{PlyFormat, PlyPrecision, depth_png, write_csv, write_ply};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate};

fn frame() -> tof_sim::Frame {
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 2, 3)
        .unwrap();
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::range(0.03),
        Subsample::Points(500),
        FrameSeed::default(),
    )
    .unwrap()
}

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
    let mut bin = Vec::new();
    write_ply(
        &mut bin,
        &f,
        PlyFormat::BinaryLittleEndian,
        PlyPrecision::F64,
    )
    .unwrap();
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
    let mut asc = Vec::new();
    write_ply(&mut asc, &f, PlyFormat::Ascii, PlyPrecision::F64).unwrap();
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
    let mut f32s = Vec::new();
    write_ply(
        &mut f32s,
        &f,
        PlyFormat::BinaryLittleEndian,
        PlyPrecision::F32,
    )
    .unwrap();
    let (h, body) = split_header(&f32s);
    assert!(h.contains("property float x\n"));
    assert_eq!(body.len(), 500 * (3 * 4 + 2 * 4));
}

#[test]
fn csv_has_a_header_and_every_point() {
    let f = frame();
    let mut out = Vec::new();
    write_csv(&mut out, &f).unwrap();
    let text = String::from_utf8(out).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x,y,z"));
    assert_eq!(lines.count(), 500);
}

#[test]
fn depth_png_decodes_with_the_image_and_a_scale_bar() {
    let f = frame();
    let mut out = Vec::new();
    depth_png(&mut out, &f, 6.0).unwrap();
    let dec = png::Decoder::new(std::io::Cursor::new(out));
    let reader = dec.read_info().unwrap();
    let info = reader.info();
    assert_eq!((info.width, info.height), (640 + 90, 480));
}

#[test]
fn atomic_writes_replace_a_planted_link_and_leave_nothing_behind() {
    let dir = std::env::temp_dir().join(format!("tofsim-out-{}", std::process::id()));
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
    tof_sim::output::write_file_atomic(&path, |w| write_csv(w, &frame())).unwrap();
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
        .filter(|e| e.file_name().to_string_lossy().starts_with(".tof-sim-"))
        .count();
    assert_eq!(temps, 0);
    let _ = std::fs::remove_dir_all(&dir);
}
