//! The physical sensor model (`Noise::physics`) against hand computations, noise
//! statistics, determinism, and the plain model left bit-identical.

use std::f64::consts::TAU;

use epd_core::Params;
use nalgebra::Vector3;
use tof_sim::physics::SPEED_OF_LIGHT;
use tof_sim::{
    Frame, FrameSeed, Noise, NoiseModel, Pipe, PoseRanges, Scene, Sensor, Subsample, ToFPhysics,
    WallModel, simulate,
};

mod common;

use common::determinism::{bits, on_threads};

/// A sensor on the axis of an untilted circular pipe of diameter `d` (m), rotated about
/// the axis by nothing, yawed by `yaw` (rad).
fn pipe(d: f64, yaw: f64) -> Params {
    Params {
        d_max: d,
        d_min: d,
        roll: 0.0,
        pitch: 0.0,
        yaw,
        dy: 0.0,
        dz: 0.0,
    }
}

/// The physical model with only the random error (no systematic error), every hit valid.
fn noise_only(sigma_ref_m: f64, ambient: f64, reflectivity: f64) -> ToFPhysics {
    ToFPhysics {
        reflectivity,
        sigma_ref_m,
        ambient,
        min_amplitude: 1e-12,
        saturation_amplitude: f64::INFINITY,
        wiggle_amplitude_m: 0.0,
        amplitude_offset_m_per_ln: 0.0,
        multipath_ratio: 0.0,
        ..ToFPhysics::helios2()
    }
}

fn with(p: ToFPhysics) -> Noise {
    Noise {
        physics: Some(p),
        ..Noise::none()
    }
}

/// The frame of `sensor` in `scene` with the physical error model `p` and no other noise,
/// every pixel, the default seeds.
fn physical_frame(sensor: &Sensor, scene: &Scene, p: ToFPhysics) -> Frame {
    simulate(
        sensor,
        scene,
        &with(p),
        Subsample::All,
        FrameSeed::default(),
    )
    .unwrap()
}

/// In a circular pipe of radius R seen from its axis, a ray at angle φ from the axis meets
/// the wall at r = R/sin φ with cos θ = sin φ (the wall normal is radial): A = ρ sin³φ/R².
/// A radial ray (φ = 90°) meets it head-on: r = R, cos θ = 1, A = ρ/R².
#[test]
fn amplitude_matches_the_hand_computation_in_a_circular_pipe() {
    let r0 = 0.242;
    let p = ToFPhysics::helios2();
    // Head-on: the pipe yawed by 90° puts its axis along the sensor's Y, so the optical
    // axis (X) is radial.
    let scene = Scene::new(
        &pipe(2.0 * r0, std::f64::consts::FRAC_PI_2),
        WallModel::Exact,
        6.0,
    )
    .unwrap();
    let (range, cos) = scene
        .cast_with_normal(&Vector3::new(1.0, 0.0, 0.0), 10.0)
        .unwrap();
    assert!((range - r0).abs() < 1e-12 && (cos - 1.0).abs() < 1e-12);
    assert!((p.amplitude(range, cos) - 0.5 / (r0 * r0)).abs() < 1e-12);
    // Oblique rays, in the exact and in a mesh wall (triangle normals).
    let scene = Scene::new(&pipe(2.0 * r0, 0.0), WallModel::Exact, 6.0).unwrap();
    let mesh = Scene::new(
        &pipe(2.0 * r0, 0.0),
        WallModel::Mesh { segments: 2048 },
        8.0,
    )
    .unwrap();
    for deg in [5.0f64, 20.0, 45.0, 80.0] {
        let phi = deg.to_radians();
        let d = Vector3::new(phi.cos(), 0.6 * phi.sin(), 0.8 * phi.sin());
        let (range, cos) = scene.cast_with_normal(&d, 10.0).unwrap();
        assert!((range - r0 / phi.sin()).abs() < 1e-12, "{deg}°");
        assert!((cos - phi.sin()).abs() < 1e-12, "{deg}°");
        let want = 0.5 * phi.sin().powi(3) / (r0 * r0);
        assert!((p.amplitude(range, cos) / want - 1.0).abs() < 1e-12);
        let (mr, mc) = mesh.cast_with_normal(&d, 10.0).unwrap();
        // A facet of 2048 tilts the normal by at most π/2048.
        assert!(
            (mr / range - 1.0).abs() < 1e-4 && (mc - cos).abs() < 2e-3,
            "{deg}°"
        );
    }
    // And the frame's intensities: scale · A, with no multipath.
    let p = ToFPhysics {
        multipath_ratio: 0.0,
        ..ToFPhysics::helios2()
    };
    let f = physical_frame(&Sensor::helios2(), &scene, p);
    let mut n = 0;
    for i in 0..f.len() {
        if !f.is_valid(i) {
            continue;
        }
        let d = Vector3::from(f.directions[i]);
        let s = d.y.hypot(d.z);
        let want = (1000.0 * 0.5 * s.powi(3) / (r0 * r0)) as f32;
        assert!((f.intensity[i] / want - 1.0).abs() < 1e-5, "{i}");
        n += 1;
    }
    assert!(n > 200_000, "{n}");
}

