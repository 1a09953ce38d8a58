//! Honest numbers off the paper's grid: the range gate on the model range keeps the
//! diameters unbiased where the measured-range gate does not, and under a robust loss
//! the sandwich 1-σ covers the errors as a 1-σ should.

mod common;

use epd_core::{
    Estimate, EstimateOptions, Loss, LossScale, Method, Params, errors_against, estimate,
};
use rand::RngExt;

/// Counts, per parameter, the estimates with a 1-σ (`determined`) and those whose
/// ±1.96σ̂ holds the truth (`covered`).
fn tally(est: &Estimate, truth: &Params, covered: &mut [usize; 7], determined: &mut [usize; 7]) {
    let e = errors_against(&est.params, truth);
    let errs = [e.d_max, e.d_min, e.roll, e.pitch, e.yaw, e.dy, e.dz];
    for i in 0..7 {
        if let Some(s) = est.sigma[i] {
            determined[i] += 1;
            covered[i] += usize::from(errs[i].abs() <= 1.96 * s);
        }
    }
}

/// Full 160×120 frames within 6 m, σ = 0.03 m, 20" pipe, 24 poses, ML-EPD, gate
/// [0.5, 2] m. The measured-range gate biases the mean diameter by ≈ +1 mm
/// (`results/range_gate_naive`); the model-range gate by less than its standard error
/// (`results/range_gate_model`: +0.004 ± 0.004 mm over 100 full Helios2 frames).
#[test]
fn the_model_range_gate_is_unbiased_where_the_measured_one_is_not() {
    let sigma = 0.03;
    let (lo, hi) = (0.5, 2.0);
    let mut rng = common::rng(17);
    let poses = 24;
    let gated = EstimateOptions::default().with_range_gate(lo, hi).unwrap();
    let (mut naive, mut model) = (Vec::new(), Vec::new());
    for k in 0..poses {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 5.0, 0.2);
        let pts = common::cloud(&truth, 320, 240, 6.0, sigma, 0, 300 + k);
        let measured: Vec<[f64; 3]> = pts
            .iter()
            .filter(|p| (lo..=hi).contains(&(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()))
            .copied()
            .collect();
        let a = estimate(&measured, Method::MlEpd, &EstimateOptions::default()).unwrap();
        let b = estimate(&pts, Method::MlEpd, &gated).unwrap();
        assert!(a.status.is_converged() && b.status.is_converged());
        assert_eq!(b.n_points + b.n_out_of_gate, pts.len());
        naive.push(errors_against(&a.params, &truth).d_mean * 1e3);
        model.push(errors_against(&b.params, &truth).d_mean * 1e3);
    }
    let stats = |v: &[f64]| {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        (m, sd / n.sqrt())
    };
    let (mn, sn) = stats(&naive);
    let (mm, sm) = stats(&model);
    eprintln!(
        "mean-diameter bias: measured gate {mn:.3} ± {sn:.3} mm, model gate {mm:.3} ± {sm:.3} mm"
    );
    // The naive bias is many of its standard errors; the model gate's is within 3 of its
    // own (a 0.1 mm bias would be ≈ 4 here).
    assert!(mn > 0.5 && mn > 5.0 * sn, "{mn} ± {sn}");
    assert!(mm.abs() < 3.0 * sm + 0.02, "{mm} ± {sm}");
}

