//! A band of multipath among the far, grazing rays of a small pipe: few points, much of
//! the information on the diameters. The error they share must reach the 1-σ (the test for
//! errors shared along the axis, `epd_core::fit::form`), or the frame must not be answered
//! `converged` (issue 22: none more than max(5σ̂, 0.5 mm) off).

use std::borrow::Cow;

use epd_core::{Params, errors_against};
use epd_frame::{EstimateConfig, EstimateSettings, FrameInput, measure_frame};
use tof_sim::camera::{CameraNoise, MultipathBand};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel};

/// Frame `k` of an 8" pipe (8.625" outside, 8.18 mm wall, 2 % ovality) at one of the
/// paper's random poses, seen by tof-sim's Helios2 model (640 × 480) with σ = 0.02 m and
/// every ray whose true range lies in [1, 2] m read 5 cm long (2.5σ): the frames of
/// `EPD_OD_IN=8.625 EPD_WALL_MM=8.18 cargo run --release -p epd-frame --example coverage
/// -- 40 multipath`.
fn frame(k: u64) -> (Params, Vec<[f64; 3]>) {
    let pipe = Pipe {
        ovality: 0.02,
        nominal_od_in: 8.625,
        wall_thickness: 8.18e-3,
    };
    let truth = PoseRanges::default()
        .sample(&pipe, 7, k)
        .expect("a pose of the paper's ranges");
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).expect("a valid scene");
    let camera = CameraNoise {
        multipath_bands: vec![MultipathBand {
            near_m: 1.0,
            far_m: 2.0,
            extra_m: 0.05,
        }],
        ..CameraNoise::default()
    };
    let f = tof_sim::simulate_with(
        &Sensor::helios2(),
        &scene,
        &Noise::range(0.02),
        &camera,
        Subsample::All,
        FrameSeed {
            seed: 7,
            trial: k,
            sweep_index: 0,
        },
    )
    .expect("a frame");
    (truth, f.measured)
}

/// 40 frames measured with `epd estimate`'s defaults: the goal allows none converged more
/// than max(5σ̂, 0.5 mm) off in Dmax or Dmin. With the form test on 2¹⁵ strided points
/// (`epd_core::fit::form::FORM_POINTS` before), frame 15 was: Dmin +1.3 mm at 5.1σ̂ (and
/// frames 5 and 30 of the same frames written as text and read by `epd estimate`): the
/// test for errors shared along the axis missed its band, and the 1-σ did not carry it
/// (checked: the test fails with 2¹⁵).
#[test]
fn a_far_band_of_multipath_is_carried_by_the_one_sigma() {
    let cfg = EstimateConfig::new(&EstimateSettings::default()).expect("the defaults are valid");
    let mut far = Vec::new();
    for k in 0..40 {
        let (truth, points) = frame(k);
        let input = FrameInput {
            points: Cow::Owned(points),
            intensity: None,
            sigma: None,
            read_ms: 0.0,
        };
        let m = measure_frame(input, &cfg).expect("a full frame is measured");
        let e = &m.estimate;
        if !e.status.is_converged() || m.geometry.as_ref().and_then(|g| g.withheld()).is_some() {
            continue;
        }
        let err = errors_against(&e.params, &truth);
        for (name, err, sigma) in [
            ("Dmax", err.d_max, e.sigma[0]),
            ("Dmin", err.d_min, e.sigma[1]),
        ] {
            let sigma = sigma.expect("a converged fit's diameters have a 1-σ");
            if err.abs() > (5.0 * sigma).max(0.5e-3) {
                far.push((k, name, err * 1e3, err / sigma));
            }
        }
    }
    assert!(
        far.is_empty(),
        "converged far off (frame, diameter, mm, z): {far:?}"
    );
}