/// Sample standard deviation of the random range error of one pixel over `n` frames of a
/// 1×1 sensor (every frame its own trial, hence its own row stream; `seed` sets them
/// apart), and its amplitude.
fn pixel_sd(p: ToFPhysics, n: u64, seed: u64) -> (f64, f64) {
    // Yawed by 0.3 rad, the optical axis meets the 20" wall at about 0.82 m.
    let scene = Scene::new(&pipe(0.484, 0.3), WallModel::Exact, 6.0).unwrap();
    let sensor = Sensor {
        width: 1,
        height: 1,
        fov_h: 0.01,
        fov_v: 0.01,
        min_range: 0.0,
        max_range: 1e9,
    };
    let d = sensor.ray_direction(0, 0);
    let (range, cos) = scene.cast_with_normal(&d, 10.0).unwrap();
    let mut e = Vec::with_capacity(n as usize);
    let mut frame = Frame::empty();
    for trial in 0..n {
        let seeds = FrameSeed {
            seed,
            trial,
            sweep_index: 0,
        };
        tof_sim::simulate_into(&sensor, &scene, &with(p), Subsample::All, seeds, &mut frame)
            .unwrap();
        let m = Vector3::from(frame.measured[0]);
        e.push(m.dot(&d) - range);
    }
    let mean = e.iter().sum::<f64>() / n as f64;
    let var = e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (var.sqrt(), p.amplitude(range, cos))
}

/// Lange's σ(A) = σ_ref √((A + B)/(1 + B))/A: the ratio of σ at ρ = 1 and ρ = 0.25
/// (amplitudes 4:1) is 2 when shot-noise-limited (B = 0) and 4 when ambient-limited
/// (B ≫ A). Each sample sd of n draws has relative standard error 1/√(2n), a ratio of two
/// independent ones 1/√n: 5 standard errors allowed.
#[test]
fn sigma_follows_lange_in_both_limits() {
    let n = 20_000;
    for (ambient, want) in [(0.0, 2.0), (1e6, 4.0)] {
        let bright = noise_only(0.001, ambient, 1.0);
        let dark = noise_only(0.001, ambient, 0.25);
        // Independent draws for the two amplitudes.
        let (s1, a1) = pixel_sd(bright, n, 11);
        let (s2, a2) = pixel_sd(dark, n, 12);
        assert!((a1 / a2 - 4.0).abs() < 1e-12);
        let formula = dark.sigma_at(a2) / bright.sigma_at(a1);
        assert!((formula / want - 1.0).abs() < 1e-5, "{formula}");
        let tol = 5.0 / (n as f64).sqrt();
        eprintln!(
            "B = {ambient}: σ {:.4} mm at A = {a1:.3}, {:.4} mm at A = {a2:.3}, ratio {:.4} (formula {formula:.4}, relative tolerance {tol:.4})",
            s1 * 1e3,
            s2 * 1e3,
            s2 / s1
        );
        assert!((s2 / s1 / formula - 1.0).abs() < tol, "ratio {}", s2 / s1);
        let tol1 = 5.0 / (2.0 * n as f64).sqrt();
        assert!((s1 / bright.sigma_at(a1) - 1.0).abs() < tol1);
        assert!((s2 / dark.sigma_at(a2) - 1.0).abs() < tol1);
    }
}

