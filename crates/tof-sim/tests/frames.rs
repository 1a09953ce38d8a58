//! The simulator against independent oracles: the analytic quadratic, a parry TriMesh,
//! a hand-derived pixel count, noise statistics, determinism, configuration errors.

use epd_core::Params;
use nalgebra::{Point3, Vector3};
use tof_sim::{
    FrameSeed, Noise, NoiseModel, Pipe, PoseRanges, Scene, Sensor, SimError, Subsample, WallModel,
    simulate,
};

mod common;

use common::determinism::{bits, on_threads};

/// The wall range along unit `d` (SCS) by the quadratic in the PCS, written here anew.
fn oracle_range(b: &Params, d: &Vector3<f64>) -> Option<f64> {
    let o = b.scs_to_pcs(&Point3::origin());
    let q = b.dir_scs_to_pcs(d);
    let (ia, ib) = (4.0 / (b.d_max * b.d_max), 4.0 / (b.d_min * b.d_min));
    let a = q.y * q.y * ia + q.z * q.z * ib;
    let bb = 2.0 * (o.y * q.y * ia + o.z * q.z * ib);
    let c = o.y * o.y * ia + o.z * o.z * ib - 1.0;
    let disc = bb * bb - 4.0 * a * c;
    (a > 0.0 && disc >= 0.0).then(|| (-bb + disc.sqrt()) / (2.0 * a))
}

/// A sensor on the axis of an untilted pipe of diameters `d_max`, `d_min` (m).
fn centred(d_max: f64, d_min: f64) -> Params {
    Params {
        d_max,
        d_min,
        roll: 0.0,
        pitch: 0.0,
        yaw: 0.0,
        dy: 0.0,
        dz: 0.0,
    }
}

/// The full noise-free Helios2 frame of `scene`.
fn noise_free_frame(scene: &Scene) -> tof_sim::Frame {
    simulate(
        &Sensor::helios2(),
        scene,
        &Noise::none(),
        Subsample::All,
        FrameSeed::default(),
    )
    .unwrap()
}

fn random_truths(n: u64) -> Vec<Params> {
    let mut pipe = Pipe::paper_20in();
    (0..n)
        .map(|k| {
            pipe.nominal_od_in = 16.0 + (k % 8) as f64 * 2.0;
            pipe.ovality = 0.01 * (k % 6) as f64;
            let ranges = PoseRanges {
                pitch: (-0.25, 0.25),
                yaw: (-0.25, 0.25),
                ..PoseRanges::default()
            };
            ranges.sample(&pipe, 42, k).unwrap()
        })
        .collect()
}

#[test]
fn exact_shape_matches_the_quadratic_and_points_lie_on_wall_and_ray() {
    let sensor = Sensor::helios2();
    for truth in random_truths(6) {
        let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
        let f = noise_free_frame(&scene);
        assert!(f.measured.len() > 250_000);
        for i in 0..f.exact.len() {
            let x = Vector3::from(f.exact[i]);
            let d = Vector3::from(f.directions[i]);
            let [u, v] = f.pixels[i];
            assert!((sensor.ray_direction(u, v) - d).norm() < 1e-15);
            // On its pixel's ray.
            assert!(x.cross(&d).norm() < 1e-9 && x.dot(&d) > 0.0);
            // On the wall.
            let p = truth.scs_to_pcs(&Point3::from(x));
            let wall =
                (p.y / (truth.d_max / 2.0)).powi(2) + (p.z / (truth.d_min / 2.0)).powi(2) - 1.0;
            assert!(
                (wall * truth.d_min / 2.0).abs() < 1e-9,
                "off the wall by {wall}"
            );
            // The analytic quadratic.
            let r = oracle_range(&truth, &d).unwrap();
            assert!((x.norm() - r).abs() < 1e-9);
            // Noise-free: measured = exact.
            assert_eq!(f.measured[i], f.exact[i]);
        }
    }
}

