//! One realistic camera frame through `epd estimate --calibration`'s path: a full
//! 640×480 Helios2 frame of the realistic model (binary PLY, float x y z + intensity,
//! invalid pixels as zeros) parsed, corrected by a depth table, gated to [0.5, 2] m and
//! estimated by weighted ML-EPD with the Cauchy loss; and `measure_frame_defaults`, the
//! frame library's whole measurement with `epd estimate`'s defaults (scene, fit, checks,
//! report context) on a plain full frame (range noise σ = 0.03 m). The camera runs at up
//! to 30 frames/s: a frame must take under 33 ms on 2 cores.
//!
//! `cargo bench -p epd-frame --bench frame`

use std::borrow::Cow;

use criterion::{Criterion, criterion_group, criterion_main};
use epd_core::{EstimateOptions, Loss, LossScale, Method, estimate_weighted};
use epd_frame::read::{Format, read_bytes};
use epd_frame::{EstimateConfig, EstimateSettings, FrameInput, measure_frame};
use epd_io::ply::{PlyFormat, PlyPrecision, write as write_ply};
use tof_sim::{FrameSeed, Noise, PoseRanges, Scene, Sensor, Subsample, WallModel};

mod helios2_rig;

use helios2_rig::{helios2_frame as frame, inspection_pipe, rig, rig_table};

fn bench(c: &mut Criterion) {
    // As `epd` does at start-up.
    epd_frame::keep_freed_memory();
    let options = EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", 0.05).expect("loss"))
        .expect("loss")
        .with_loss_scale(LossScale::Auto)
        .with_range_gate(0.5, 2.0)
        .expect("gate");
    // The table from three rig frames (20", 9.5 mm wall, round).
    let table = rig_table(&rig(), &options);
    // One inspection frame as the camera's PLY.
    let pipe = inspection_pipe();
    let f = frame(&pipe, 10);
    let mut ply = Vec::new();
    write_ply(
        &mut ply,
        &f.cloud(),
        PlyFormat::BinaryLittleEndian,
        PlyPrecision::F32,
    )
    .expect("ply");
    let mut g = c.benchmark_group("frame");
    g.sample_size(30);
    g.bench_function("read_calibrate_gate_estimate", |b| {
        b.iter(|| {
            let mut cloud = read_bytes(Format::Ply, &ply).expect("read");
            let i = cloud
                .extra
                .iter()
                .find(|(n, _)| n == "intensity")
                .map(|(_, v)| v.clone())
                .expect("intensity");
            let (_, s) = table
                .correct_with_sigmas(&mut cloud.points, &i)
                .expect("correct");
            estimate_weighted(&cloud.points, &s, Method::MlEpd, &options).expect("estimate")
        })
    });
    let cloud = read_bytes(Format::Ply, &ply).expect("read");
    let i: Vec<f64> = f.intensity.iter().map(|&v| v as f64).collect();
    g.bench_function("correct", |b| {
        b.iter(|| {
            let mut p = cloud.points.clone();
            table.correct_with_sigmas(&mut p, &i).expect("correct")
        })
    });
    let mut corrected = cloud.points.clone();
    let (_, s) = table
        .correct_with_sigmas(&mut corrected, &i)
        .expect("correct");
    g.bench_function("estimate_weighted", |b| {
        b.iter(|| estimate_weighted(&corrected, &s, Method::MlEpd, &options).expect("estimate"))
    });
    g.bench_function("estimate_unweighted", |b| {
        b.iter(|| epd_core::estimate(&corrected, Method::MlEpd, &options).expect("estimate"))
    });
    g.bench_function("read", |b| {
        b.iter(|| read_bytes(Format::Ply, &ply).expect("read"))
    });
    // The whole measurement with `epd estimate`'s defaults on a plain frame.
    let settings = EstimateSettings::default();
    let cfg = EstimateConfig::new(&settings).expect("config");
    let truth = PoseRanges::default().sample(&pipe, 3, 11).expect("pose");
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).expect("scene");
    let plain = tof_sim::simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::range(0.03),
        Subsample::All,
        FrameSeed::default(),
    )
    .expect("frame");
    g.bench_function("measure_frame_defaults", |b| {
        b.iter(|| {
            let input = FrameInput {
                points: Cow::Borrowed(&plain.measured),
                intensity: None,
                sigma: None,
                read_ms: 0.0,
            };
            measure_frame(input, &cfg).expect("measure")
        })
    });
    // What the measurement above spends, once per frame, on the checks that the model
    // fits (the form test over its cells and the plausibility check) and on the 1-σ's
    // cluster pass, at the frame's fitted β: issue 22's goal is that the checks add
    // ≤ 15 % to the whole (docs/benchmarks.md).
    let fitted = epd_core::estimate(&plain.measured, Method::MlEpd, &EstimateOptions::default())
        .expect("estimate");
    let beta = fitted.params;
    let form_cells = epd_core::fit::covariance::wall_cells(
        &plain.measured,
        &beta,
        epd_core::fit::form::FORM_AXIAL_CELLS,
    );
    let cells = epd_core::fit::covariance::wall_cells(
        &plain.measured,
        &beta,
        epd_core::estimate::AXIAL_CELLS,
    );
    g.bench_function("checks_full_frame", |b| {
        b.iter(|| {
            let wall =
                epd_core::fit::form::WallCells::gather(&plain.measured, None, &beta, &form_cells);
            let misfit = wall
                .as_ref()
                .map(|w| (w.form_test(), w.misfit_slices(), w.shared_along_axis()));
            (misfit, epd_core::check::assess(&plain.measured, &beta))
        })
    });
    g.bench_function("one_sigma_cluster_pass_full_frame", |b| {
        let fit = epd_core::problem::PipeFit::new(&plain.measured, epd_core::Residual::Range);
        b.iter(|| {
            fit.cluster_sandwich_at(&beta, &cells, epd_core::problem::Curvature::Exact)
                .expect("inside")
        })
    });
    // The survey's departure profile of the frame against its fit (one pass of the
    // survey; a frame takes one to four): its time, and its memory (issue 27: the
    // deviations are held once, in 32 bits, in one buffer).
    let axis = epd_core::scene::profile::AxisSigma::of(&fitted);
    let seg = epd_core::segment::SegmentOptions::default();
    g.bench_function("survey_profile_full_frame", |b| {
        b.iter(|| epd_core::scene::profile::profile(&plain.measured, &beta, &axis, &seg))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