#[test]
fn wiggle_period_is_a_quarter_of_the_unambiguous_range() {
    for f in [25e6, 50e6, 120e6] {
        let p = ToFPhysics {
            modulation_hz: f,
            wiggle_phase_rad: 0.3,
            ..ToFPhysics::helios2()
        };
        let l = SPEED_OF_LIGHT / (2.0 * f);
        assert_eq!(p.unambiguous_range(), l);
        assert_eq!(p.wiggle_period(), l / 4.0);
        for k in 0..100 {
            let r = 0.1 + 0.037 * k as f64;
            let w = p.wiggle(r);
            assert!((p.wiggle(r + l / 4.0) - w).abs() < 1e-14);
            assert!((p.wiggle(r + l / 8.0) + w).abs() < 1e-14);
            let want = 0.006 * (TAU * 4.0 * r / l + 0.3).sin();
            assert!((w - want).abs() < 1e-14);
        }
    }
}

#[test]
fn multipath_always_lengthens_more_at_weak_returns_and_vanishes_with_its_ratio() {
    let h = ToFPhysics::helios2();
    let l = h.unambiguous_range();
    for extra in [0.0, 0.01, 0.5, 1.5, 2.9, 0.499 * l] {
        for ratio in [0.0, 1e-6, 1e-3, 0.01, 0.1, 1.0] {
            let p = ToFPhysics {
                multipath_ratio: ratio,
                multipath_extra_path_m: extra,
                ..h
            };
            p.validate().unwrap();
            for r in [0.2, 0.5, 1.0, 2.0, 5.0] {
                let mut last = 0.0;
                for k in 0..60 {
                    let a = 10f64.powf(1.0 - 0.15 * k as f64); // 10 … 1e-8
                    let (shift, _) = p.multipath(r, a);
                    assert!(shift >= 0.0 && shift <= extra + 1e-12, "{shift}");
                    // The weaker the direct return, the larger the shift.
                    assert!(shift >= last - 1e-15, "{r} m, A = {a}: {shift} < {last}");
                    last = shift;
                }
            }
        }
    }
    // Monotone in A and → 0 with the ratio, at the Helios2 defaults.
    let shifts: Vec<f64> = [1.0, 0.1, 0.01, 0.001]
        .iter()
        .map(|&a| h.multipath(1.0, a).0)
        .collect();
    assert!(shifts.windows(2).all(|w| w[1] > w[0]), "{shifts:?}");
    let mut prev = f64::INFINITY;
    for ratio in [1e-2, 1e-4, 1e-6, 1e-8, 0.0] {
        let p = ToFPhysics {
            multipath_ratio: ratio,
            ..h
        };
        let s = p.multipath(1.0, 0.1).0;
        // atan x ≤ x and sin δ ≤ δ: shift ≤ Δ·a_i/A, a_i = ratio/r².
        assert!(s < prev && s <= 0.5 * ratio / 0.1, "{ratio}: {s}");
        prev = s;
    }
    assert_eq!(prev, 0.0);
}

/// Noise-free (σ_ref = 0): every valid point lies on its ray at r + systematic_error(r, A).
#[test]
fn frame_systematic_error_is_the_model() {
    let r0 = 0.242;
    let p = ToFPhysics {
        sigma_ref_m: 0.0,
        ..ToFPhysics::helios2()
    };
    let scene = Scene::new(&pipe(2.0 * r0, 0.0), WallModel::Exact, 6.0).unwrap();
    let f = physical_frame(&Sensor::helios2(), &scene, p);
    let mut n = 0;
    for i in 0..f.len() {
        if !f.is_valid(i) {
            continue;
        }
        let (m, x) = (Vector3::from(f.measured[i]), Vector3::from(f.exact[i]));
        let d = Vector3::from(f.directions[i]);
        let r = x.norm();
        let a = p.amplitude(r, d.y.hypot(d.z));
        assert!(
            (m.norm() - r - p.systematic_error(r, a)).abs() < 1e-9,
            "{i}"
        );
        assert!(m.cross(&d).norm() < 1e-9);
        assert_eq!(f.sigma[i], 0.0);
        n += 1;
    }
    assert!(n > 200_000);
}