/// Far points are seen at grazing incidence (sin φ ≈ R/6 m ≈ 0.04), which multiplies a
/// facet's radial error by 1/sin φ ≈ 25 in range: 1024 segments give up to 39 µm, 2048
/// segments (radial error ±0.15 µm) stay within 10 µm.
#[test]
fn closed_form_and_parry_trimesh_agree_within_10_um() {
    let sensor = Sensor::helios2();
    let mut worst = 0.0f64;
    for truth in random_truths(2) {
        let exact = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
        let mesh = Scene::new(&truth, WallModel::Mesh { segments: 2048 }, 8.0).unwrap();
        for v in 0..sensor.height {
            for u in 0..sensor.width {
                let d = sensor.ray_direction(u, v);
                let a = exact.cast(&d, 6.0);
                let b = mesh.cast(&d, 6.0);
                match (a, b) {
                    (Some(a), Some(b)) => worst = worst.max((a - b).abs()),
                    (None, None) => {}
                    // At the 6 m edge the two may differ by the tessellation depth.
                    (Some(a), None) | (None, Some(a)) => {
                        assert!(a > 6.0 - 1e-3, "({u}, {v}): one miss at {a}")
                    }
                }
            }
        }
    }
    eprintln!(
        "worst closed-form − mesh range difference: {:.3} µm",
        worst * 1e6
    );
    assert!(worst < 10e-6, "{worst}");
}

/// A centred sensor (no tilt, no offset) in a circular 20" pipe (ID 0.484 m, R = 0.242 m):
/// a ray at angle φ from the axis meets the wall at range R/sin φ, so it stays within 6 m
/// unless tan φ < R/√(36 − R²) = 0.040366. Those rays fill an ellipse of area
/// π·fx·fy·0.040366² = π·465.60·503.16·0.0016294 ≈ 1199 pixels at the image centre, so
/// 307 200 − 1199 ≈ 306 001 pixels are within 6 m (± the ~120-pixel rim of that ellipse).
#[test]
fn pixel_count_within_6m_matches_hand_derivation() {
    let truth = centred(0.484, 0.484);
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    let f = noise_free_frame(&scene);
    let n = f.measured.len() as f64;
    eprintln!("pixels within 6 m: {n}");
    assert!((n - 306_001.0).abs() < 60.0, "{n}");
}

fn stats(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
    (m, s)
}

/// The noise models' statistics over one full frame (n ≈ 3·10⁵ points), each checked
/// within 4 of its standard error (two-sided false-failure rate 6·10⁻⁵ each; 9 checks:
/// ≤ 6·10⁻⁴ for the test): a mean of n N(0, s²) draws has standard error s/√n; their
/// sample sd has relative standard error 1/√(2(n − 1)) (0.13 % here, so ±0.51 %); a
/// fraction of n Bernoulli(p) trials has standard error √(p(1 − p)/n) (0.054 % at
/// p = 0.1, so ±0.22 %).
#[test]
fn noise_statistics() {
    const Z: f64 = 4.0;
    let truth = random_truths(1)[0];
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    let sensor = Sensor {
        max_range: 100.0,
        ..Sensor::helios2()
    };
    let seeds = FrameSeed {
        seed: 3,
        trial: 1,
        sweep_index: 2,
    };
    // Range model: ε along the ray, mean 0, sd σ; no perpendicular part.
    let f = simulate(&sensor, &scene, &Noise::range(0.03), Subsample::All, seeds).unwrap();
    let mut eps = Vec::new();
    for i in 0..f.measured.len() {
        let (m, x, d) = (
            Vector3::from(f.measured[i]),
            Vector3::from(f.exact[i]),
            Vector3::from(f.directions[i]),
        );
        let e = m - x;
        assert!(e.cross(&d).norm() < 1e-12, "displacement off the ray");
        eps.push(e.dot(&d));
    }
    let (mean, sd) = stats(&eps);
    let n = eps.len() as f64;
    let sd_rel_se = 1.0 / (2.0 * (n - 1.0)).sqrt();
    eprintln!(
        "range noise: n {n}, mean {mean:.2e} (SE {:.1e}), sd/σ − 1 = {:.2e} (SE {sd_rel_se:.1e})",
        0.03 / n.sqrt(),
        sd / 0.03 - 1.0
    );
    assert!(mean.abs() < Z * 0.03 / n.sqrt(), "mean {mean}");
    assert!((sd / 0.03 - 1.0).abs() < Z * sd_rel_se, "sd {sd}");
    // Isotropic model: each coordinate N(0, σ²/3).
    let noise = Noise {
        model: NoiseModel::Isotropic,
        ..Noise::range(0.03)
    };
    let f = simulate(&sensor, &scene, &noise, Subsample::All, seeds).unwrap();
    let s = 0.03 / 3f64.sqrt();
    for k in 0..3 {
        let e: Vec<f64> = (0..f.measured.len())
            .map(|i| f.measured[i][k] - f.exact[i][k])
            .collect();
        let (mean, sd) = stats(&e);
        let n = e.len() as f64;
        let sd_rel_se = 1.0 / (2.0 * (n - 1.0)).sqrt();
        eprintln!(
            "isotropic axis {k}: mean {mean:.2e} (SE {:.1e}), sd/s − 1 = {:.2e} (SE {sd_rel_se:.1e})",
            s / n.sqrt(),
            sd / s - 1.0
        );
        assert!(mean.abs() < Z * s / n.sqrt(), "axis {k} mean {mean}");
        assert!((sd / s - 1.0).abs() < Z * sd_rel_se, "axis {k} sd {sd}");
    }
    // Depth bias b0 + b1·r along the ray, no random part.
    let noise = Noise {
        bias_b0: 0.01,
        bias_b1: 0.002,
        ..Noise::none()
    };
    let f = simulate(&sensor, &scene, &noise, Subsample::All, seeds).unwrap();
    for i in 0..f.measured.len() {
        let (m, x) = (Vector3::from(f.measured[i]), Vector3::from(f.exact[i]));
        assert!((m.norm() - x.norm() - (0.01 + 0.002 * x.norm())).abs() < 1e-12);
    }
    // Outliers: each point independently with probability p lands off the wall (its
    // range × U(0.5, 1.5), never exactly 1).
    let p = 0.1;
    let noise = Noise {
        outlier_fraction: p,
        far_outlier_fraction: 0.0,
        ..Noise::none()
    };
    let f = simulate(&sensor, &scene, &noise, Subsample::All, seeds).unwrap();
    let n = f.measured.len() as f64;
    let moved = (0..f.measured.len())
        .filter(|&i| f.measured[i] != f.exact[i])
        .count() as f64
        / n;
    let se = (p * (1.0 - p) / n).sqrt();
    eprintln!("outliers: fraction {moved:.5} (SE {se:.1e})");
    assert!((moved - p).abs() < Z * se, "{moved}");
}

