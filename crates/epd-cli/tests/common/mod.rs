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

/// The report's keys of the seven parameters β (eq. 2), in mm and degrees: what a frame's
/// truth (`frame_NNNN.json`) and an estimate share.
#[allow(dead_code)]
pub const PARAM_KEYS: [&str; 7] = [
    "d_max_mm",
    "d_min_mm",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
    "dy_mm",
    "dz_mm",
];

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

/// Run `cmd` and wait for it at most `limit`; `None` (the child killed) when it is still
/// running then.
#[allow(dead_code)]
pub fn output_within(
    mut cmd: std::process::Command,
    limit: std::time::Duration,
) -> Option<std::process::Output> {
    let mut child = cmd
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while t0.elapsed() < limit {
        if child.try_wait().unwrap().is_some() {
            return Some(child.wait_with_output().unwrap());
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.kill().ok();
    child.wait().ok();
    None
}
