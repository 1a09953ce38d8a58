//! Frames and an independent XYZ writer for the tests of the `epd` tool: the reader
//! tests' helpers of epd-io (one copy for both crates), and simulated frames.

#[path = "../../../epd-io/tests/common/mod.rs"]
mod shared;

// Each test file uses a part of them.
#[allow(unused_imports)]
pub use shared::{temp_dir, xyz};

use tof_sim::{
    Frame, FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate,
};

/// A noise-free frame of trial `k` (20" pipe, 3 % ovality), `n` points.
#[allow(dead_code)]
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