#[test]
fn range_filter_and_subsample() {
    let truth = random_truths(1)[0];
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    let sensor = Sensor {
        min_range: 0.5,
        max_range: 2.0,
        ..Sensor::helios2()
    };
    let f = simulate(
        &sensor,
        &scene,
        &Noise::range(0.05),
        Subsample::All,
        FrameSeed::default(),
    )
    .unwrap();
    assert!(
        f.measured
            .iter()
            .all(|p| (0.5..=2.0).contains(&Vector3::from(*p).norm()))
    );
    let g = simulate(
        &sensor,
        &scene,
        &Noise::range(0.05),
        Subsample::Points(1000),
        FrameSeed::default(),
    )
    .unwrap();
    assert_eq!(g.measured.len(), 1000);
    // Distinct pixels, all from the full frame.
    let mut px = g.pixels.clone();
    px.dedup();
    assert_eq!(px.len(), 1000);
    assert!(g.pixels.iter().all(|p| f.pixels.contains(p)));
    // More than available: everything.
    let h = simulate(
        &sensor,
        &scene,
        &Noise::range(0.05),
        Subsample::Points(10_000_000),
        FrameSeed::default(),
    )
    .unwrap();
    assert_eq!(h.measured.len(), f.measured.len());
}

#[test]
fn identical_for_one_and_two_threads_and_a_function_of_the_seeds() {
    let truth = random_truths(1)[0];
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    let seeds = FrameSeed {
        seed: 9,
        trial: 4,
        sweep_index: 1,
    };
    let run = |threads: usize, seeds: FrameSeed| {
        on_threads(threads, || {
            simulate(
                &Sensor::helios2(),
                &scene,
                &Noise::range(0.03),
                Subsample::Points(5000),
                seeds,
            )
            .unwrap()
        })
    };
    let one = run(1, seeds);
    let two = run(2, seeds);
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(one.pixels, two.pixels);
    let other = run(
        2,
        FrameSeed {
            sweep_index: 2,
            ..seeds
        },
    );
    assert_ne!(bits(&one), bits(&other));
    // Poses depend on (seed, trial) only.
    let pipe = Pipe::paper_20in();
    let r = PoseRanges::default();
    assert_eq!(
        r.sample(&pipe, 1, 7).unwrap(),
        r.sample(&pipe, 1, 7).unwrap()
    );
    assert_ne!(
        r.sample(&pipe, 1, 7).unwrap(),
        r.sample(&pipe, 1, 8).unwrap()
    );
}

fn field_of(e: SimError) -> String {
    match e {
        SimError::Invalid { field, .. } => field.to_string(),
        other => panic!("not a field error: {other}"),
    }
}

