//! Tests of the choice: every parameter determined, no bias, the pilot's witness.

use super::*;
use epd_core::problem::PipeFit;
use epd_core::{Loss, LossScale, Params, errors_against};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel};

/// A full 640 × 480 frame of the paper's 20" pipe (2 % ovality), pose `k`.
fn frame(k: u64, sigma: f64) -> tof_sim::Frame {
    let pipe = Pipe {
        ovality: 0.02,
        ..Pipe::paper_20in()
    };
    let truth = PoseRanges::default().sample(&pipe, 7, k).expect("pose");
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).expect("scene");
    let seed = FrameSeed {
        seed: 7,
        trial: k,
        sweep_index: 0,
    };
    tof_sim::simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::range(sigma),
        Subsample::All,
        seed,
    )
    .expect("frame")
}

fn options() -> EstimateOptions {
    EstimateOptions::default()
        .with_loss(Loss::from_name("cauchy", 0.05).expect("loss"))
        .expect("loss")
        .with_loss_scale(LossScale::Auto)
}

/// (JᵀJ)⁻¹ of the range residual at `truth` over `pts`: the Cramér–Rao covariance
/// over σ².
fn crb(pts: &[[f64; 3]], truth: &Params) -> SMatrix<f64, N_PARAMS, N_PARAMS> {
    let eq = PipeFit::new(pts, Residual::Range)
        .equations_at(truth)
        .expect("inside");
    eq.jtj.try_inverse().expect("every parameter determined")
}

/// The informed choice's pilot witnesses what the frame says: on clean frames the fit
/// of the chosen points agrees with it; moved by more than the two-sided 10⁻³
/// quantile (3.29) of the difference's 1-σ it disagrees, and by less it does not; a
/// fit that did not converge is not judged.
#[test]
fn the_pilot_witnesses_the_fit_of_the_chosen_points() {
    let sampling = Sampling::new(20_000, SamplingMethod::Informed).expect("sampling");
    let z_star = epd_core::fit::form::normal_upper_quantile(WITNESS_ALPHA / 2.0);
    assert!((z_star - 3.2905).abs() < 1e-3, "{z_star}");
    for k in 0..2 {
        let f = frame(k, 0.03);
        let c = choose(&f.measured, &sampling, Method::MlEpd, &options()).expect("chosen");
        let w = c.witness.expect("the pilot has a 1-σ");
        let pts: Vec<[f64; 3]> = c.indices.iter().map(|&i| f.measured[i]).collect();
        let fit = estimate(&pts, Method::MlEpd, &options()).expect("fit");
        assert!(
            !w.disagrees(&fit),
            "clean frame {k}: z = {}",
            w.z(fit.d_mean(), fit.sigma_d_mean().expect("σ"))
        );
        let spread = (fit.sigma_d_mean().expect("σ").powi(2) + w.sigma_m.powi(2)).sqrt();
        for (factor, disagrees) in [(0.9, false), (1.1, true)] {
            let mut moved = fit;
            // The fit put where the witness's z is `factor` × the critical value.
            let shift = w.d_mean_m + factor * z_star * spread - fit.d_mean();
            moved.params.d_max += shift;
            moved.params.d_min += shift;
            assert_eq!(w.disagrees(&moved), disagrees, "frame {k}, {factor} × z*");
            assert!(
                (w.z(moved.d_mean(), fit.sigma_d_mean().expect("σ")) - factor * z_star).abs()
                    < 1e-9
            );
        }
        let mut unfinished = fit;
        unfinished.params.d_max += 10.0 * spread;
        unfinished.params.d_min += 10.0 * spread;
        unfinished.status = epd_core::FitStatus::IterationLimit;
        assert!(
            !w.disagrees(&unfinished),
            "a fit that did not converge is not judged"
        );
    }
}

/// The chosen set's JᵀJ is as well conditioned as the full frame's, parameter by
/// parameter: each parameter's Cramér–Rao bound on the chosen N points is within
/// 1.25 × √(frame/N) of the full frame's (√(frame/N) is what a uniform sample of N
/// gives; measured ≤ 0.8 × for stratified and informed over six poses, example
/// `sampling`), roll included; and the informed choice's bound on the mean diameter
/// is within the 1.5 × the full frame's at N = 20 000 (measured 1.42–1.44).
#[test]
fn every_parameter_stays_determined() {
    let n = 20_000;
    for k in 0..2 {
        let f = frame(k, 0.03);
        let full = crb(&f.exact, &f.truth);
        let uniform_ratio = (f.exact.len() as f64 / n as f64).sqrt();
        let c = SVector::<f64, N_PARAMS>::from(D_MEAN);
        let d_full = (c.transpose() * full * c)[(0, 0)].sqrt();
        for how in [SamplingMethod::Stratified, SamplingMethod::Informed] {
            let s = Sampling::new(n, how).expect("n");
            let chosen = choose(&f.measured, &s, Method::MlEpd, &options()).expect("fewer");
            assert_eq!(chosen.method, how);
            assert_eq!(chosen.indices.len(), n);
            let pts: Vec<[f64; 3]> = chosen.indices.iter().map(|&i| f.exact[i]).collect();
            let sub = crb(&pts, &f.truth);
            for p in 0..N_PARAMS {
                let ratio = (sub[(p, p)] / full[(p, p)]).sqrt() / uniform_ratio;
                assert!(
                    ratio < 1.25,
                    "{how} pose {k}: {} bound {ratio:.2} × a uniform sample's",
                    epd_core::PARAM_NAMES[p]
                );
            }
            if how == SamplingMethod::Informed {
                let d = (c.transpose() * sub * c)[(0, 0)].sqrt() / d_full;
                assert!(d < 1.5, "pose {k}: mean-diameter bound {d:.3} × full");
            }
        }
    }
}