/// Invalid pixels: zeros, intensity 0, σ NaN, kept whatever the range filter — dark ones
/// far down the 20" pipe, saturated ones near the sensor in a 0.1 m pipe.
#[test]
fn invalid_pixels_are_zeros_with_intensity_zero() {
    let p = ToFPhysics::helios2();
    for (d, expect) in [(0.484, "dark"), (0.1, "saturated")] {
        let scene = Scene::new(&pipe(d, 0.0), WallModel::Exact, 6.0).unwrap();
        let sensor = Sensor {
            min_range: 0.5,
            max_range: 2.0,
            ..Sensor::helios2()
        };
        let f = physical_frame(&sensor, &scene, p);
        let (mut invalid, mut of_kind) = (0, 0);
        for i in 0..f.len() {
            let x = Vector3::from(f.exact[i]);
            if f.is_valid(i) {
                let r = Vector3::from(f.measured[i]).norm();
                assert!((0.5..=2.0).contains(&r));
                assert!(f.intensity[i] > 0.0 && f.sigma[i].is_finite());
                let a = f.intensity[i] as f64 / p.intensity_scale;
                assert!(p.is_valid(a * (1.0 + 1e-6)) || p.is_valid(a * (1.0 - 1e-6)));
            } else {
                invalid += 1;
                assert_eq!(f.measured[i], [0.0; 3]);
                assert_eq!(f.intensity[i], 0.0);
                assert!(f.sigma[i].is_nan());
                // Saturated: nearer than the 0.5 m range filter, kept anyway; too dark:
                // far, or no wall within reach (exact NaN).
                let r = x.norm();
                let saturated = r < 0.5;
                assert!(saturated || r.is_nan() || r > 2.0, "{r}");
                if saturated == (expect == "saturated") {
                    of_kind += 1;
                }
            }
        }
        eprintln!(
            "{d} m pipe: {invalid} invalid pixels ({of_kind} {expect}) of {} kept",
            f.len()
        );
        assert!(of_kind > 1000, "{of_kind}");
    }
}

/// Row gaps closed and subsampling keep every list aligned: each kept point equals the
/// full frame's point of the same pixel (the row streams do not depend on subsampling).
#[test]
fn subsample_keeps_intensity_and_sigma_with_their_points() {
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 5, 1)
        .unwrap();
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    let sensor = Sensor {
        min_range: 0.5,
        max_range: 2.0,
        ..Sensor::helios2()
    };
    let noise = Noise {
        outlier_fraction: 0.02,
        ..with(ToFPhysics::helios2())
    };
    let seeds = FrameSeed {
        seed: 3,
        trial: 1,
        sweep_index: 0,
    };
    let full = simulate(&sensor, &scene, &noise, Subsample::All, seeds).unwrap();
    let sub = simulate(&sensor, &scene, &noise, Subsample::Points(2000), seeds).unwrap();
    assert_eq!(sub.len(), 2000);
    let index: std::collections::HashMap<[u32; 2], usize> = full
        .pixels
        .iter()
        .enumerate()
        .map(|(i, &p)| (p, i))
        .collect();
    for i in 0..sub.len() {
        let j = index[&sub.pixels[i]];
        assert_eq!(sub.measured[i], full.measured[j]);
        assert_eq!(
            sub.exact[i].map(f64::to_bits),
            full.exact[j].map(f64::to_bits)
        );
        assert_eq!(sub.intensity[i].to_bits(), full.intensity[j].to_bits());
        assert_eq!(sub.sigma[i].to_bits(), full.sigma[j].to_bits());
    }
    let mut valid = full.clone();
    valid.retain_valid();
    assert!(valid.len() < full.len());
    assert!((0..valid.len()).all(|i| valid.is_valid(i) && valid.sigma[i].is_finite()));
}

#[test]
fn physical_frames_identical_for_one_and_two_threads() {
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 9, 4)
        .unwrap();
    for wall in [WallModel::Exact, WallModel::Mesh { segments: 512 }] {
        let scene = Scene::new(&truth, wall, 8.0).unwrap();
        let noise = Noise {
            outlier_fraction: 0.01,
            far_outlier_fraction: 0.01,
            ..with(ToFPhysics::helios2())
        };
        let run = |threads: usize, sweep_index: u64| {
            on_threads(threads, || {
                simulate(
                    &Sensor::helios2(),
                    &scene,
                    &noise,
                    Subsample::Points(20_000),
                    FrameSeed {
                        seed: 9,
                        trial: 4,
                        sweep_index,
                    },
                )
                .unwrap()
            })
        };
        let one = run(1, 1);
        assert_eq!(bits(&one), bits(&run(2, 1)));
        assert_ne!(bits(&one), bits(&run(2, 2)));
    }
}

