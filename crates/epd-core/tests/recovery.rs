//! Recovery from random poses: noise-free clouds exactly (after canonicalisation); noisy
//! clouds from the data-only start and from deliberately perturbed starts, within the
//! reported uncertainty.

mod common;

use epd_core::{EstimateOptions, Method, Params, errors_against, estimate};
use rand::RngExt;

fn max_abs_err(est: &Params, truth: &Params) -> (f64, f64) {
    let e = errors_against(est, truth);
    let len = [e.d_max, e.d_min, e.dy, e.dz]
        .iter()
        .map(|v| v.abs())
        .fold(0.0, f64::max);
    let ang = [e.roll, e.pitch, e.yaw]
        .iter()
        .map(|v| v.abs())
        .fold(0.0, f64::max);
    (len, ang)
}

/// ≥ 1000 random poses over the ranges the initial guess promises: any roll, pitch/yaw
/// within ±15°, offsets up to 25 % of the radius, ovality 1–6 %, 16–30" pipes,
/// 10² to 10⁵ points. Every method recovers β to 1e-6 m and 1e-6 rad.
#[test]
fn noise_free_random_poses_are_recovered() {
    let mut rng = common::rng(2024);
    let opts = EstimateOptions::default();
    let sizes = [100usize, 1_000, 10_000, 100_000];
    let mut worst = (0.0f64, 0.0f64);
    let mut fails = Vec::new();
    let trials = 1000;
    for k in 0..trials {
        let od = rng.random_range(16.0..30.0f64);
        let ovality = rng.random_range(0.01..0.06f64);
        let truth = common::random_params(&mut rng, common::id_m(od), ovality, 15.0, 0.25);
        // Most trials on small grids (fast); every 50th on a full frame.
        let n = sizes[k % 4];
        let (w, h) = if k % 50 == 0 { (640, 480) } else { (160, 120) };
        let n = if w == 640 { n } else { n.min(10_000) };
        let pts = common::cloud(&truth, w, h, 6.0, 0.0, n, k as u64);
        let method = Method::ALL[k % 3];
        match estimate(&pts, method, &opts) {
            Ok(est) => {
                let (l, a) = max_abs_err(&est.params, &truth);
                worst = (worst.0.max(l), worst.1.max(a));
                if l > 1e-6 || a > 1e-6 || !est.status.is_converged() {
                    fails.push(format!(
                        "trial {k} {method} n={}: {l:.2e} m {a:.2e} rad {:?} truth {truth:?}",
                        pts.len(),
                        est.status
                    ));
                }
            }
            Err(e) => fails.push(format!("trial {k} {method}: error {e}")),
        }
    }
    eprintln!(
        "worst over {trials} poses: {:.2e} m, {:.2e} rad; failures {}",
        worst.0,
        worst.1,
        fails.len()
    );
    assert!(fails.is_empty(), "not recovered:\n{}", fails.join("\n"));
}

/// A circular pipe: diameters, tilt and offset distance are recovered; the roll is
/// reported as undetermined.
#[test]
fn circular_pipe_recovers_what_is_observable() {
    let mut rng = common::rng(7);
    for k in 0..30 {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.0, 5.0, 0.25);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.0, 0, k);
        for method in Method::ALL {
            let est = estimate(&pts, method, &EstimateOptions::default()).unwrap();
            let p = est.params;
            assert!((p.d_max - truth.d_max).abs() < 1e-6 && (p.d_min - truth.d_min).abs() < 1e-6);
            // Tilt of the axis: angle between the SCS X axis and the pipe axis.
            let axis_t = truth.dir_pcs_to_scs(&nalgebra::Vector3::x());
            let axis_e = p.dir_pcs_to_scs(&nalgebra::Vector3::x());
            assert!(
                axis_t.angle(&axis_e) < 1e-6,
                "{method} axis {}",
                axis_t.angle(&axis_e)
            );
            let off_t = truth.dy.hypot(truth.dz);
            let off_e = p.dy.hypot(p.dz);
            assert!((off_t - off_e).abs() < 1e-6, "{method} offset");
            assert!(
                !est.roll_determined,
                "{method}: roll reported as determined"
            );
            assert!(est.sigma[2].is_none());
        }
    }
}