/// 400 clouds (10⁴ points, σ = 0.03 m, 3 % ovality) with 5 % of the ranges replaced by
/// wrong ones (× U(0.5, 1.5)), ML-EPD with the Cauchy loss scaled by the data: each
/// parameter's error lies within 1.96 reported (sandwich) σ in 95 % of the clouds.
///
/// The number covered out of n is binomial: at a true coverage of 0.95 the observed
/// fraction has standard error √(0.95·0.05/n) = 0.0109 for n = 400, and the test
/// accepts 0.95 ± 4 of them, [0.906, 0.994] (363…397 clouds). Exact binomial tails:
/// P(X ≤ 362) = 1.4·10⁻⁴, P(X ≥ 398) = 3·10⁻⁷, so ≤ 10⁻³ for the 7 parameters. For
/// normal errors the bounds are a 1-σ 14 % too small (coverage 2Φ(1.96·0.855) − 1 =
/// 0.906) or 39 % too large (0.994); the old bound, 0.83 of 60 clouds, let one 30 %
/// too small through.
///
/// Measured over 1000 clouds (`EPD_TEST_CLOUDS=1000 cargo test -p epd-core --test
/// trust -- sandwich --nocapture`): covered 938, 943, 954, 962, 949, 944, 949 (Dmax,
/// Dmin, roll, pitch, yaw, δy, δz), each within 1.8 standard errors (0.0069) of 0.95:
/// the sandwich 1-σ does not under-cover. Every parameter's 1-σ was given in every
/// cloud (the 3 % ovality determines the roll).
#[test]
fn sandwich_sigmas_cover_the_errors_under_a_robust_loss() {
    let opts = EstimateOptions::default()
        .with_loss(Loss::Cauchy { scale: 0.05 })
        .unwrap()
        .with_loss_scale(LossScale::Auto);
    let mut rng = common::rng(23);
    let clouds: u64 = std::env::var("EPD_TEST_CLOUDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(400);
    let mut covered = [0usize; 7];
    let mut determined = [0usize; 7];
    for k in 0..clouds {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.03, 5.0, 0.2);
        let mut pts = common::cloud(&truth, 320, 240, 6.0, 0.03, 10_000, 700 + k);
        for p in pts.iter_mut() {
            if rng.random::<f64>() < 0.05 {
                let f = rng.random_range(0.5..1.5);
                *p = p.map(|v| v * f);
            }
        }
        let est = estimate(&pts, Method::MlEpd, &opts).unwrap();
        assert!(est.status.is_converged(), "{:?}", est.status);
        tally(&est, &truth, &mut covered, &mut determined);
    }
    eprintln!("covered {covered:?} of {determined:?}");
    let se = (0.95 * 0.05 / clouds as f64).sqrt();
    for i in 0..7 {
        assert_eq!(
            determined[i], clouds as usize,
            "parameter {i}: {determined:?}"
        );
        let c = covered[i] as f64 / determined[i] as f64;
        assert!(
            (c - 0.95).abs() <= 4.0 * se,
            "parameter {i}: coverage {c}, 0.95 ± {:.4}",
            4.0 * se
        );
    }
}

/// Range noise growing as the square of the range, σ(r) = 0.02 m·(r/1 m)² (the
/// `sigma ~ r^2` model of `scenarios/noise_models.toml`; a ToF camera's return falls as
/// r⁻²): the far, noisy points lie past the Cauchy loss's knee, where the cost's
/// curvature is negative. The sandwich's bread takes the exact curvature
/// (`problem::Curvature::Exact`); with the solver's clipped one it overstated the
/// information and the pose's ±1.96σ̂ covered 0.745–0.825 (the harness, 200 full frames).
/// Here 200 clouds of 320 × 240 rays within 6 m, 20" pipe, ML-EPD with the defaults'
/// loss: every parameter covered within 4 binomial standard errors of 0.95
/// (√(0.95·0.05/200) = 0.0154). Measured (`cargo test --release -p epd-core --test trust
/// range_dependent -- --nocapture`): 192, 195, 199, 186, 193, 185, 187 of 200; with the
/// clipped bread (the call in `covariance.rs` switched) 183, 189, 193, 158, 168, 161,
/// 156 — pitch, yaw, δy and δz below the band. At 160 × 120 rays the exact bread still
/// covers δy in only 0.89 (fewer points per cell): not claimed here.
#[test]
fn sandwich_sigmas_cover_the_errors_under_range_dependent_noise() {
    use rand_distr::{Distribution, Normal};
    let opts = EstimateOptions::default()
        .with_loss(Loss::Cauchy { scale: 0.05 })
        .unwrap()
        .with_loss_scale(LossScale::Auto);
    let mut rng = common::rng(31);
    let clouds = 200usize;
    let rays = common::rays(320, 240);
    let unit = Normal::new(0.0, 1.0).unwrap();
    let mut covered = [0usize; 7];
    let mut determined = [0usize; 7];
    for _ in 0..clouds {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 5.0, 0.2);
        let pts: Vec<[f64; 3]> = rays
            .iter()
            .filter_map(|d| {
                let r = common::range_to_wall(&truth, d)?;
                (r <= 6.0).then(|| {
                    let m = r + 0.02 * r * r * unit.sample(&mut rng);
                    [d.x * m, d.y * m, d.z * m]
                })
            })
            .collect();
        let est = estimate(&pts, Method::MlEpd, &opts).unwrap();
        if !est.status.is_converged() {
            continue;
        }
        tally(&est, &truth, &mut covered, &mut determined);
    }
    eprintln!("covered {covered:?} of {determined:?}");
    for i in 0..7 {
        let n = determined[i] as f64;
        assert!(n >= 0.95 * clouds as f64, "parameter {i}: {determined:?}");
        let se = (0.95 * 0.05 / n).sqrt();
        let c = covered[i] as f64 / n;
        assert!(
            (c - 0.95).abs() <= 4.0 * se,
            "parameter {i}: coverage {c}, 0.95 ± {:.4}",
            4.0 * se
        );
    }
}

