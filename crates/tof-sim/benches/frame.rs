//! One full 640×480 frame, noise included: the exact shape, and a 2048-segment parry
//! TriMesh beside it (buffers reused, as in a sweep), plus the exact shape into fresh
//! buffers; the exact shape with a floor layer, a box and a dent; and with the camera's
//! correlated noise (ℓ = 2 px) and flying pixels.
//!
//! `cargo bench -p tof-sim`

use criterion::{Criterion, criterion_group, criterion_main};
use tof_sim::{
    CameraNoise, Contamination, Dent, FloorLayer, FlyingPixels, Frame, FrameSeed, Noise, Obstacle,
    Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate, simulate_into,
    simulate_into_with,
};

fn bench(c: &mut Criterion) {
    let sensor = Sensor::helios2();
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 1, 0)
        .expect("valid pose");
    let noise = Noise::range(0.03);
    let seeds = FrameSeed::default();
    let mut g = c.benchmark_group("frame_640x480");
    g.sample_size(30);
    for (name, wall) in [
        ("exact", WallModel::Exact),
        ("trimesh_2048", WallModel::Mesh { segments: 2048 }),
    ] {
        let scene = Scene::new(&truth, wall, 8.0).expect("scene");
        // Steady state, as a sweep runs: the frame's buffers are reused.
        let mut frame = Frame::empty();
        g.bench_function(name, |b| {
            b.iter(|| {
                simulate_into(&sensor, &scene, &noise, Subsample::All, seeds, &mut frame)
                    .expect("frame")
            })
        });
        if wall == WallModel::Exact {
            // A fresh frame each time: the first-touch page faults of ~24 MB included.
            g.bench_function("exact_fresh_buffers", |b| {
                b.iter(|| simulate(&sensor, &scene, &noise, Subsample::All, seeds).expect("frame"))
            });
        }
    }
    // A floor layer, a box on it and a dent: the dent's root search is the cost.
    let dirty = Scene::new(&truth, WallModel::Exact, 8.0)
        .expect("scene")
        .with_contamination(Contamination {
            floor: Some(FloorLayer { depth_m: 0.05 }),
            obstacle: Some(Obstacle::Box {
                x_m: 1.0,
                length_m: 0.3,
                width_m: 0.2,
                height_m: 0.1,
                y_m: 0.0,
            }),
            dent: Some(Dent {
                x_m: 1.5,
                clock_rad: 1.0,
                depth_m: 0.03,
                axial_sigma_m: 0.05,
                circumferential_sigma_m: 0.05,
            }),
            view: None,
        })
        .expect("contamination");
    let mut frame = Frame::empty();
    g.bench_function("exact_floor_box_dent", |b| {
        b.iter(|| {
            simulate_into(&sensor, &dirty, &noise, Subsample::All, seeds, &mut frame)
                .expect("frame")
        })
    });
    // The camera's correlated field and flying pixels (a second cast of every ray).
    let camera = CameraNoise {
        correlation_length_px: 2.0,
        flying_pixels: Some(FlyingPixels::new(0.5)),
        ..CameraNoise::default()
    };
    g.bench_function("exact_floor_box_dent_correlated_flying", |b| {
        b.iter(|| {
            simulate_into_with(
                &sensor,
                &dirty,
                &noise,
                &camera,
                Subsample::All,
                seeds,
                &mut frame,
            )
            .expect("frame")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