/// The same frame and seed give the same points; another seed other points; the
/// indices ascend and are valid pixels only.
#[test]
fn deterministic_for_a_seed() {
    let mut f = frame(3, 0.03);
    // Invalid pixels as a camera writes them: never chosen.
    for i in (0..f.measured.len()).step_by(7) {
        f.measured[i] = [0.0; 3];
    }
    f.measured[1] = [f64::NAN; 3];
    for how in SamplingMethod::ALL {
        let s = Sampling::new(5000, how).expect("n");
        let a = choose(&f.measured, &s, Method::MlEpd, &options()).expect("fewer");
        let b = choose(&f.measured, &s, Method::MlEpd, &options()).expect("fewer");
        assert_eq!(a, b, "{how}");
        let other = choose(&f.measured, &s.with_seed(99), Method::MlEpd, &options());
        assert_ne!(Some(&a), other.as_ref(), "{how}");
        assert!(a.indices.windows(2).all(|w| w[0] < w[1]), "{how}");
        assert!(
            a.indices.iter().all(|&i| usable(&f.measured[i])),
            "{how}: an invalid pixel chosen"
        );
    }
}

/// No more valid points than N: the frame is used whole (`None`), whatever the method.
#[test]
fn few_points_are_kept_whole() {
    let mut pts: Vec<[f64; 3]> = (0..1500)
        .map(|i| [1.0 + i as f64 * 1e-3, 0.2, 0.1])
        .collect();
    pts.extend([[0.0; 3]; 600]);
    for how in SamplingMethod::ALL {
        let s = Sampling::new(1500, how).expect("n");
        assert_eq!(choose(&pts, &s, Method::MlEpd, &options()), None, "{how}");
    }
    let s = Sampling::new(1499, SamplingMethod::Uniform).expect("n");
    let c = choose(&pts, &s, Method::MlEpd, &options()).expect("one fewer");
    assert_eq!(c.indices.len(), 1499);
}

/// Too few points asked for, or an unknown method: a message naming the limit.
#[test]
fn bad_settings_say_what_to_do() {
    let e = Sampling::new(MIN_MAX_POINTS - 1, SamplingMethod::Informed).unwrap_err();
    assert_eq!(e, SamplingError::TooFew(MIN_MAX_POINTS - 1));
    assert!(e.to_string().contains("at least 1000"), "{e}");
    let e = "best".parse::<SamplingMethod>().unwrap_err();
    assert!(
        e.to_string().contains("uniform, stratified, informed"),
        "{e}"
    );
    for m in SamplingMethod::ALL {
        assert_eq!(m.name().parse::<SamplingMethod>(), Ok(m));
    }
}

/// Equal shares per stratum, the small strata giving all they have.
#[test]
fn allocation_fills_the_small_strata_first() {
    assert_eq!(allocate(&[10, 1, 10, 0], 9), vec![4, 1, 4, 0]);
    assert_eq!(allocate(&[2, 2], 10), vec![2, 2]);
    assert_eq!(allocate(&[5, 5, 5], 3), vec![1, 1, 1]);
}

/// The informed choice biases nothing: over 24 frames (σ = 0.03 m, the paper's poses)
/// the mean error of the mean diameter fitted on its 20 000 points is within three
/// of its standard errors (s/√24, s the errors' spread) of zero: a test at the
/// 0.3 % level under no bias (the frames are seeded, so it gives the same verdict on
/// every run).
#[test]
fn informed_choice_is_unbiased() {
    let frames = 24;
    let errors: Vec<f64> = (0..frames)
        .map(|k| {
            let f = frame(100 + k, 0.03);
            let s = Sampling::new(20_000, SamplingMethod::Informed).expect("n");
            let c = choose(&f.measured, &s, Method::MlEpd, &options()).expect("fewer");
            let pts: Vec<[f64; 3]> = c.indices.iter().map(|&i| f.measured[i]).collect();
            let e = estimate(&pts, Method::MlEpd, &options()).expect("estimate");
            assert!(e.status.is_converged(), "frame {k}");
            errors_against(&e.params, &f.truth).d_mean
        })
        .collect();
    let n = errors.len() as f64;
    let mean = errors.iter().sum::<f64>() / n;
    let sd = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let se = sd / n.sqrt();
    assert!(
        mean.abs() <= 3.0 * se,
        "mean error {:.4} mm, standard error {:.4} mm",
        mean * 1e3,
        se * 1e3
    );
}
