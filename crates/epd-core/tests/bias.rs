//! Bias under range noise (Theorems 1 and 2): C-EPD overestimates the diameters,
//! ML-EPD does not, RU-EPD only by its second-order tilt bias (docs/trust.md, "Tilt"); and the
//! reported 1-σ against the scatter over noise draws.

mod common;

use epd_core::{EstimateOptions, Method, cramer_rao_bound, errors_against, estimate};

/// σ = 0.05 m, 20" pipe (12 mm wall), 2 % ovality, 10⁴ points per cloud, 12 poses in the
/// paper's ranges. An independent implementation measured the C-EPD mean-diameter bias
/// at ≈ 1.75·σ²/ID (≈ +9 mm here). Each bias is compared with its standard error
/// computed here from the scatter over the poses.
#[test]
fn c_epd_is_biased_ml_is_not_ru_by_its_tilt_bias() {
    let sigma = 0.05;
    let id = common::id_m(20.0);
    let mut rng = common::rng(99);
    let poses = 12;
    let mut sums = [0.0f64; 3];
    let mut sq = [0.0f64; 3];
    let mut tan2_tilt = 0.0;
    for k in 0..poses {
        let truth = common::random_params(&mut rng, id, 0.02, 5.0, 0.2);
        tan2_tilt += ru_tilt_weight(&truth) / poses as f64;
        let pts = common::cloud(&truth, 640, 480, 6.0, sigma, 10_000, 1000 + k);
        for (i, m) in Method::ALL.iter().enumerate() {
            let est = estimate(&pts, *m, &EstimateOptions::default()).unwrap();
            assert!(est.status.is_converged(), "{m} {:?}", est.status);
            let e = errors_against(&est.params, &truth);
            sums[i] += e.d_mean;
            sq[i] += e.d_mean * e.d_mean;
        }
    }
    let n = poses as f64;
    let mean: Vec<f64> = sums.iter().map(|s| s / n * 1e3).collect();
    // Standard error of each mean from the scatter over the poses.
    let sem: Vec<f64> = (0..3)
        .map(|i| ((sq[i] * 1e6 / n - mean[i] * mean[i]).max(0.0) * n / (n - 1.0) / n).sqrt())
        .collect();
    let expected = 1.75 * sigma * sigma / id * 1e3;
    eprintln!(
        "mean-diameter bias (mm): c-epd {:.3} ± {:.3}, ru-epd {:.3} ± {:.3}, ml-epd {:.3} ± {:.3}; \
         1.75σ²/ID = {expected:.3} mm",
        mean[0], sem[0], mean[1], sem[1], mean[2], sem[2]
    );
    // C-EPD: the σ²/ID law within 30 % (its scatter is far smaller).
    assert!(
        (mean[0] / expected - 1.0).abs() < 0.3,
        "C-EPD bias {} mm",
        mean[0]
    );
    // ML-EPD: unbiased within 3 standard errors.
    assert!(
        mean[2].abs() < 3.0 * sem[2],
        "ML-EPD bias {} ± {} mm",
        mean[2],
        sem[2]
    );
    // RU-EPD: its second-order tilt bias (docs/trust.md, "Tilt"), predicted for these poses,
    // within 3 standard errors (this test's and the prediction's, in quadrature).
    let (predicted, predicted_se) = ru_tilt_bias_mm(sigma, tan2_tilt);
    let limit = 3.0 * sem[1].hypot(predicted_se);
    eprintln!("RU-EPD predicted tilt bias {predicted:.3} ± {predicted_se:.3} mm");
    assert!(
        (mean[1] - predicted).abs() < limit,
        "RU-EPD bias {:.4} ± {:.4} mm, predicted {predicted:.4} ± {predicted_se:.4}: limit {limit:.4}",
        mean[1],
        sem[1]
    );
}

/// tan²(tilt) / tan²(10°) of a pose, the tilt the angle between the pipe axis and the
/// sensor's X axis: cos(tilt) = cos θy·cos θz (the shared SPEC, "Conventions").
fn ru_tilt_weight(p: &epd_core::Params) -> f64 {
    let c2 = (p.pitch.cos() * p.yaw.cos()).powi(2);
    (1.0 / c2 - 1.0) / 10f64.to_radians().tan().powi(2)
}

/// RU-EPD's mean-diameter bias (mm) under range noise σ (m) on a 20" pipe, and its
/// standard error, for poses of mean [`ru_tilt_weight`] `w`: a pull of order σ² that
/// grows as tan²(tilt) (docs/trust.md, "Tilt"), scaled from `results/tilt_sweep` at 10° and
/// σ = 0.05 m (+0.549 ± 0.027 mm, 100 poses; the same law gives 0.135 mm at 5° and
/// 1.29 mm at 15°, measured 0.127 ± 0.014 and 1.37 ± 0.07).
fn ru_tilt_bias_mm(sigma: f64, w: f64) -> (f64, f64) {
    let scale = w * (sigma / 0.05).powi(2);
    (0.5487 * scale, 0.0269 * scale)
}

