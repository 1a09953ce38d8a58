//! Per-point weights: `estimate_weighted` (sᵢ = σ̃/σᵢ on each residual and gradient) and
//! `cramer_rao_bound_weighted`.

mod common;

use epd_core::lm::NormalEquations;
use epd_core::problem::PipeFit;
use epd_core::residual::{Geometry, Residual};
use epd_core::{
    EpdError, Estimate, EstimateOptions, Loss, LossScale, Method, N_PARAMS, Params,
    cramer_rao_bound, cramer_rao_bound_weighted, errors_against, estimate, estimate_weighted,
};
use proptest::prelude::*;
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};

fn rel_close(a: f64, b: f64, tol: f64) -> bool {
    a == b || (a - b).abs() <= tol * a.abs().max(b.abs())
}

fn same_estimate(a: &Estimate, b: &Estimate, tol: f64, what: &str) {
    for (i, (x, y)) in a
        .params
        .to_array()
        .iter()
        .zip(b.params.to_array())
        .enumerate()
    {
        assert!(rel_close(*x, y, tol), "{what}: parameter {i}: {x} vs {y}");
    }
    for i in 0..N_PARAMS {
        match (a.sigma[i], b.sigma[i]) {
            (Some(x), Some(y)) => assert!(rel_close(x, y, tol), "{what}: σ {i}: {x} vs {y}"),
            (x, y) => assert_eq!(x, y, "{what}: σ {i}"),
        }
    }
    assert!(rel_close(a.cost, b.cost, tol), "{what}: cost");
    assert_eq!(a.status, b.status, "{what}");
    assert_eq!(
        (a.n_points, a.n_dropped, a.n_out_of_gate, a.iterations),
        (b.n_points, b.n_dropped, b.n_out_of_gate, b.iterations),
        "{what}"
    );
}

/// (a) Equal σᵢ give `estimate`'s result, for every method, with and without the
/// subsample stage, the range gate and a data-scaled robust loss.
#[test]
fn equal_weights_give_the_unweighted_estimate() {
    let truth = common::random_params(&mut common::rng(3), common::id_m(20.0), 0.02, 8.0, 0.2);
    let options = [
        EstimateOptions::default(),
        EstimateOptions::default()
            .with_range_gate(0.5, 3.0)
            .unwrap(),
        EstimateOptions::default()
            .with_loss(Loss::Huber { scale: 0.02 })
            .unwrap()
            .with_loss_scale(LossScale::Auto),
    ];
    for (n, seed) in [(3_000usize, 1u64), (0, 2)] {
        let pts = common::cloud(&truth, 320, 240, 6.0, 0.02, n, seed);
        let sigma = vec![0.02; pts.len()];
        for (o, opts) in options.iter().enumerate() {
            for method in Method::ALL {
                let a = estimate(&pts, method, opts).unwrap();
                let b = estimate_weighted(&pts, &sigma, method, opts).unwrap();
                same_estimate(
                    &a,
                    &b,
                    1e-12,
                    &format!("{method} n={} options {o}", pts.len()),
                );
            }
        }
    }
}