#[test]
fn configuration_errors_name_the_field() {
    let truth = random_truths(1)[0];
    let scene = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    let run = |s: Sensor, n: Noise| {
        simulate(&s, &scene, &n, Subsample::All, FrameSeed::default()).map(|_| ())
    };
    let h = Sensor::helios2();
    let cases: Vec<(Result<(), SimError>, &str)> = vec![
        (
            run(
                Sensor {
                    fov_h: 180f64.to_radians(),
                    ..h
                },
                Noise::none(),
            ),
            "sensor.fov_h_deg",
        ),
        (
            run(
                Sensor {
                    fov_v: 200f64.to_radians(),
                    ..h
                },
                Noise::none(),
            ),
            "sensor.fov_v_deg",
        ),
        (run(Sensor { width: 0, ..h }, Noise::none()), "sensor.width"),
        (
            run(Sensor { height: 0, ..h }, Noise::none()),
            "sensor.height",
        ),
        (
            run(
                Sensor {
                    min_range: 3.0,
                    max_range: 3.0,
                    ..h
                },
                Noise::none(),
            ),
            "sensor.max_range_m",
        ),
        (run(h, Noise::range(-0.01)), "noise.sigma_m"),
        (
            run(
                h,
                Noise {
                    outlier_fraction: 1.5,
                    far_outlier_fraction: 0.0,
                    ..Noise::none()
                },
            ),
            "noise.outlier_fraction",
        ),
    ];
    for (r, field) in cases {
        assert_eq!(field_of(r.unwrap_err()), field);
    }
    let mut pipe = Pipe::paper_20in();
    pipe.ovality = -0.1;
    assert_eq!(
        field_of(PoseRanges::default().sample(&pipe, 1, 0).unwrap_err()),
        "pipe.ovality"
    );
    pipe.ovality = 0.02;
    pipe.wall_thickness = 0.3;
    assert_eq!(
        field_of(PoseRanges::default().sample(&pipe, 1, 0).unwrap_err()),
        "pipe.wall_thickness_mm"
    );
    let far = PoseRanges {
        dy: (0.3, 0.3),
        ..PoseRanges::default()
    };
    assert_eq!(
        field_of(far.sample(&Pipe::paper_20in(), 1, 0).unwrap_err()),
        "poses.dy_mm/dz_mm"
    );
    let bad = PoseRanges {
        pitch: (0.2, -0.2),
        ..PoseRanges::default()
    };
    assert_eq!(
        field_of(bad.sample(&Pipe::paper_20in(), 1, 0).unwrap_err()),
        "poses.pitch_deg"
    );
    let outside = Params { dy: 0.5, ..truth };
    assert!(Scene::new(&outside, WallModel::Exact, 6.0).is_err());
}

/// A geometry without a closed form: a pipe with a dent (the wall pushed 2 % inwards for
/// 1 m < x < 2 m, 0 < φ < 1 rad), as a parry TriMesh. Points in the dent lie on the
/// dented wall, the others on the ellipse, within the tessellation error.
#[test]
fn dented_pipe_as_a_trimesh() {
    let truth = centred(0.49, 0.47);
    let in_dent = |x: f64, phi: f64| (1.0..2.0).contains(&x) && (0.0..1.0).contains(&phi);
    let dent = |x: f64, phi: f64| if in_dent(x, phi) { 0.98 } else { 1.0 };
    let mesh = tof_sim::mesh::tube_mesh(0.245, 0.235, -1.0, 8.0, 2048, 181, Some(&dent)).unwrap();
    let scene = Scene::with_mesh(&truth, mesh).unwrap();
    let f = noise_free_frame(&scene);
    let (mut dented, mut plain) = (0, 0);
    for p in &f.exact {
        let q = truth.scs_to_pcs(&Point3::from(*p));
        let phi = q.z.atan2(q.y).rem_euclid(std::f64::consts::TAU);
        let ell = ((q.y / 0.245).powi(2) + (q.z / 0.235).powi(2)).sqrt();
        // Away from the dent's edges, where facets bridge the step.
        if in_dent(q.x, phi) && (1.05..1.95).contains(&q.x) && (0.05..0.95).contains(&phi) {
            assert!((ell - 0.98).abs() < 2e-4, "in the dent: {ell}");
            dented += 1;
        } else if !(0.9..2.1).contains(&q.x) {
            assert!((ell - 1.0).abs() < 2e-4, "outside the dent: {ell}");
            plain += 1;
        }
    }
    assert!(dented > 100 && plain > 100_000, "{dented} {plain}");
}
