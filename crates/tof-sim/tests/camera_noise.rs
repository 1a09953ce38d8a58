//! The camera's noise options ([`tof_sim::CameraNoise`]) against the statistics they
//! should produce, and the frames of the options left off against the frames the
//! simulator gave before they existed.

use std::f64::consts::TAU;

use epd_core::Params;
use nalgebra::Vector3;
use tof_sim::camera::correlation;
use tof_sim::{
    CameraNoise, Contamination, FloorLayer, FlyingPixels, Frame, FrameSeed, MultipathBand, Noise,
    NoiseModel, Obstacle, Pipe, PoseRanges, Scene, Sensor, SimError, Subsample, ToFPhysics,
    WallModel, Wiggle, simulate, simulate_with,
};

mod common;

use common::determinism::{bits, on_threads};

/// FNV-1a (64-bit) over the bits of every list of a frame: equal hashes ⇔ (for practical
/// purposes) bit-identical frames.
fn frame_hash(f: &Frame) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |x: u64| {
        for b in x.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for i in 0..f.len() {
        for k in 0..3 {
            eat(f.measured[i][k].to_bits());
            eat(f.exact[i][k].to_bits());
            eat(f.directions[i][k].to_bits());
        }
        eat(u64::from(f.pixels[i][0]) << 32 | u64::from(f.pixels[i][1]));
        eat(u64::from(f.intensity[i].to_bits()));
        eat(f.sigma[i].to_bits());
    }
    eat(f.len() as u64);
    h
}

/// The configurations whose frames must not change: (name, wall, noise, subsample).
fn golden_cases() -> Vec<(&'static str, WallModel, Noise, Subsample)> {
    vec![
        (
            "range+outliers+bias",
            WallModel::Exact,
            Noise {
                outlier_fraction: 0.05,
                far_outlier_fraction: 0.02,
                bias_b0: 0.004,
                bias_b1: 0.003,
                ..Noise::range(0.03)
            },
            Subsample::All,
        ),
        (
            "isotropic, 5000 points",
            WallModel::Exact,
            Noise {
                model: NoiseModel::Isotropic,
                ..Noise::range(0.02)
            },
            Subsample::Points(5000),
        ),
        (
            "physics",
            WallModel::Exact,
            Noise {
                physics: Some(ToFPhysics::helios2()),
                outlier_fraction: 0.01,
                ..Noise::none()
            },
            Subsample::All,
        ),
        (
            "mesh, range",
            WallModel::Mesh { segments: 256 },
            Noise::range(0.01),
            Subsample::All,
        ),
    ]
}

/// The frames of `golden_cases` for one pose and seed.
fn golden_hashes() -> Vec<(&'static str, u64)> {
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 7, 3)
        .unwrap();
    let seeds = FrameSeed {
        seed: 11,
        trial: 3,
        sweep_index: 2,
    };
    golden_cases()
        .into_iter()
        .map(|(name, wall, noise, sub)| {
            let scene = Scene::new(&truth, wall, 8.0).unwrap();
            let f = simulate(&Sensor::helios2(), &scene, &noise, sub, seeds).unwrap();
            (name, frame_hash(&f))
        })
        .collect()
}

/// Recorded from the simulator before `CameraNoise` and `Contamination` existed
/// (commit b6cad14): with every new option off, the seeded streams give the same frames,
/// bit for bit.
#[test]
fn frames_with_the_new_options_off_are_unchanged() {
    let expected: [(&str, u64); 4] = [
        ("range+outliers+bias", 0x4f3f_8400_0536_df89),
        ("isotropic, 5000 points", 0x0552_5109_bc98_bf66),
        ("physics", 0x6b12_2bac_4efc_8c89),
        ("mesh, range", 0x4fcc_def3_3e8d_5e51),
    ];
    let got = golden_hashes();
    for (g, e) in got.iter().zip(expected) {
        assert_eq!(g.0, e.0);
        assert_eq!(g.1, e.1, "{}: 0x{:016x}", g.0, g.1);
    }
}

/// A pose of the paper's ranges with pitch and yaw within ±2°.
fn truth() -> Params {
    let r = PoseRanges {
        pitch: (-0.035, 0.035),
        yaw: (-0.035, 0.035),
        ..PoseRanges::default()
    };
    r.sample(&Pipe::paper_20in(), 5, 1).unwrap()
}