/// Small clouds: ν = N − 7 residual degrees of freedom below
/// `MIN_UNCERTAINTY_DOF` (= 3) are refused with that reason, never answered; at ν = 3 the
/// reason is not given, and over 200 random 12-point subsets (ν = 5) of noisy frames the
/// converged answers lie within 5 reported σ at the rate Student's t with 5 degrees of
/// freedom allows: P(|t₅| > 5·1.96/t₀.₉₇₅(5)) = P(|t₅| > 3.81) = 1.2 %, so more than 10 of
/// 200 (expected 2.5, standard deviation 1.6) would say the 1-σ does not hold. And the
/// test must not pass by refusing: at least 90 % are answered (180 of 200). Measured 198
/// of 200 (`cargo test --release -p epd-core --test trust small_clouds -- --nocapture`);
/// at that rate the share answered has a standard error of √(0.99·0.01/200) = 0.7 %, so
/// the floor lies 13 standard errors below it, and a check that refused one small cloud
/// in ten would fail it.
#[test]
fn small_clouds_get_a_one_sigma_that_holds_or_are_refused() {
    use epd_core::FitStatus;
    use epd_core::check::{Implausible, MIN_UNCERTAINTY_DOF};
    let opts = EstimateOptions::default();
    let mut rng = common::rng(23);
    let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 5.0, 0.2);
    let nine = common::cloud(&truth, 160, 120, 6.0, 0.02, 9, 1);
    let e = estimate(&nine, Method::MlEpd, &opts).unwrap();
    assert!(
        matches!(
            e.status,
            FitStatus::Implausible(Implausible::TooFewForUncertainty { points: 9, dof: 2 })
        ),
        "{:?}",
        e.status
    );
    assert!(e.status.reason().contains(&MIN_UNCERTAINTY_DOF.to_string()));
    let ten = common::cloud(&truth, 160, 120, 6.0, 0.02, 10, 2);
    let e = estimate(&ten, Method::MlEpd, &opts).unwrap();
    assert!(
        !matches!(
            e.status,
            FitStatus::Implausible(Implausible::TooFewForUncertainty { .. })
        ),
        "{:?}",
        e.status
    );
    let mut off = 0;
    let mut converged = 0;
    for k in 0..200u64 {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 5.0, 0.2);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.02, 12, 100 + k);
        let Ok(e) = estimate(&pts, Method::MlEpd, &opts) else {
            continue;
        };
        if !e.status.is_converged() {
            continue;
        }
        converged += 1;
        let err = errors_against(&e.params, &truth);
        let far = |x: f64, s: Option<f64>| s.is_none_or(|s| x.abs() > 5.0 * s);
        if far(err.d_max, e.sigma[0]) || far(err.d_min, e.sigma[1]) {
            off += 1;
        }
    }
    eprintln!("{converged} of 200 converged, {off} more than 5σ̂ off");
    assert!(converged >= 180, "only {converged} of 200 converged");
    assert!(off <= 10, "{off} of {converged} more than 5σ̂ off");
}