/// The least ratio scatter/reported 1-σ allowed: the 1-σ is the cluster jackknife
/// (`epd_core::fit::uncertainty`), conservative in expectation (Efron–Stein) — it may
/// overstate the scatter, never understate it beyond sampling. Measured with it
/// (`cargo test -p epd-core --test bias -- reported --nocapture`, 600 draws, relative
/// SE 0.03): ML-EPD 0.90–0.98 (its 1-σ 5–9 % above the Cramér–Rao bound, its scatter
/// 0–6 % above), RU-EPD's diameters 0.96–1.04 and its pose 0.86–0.99 (RU-EPD's depth
/// residual, eqs. (20)–(23), is not the range error, so its scores are not its
/// likelihood's). The floor is the lowest measured ratio, 0.86, less 4 of its standard
/// errors (4 × 0.03): 0.74, taken as 0.75; a 1-σ a third above the scatter fails.
const MIN_SD_OVER_REPORTED: f64 = 0.75;

/// The reported 1-σ against the scatter over repeated noise draws of one pose (σ = 0.03
/// m, 160×120 pixels, 600 draws): for both methods and all 7 parameters the 1-σ does
/// not understate the scatter (sd/reported below 1 + 4 SE) nor overstate it beyond
/// [`MIN_SD_OVER_REPORTED`]; ML-EPD's scatter sits at the Cramér–Rao bound and its
/// 1-σ never below it.
///
/// Tolerances: the sample sd of n normal draws has a relative standard error
/// 1/√(2(n − 1)) (0.029 for n = 600); the mean reported 1-σ has its own, sd(reported)/
/// (mean·√n) (≤ 0.003 here), in quadrature: SE(sd/reported). The CRB is exact, so
/// sd/CRB has the first alone and the mean reported/CRB the second alone. Each check
/// allows 4 of its standard errors (two-sided false-failure rate 6·10⁻⁵; 28 checks:
/// ≤ 2·10⁻³ for the test).
#[test]
fn reported_sigma_matches_scatter_and_crb() {
    const Z: f64 = 4.0;
    let sigma = 0.03;
    let truth = common::random_params(&mut common::rng(5), common::id_m(20.0), 0.02, 5.0, 0.2);
    let exact = common::cloud(&truth, 160, 120, 6.0, 0.0, 0, 0);
    let crb = cramer_rao_bound(&exact, &truth, sigma).unwrap();
    let draws: u64 = std::env::var("EPD_TEST_DRAWS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(600);
    let n = draws as f64;
    let se_sd = 1.0 / (2.0 * (n - 1.0)).sqrt();
    let names = ["Dmax", "Dmin", "roll", "pitch", "yaw", "dy", "dz"];
    for method in [Method::RuEpd, Method::MlEpd] {
        let mut errs = vec![Vec::new(); 7];
        let mut reported = vec![Vec::new(); 7];
        for k in 0..draws {
            let pts = common::cloud(&truth, 160, 120, 6.0, sigma, 0, 500 + k);
            let est = estimate(&pts, method, &EstimateOptions::default()).unwrap();
            assert!(
                est.status.is_converged(),
                "{method} draw {k}: {:?}",
                est.status
            );
            let e = errors_against(&est.params, &truth);
            let e = [e.d_max, e.d_min, e.roll, e.pitch, e.yaw, e.dy, e.dz];
            for i in 0..7 {
                errs[i].push(e[i]);
                let s = est.sigma[i];
                reported[i]
                    .push(s.unwrap_or_else(|| panic!("{method} draw {k}: no 1-σ of {}", names[i])));
            }
        }
        for i in 0..7 {
            let (_, sd) = mean_sd(&errs[i]);
            let (rep, rep_sd) = mean_sd(&reported[i]);
            let se_rep = rep_sd / rep / n.sqrt();
            let se = se_sd.hypot(se_rep);
            let bound = crb[i].unwrap();
            let ratio = sd / rep;
            eprintln!(
                "{method} {}: sd {sd:.4e}, reported {rep:.4e}, CRB {bound:.4e}: sd/reported {ratio:.4} ± {se:.4}, sd/CRB {:.4}, reported/CRB {:.5} ± {se_rep:.5}",
                names[i],
                sd / bound,
                rep / bound
            );
            let what = format!("{method} {}: sd/reported {ratio:.4} ± {se:.4}", names[i]);
            assert!(
                ratio < 1.0 + Z * se,
                "{what}: the 1-σ understates the scatter"
            );
            assert!(
                ratio > MIN_SD_OVER_REPORTED,
                "{what}: the 1-σ overstates the scatter by more than a third"
            );
            if method == Method::MlEpd {
                assert!(
                    (sd / bound - 1.0).abs() < Z * se_sd,
                    "ML-EPD {}: sd {sd} vs CRB {bound}",
                    names[i]
                );
                assert!(
                    rep / bound > 1.0 - Z * se_rep,
                    "ML-EPD {}: reported {rep} (relative SE {se_rep:.2e}) below the CRB {bound}",
                    names[i]
                );
            }
        }
    }
}

/// Mean and sample standard deviation (n − 1).
fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (
        m,
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt(),
    )
}
