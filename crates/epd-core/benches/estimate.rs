//! One whole estimate (initial guess included) per method at 10² … 10⁵ points:
//! 20" pipe (12 mm wall), 2 % ovality, σ = 0.03 m range noise, Helios2 rays.
//!
//! `cargo bench -p epd-core`

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use epd_core::{EstimateOptions, Method, estimate};

#[path = "../tests/common/mod.rs"]
mod common;
#[path = "../tests/common/crate_lm.rs"]
mod crate_lm;

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

/// The parts an estimate adds to the solver at 10⁵ points: the data-only initial guess,
/// the plausibility check, and the uncertainty's cluster pass (every point's cell and the
/// cells' scores and breads) beside one pass of the solver's normal equations over the
/// same points, and the form test: what the checks cost in units of a solver pass.
fn parts(c: &mut Criterion) {
    use epd_core::check::assess;
    use epd_core::init::initial_guess;
    let truth = common::random_params(&mut common::rng(11), common::id_m(20.0), 0.02, 5.0, 0.2);
    let pts = common::cloud(&truth, 640, 480, 6.0, 0.03, 100_000, 5);
    let mut group = c.benchmark_group("parts");
    group.sample_size(30);
    group.bench_function("initial_guess/100000", |b| {
        b.iter(|| initial_guess(&pts).expect("a pipe cloud"))
    });
    group.bench_function("assess/100000", |b| {
        b.iter(|| assess(&pts, &truth).expect("inside"))
    });
    let fit = epd_core::problem::PipeFit::new(&pts, epd_core::Residual::Range);
    let cells = epd_core::problem::Cells {
        axial_edges: vec![0.4, 0.6, 0.8, 1.0, 1.3, 1.8, 2.6],
        sectors: epd_core::estimate::CLOCK_SECTORS,
    };
    group.bench_function("equations/100000", |b| {
        b.iter(|| fit.equations_at(&truth).expect("inside"))
    });
    group.bench_function("cluster_sandwich/100000", |b| {
        b.iter(|| {
            fit.cluster_sandwich_at(&truth, &cells, epd_core::problem::Curvature::Exact)
                .expect("inside")
        })
    });
    let form_cells = epd_core::problem::Cells {
        axial_edges: (1..16).map(|k| 0.3 + 0.15 * k as f64).collect(),
        sectors: epd_core::estimate::CLOCK_SECTORS,
    };
    group.bench_function("form_test/100000", |b| {
        b.iter(|| epd_core::fit::form::form_test(&pts, None, &truth, &form_cells))
    });
    group.finish();
}

/// The solver choice: our normal-equation LM against the `levenberg-marquardt` crate
/// (MINPACK: full N×7 Jacobian and QR), both from the same data-only start, RU-EPD
/// residual, all points in one stage, no statistical stop.
fn solvers(c: &mut Criterion) {
    use epd_core::init::initial_guess;
    use epd_core::lm::{LmOptions, minimize};
    use epd_core::problem::PipeFit;
    use epd_core::residual::Residual;
    let truth = common::random_params(&mut common::rng(11), common::id_m(20.0), 0.02, 5.0, 0.2);
    let mut group = c.benchmark_group("solver");
    group.sample_size(20);
    for n in [10_000usize, 100_000] {
        let pts = common::cloud(&truth, 640, 480, 6.0, 0.03, n, 5);
        let x0 = initial_guess(&pts).expect("a pipe cloud");
        group.bench_with_input(BenchmarkId::new("ours", n), &pts, |b, pts| {
            b.iter(|| {
                minimize(
                    &PipeFit::new(pts, Residual::ErrorBased),
                    nalgebra::SVector::from(x0.to_array()),
                    &LmOptions::default(),
                )
            })
        });
        group.bench_with_input(
            BenchmarkId::new("levenberg-marquardt", n),
            &pts,
            |b, pts| {
                b.iter(|| {
                    levenberg_marquardt::LevenbergMarquardt::new()
                        .minimize(crate_lm::CratePipe::new(pts, Residual::ErrorBased, &x0))
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench, parts, solvers);
criterion_main!(benches);