/// The Helios2 with its range filter opened wide, so that no point is dropped for its
/// noise (the statistics below are of every pixel).
fn wide() -> Sensor {
    Sensor {
        max_range: 100.0,
        ..Sensor::helios2()
    }
}

fn seeds(sweep_index: u64) -> FrameSeed {
    FrameSeed {
        seed: 21,
        trial: 1,
        sweep_index,
    }
}

/// Frame `seeds(0)` of the [`wide`] sensor in `scene`: range noise of σ = 0.01 m with
/// `cam`'s options, every pixel.
fn wide_frame(scene: &Scene, cam: &CameraNoise) -> Result<Frame, SimError> {
    simulate_with(
        &wide(),
        scene,
        &Noise::range(0.01),
        cam,
        Subsample::All,
        seeds(0),
    )
}

/// Each point's range error along its ray (m): (x̂ − x)·d, and its true range |x|.
fn errors(f: &Frame) -> Vec<(f64, f64)> {
    (0..f.len())
        .map(|i| {
            let (m, x, d) = (
                Vector3::from(f.measured[i]),
                Vector3::from(f.exact[i]),
                Vector3::from(f.directions[i]),
            );
            ((m - x).dot(&d), x.norm())
        })
        .collect()
}

/// The standardised errors ε = (x̂ − x)·d / σ of a frame as a W×H image, NaN where no
/// point.
fn eps_image(f: &Frame) -> Vec<f64> {
    let [w, h] = f.image_size;
    let mut img = vec![f64::NAN; (w * h) as usize];
    for (i, (e, _)) in errors(f).into_iter().enumerate() {
        let [u, v] = f.pixels[i];
        img[(v * w + u) as usize] = e / f.sigma[i];
    }
    img
}

/// Bartlett's (Isserlis') variance of the sample covariance ĉ(h) = mean ε_p ε_{p+h} of a
/// zero-mean, unit-variance Gaussian field over N pairs:
/// Var ĉ(h) = (1/N) Σ_k [ρ(k)² + ρ(k + h) ρ(k − h)], ρ separable, ρ(k) = c(k_u)·c(k_v).
fn covariance_se(ell: f64, (hu, hv): (i64, i64), n: f64) -> f64 {
    let span = (8.0 * ell).ceil() as i64 + 2;
    let axis = |h: i64| -> (f64, f64) {
        let mut sq = 0.0;
        let mut cross = 0.0;
        for k in -span - h.abs()..=span + h.abs() {
            sq += correlation(ell, k).powi(2);
            cross += correlation(ell, k + h) * correlation(ell, k - h);
        }
        (sq, cross)
    };
    let ((su, cu), (sv, cv)) = (axis(hu), axis(hv));
    ((su * sv + cu * cv) / n).sqrt()
}

