//! One full 640×480 frame, noise included: the exact shape, and a 2048-segment parry
//! TriMesh beside it (buffers reused, as in a sweep), plus the exact shape into fresh
//! buffers.
//!
//! `cargo bench -p tof-sim`

use criterion::{Criterion, criterion_group, criterion_main};
use tof_sim::{
    Frame, FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel, simulate,
    simulate_into,
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
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
