//! Frames and an independent XYZ writer for the tests of the `epd` tool.
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

/// Whitespace-separated XYZ text, no header.
pub fn xyz(frame: &Frame) -> Vec<u8> {
    let mut s = String::new();
    for p in &frame.measured {
        s.push_str(&format!("{}\t{} {}\n", p[0], p[1], p[2]));
    }
    s.into_bytes()
}

pub fn temp_dir(tag: &str) -> std::path::PathBuf {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let d = std::env::temp_dir().join(format!("epd-cli-{tag}-{}-{nanos}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}
