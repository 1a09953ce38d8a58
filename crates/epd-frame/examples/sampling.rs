//! The sampling's efficiency without noise: for each frame and N, the Cramér–Rao bound
//! of the mean diameter (and of every parameter) on the points each method chooses,
//! over the full frame's bound (at the true β, range noise; the bound scales as 1/√N, so
//! a uniform sample gives ≈ √(frame/N)). "worst" is the largest ratio over the seven
//! parameters divided by √(frame/N): below 1, every parameter is at least as well
//! determined as by a uniform sample of the same size.
//!
//! ```text
//! cargo run --release -p epd-frame --example sampling [uniform|stratified|informed …]
//! ```
use epd_core::problem::PipeFit;
use epd_core::{EstimateOptions, Loss, LossScale, Method, Residual};
use epd_frame::sampling::{Sampling, SamplingMethod, choose};
use nalgebra::{SMatrix, SVector};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel};

fn var(pts: &[[f64; 3]], truth: &epd_core::Params) -> [f64; 8] {
    let eq = PipeFit::new(pts, Residual::Range)
        .equations_at(truth)
        .unwrap();
    let inv: SMatrix<f64, 7, 7> = eq.jtj.pseudo_inverse(1e-18).unwrap();
    let c = SVector::<f64, 7>::from([0.5, 0.5, 0., 0., 0., 0., 0.]);
    let mut o = [0.0; 8];
    o[0] = (c.transpose() * inv * c)[(0, 0)];
    for k in 0..7 {
        o[k + 1] = inv[(k, k)];
    }
    o
}

fn main() {
    let pipe = Pipe {
        ovality: 0.02,
        ..Pipe::paper_20in()
    };
    let opts = EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", 0.05).unwrap())
        .unwrap()
        .with_loss_scale(LossScale::Auto);
    let ns = [10000usize, 20000];
    let methods: Vec<SamplingMethod> = std::env::args()
        .skip(1)
        .map(|a| a.parse().unwrap())
        .collect();
    let methods = if methods.is_empty() {
        SamplingMethod::ALL.to_vec()
    } else {
        methods
    };
    let mut sum = vec![0.0; ns.len() * methods.len()];
    let mut worst = vec![0.0f64; ns.len() * methods.len()];
    let frames = 6u64;
    for k in 0..frames {
        let truth = PoseRanges::default().sample(&pipe, 1, k).unwrap();
        let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
        let f = tof_sim::simulate(
            &Sensor::helios2(),
            &scene,
            &Noise::range(0.03),
            Subsample::All,
            FrameSeed {
                seed: 1,
                trial: k,
                sweep_index: 0,
            },
        )
        .unwrap();
        let full = var(&f.exact, &truth);
        let mut line = format!("frame {k} ");
        for (a, &n) in ns.iter().enumerate() {
            for (b, &m) in methods.iter().enumerate() {
                let s = Sampling::new(n, m).unwrap();
                let t0 = std::time::Instant::now();
                let c = choose(&f.measured, &s, Method::MlEpd, &opts).unwrap();
                let ms = t0.elapsed().as_secs_f64() * 1e3;
                let meas: Vec<[f64; 3]> = c.indices.iter().map(|&i| f.measured[i]).collect();
                let t1 = std::time::Instant::now();
                let e = epd_core::estimate(&meas, Method::MlEpd, &opts).unwrap();
                let est_ms = t1.elapsed().as_secs_f64() * 1e3;
                let sub: Vec<[f64; 3]> = c.indices.iter().map(|&i| f.exact[i]).collect();
                let v = var(&sub, &truth);
                let r: Vec<f64> = (0..8).map(|i| (v[i] / full[i]).sqrt()).collect();
                let w = r[1..].iter().cloned().fold(0.0, f64::max)
                    / (f.exact.len() as f64 / n as f64).sqrt();
                sum[a * methods.len() + b] += r[0] / frames as f64;
                worst[a * methods.len() + b] = worst[a * methods.len() + b].max(w);
                line += &format!(
                    "| {n} {} dm {:.2} worst {:.2} (choice {:.1} ms, estimate {:.1} ms, {} iterations) ",
                    &m.name()[..3],
                    r[0],
                    w,
                    ms,
                    est_ms,
                    e.iterations
                );
            }
        }
        println!("{line}");
    }
    for (a, &n) in ns.iter().enumerate() {
        for (b, m) in methods.iter().enumerate() {
            println!(
                "N={n} {m}: mean dm ratio {:.3}, worst param {:.2}",
                sum[a * methods.len() + b],
                worst[a * methods.len() + b]
            );
        }
    }
}