/// The normal equations of a weighted fit, point by point: the reference for the SIMD
/// kernel.
fn reference(
    pts: &[[f64; 3]],
    s: &[f64],
    kind: Residual,
    loss: Loss,
    beta: &Params,
) -> (NormalEquations<N_PARAMS>, f64) {
    let geom = Geometry::new(beta).unwrap();
    let mut eq = NormalEquations::zero();
    let mut magnitude = 0.0;
    for (p, si) in pts.iter().zip(s) {
        let (r, g) = geom.residual_and_gradient(kind, p);
        let (r, g) = (r * si, g.map(|v| v * si));
        let (c, wg, wh) = loss.cost_and_weights(r);
        eq.cost += c;
        for a in 0..N_PARAMS {
            eq.jtr[a] += wg * g[a] * r;
            for b in 0..N_PARAMS {
                eq.jtj[(a, b)] += wh * g[a] * g[b];
            }
        }
        magnitude += c.abs() + g.iter().map(|v| v * v).sum::<f64>() * (1.0 + r.abs());
    }
    (eq, magnitude)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// (b) The weighted kernel (4 lanes, 4096-point chunks in parallel, remainders)
    /// equals the plain per-point sums Σ c(sᵢrᵢ), Σ w_H (sᵢgᵢ)(sᵢgᵢ)ᵀ, Σ w_g (sᵢgᵢ)(sᵢrᵢ)
    /// on random points and weights (up to rounding: 1e-12 of the terms' magnitude).
    #[test]
    fn weighted_kernel_equals_reference(
        seed in 0u64..1_000_000,
        n in 1usize..12_000,
        kind_i in 0usize..3,
        loss_i in 0usize..3,
    ) {
        let mut rng = common::rng(seed);
        let truth = common::random_params(&mut rng, common::id_m(20.0), 0.03, 10.0, 0.2);
        let pts = common::cloud(&truth, 160, 120, 6.0, 0.02, n, seed);
        let s: Vec<f64> = (0..pts.len()).map(|_| 10f64.powf(rng.random_range(-1.0..1.0))).collect();
        let kind = [Residual::Canonical, Residual::ErrorBased, Residual::Range][kind_i];
        let loss = [Loss::Squared, Loss::Huber { scale: 0.01 }, Loss::Cauchy { scale: 0.01 }][loss_i];
        // Off the truth, so that the residuals are not all noise.
        let beta = Params { d_max: truth.d_max * 1.01, roll: truth.roll + 0.05, dy: truth.dy + 0.01, ..truth };
        let got = PipeFit::new(&pts, kind).with_loss(loss).with_scales(Some(&s)).equations_at(&beta).unwrap();
        let (want, mag) = reference(&pts, &s, kind, loss, &beta);
        let tol = 1e-12 * mag + 1e-300;
        prop_assert_eq!(got.n_residuals, pts.len());
        prop_assert!((got.cost - want.cost).abs() <= tol, "cost {} vs {}", got.cost, want.cost);
        for a in 0..N_PARAMS {
            prop_assert!((got.jtr[a] - want.jtr[a]).abs() <= tol, "jtr {a}");
            for b in 0..N_PARAMS {
                prop_assert!((got.jtj[(a, b)] - want.jtj[(a, b)]).abs() <= tol, "jtj {a} {b}");
            }
        }
        // The sandwich of the same scaled residuals.
        let sw = PipeFit::new(&pts, kind).with_loss(loss).with_scales(Some(&s)).sandwich_at(&beta).unwrap();
        for a in 0..N_PARAMS {
            for b in 0..N_PARAMS {
                prop_assert!((sw.bread[(a, b)] - want.jtj[(a, b)]).abs() <= tol, "bread {a} {b}");
            }
        }
        // Held parameters: zero rows and columns, the rest untouched.
        let mut fixed = [false; N_PARAMS];
        fixed[(seed % 7) as usize] = true;
        let held = PipeFit::new(&pts, kind).with_loss(loss).with_scales(Some(&s)).with_fixed(fixed).equations_at(&beta).unwrap();
        for a in 0..N_PARAMS {
            let want_g = if fixed[a] { 0.0 } else { got.jtr[a] };
            prop_assert_eq!(held.jtr[a], want_g);
            for b in 0..N_PARAMS {
                let want_h = if fixed[a] || fixed[b] { 0.0 } else { got.jtj[(a, b)] };
                prop_assert_eq!(held.jtj[(a, b)], want_h);
            }
        }
    }
}

/// A heteroscedastic frame: the noise-free wall points of `truth` (160×120 rays within
/// 4 m) and σᵢ = 0.005·rangeᵢ^1.5·kᵢ (m) with kᵢ log-uniform in [0.5, 2] (the amplitude's
/// share), fixed per point.
fn heteroscedastic_frame(truth: &Params, seed: u64) -> (Vec<[f64; 3]>, Vec<f64>) {
    let pts = common::cloud(truth, 160, 120, 4.0, 0.0, 0, seed);
    let mut rng = common::rng(seed ^ 0x5eed);
    let sigma = pts
        .iter()
        .map(|p| {
            let range = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            0.005 * range.powf(1.5) * 2f64.powf(rng.random_range(-1.0..1.0))
        })
        .collect();
    (pts, sigma)
}

