//! Frames and independent writers of PCD and XYZ for the reader tests; epd-cli's tests
//! include this file too (`crates/epd-cli/tests/common/mod.rs`), so it uses nothing of
//! epd-io.
#![allow(dead_code)]

use tof_sim::{
    Frame, FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate,
};

/// A noise-free frame of trial `k` (20" pipe, 3 % ovality), `n` points.
pub fn frame(k: u64, n: usize) -> Frame {
    let pipe = Pipe {
        ovality: 0.03,
        ..Pipe::paper_20in()
    };
    let truth = PoseRanges::default().sample(&pipe, 5, k).unwrap();
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::none(),
        Subsample::Points(n),
        FrameSeed::default(),
    )
    .unwrap()
}

/// A PCD file of the frame's measured points plus an `intensity` field.
/// `data`: ascii, binary or binary_compressed (LZF with literal runs only, which is valid LZF).
pub fn pcd(frame: &Frame, data: &str) -> Vec<u8> {
    let n = frame.measured.len();
    let mut out = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 8 8 8 4\nTYPE F F F F\n\
         COUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )
    .into_bytes();
    let intensity = |i: usize| (i % 100) as f32;
    match data {
        "ascii" => {
            for (i, p) in frame.measured.iter().enumerate() {
                out.extend(format!("{} {} {} {}\n", p[0], p[1], p[2], intensity(i)).bytes());
            }
        }
        "binary" => {
            for (i, p) in frame.measured.iter().enumerate() {
                for c in p {
                    out.extend(c.to_le_bytes());
                }
                out.extend(intensity(i).to_le_bytes());
            }
        }
        _ => {
            // Field-major raw data, then LZF literal runs of ≤ 32 bytes.
            let mut raw = Vec::new();
            for k in 0..3 {
                for p in &frame.measured {
                    raw.extend(p[k].to_le_bytes());
                }
            }
            for i in 0..n {
                raw.extend(intensity(i).to_le_bytes());
            }
            let mut comp = Vec::new();
            for chunk in raw.chunks(32) {
                comp.push((chunk.len() - 1) as u8);
                comp.extend_from_slice(chunk);
            }
            out.extend((comp.len() as u32).to_le_bytes());
            out.extend((raw.len() as u32).to_le_bytes());
            out.extend(comp);
        }
    }
    out
}

/// Whitespace-separated XYZ text, no header.
pub fn xyz(frame: &Frame) -> Vec<u8> {
    let mut s = String::new();
    for p in &frame.measured {
        s.push_str(&format!("{}\t{} {}\n", p[0], p[1], p[2]));
    }
    s.into_bytes()
}

/// A fresh folder under the system's temporary folder, named after the crate under
/// test, `tag`, the process and the time.
pub fn temp_dir(tag: &str) -> std::path::PathBuf {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let d = std::env::temp_dir().join(format!(
        "{}-{tag}-{}-{nanos}",
        env!("CARGO_PKG_NAME"),
        std::process::id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}
