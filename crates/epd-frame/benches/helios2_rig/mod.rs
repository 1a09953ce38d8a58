//! The realistic frames and the depth table that `benches/frame.rs` and
//! `examples/table_cost.rs` both measure (the example includes this file by its path):
//! full 640×480 Helios2 frames of tof-sim's physical model, a table from three frames of a
//! round 20" rig with `epd calibrate`'s default 30 × 12 bins, and the inspection pipe.

use epd_core::calibration::{CalibrationFrame, CalibrationSettings, calibrate};
use epd_core::{DepthTable, EstimateOptions};
use tof_sim::{
    FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, ToFPhysics, WallModel,
};

/// Frame `k` of seed 3 in `pipe`: a random pose of [`PoseRanges::default`], the exact
/// wall out to 6 m, the Helios2 sensor with its physical error model, every pixel.
pub fn helios2_frame(pipe: &Pipe, k: u64) -> tof_sim::Frame {
    let truth = PoseRanges::default().sample(pipe, 3, k).expect("pose");
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).expect("scene");
    let noise = Noise {
        physics: Some(ToFPhysics::helios2()),
        ..Noise::none()
    };
    let seed = FrameSeed {
        seed: 3,
        trial: k,
        sweep_index: 0,
    };
    tof_sim::simulate(&Sensor::helios2(), &scene, &noise, Subsample::All, seed).expect("frame")
}

/// The calibration rig: a round 20" pipe with a 9.5 mm wall.
pub fn rig() -> Pipe {
    Pipe {
        nominal_od_in: 20.0,
        wall_thickness: 0.0095,
        ovality: 0.0,
    }
}

/// The depth table `epd calibrate` makes from frames 0–2 of `rig` ([`helios2_frame`]),
/// gated to [0.5, 2] m, on 30 × 12 range × intensity bins of at least 30 points, in three
/// passes, without the incidence axis; the rigs' poses fitted with `options`.
pub fn rig_table(rig: &Pipe, options: &EstimateOptions) -> DepthTable {
    let rig_frames: Vec<(tof_sim::Frame, Vec<f64>)> = (0..3)
        .map(|k| {
            let f = helios2_frame(rig, k);
            let i = f.intensity.iter().map(|&v| v as f64).collect();
            (f, i)
        })
        .collect();
    let views: Vec<CalibrationFrame<'_>> = rig_frames
        .iter()
        .map(|(f, i)| CalibrationFrame {
            points: &f.measured,
            intensity: i,
        })
        .collect();
    let settings = CalibrationSettings {
        known: (rig.d_max(), rig.d_min()),
        gate: (0.5, 2.0),
        bins: (30, 12),
        min_count: 30,
        passes: 3,
        incidence_bins: 0,
    };
    calibrate(&views, &settings, options).expect("table").table
}

/// The pipe inspected: the paper's 20" pipe with a 12.7 mm wall and 1 % ovality.
pub fn inspection_pipe() -> Pipe {
    Pipe {
        wall_thickness: 0.0127,
        ovality: 0.01,
        ..Pipe::paper_20in()
    }
}