/// The frame with N(0, σᵢ²) noise along each ray.
fn noisy(pts: &[[f64; 3]], sigma: &[f64], seed: u64) -> Vec<[f64; 3]> {
    let mut rng = common::rng(seed);
    pts.iter()
        .zip(sigma)
        .map(|(p, s)| {
            let range = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let e: f64 = StandardNormal.sample(&mut rng);
            let f = (range + s * e) / range;
            [p[0] * f, p[1] * f, p[2] * f]
        })
        .collect()
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (
        m,
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt(),
    )
}

/// (c) 200 noise draws of one heteroscedastic frame (20" pipe, 3 % ovality, a random
/// pose with tilt up to 8°, σᵢ spread ≥ 8×): the weighted ML-EPD's empirical standard
/// deviation of Dmax and Dmin is the weighted Cramér–Rao bound within its Monte-Carlo
/// tolerance, smaller than the unweighted ML-EPD's, and its mean error is within 4
/// standard errors of zero.
///
/// Tolerance: the sample standard deviation of 200 draws has a relative standard error
/// √(1/(2·199)) = 0.050; 3 of them, plus 0.02 for what separates the estimator from the
/// bound at this noise: the solver stops once the remaining step is below 0.1 standard
/// deviations (the step is taken, so the stop adds well under √(1 + 0.1²) − 1 = 0.5 %),
/// and the bound is the first-order (asymptotic) variance, whose O(σ²/R²) corrections are
/// below 1 % here (σᵢ/R ≤ 0.2 at the farthest, grazing points, whose radial error is
/// ≤ 0.03·σᵢ).
#[test]
fn weighted_ml_epd_attains_the_weighted_cramer_rao_bound() {
    let truth = common::random_params(&mut common::rng(808), common::id_m(20.0), 0.03, 8.0, 0.2);
    let (pts, sigma) = heteroscedastic_frame(&truth, 1);
    let (lo, hi) = sigma
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &s| (a.min(s), b.max(s)));
    assert!(hi / lo >= 8.0, "σ spread {}", hi / lo);
    let crb = cramer_rao_bound_weighted(&pts, &sigma, &truth).unwrap();
    let (crb_max, crb_min) = (crb[0].unwrap(), crb[1].unwrap());
    let draws = 200;
    let opts = EstimateOptions::default();
    let (mut w_max, mut w_min, mut u_max, mut u_min) = (vec![], vec![], vec![], vec![]);
    for seed in 0..draws {
        let meas = noisy(&pts, &sigma, 10_000 + seed);
        let w = estimate_weighted(&meas, &sigma, Method::MlEpd, &opts).unwrap();
        let u = estimate(&meas, Method::MlEpd, &opts).unwrap();
        assert!(
            w.status.is_converged() && u.status.is_converged(),
            "draw {seed}"
        );
        let (ew, eu) = (
            errors_against(&w.params, &truth),
            errors_against(&u.params, &truth),
        );
        w_max.push(ew.d_max);
        w_min.push(ew.d_min);
        u_max.push(eu.d_max);
        u_min.push(eu.d_min);
    }
    let tol = 3.0 * (1.0 / (2.0 * (draws as f64 - 1.0))).sqrt() + 0.02;
    for (name, w, u, bound) in [
        ("d_max", &w_max, &u_max, crb_max),
        ("d_min", &w_min, &u_min, crb_min),
    ] {
        let (wm, wsd) = mean_sd(w);
        let (um, usd) = mean_sd(u);
        eprintln!(
            "{name}: σᵢ spread {:.0}×, {} points; weighted ML-EPD mean {:+.4} mm, sd {:.4} mm = \
             {:.3} × CRB {:.4} mm; unweighted mean {:+.4} mm, sd {:.4} mm = {:.3} × the weighted sd",
            hi / lo,
            pts.len(),
            wm * 1e3,
            wsd * 1e3,
            wsd / bound,
            bound * 1e3,
            um * 1e3,
            usd * 1e3,
            usd / wsd
        );
        assert!(
            (wsd / bound - 1.0).abs() <= tol,
            "{name}: sd/CRB = {}",
            wsd / bound
        );
        assert!(usd > wsd, "{name}: unweighted sd {usd} ≤ weighted {wsd}");
        let sem = wsd / (draws as f64).sqrt();
        assert!(wm.abs() < 4.0 * sem, "{name}: mean error {wm} ± {sem}");
    }
}