/// A range error shared along the pipe: every range t read as t + A·sin(2πt/λ + φ), the
/// wiggling of a ToF camera's phase unwrapping (A = 6 mm, λ = 0.7 m, φ uniform per frame),
/// over independent noise σ = 0.02 m; full 160×120 frames of a 20" pipe within 6 m,
/// ML-EPD with the defaults. The wiggle is the same at every clock angle of a slice, so
/// cells are not independent; the 1-σ must still cover the mean diameter's error.
///
/// Covered counts out of n frames are binomial: at the nominal 0.95 the observed share
/// has standard error √(0.95·0.05/n) (0.0154 at n = 200) and the test fails below
/// 0.95 − 4 SE = 0.888, which a true coverage of 0.95 does with probability < 10⁻⁴ and
/// one of 0.85 passes with probability < 10⁻². Measured (`cargo test --release -p
/// epd-core --test trust -- shared_range --nocapture`, 200 frames): before the
/// covariance of the slices' shared offsets (`add_shared_offsets`) 176, 181 and 135 of
/// 200 covered (Dmax, Dmin, mean diameter; RMS of err/σ̂ 1.26, 1.17, 1.70); with it 200
/// of 200 each, RMS of err/σ̂ 0.69, 0.63, 0.62: a 1-σ about 1.5 times too wide for this
/// wiggle, whose sign alternates along the pipe (see `shared_offset_cov`).
#[test]
fn shared_range_errors_are_covered_by_the_one_sigma() {
    let frames: u64 = std::env::var("EPD_TEST_CLOUDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    let (amplitude, wavelength) = (0.006, 0.7);
    let mut rng = common::rng(41);
    let mut covered = [0usize; 3];
    let mut z2 = [0.0f64; 3];
    let mut err2 = [0.0f64; 3];
    let mut answered = 0usize;
    for k in 0..frames {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.02, 5.0, 0.2);
        let phase = rng.random_range(0.0..std::f64::consts::TAU);
        let pts: Vec<[f64; 3]> = common::cloud(&truth, 160, 120, 6.0, 0.02, 0, 900 + k)
            .into_iter()
            .map(|p| {
                let t = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let f =
                    1.0 + amplitude * (std::f64::consts::TAU * t / wavelength + phase).sin() / t;
                p.map(|v| v * f)
            })
            .collect();
        let est = estimate(&pts, Method::MlEpd, &EstimateOptions::default()).unwrap();
        if !est.status.is_converged() {
            continue;
        }
        answered += 1;
        let e = errors_against(&est.params, &truth);
        let sigmas = [est.sigma[0], est.sigma[1], est.sigma_d_mean()];
        for (i, err) in [e.d_max, e.d_min, e.d_mean].into_iter().enumerate() {
            covered[i] += usize::from(sigmas[i].is_some_and(|s| err.abs() <= 1.96 * s));
            if let Some(s) = sigmas[i] {
                z2[i] += (err / s).powi(2);
                err2[i] += err * err;
            }
        }
    }
    eprintln!(
        "wiggle {amplitude} m: {answered} of {frames} answered, covered {covered:?}, rms z {:?}, rms err mm {:?}",
        z2.map(|v| (v / answered as f64).sqrt()),
        err2.map(|v| (v / answered as f64).sqrt() * 1e3)
    );
    let floor = 0.95 - 4.0 * (0.95 * 0.05 / answered as f64).sqrt();
    // A wiggle is a camera's own error, not a defect of the pipe: at most 1 % of such
    // frames refused (issue 22's rate for good frames), with the binomial's 4 SE.
    let n = frames as f64;
    assert!(
        answered as f64 >= 0.99 * n - 4.0 * (n * 0.01 * 0.99).sqrt(),
        "answered {answered} of {frames}"
    );
    for (i, c) in covered.iter().enumerate() {
        let share = *c as f64 / answered as f64;
        assert!(
            share >= floor,
            "parameter {i}: coverage {share:.3} < {floor:.3}"
        );
    }
}

