mod common;
use epd_core::{
    EstimateOptions, Method, estimate,
    init::initial_guess,
    lm::{LmOptions, minimize},
    problem::PipeFit,
    residual::Residual,
};
use std::time::Instant;
#[test]
fn scratch() {
    let truth = common::random_params(&mut common::rng(11), common::id_m(20.0), 0.02, 5.0, 0.2);
    let pts = common::cloud(&truth, 640, 480, 6.0, 0.03, 100_000, 5);
    let t = Instant::now();
    for _ in 0..20 {
        let _ = initial_guess(&pts).unwrap();
    }
    println!("init {:.3} ms", t.elapsed().as_secs_f64() * 1e3 / 20.0);
    let fit = PipeFit {
        points: &pts,
        residual: Residual::ErrorBased,
    };
    let t = Instant::now();
    for _ in 0..20 {
        let _ = fit.equations_at(&truth).unwrap();
    }
    println!(
        "one RU pass {:.3} ms",
        t.elapsed().as_secs_f64() * 1e3 / 20.0
    );
    let fit = PipeFit {
        points: &pts,
        residual: Residual::Canonical,
    };
    let t = Instant::now();
    for _ in 0..20 {
        let _ = fit.equations_at(&truth).unwrap();
    }
    println!(
        "one C pass {:.3} ms",
        t.elapsed().as_secs_f64() * 1e3 / 20.0
    );
    let g = initial_guess(&pts).unwrap();
    let sub: Vec<[f64; 3]> = pts.iter().step_by(12).copied().collect();
    let r1 = minimize(
        &PipeFit {
            points: &sub,
            residual: Residual::ErrorBased,
        },
        nalgebra::SVector::from(g.to_array()),
        &LmOptions::default(),
    );
    println!("stage1 iters {} {:?}", r1.iterations, r1.status);
    let r2 = minimize(
        &PipeFit {
            points: &pts,
            residual: Residual::ErrorBased,
        },
        r1.x,
        &LmOptions::default(),
    );
    println!("stage2 iters {} {:?}", r2.iterations, r2.status);
    for m in Method::ALL {
        let e = estimate(&pts, m, &EstimateOptions::default()).unwrap();
        println!("{m} iters {}", e.iterations);
    }
}