/// (d) Held diameters with weights: on the noise-free frame the pose is recovered to
/// 1e-6 and the diameters are returned bit for bit; on noisy draws the weighted pose is
/// within 5 of its reported standard deviations of the truth, and its roll's standard
/// deviation is smaller than with the diameters free.
#[test]
fn held_diameters_with_weights() {
    let truth = common::random_params(&mut common::rng(909), common::id_m(24.0), 0.03, 8.0, 0.2);
    let (pts, sigma) = heteroscedastic_frame(&truth, 2);
    let held = EstimateOptions::default()
        .with_fixed_diameters(truth.d_max, truth.d_min)
        .unwrap();
    for method in Method::ALL {
        let est = estimate_weighted(&pts, &sigma, method, &held).unwrap();
        assert!(est.status.is_converged(), "{method}: {:?}", est.status);
        assert_eq!(est.params.d_max.to_bits(), truth.d_max.to_bits());
        assert_eq!(est.params.d_min.to_bits(), truth.d_min.to_bits());
        let e = errors_against(&est.params, &truth);
        let worst = [e.roll, e.pitch, e.yaw, e.dy, e.dz]
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(worst < 1e-6, "{method}: {e:?}");
    }
    let (mut held_roll, mut free_roll) = (0.0, 0.0);
    for seed in 0..20 {
        let meas = noisy(&pts, &sigma, 20_000 + seed);
        let est = estimate_weighted(&meas, &sigma, Method::MlEpd, &held).unwrap();
        let free =
            estimate_weighted(&meas, &sigma, Method::MlEpd, &EstimateOptions::default()).unwrap();
        assert!(est.status.is_converged(), "draw {seed}: {:?}", est.status);
        assert_eq!(est.params.d_max.to_bits(), truth.d_max.to_bits());
        assert_eq!(est.params.d_min.to_bits(), truth.d_min.to_bits());
        assert!(est.sigma[0].is_none() && est.sigma[1].is_none() && est.roll_determined);
        let e = errors_against(&est.params, &truth);
        for (i, err) in [(2, e.roll), (3, e.pitch), (4, e.yaw), (5, e.dy), (6, e.dz)] {
            let s = est.sigma[i].unwrap();
            assert!(
                err.abs() < 5.0 * s,
                "draw {seed} parameter {i}: {err:e} vs σ̂ {s:e}"
            );
        }
        held_roll += est.sigma[2].unwrap();
        free_roll += free.sigma[2].unwrap();
    }
    // Holding the diameters determines the roll better: on average over the draws (one
    // draw's jackknife 1-σ scatters by ~7 %, so a single pair may cross).
    assert!(
        held_roll < free_roll,
        "roll 1-σ held {held_roll:e} vs free {free_roll:e}"
    );
}