/// Round pipes: the roll is undetermined, and the pitch, yaw, δy and δz that go with the
/// reported roll have a 1-σ that covers their errors as a 1-σ should. A round pipe's wall
/// is the same after any turn about its axis, so its truth is re-expressed at the
/// estimate's roll before the errors are taken: the turn R' = Rx(φ)·R, δ' = Rx(φ)·δ,
/// written here with nalgebra's own rotations and Euler angles (not the library's
/// `turn_about_axis`), with φ found by the fixed-point iteration φ ← φ + (θx − θx(φ)),
/// which converges here since dθx/dφ = cos θz / cos θy lies within 1 % of 1 for tilts of
/// 5° (checked to 10⁻⁹ below).
///
/// 400 clouds (10⁴ points, σ = 0.03 m, 20", ovality 0, pitch and yaw within ±5°, offsets
/// within 20 % of the radius): the same binomial band as the sandwich test above,
/// 0.95 ± 4·0.0109. With the 1-σ of Σ taken one by one (before this test), pitch, yaw
/// and the offsets carried the whole turn (2°, 44 mm on a 20" frame) and every error was
/// covered, a coverage of 1.0 outside the band.
#[test]
fn round_pipes_pose_sigmas_hold_at_the_reported_roll() {
    use nalgebra::{Rotation3, Vector3};
    let opts = EstimateOptions::default();
    let mut rng = common::rng(31);
    let clouds: u64 = std::env::var("EPD_TEST_CLOUDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(400);
    // The truth turned about its axis by φ: (roll, pitch, yaw, δy, δz).
    let turned = |t: &epd_core::Params, phi: f64| -> [f64; 5] {
        let r = Rotation3::from_axis_angle(&Vector3::x_axis(), phi) * t.rotation();
        let (roll, pitch, yaw) = r.euler_angles();
        let (s, c) = phi.sin_cos();
        [roll, pitch, yaw, c * t.dy - s * t.dz, s * t.dy + c * t.dz]
    };
    let wrap = |a: f64| {
        (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
    };
    let (mut covered, mut undetermined) = ([0usize; 4], 0usize);
    let mut widest = [0.0f64; 4];
    for k in 0..clouds {
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.0, 5.0, 0.2);
        let pts = common::cloud(&truth, 320, 240, 6.0, 0.03, 10_000, 900 + k);
        let est = estimate(&pts, Method::MlEpd, &opts).unwrap();
        assert!(est.status.is_converged(), "{:?}", est.status);
        if est.roll_determined {
            continue;
        }
        undetermined += 1;
        let mut phi = wrap(est.params.roll - truth.roll);
        for _ in 0..20 {
            phi += wrap(est.params.roll - turned(&truth, phi)[0]);
        }
        let t = turned(&truth, phi);
        assert!(wrap(t[0] - est.params.roll).abs() < 1e-9);
        let e = [
            wrap(est.params.pitch - t[1]),
            wrap(est.params.yaw - t[2]),
            est.params.dy - t[3],
            est.params.dz - t[4],
        ];
        for i in 0..4 {
            let s = est.sigma[3 + i].expect("pitch, yaw and the offsets are determined");
            widest[i] = widest[i].max(s);
            covered[i] += usize::from(e[i].abs() <= 1.96 * s);
        }
    }
    eprintln!(
        "round pipes: {undetermined} of {clouds} with the roll undetermined; covered \
         {covered:?}; widest 1-σ pitch {:.3}°, yaw {:.3}°, δy {:.2} mm, δz {:.2} mm",
        widest[0].to_degrees(),
        widest[1].to_degrees(),
        widest[2] * 1e3,
        widest[3] * 1e3
    );
    // A round pipe's ovality is significant at 3σ in 0.13 % of frames: at most a few.
    assert!(
        undetermined as f64 >= 0.98 * clouds as f64,
        "{undetermined}"
    );
    let se = (0.95 * 0.05 / undetermined as f64).sqrt();
    for (i, c) in covered.iter().enumerate() {
        let c = *c as f64 / undetermined as f64;
        assert!(
            (c - 0.95).abs() <= 4.0 * se,
            "pose parameter {i}: coverage {c}, 0.95 ± {:.4}",
            4.0 * se
        );
    }
}
