//! One whole estimate (initial guess included) per method at 10² … 10⁵ points:
//! 20" pipe (12 mm wall), 2 % ovality, σ = 0.03 m range noise, Helios2 rays.
//!
//! `cargo bench -p epd-core`

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use epd_core::{EstimateOptions, Method, estimate};

#[path = "../tests/common/mod.rs"]
mod common;

fn bench(c: &mut Criterion) {
    let truth = common::random_params(&mut common::rng(11), common::id_m(20.0), 0.02, 5.0, 0.2);
    let opts = EstimateOptions::default();
    let mut group = c.benchmark_group("estimate");
    group.sample_size(30);
    for n in [100usize, 1_000, 10_000, 100_000] {
        let pts = common::cloud(&truth, 640, 480, 6.0, 0.03, n, 5);
        for m in Method::ALL {
            group.bench_with_input(BenchmarkId::new(m.name(), n), &pts, |b, pts| {
                b.iter(|| estimate(pts, m, &opts).expect("a pipe cloud"))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