/// The weights travel with their points: points pushed 3 % further along their rays
/// (a fifth of the cloud) with σᵢ = 10⁴ m weigh nothing, so a noise-free frame is
/// recovered through the cleaning (non-finite points and σᵢ), the subsample stage, both
/// passes of the range gate and the data-scaled robust loss; with the weights swapped
/// (the far-off points trusted) it is not.
#[test]
fn weights_stay_with_their_points() {
    let truth = common::random_params(&mut common::rng(12), common::id_m(20.0), 0.02, 6.0, 0.2);
    let clean_pts = common::cloud(&truth, 320, 240, 6.0, 0.0, 0, 4);
    let mut pts = Vec::new();
    let mut sigma = Vec::new();
    let mut dropped = 0;
    for (i, p) in clean_pts.iter().enumerate() {
        match i % 10 {
            3 | 7 => {
                pts.push(p.map(|v| v * 1.03));
                sigma.push(1e4);
            }
            5 if i % 20 == 5 => {
                // Unusable: dropped with its partner.
                pts.push(if i % 40 == 5 { [f64::NAN; 3] } else { *p });
                sigma.push(if i % 40 == 5 { 0.01 } else { f64::NAN });
                dropped += 1;
            }
            _ => {
                pts.push(*p);
                sigma.push(0.01);
            }
        }
    }
    let robust = EstimateOptions::default()
        .with_range_gate(0.5, 4.0)
        .unwrap()
        .with_loss(Loss::Huber { scale: 0.01 })
        .unwrap()
        .with_loss_scale(LossScale::Auto);
    for (o, opts) in [
        EstimateOptions::default(),
        EstimateOptions::default()
            .with_range_gate(0.5, 4.0)
            .unwrap(),
        robust,
    ]
    .iter()
    .enumerate()
    {
        for method in [Method::RuEpd, Method::MlEpd] {
            let est = estimate_weighted(&pts, &sigma, method, opts).unwrap();
            assert_eq!(est.n_dropped, dropped);
            assert!(est.n_points > 16_384, "the subsample stage runs");
            let e = errors_against(&est.params, &truth);
            let worst = [e.d_max, e.d_min, e.roll, e.pitch, e.yaw, e.dy, e.dz]
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(worst < 1e-5, "options {o} {method}: {e:?}");
            // The trusted points swapped: the fit follows the pushed wall.
            let swapped: Vec<f64> = sigma
                .iter()
                .map(|&s| {
                    if s == 1e4 {
                        0.01
                    } else if s == 0.01 {
                        1e4
                    } else {
                        s
                    }
                })
                .collect();
            let bad = estimate_weighted(&pts, &swapped, method, opts).unwrap();
            let e = errors_against(&bad.params, &truth);
            assert!(e.d_mean > 0.005, "options {o} {method}: {e:?}");
        }
    }
}

#[test]
fn mismatched_or_unusable_sigma() {
    let truth = common::random_params(&mut common::rng(1), common::id_m(20.0), 0.02, 5.0, 0.2);
    let pts = common::cloud(&truth, 80, 60, 6.0, 0.0, 0, 1);
    let opts = EstimateOptions::default();
    for len in [0, pts.len() - 1, pts.len() + 1] {
        let sigma = vec![0.01; len];
        assert!(matches!(
            estimate_weighted(&pts, &sigma, Method::MlEpd, &opts),
            Err(EpdError::InvalidOption(_))
        ));
        assert!(matches!(
            cramer_rao_bound_weighted(&pts, &sigma, &truth),
            Err(EpdError::InvalidOption(_))
        ));
    }
    // All σᵢ unusable: every point dropped.
    for bad in [0.0, -0.01, f64::NAN, f64::INFINITY] {
        let sigma = vec![bad; pts.len()];
        match estimate_weighted(&pts, &sigma, Method::MlEpd, &opts) {
            Err(EpdError::TooFewPoints {
                usable, dropped, ..
            }) => {
                assert_eq!((usable, dropped), (0, pts.len()));
            }
            other => panic!("σ = {bad}: {other:?}"),
        }
    }
}

/// The constant-σ case of the weighted bound is `cramer_rao_bound`; the bound scales
/// as σ, and heavier noise on some points raises it.
#[test]
fn weighted_bound_with_constant_sigma_is_the_plain_bound() {
    let truth = common::random_params(&mut common::rng(2), common::id_m(20.0), 0.03, 5.0, 0.2);
    let pts = common::cloud(&truth, 160, 120, 6.0, 0.0, 0, 1);
    let plain = cramer_rao_bound(&pts, &truth, 0.02).unwrap();
    let weighted = cramer_rao_bound_weighted(&pts, &vec![0.02; pts.len()], &truth).unwrap();
    assert_eq!(plain, weighted);
    let double = cramer_rao_bound_weighted(&pts, &vec![0.04; pts.len()], &truth).unwrap();
    let mixed: Vec<f64> = (0..pts.len())
        .map(|i| if i % 2 == 0 { 0.02 } else { 0.08 })
        .collect();
    let mixed = cramer_rao_bound_weighted(&pts, &mixed, &truth).unwrap();
    for i in 0..N_PARAMS {
        if let (Some(a), Some(b), Some(c)) = (plain[i], double[i], mixed[i]) {
            assert!(rel_close(b, 2.0 * a, 1e-12), "{i}");
            assert!(c > a && c < 2.0 * a * 4.0, "{i}");
        }
    }
}