/// The correlated field over the pixel grid: the pooled sample covariance of the
/// standardised errors at lags (Δu, Δv) of four frames against ρ = c(Δu)·c(Δv), each
/// within 4 of its standard errors (Bartlett's formula above: the pairs overlap and are
/// correlated, so the naive 1/√N would be far too tight), and the marginal σ (lag 0)
/// likewise. ℓ = 2 px: 4 SE ≈ 0.027 at lag 0, ≈ 0.02 at lag 1.
#[test]
fn correlated_noise_has_the_stated_correlation_and_marginal_sigma() {
    let ell = 2.0;
    let scene = Scene::new(&truth(), WallModel::Exact, 8.0).unwrap();
    let cam = CameraNoise {
        correlation_length_px: ell,
        ..CameraNoise::default()
    };
    let frames: Vec<Vec<f64>> = (0..4)
        .map(|k| {
            let f = simulate_with(
                &wide(),
                &scene,
                &Noise::range(0.02),
                &cam,
                Subsample::All,
                seeds(k),
            )
            .unwrap();
            eps_image(&f)
        })
        .collect();
    let (w, h) = (640i64, 480i64);
    for lag in [
        (0, 0),
        (1, 0),
        (0, 1),
        (1, 1),
        (2, 0),
        (0, 3),
        (4, 2),
        (8, 0),
        (12, 0),
    ] {
        let (mut sum, mut n) = (0.0, 0.0);
        for img in &frames {
            for v in 0..h - lag.1 {
                for u in 0..w - lag.0 {
                    let (a, b) = (
                        img[(v * w + u) as usize],
                        img[((v + lag.1) * w + u + lag.0) as usize],
                    );
                    if a.is_finite() && b.is_finite() {
                        sum += a * b;
                        n += 1.0;
                    }
                }
            }
        }
        let got = sum / n;
        let want = correlation(ell, lag.0) * correlation(ell, lag.1);
        let se = covariance_se(ell, lag, n);
        eprintln!(
            "lag {lag:?}: ĉ {got:.4}, model {want:.4}, SE {se:.4}, continuum {:.4}",
            (-((lag.0 * lag.0 + lag.1 * lag.1) as f64) / (4.0 * ell * ell)).exp()
        );
        assert!(
            (got - want).abs() < 4.0 * se,
            "lag {lag:?}: {got} vs {want}"
        );
    }
    // ℓ = 0: independent, as before (neighbours' covariance 0 within 4/√N).
    let f = simulate(
        &wide(),
        &scene,
        &Noise::range(0.02),
        Subsample::All,
        seeds(0),
    )
    .unwrap();
    let img = eps_image(&f);
    let (mut sum, mut n) = (0.0, 0.0);
    for i in 0..img.len() - 1 {
        if (i + 1) % 640 != 0 && img[i].is_finite() && img[i + 1].is_finite() {
            sum += img[i] * img[i + 1];
            n += 1.0;
        }
    }
    eprintln!(
        "ℓ = 0, lag (1, 0): ĉ {:.4}, 4/√N {:.4}",
        sum / n,
        4.0 / n.sqrt()
    );
    assert!((sum / n).abs() < 4.0 / n.sqrt());
}