/// Noisy clouds from cold starts (the data-only initial guess, never the truth): 300
/// random poses over the promised ranges (any roll, pitch/yaw ±15°, offsets up to 25 %
/// of the radius, 16–30", 1–6 % ovality, σ = 0.01–0.05 m range noise). RU-EPD and
/// ML-EPD always converge, C-EPD on at least 98 % of the poses (refused, not wrong,
/// on the others: measured 3 of 300); ML-EPD, the maximum-likelihood fit, lands within 5 reported standard
/// deviations of the truth in every determined parameter (a diverged or wrong-basin fit
/// is off by hundreds); its mean-diameter error over the poses is within 3 standard
/// errors of zero.
#[test]
fn noisy_clouds_from_cold_starts() {
    let mut rng = common::rng(4242);
    let opts = EstimateOptions::default();
    let poses = 300;
    let mut fails = Vec::new();
    let mut dmean = Vec::new();
    let mut c_refused = 0;
    let mut c_lack = 0;
    for k in 0..poses {
        let od = rng.random_range(16.0..30.0f64);
        let ovality = rng.random_range(0.01..0.06f64);
        let sigma = rng.random_range(0.01..0.05f64);
        let truth = common::random_params(&mut rng, common::id_m(od), ovality, 15.0, 0.25);
        let pts = common::cloud(&truth, 160, 120, 6.0, sigma, 0, 9000 + k as u64);
        for method in Method::ALL {
            let est = match estimate(&pts, method, &opts) {
                Ok(e) => e,
                Err(e) => {
                    fails.push(format!("pose {k} {method}: {e}"));
                    continue;
                }
            };
            if !est.status.is_converged() {
                // C-EPD's cost falls along ever larger ellipses and its bias grows with
                // the tilt: a refusal is its honest answer on a few tilted, noisy poses.
                // Its biased wall also lies off the points beyond their noise in places,
                // which the form test reports (`lack_of_fit`): counted apart.
                if method == Method::CEpd && matches!(est.status, epd_core::FitStatus::LackOfFit(_))
                {
                    c_lack += 1;
                } else if method == Method::CEpd {
                    c_refused += 1;
                } else {
                    fails.push(format!("pose {k} {method}: {}", est.status.reason()));
                }
                continue;
            }
            if method != Method::MlEpd {
                continue;
            }
            let e = errors_against(&est.params, &truth);
            dmean.push(e.d_mean);
            let errs = [e.d_max, e.d_min, e.roll, e.pitch, e.yaw, e.dy, e.dz];
            for (i, err) in errs.iter().enumerate() {
                if let Some(s) = est.sigma[i]
                    && err.abs() > 5.0 * s
                {
                    fails.push(format!(
                        "pose {k} ml-epd parameter {i}: error {err:.3e} = {:.1} σ̂",
                        err.abs() / s
                    ));
                }
            }
        }
    }
    let n = dmean.len() as f64;
    let m = dmean.iter().sum::<f64>() / n;
    let sem = (dmean.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
    eprintln!(
        "{poses} noisy poses: {} failures, {c_refused} C-EPD fits refused, {c_lack} C-EPD \
         walls off their points (lack_of_fit); ML-EPD mean-diameter \
         error {:.4} ± {:.4} mm",
        fails.len(),
        m * 1e3,
        sem * 1e3
    );
    assert!(fails.is_empty(), "{}", fails.join("\n"));
    assert!(c_refused <= poses / 50, "{c_refused} C-EPD fits refused");
    assert!(m.abs() < 3.0 * sem, "ML-EPD bias {m} ± {sem}");
}

/// Deliberately perturbed starts on noisy clouds: 60 random poses off the paper's grid
/// (any roll, pitch/yaw ±15°, offsets up to 25 % of the radius, 16–30", 1–6 % ovality,
/// σ = 0.01–0.05 m range noise). From each of 3 starts per pose — the truth with the
/// diameters off by up to ±10 %, the roll by ±30°, pitch and yaw by ±5°, the offsets by
/// ±10 % of the radius — the bare solver ([`minimize`] on eq. (4), no initial guess, no
/// stages, no statistical stop) minimises the RU-EPD cost, and for ML-EPD then the
/// ML-EPD cost from the RU-EPD minimum, as [`estimate`] does (ML-EPD's cost has poles
/// where the model axis crosses a measured ray: started directly from these starts it
/// settles in a wrong basin on 124 of 180, at 10²–10³ times the cost). Every run must
/// converge, and to the minimum [`estimate`] found from its data-only start: every
/// determined parameter within 0.1 of the estimate's reported 1-σ (the statistical stop
/// of the default options, `stat_tol` = 0.1, ends a fit once its step is below 0.1 σ,
/// and the distance left to the minimum is of the order of that step: measured
/// 0.014 σ̂ for RU-EPD, 0.082 σ̂ for ML-EPD). For ML-EPD the result must also lie within
/// 5 reported standard deviations of the truth (|z| > 5 has probability 6·10⁻⁷).
#[test]
fn perturbed_starts_reach_the_estimate() {
    use epd_core::lm::minimize;
    use epd_core::problem::PipeFit;
    use epd_core::{LmOptions, Residual, canonicalize};
    use nalgebra::SVector;

    let mut rng = common::rng(31337);
    let mut fails = Vec::new();
    let mut worst = [0.0f64; 2];
    let poses = 60;
    for k in 0..poses {
        let od = rng.random_range(16.0..30.0f64);
        let ovality = rng.random_range(0.01..0.06f64);
        let sigma = rng.random_range(0.01..0.05f64);
        let truth = common::random_params(&mut rng, common::id_m(od), ovality, 15.0, 0.25);
        let pts = common::cloud(&truth, 160, 120, 6.0, sigma, 0, 7000 + k as u64);
        let r = 0.5 * truth.d_min;
        let starts: Vec<Params> = (0..3)
            .map(|_| {
                let mut u = |a: f64| rng.random_range(-a..a);
                Params {
                    d_max: truth.d_max * (1.0 + u(0.1)),
                    d_min: truth.d_min * (1.0 + u(0.1)),
                    roll: truth.roll + u(30f64.to_radians()),
                    pitch: truth.pitch + u(5f64.to_radians()),
                    yaw: truth.yaw + u(5f64.to_radians()),
                    dy: truth.dy + u(0.1 * r),
                    dz: truth.dz + u(0.1 * r),
                }
            })
            .collect();
        for (mi, (method, residuals)) in [
            (Method::RuEpd, &[Residual::ErrorBased][..]),
            (Method::MlEpd, &[Residual::ErrorBased, Residual::Range][..]),
        ]
        .into_iter()
        .enumerate()
        {
            let est = match estimate(&pts, method, &EstimateOptions::default()) {
                Ok(e) if e.status.is_converged() => e,
                Ok(e) => {
                    fails.push(format!("pose {k} {method}: {}", e.status.reason()));
                    continue;
                }
                Err(e) => {
                    fails.push(format!("pose {k} {method}: {e}"));
                    continue;
                }
            };
            'start: for (si, start) in starts.iter().enumerate() {
                let mut x = SVector::from(start.to_array());
                for &residual in residuals {
                    let rep = minimize(&PipeFit::new(&pts, residual), x, &LmOptions::default());
                    if !rep.status.is_converged() {
                        fails.push(format!(
                            "pose {k} {method} start {si} {residual:?}: {}",
                            rep.status.reason()
                        ));
                        continue 'start;
                    }
                    x = rep.x;
                }
                let got = canonicalize(&Params::from_array(x.into()));
                let to_est = errors_against(&got, &est.params);
                let to_truth = errors_against(&got, &truth);
                let pick = |e: &epd_core::ParamErrors| {
                    [e.d_max, e.d_min, e.roll, e.pitch, e.yaw, e.dy, e.dz]
                };
                for (i, (de, dt)) in pick(&to_est).iter().zip(pick(&to_truth)).enumerate() {
                    let Some(s) = est.sigma[i] else { continue };
                    worst[mi] = worst[mi].max(de.abs() / s);
                    if de.abs() > 0.1 * s {
                        fails.push(format!(
                            "pose {k} {method} start {si} parameter {i}: {:.3} σ̂ from the estimate",
                            de.abs() / s
                        ));
                    }
                    if method == Method::MlEpd && dt.abs() > 5.0 * s {
                        fails.push(format!(
                            "pose {k} {method} start {si} parameter {i}: {:.1} σ̂ from the truth",
                            dt.abs() / s
                        ));
                    }
                }
            }
        }
    }
    eprintln!(
        "{poses} poses × 3 perturbed starts: largest distance to the estimate {:.4} σ̂ (RU-EPD), \
         {:.4} σ̂ (ML-EPD); {} failures",
        worst[0],
        worst[1],
        fails.len()
    );
    assert!(fails.is_empty(), "{}", fails.join("\n"));
}