/// `physics: None` leaves frames bit-identical to the simulator before the physical model:
/// FNV-1a-style hashes (prime 0x100000001b3, basis 1469598103934665603) of the measured, exact and direction bits and the pixels, recorded at
/// commit dc14748 (x86-64), for range and isotropic noise, outliers, bias, subsampling,
/// the exact wall and a mesh.
#[test]
fn plain_model_frames_are_bit_identical_to_before() {
    let truth = PoseRanges::default()
        .sample(&Pipe::paper_20in(), 7, 3)
        .unwrap();
    let want = [
        (185137, 0x3fa5d2b078238681u64),
        (188600, 0x4d312825f6814450),
        (5000, 0xc09b082f88852c5c),
        (100, 0x59b45b086e005881),
        (185134, 0xea10d36eccf9a413),
        (188594, 0xc4fa40bbc9b918c9),
        (5000, 0x9a1467608570abc8),
        (100, 0xddd3753d1ffb7451),
    ];
    let mut got = Vec::new();
    for (wall, lim) in [
        (WallModel::Exact, 6.0),
        (WallModel::Mesh { segments: 256 }, 8.0),
    ] {
        let scene = Scene::new(&truth, wall, lim).unwrap();
        let n1 = Noise {
            outlier_fraction: 0.05,
            far_outlier_fraction: 0.02,
            bias_b0: 0.01,
            bias_b1: 0.003,
            ..Noise::range(0.03)
        };
        let n2 = Noise {
            model: NoiseModel::Isotropic,
            ..n1
        };
        for (noise, sub) in [
            (Noise::range(0.03), Subsample::All),
            (n1, Subsample::All),
            (n2, Subsample::Points(5000)),
            (Noise::none(), Subsample::Points(100)),
        ] {
            let s = Sensor {
                min_range: 0.5,
                max_range: 2.0,
                ..Sensor::helios2()
            };
            let seeds = FrameSeed {
                seed: 5,
                trial: 2,
                sweep_index: 1,
            };
            let f = simulate(&s, &scene, &noise, sub, seeds).unwrap();
            let mut h: u64 = 1_469_598_103_934_665_603;
            let mut eat = |x: u64| {
                h ^= x;
                h = h.wrapping_mul(0x100_0000_01b3);
            };
            for i in 0..f.len() {
                for k in 0..3 {
                    eat(f.measured[i][k].to_bits());
                    eat(f.exact[i][k].to_bits());
                    eat(f.directions[i][k].to_bits());
                }
                eat(f.pixels[i][0] as u64);
                eat(f.pixels[i][1] as u64);
            }
            got.push((f.len(), h));
        }
    }
    assert_eq!(got, want);
}

/// Figures of the Helios2 preset in the paper's 20" pipe, sensor on the axis: σ, the
/// systematic error and the share of invalid pixels, by range.
#[test]
fn helios2_figures_in_the_20in_pipe() {
    let p = ToFPhysics::helios2();
    let r0 = 0.242;
    for r in [0.5, 1.0, 2.0, 3.0] {
        let a = p.amplitude(r, r0 / r);
        let (mp, am) = p.multipath(r, a);
        eprintln!(
            "r = {r} m: A = {a:.4}, A_measured = {am:.4}, σ = {:.1} mm, wiggle {:+.1} mm, offset {:+.1} mm, multipath {:+.1} mm, systematic {:+.1} mm",
            p.sigma_at(am) * 1e3,
            p.wiggle(r) * 1e3,
            p.amplitude_offset(am) * 1e3,
            mp * 1e3,
            p.systematic_error(r, a) * 1e3
        );
    }
    let at = |r: f64| p.sigma_at(p.multipath(r, p.amplitude(r, r0 / r)).1);
    assert!((0.001..0.004).contains(&at(0.5)));
    assert!((0.01..0.03).contains(&at(2.0)), "{}", at(2.0));
    let scene = Scene::new(&pipe(2.0 * r0, 0.0), WallModel::Exact, 6.0).unwrap();
    let f = physical_frame(&Sensor::helios2(), &scene, p);
    let invalid = (0..f.len()).filter(|&i| !f.is_valid(i)).count();
    let far_valid = (0..f.len())
        .filter(|&i| f.is_valid(i))
        .map(|i| Vector3::from(f.exact[i]).norm())
        .fold(0.0, f64::max);
    eprintln!(
        "full frame: {} points, {invalid} invalid, farthest valid wall point {far_valid:.2} m",
        f.len()
    );
    assert_eq!(
        f.len(),
        640 * 480,
        "every pixel is either valid in range or invalid"
    );
    assert!((3.0..4.5).contains(&far_valid));
}