/// σ(r) = σ0·(r/r0)^p: each point's σ is the formula's, and in range bands the rms of
/// ε/σ(r) is 1 within 4 standard errors 1/√(2n) (the sd of a normal sample).
#[test]
fn range_dependent_sigma_follows_the_power_law() {
    let scene = Scene::new(&truth(), WallModel::Exact, 8.0).unwrap();
    let cam = CameraNoise {
        sigma_range_exponent: 2.0,
        sigma_reference_range_m: 1.5,
        ..CameraNoise::default()
    };
    let f = wide_frame(&scene, &cam).unwrap();
    let e = errors(&f);
    for (i, &(_, r)) in e.iter().enumerate() {
        assert!((f.sigma[i] - 0.01 * (r / 1.5).powi(2)).abs() < 1e-15 * f.sigma[i].max(1.0));
    }
    for (lo, hi) in [(0.2, 0.6), (0.6, 1.5), (1.5, 3.0), (3.0, 6.0)] {
        let z: Vec<f64> = e
            .iter()
            .filter(|(_, r)| (lo..hi).contains(r))
            .map(|(e, r)| e / (0.01 * (r / 1.5).powi(2)))
            .collect();
        let n = z.len() as f64;
        let rms = (z.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
        let sd_of_sigma = 0.01 * (0.5 * (lo + hi) / 1.5f64).powi(2);
        eprintln!(
            "[{lo}, {hi}) m: n {n}, rms ε/σ(r) {rms:.4} (±{:.4}); σ ≈ {:.1} mm",
            4.0 / (2.0 * n).sqrt(),
            sd_of_sigma * 1e3
        );
        assert!(n > 1000.0 && (rms - 1.0).abs() < 4.0 / (2.0 * n).sqrt());
    }
}

/// Wiggling without random error: every point reads a·sin(2πr/P + φ) long, to rounding.
/// With a random phase, the phase fitted in each of 40 frames is uniform: Rayleigh's test,
/// N·R̄² < 9.2 (under uniformity 2N·R̄² ~ χ²₂, P(N·R̄² > 9.2) = e^−9.2 ≈ 10⁻⁴).
#[test]
fn wiggle_is_the_sine_and_its_random_phase_uniform() {
    let scene = Scene::new(&truth(), WallModel::Exact, 8.0).unwrap();
    let wig = Wiggle {
        amplitude_m: 0.01,
        period_m: 1.5,
        phase_rad: 0.7,
        random_phase: false,
    };
    let run = |w: Wiggle, s: FrameSeed, sub: Subsample| {
        let cam = CameraNoise {
            wiggle: Some(w),
            ..CameraNoise::default()
        };
        simulate_with(&wide(), &scene, &Noise::none(), &cam, sub, s).unwrap()
    };
    let f = run(wig, seeds(0), Subsample::All);
    for (e, r) in errors(&f) {
        assert!((e - 0.01 * (TAU * r / 1.5 + 0.7).sin()).abs() < 1e-12);
    }
    let random = Wiggle {
        random_phase: true,
        ..wig
    };
    let phase = |f: &Frame| {
        // e = a·sin θ cos φ + a·cos θ sin φ, θ = 2πr/P: least squares for (cos φ, sin φ).
        let (mut ss, mut sc, mut cc, mut es, mut ec) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (e, r) in errors(f) {
            let (s, c) = (TAU * r / 1.5).sin_cos();
            ss += s * s;
            sc += s * c;
            cc += c * c;
            es += e * s;
            ec += e * c;
        }
        let det = ss * cc - sc * sc;
        let (x, y) = ((es * cc - ec * sc) / det, (ec * ss - es * sc) / det);
        assert!((x.hypot(y) - 0.01).abs() < 1e-9, "amplitude {}", x.hypot(y));
        y.atan2(x)
    };
    let n = 40;
    let (mut cs, mut sn) = (0.0, 0.0);
    for k in 0..n {
        let p = phase(&run(random, seeds(k), Subsample::Points(500)));
        cs += p.cos();
        sn += p.sin();
    }
    let r2 = (cs * cs + sn * sn) / (n * n) as f64;
    eprintln!("random wiggle phase: N·R̄² = {:.3} (< 9.2)", n as f64 * r2);
    assert!(n as f64 * r2 < 9.2);
    // The phase is a function of the seeds.
    let a = phase(&run(random, seeds(3), Subsample::Points(500)));
    let b = phase(&run(random, seeds(3), Subsample::Points(500)));
    assert_eq!(a, b);
}

/// Multipath bands: with σ = 1 cm the mean range error of the points in each stretch is
/// the sum of the extras of the bands holding it (0 outside), within 4 σ/√n.
#[test]
fn multipath_bands_add_their_offset() {
    let scene = Scene::new(&truth(), WallModel::Exact, 8.0).unwrap();
    let band = |near_m, far_m, extra_m| MultipathBand {
        near_m,
        far_m,
        extra_m,
    };
    let cam = CameraNoise {
        multipath_bands: vec![band(1.0, 1.5, 0.04), band(1.3, 2.0, 0.01)],
        ..CameraNoise::default()
    };
    let f = wide_frame(&scene, &cam).unwrap();
    let e = errors(&f);
    for (lo, hi, want) in [
        (0.0, 1.0, 0.0),
        (1.0, 1.3, 0.04),
        (1.3, 1.5, 0.05),
        (1.5, 2.0, 0.01),
        (2.0, 6.0, 0.0),
    ] {
        let v: Vec<f64> = e
            .iter()
            .filter(|(_, r)| *r > lo && *r < hi)
            .map(|(e, _)| *e)
            .collect();
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        eprintln!(
            "({lo}, {hi}) m: n {n}, mean error {:.3} mm (model {:.0} mm, 4 SE {:.3} mm)",
            mean * 1e3,
            want * 1e3,
            4e3 * 0.01 / n.sqrt()
        );
        assert!(
            (mean - want).abs() < 4.0 * 0.01 / n.sqrt(),
            "{lo}..{hi}: {mean}"
        );
    }
}

/// A box on a floor layer, seen from the axis: its outline against the floor and the
/// wall far behind is a depth edge.
fn obstacle_scene() -> Scene {
    let t = Params {
        d_max: 0.484,
        d_min: 0.484,
        roll: 0.0,
        pitch: 0.0,
        yaw: 0.0,
        dy: 0.0,
        dz: 0.0,
    };
    Scene::new(&t, WallModel::Exact, 8.0)
        .unwrap()
        .with_contamination(Contamination {
            floor: Some(FloorLayer { depth_m: 0.06 }),
            obstacle: Some(Obstacle::Box {
                x_m: 0.8,
                length_m: 0.3,
                width_m: 0.2,
                height_m: 0.12,
                y_m: 0.03,
            }),
            ..Contamination::default()
        })
        .unwrap()
}

/// Flying pixels at the box's outline, without random error: only edge pixels move; the
/// fraction that moves is the probability within 4 binomial standard errors
/// √(p(1 − p)/n_edge); each moved one reads r + α(r_partner − r) with α in [0, ½), of
/// mean ¼ within 4 standard errors (½/√12)/√n_flown. With σ > 0 every other pixel is
/// bit-identical to the frame without flying pixels (their draws have their own stream).
#[test]
fn flying_pixels_mix_ranges_across_depth_edges() {
    let scene = obstacle_scene();
    // Every pixel's ray within range (those near the axis reach ~100 m), so the test's
    // range image is the simulator's.
    let sensor = Sensor {
        max_range: 1e4,
        ..Sensor::helios2()
    };
    let p = 0.3;
    let fp = FlyingPixels::new(p);
    let clean = simulate(&sensor, &scene, &Noise::none(), Subsample::All, seeds(0)).unwrap();
    let mut ranges = vec![f64::NAN; 640 * 480];
    for (i, x) in clean.exact.iter().enumerate() {
        let [u, v] = clean.pixels[i];
        ranges[(v * 640 + u) as usize] = Vector3::from(*x).norm();
    }
    let partners = fp.edge_partners(&ranges, 640);
    let n_edge = partners.iter().flatten().count();
    let n_far = (0..partners.len())
        .filter(|&k| partners[k].is_some_and(|j| ranges[k].max(ranges[j]) >= 6.0))
        .count();
    // Every edge within 6 m is the box's outline: the pixel or its partner sees the box
    // (the PCS is the SCS here; the box spans x 0.8..1.1, y −0.07..0.13,
    // z −0.182..−0.062 m). Beyond, within a pixel or two of the axis' vanishing point,
    // ranges of tens of metres grow like 1/angle and their steps by factors up to 3
    // from pixel to pixel: a few of those count as edges (no camera ranges that far).
    let pixel_point = |k: usize| {
        let (u, v) = ((k % 640) as u32, (k / 640) as u32);
        sensor.ray_direction(u, v) * ranges[k]
    };
    let on_box = |x: Vector3<f64>| {
        let e = 1e-9;
        (0.8 - e..=1.1 + e).contains(&x.x)
            && (-0.07 - e..=0.13 + e).contains(&x.y)
            && (-0.182 - e..=-0.062 + e).contains(&x.z)
    };
    for (k, j) in partners.iter().enumerate() {
        if let Some(j) = *j
            && ranges[k].max(ranges[j]) < 6.0
        {
            assert!(
                on_box(pixel_point(k)) != on_box(pixel_point(j)),
                "edge {k}–{j}"
            );
        }
    }
    let cam = CameraNoise {
        flying_pixels: Some(fp),
        ..CameraNoise::default()
    };
    let f = simulate_with(
        &sensor,
        &scene,
        &Noise::none(),
        &cam,
        Subsample::All,
        seeds(0),
    )
    .unwrap();
    assert_eq!(f.len(), clean.len());
    let mut alphas = Vec::new();
    for i in 0..f.len() {
        if f.measured[i] == f.exact[i] {
            continue;
        }
        let [u, v] = f.pixels[i];
        let k = (v * 640 + u) as usize;
        let j = partners[k].expect("only edge pixels fly");
        let m = Vector3::from(f.measured[i]).norm();
        let alpha = (m - ranges[k]) / (ranges[j] - ranges[k]);
        assert!((-1e-9..0.5 + 1e-9).contains(&alpha), "α {alpha}");
        alphas.push(alpha);
    }
    let n_fly = alphas.len() as f64;
    let frac = n_fly / n_edge as f64;
    let se = (p * (1.0 - p) / n_edge as f64).sqrt();
    let mean_alpha = alphas.iter().sum::<f64>() / n_fly;
    let se_alpha = 0.5 / 12f64.sqrt() / n_fly.sqrt();
    eprintln!(
        "edge pixels {n_edge} ({n_far} beyond 6 m; {:.2} % of the frame), flying {n_fly}: fraction {frac:.4} \
         (p {p} ± {:.4}), mean α {mean_alpha:.4} (¼ ± {:.4})",
        100.0 * n_edge as f64 / f.len() as f64,
        4.0 * se,
        4.0 * se_alpha
    );
    assert!(n_edge > 500, "{n_edge}");
    assert!((frac - p).abs() < 4.0 * se);
    assert!((mean_alpha - 0.25).abs() < 4.0 * se_alpha);
    // With σ > 0, the pixels that do not fly are as without flying pixels.
    let noisy = |c: &CameraNoise| {
        simulate_with(
            &sensor,
            &scene,
            &Noise::range(0.01),
            c,
            Subsample::All,
            seeds(0),
        )
        .unwrap()
    };
    let (a, b) = (noisy(&cam), noisy(&CameraNoise::default()));
    let differ = (0..a.len())
        .filter(|&i| a.measured[i] != b.measured[i])
        .count();
    assert_eq!(
        differ as f64, n_fly,
        "the same pixels fly, and only they differ"
    );
}

/// Every option on, a contaminated scene: the same frame for one and two threads, a
/// function of (seed, trial, sweep index).
#[test]
fn every_option_is_deterministic_per_seeds_and_threads() {
    let scene = obstacle_scene();
    let cam = CameraNoise {
        correlation_length_px: 1.5,
        sigma_range_exponent: 1.0,
        sigma_reference_range_m: 1.0,
        wiggle: Some(Wiggle {
            random_phase: true,
            ..Wiggle::helios2()
        }),
        multipath_bands: vec![MultipathBand {
            near_m: 1.0,
            far_m: 2.0,
            extra_m: 0.02,
        }],
        flying_pixels: Some(FlyingPixels::new(0.5)),
    };
    let noise = Noise {
        outlier_fraction: 0.01,
        far_outlier_fraction: 0.01,
        ..Noise::range(0.01)
    };
    let run = |threads: usize, s: FrameSeed| {
        on_threads(threads, || {
            simulate_with(
                &Sensor::helios2(),
                &scene,
                &noise,
                &cam,
                Subsample::Points(20_000),
                s,
            )
            .unwrap()
        })
    };
    let one = run(1, seeds(1));
    let two = run(2, seeds(1));
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(one.pixels, two.pixels);
    assert_ne!(bits(&one), bits(&run(2, seeds(2))));
    assert_ne!(
        bits(&one),
        bits(&run(
            2,
            FrameSeed {
                trial: 2,
                ..seeds(1)
            }
        ))
    );
    // The physical model takes the correlated field and the flying pixels too.
    let physical = Noise {
        physics: Some(ToFPhysics::helios2()),
        ..Noise::none()
    };
    let cam = CameraNoise {
        sigma_range_exponent: 0.0,
        ..cam
    };
    let run = || {
        simulate_with(
            &Sensor::helios2(),
            &scene,
            &physical,
            &cam,
            Subsample::All,
            seeds(1),
        )
        .unwrap()
    };
    assert_eq!(bits(&run()), bits(&run()));
}

/// A bad option is refused before anything is cast, naming its field.
#[test]
fn bad_options_name_their_field() {
    let scene = Scene::new(&truth(), WallModel::Exact, 8.0).unwrap();
    let cam = CameraNoise {
        correlation_length_px: f64::NAN,
        ..CameraNoise::default()
    };
    let e = wide_frame(&scene, &cam).unwrap_err();
    assert!(e.to_string().contains("noise.correlation_length_px"), "{e}");
    let cam = CameraNoise {
        multipath_bands: vec![MultipathBand {
            near_m: 0.5,
            far_m: f64::NAN,
            extra_m: 0.01,
        }],
        ..CameraNoise::default()
    };
    let e = wide_frame(&scene, &cam).unwrap_err();
    assert!(e.to_string().contains("noise.multipath_bands.far_m"), "{e}");
}
