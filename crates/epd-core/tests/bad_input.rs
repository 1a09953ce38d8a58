//! Bad input is an error or a status, never a panic and never NaN in the output.

mod common;

use epd_core::{EpdError, EstimateOptions, Method, estimate};
use proptest::prelude::*;

fn opts() -> EstimateOptions {
    EstimateOptions::default()
}

fn assert_finite(est: &epd_core::Estimate) {
    assert!(est.params.is_finite(), "{est:?}");
    assert!(est.cost.is_finite() && est.rms_residual.is_finite());
    assert!(
        est.sigma
            .iter()
            .flatten()
            .all(|s| s.is_finite() && *s >= 0.0)
    );
}

#[test]
fn too_few_points() {
    let pts = [[1.0, 0.1, 0.2]; 6];
    for m in Method::ALL {
        match estimate(&pts, m, &opts()) {
            Err(EpdError::TooFewPoints { usable: 6, .. }) => {}
            other => panic!("{other:?}"),
        }
    }
    let empty: [[f64; 3]; 0] = [];
    assert!(matches!(
        estimate(&empty, Method::RuEpd, &opts()),
        Err(EpdError::TooFewPoints { usable: 0, .. })
    ));
}

#[test]
fn non_finite_and_zero_points_are_dropped_and_counted() {
    let truth = common::random_params(&mut common::rng(3), common::id_m(20.0), 0.02, 5.0, 0.2);
    let mut pts = common::cloud(&truth, 160, 120, 6.0, 0.0, 0, 1);
    let good = pts.len();
    pts.push([f64::NAN, 0.0, 0.0]);
    pts.push([0.0, 0.0, 0.0]);
    pts.push([f64::INFINITY, 1.0, 2.0]);
    pts.insert(0, [0.0, f64::NEG_INFINITY, 0.0]);
    let est = estimate(&pts, Method::RuEpd, &opts()).unwrap();
    assert_eq!(est.n_points, good);
    assert_eq!(est.n_dropped, 4);
    assert!((est.params.d_max - truth.d_max).abs() < 1e-9);
}

/// Points absurdly far from the sensor are named (issue 27: one point at 1e300 gave "no
/// step lowers the cost", 0.3 % at 1e30 "points lie on a plane").
#[test]
fn absurdly_far_points_are_named() {
    let truth = common::random_params(&mut common::rng(3), common::id_m(20.0), 0.02, 5.0, 0.2);
    let pts = common::cloud(&truth, 160, 120, 6.0, 0.01, 0, 1);
    let mut one = pts.clone();
    one[17] = [1e300, 2.0, 3.0];
    let mut some = pts.clone();
    let n = pts.len() * 3 / 1000;
    for p in some.iter_mut().skip(5).step_by(pts.len() / n).take(n) {
        *p = [p[0] * 1e30, p[1] * 1e30, p[2] * 1e30];
    }
    for (cloud, count, index) in [(&one, 1, 17), (&some, n, 5)] {
        let p = cloud[index];
        let r = (p[0] / 1e30).hypot(p[1] / 1e30).hypot(p[2] / 1e30) * 1e30;
        for m in Method::ALL {
            let e = estimate(cloud, m, &opts()).unwrap_err();
            assert!(
                matches!(e, EpdError::FarPoints { count: c, index: i, .. } if c == count && i == index),
                "{m:?}: {e}"
            );
            let text = e.to_string();
            let at = format!("point {index}, at ");
            assert!(
                text.contains("farther than 1000 m") && text.contains(&at),
                "{text}"
            );
            let shown: f64 = text
                .split(&at)
                .nth(1)
                .and_then(|t| t.split(' ').next())
                .and_then(|v| v.parse().ok())
                .unwrap_or(f64::NAN);
            assert!((shown / r - 1.0).abs() < 1e-12, "{text} vs {r}");
            let sigma = vec![0.01; cloud.len()];
            let e = epd_core::estimate_weighted(cloud, &sigma, m, &opts()).unwrap_err();
            assert!(matches!(e, EpdError::FarPoints { .. }), "{e}");
        }
    }
    // At the limit: fitted (a point 999 m away is an outlier, not an error).
    let mut near = pts.clone();
    near[3] = [999.0, 0.0, 0.0];
    assert!(estimate(&near, Method::MlEpd, &opts()).is_ok());
}

#[test]
fn degenerate_geometries_are_errors() {
    let plane: Vec<[f64; 3]> = (0..400)
        .map(|i| {
            [
                1.0 + (i % 20) as f64 * 0.1,
                (i / 20) as f64 * 0.05 - 0.5,
                -0.25,
            ]
        })
        .collect();
    let line: Vec<[f64; 3]> = (0..100)
        .map(|i| [1.0 + i as f64 * 0.01, 0.2, 0.1])
        .collect();
    let same = vec![[1.0, 0.2, 0.1]; 100];
    // A cloud that is no pipe: points on a sphere around the sensor.
    let sphere: Vec<[f64; 3]> = (0..500)
        .map(|i| {
            let (a, b) = (i as f64 * 0.37, (i as f64 * 0.11).sin());
            [b.cos() * a.cos(), b.cos() * a.sin(), b.sin()]
        })
        .collect();
    // Points all on one side of the sensor: the sensor is outside whatever fits them.
    let outside: Vec<[f64; 3]> = (0..500)
        .map(|i| {
            let phi = i as f64 * 0.05;
            [
                1.0 + (i % 23) as f64 * 0.1,
                2.0 + 0.2 * phi.cos(),
                0.2 * phi.sin(),
            ]
        })
        .collect();
    for (name, pts) in [
        ("plane", plane),
        ("line", line),
        ("same", same),
        ("sphere", sphere),
        ("outside", outside),
    ] {
        for m in Method::ALL {
            let strict = matches!(name, "plane" | "line" | "same" | "sphere");
            match estimate(&pts, m, &opts()) {
                Err(e) => {
                    eprintln!("{name} {m}: {e}");
                    assert!(matches!(e, EpdError::Degenerate(_) | EpdError::NotAPipe(_)));
                }
                Ok(est) => {
                    eprintln!("{name} {m}: Ok {:?} rms {}", est.status, est.rms_residual);
                    assert!(!strict, "{name} {m} must be an error: {est:?}");
                    // Allowed only as a flagged status with finite numbers.
                    assert_finite(&est);
                    assert!(
                        !est.status.is_converged() || est.rms_residual > 1e-3,
                        "{name} {m}: {est:?}"
                    );
                }
            }
        }
    }
}

fn finite_coord() -> impl Strategy<Value = f64> {
    prop_oneof![
        -10.0..10.0f64,
        Just(0.0),
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(1e-300),
        Just(1e300),
        -1e6..1e6f64,
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, .. ProptestConfig::default() })]

    /// Random clouds: never a panic, never a NaN in an Ok result.
    #[test]
    fn random_clouds_never_panic(pts in prop::collection::vec(prop::array::uniform3(finite_coord()), 0..200), m in 0usize..3) {
        if let Ok(est) = estimate(&pts, Method::ALL[m], &opts()) {
            assert_finite(&est);
        }
    }

    /// Real pipe clouds with adversarial corruption: a fraction of points replaced by
    /// garbage, duplicated or scaled.
    #[test]
    fn corrupted_pipe_clouds_never_panic(seed in 0u64..1000, frac in 0.0..0.9f64, mode in 0usize..3, m in 0usize..3) {
        let truth = common::random_params(&mut common::rng(seed), common::id_m(20.0), 0.02, 15.0, 0.25);
        let mut pts = common::cloud(&truth, 40, 30, 6.0, 0.02, 0, seed);
        let k = (pts.len() as f64 * frac) as usize;
        for i in 0..k {
            let v = (i as f64 * 1.618).fract();
            pts[i] = match mode {
                0 => [v * 100.0 - 50.0, v * 1e-9, -v],
                1 => pts[pts.len() - 1],
                _ => [pts[i][0] * 1e8, pts[i][1], pts[i][2] * 1e-8],
            };
        }
        if let Ok(est) = estimate(&pts, Method::ALL[m], &opts()) {
            assert_finite(&est);
        }
    }
}

/// A loss scale outside `loss::SCALE_RANGE` is refused naming the range (1e200 m had
/// overflowed c² and "converged after 0 iterations" off the truth); at the range's top the
/// Cauchy and Huber fits are least squares' (to 1e-9 relative), as a scale far above every
/// residual should make them.
#[test]
fn loss_scales_beyond_their_range_are_refused_and_its_top_is_least_squares() {
    use epd_core::Loss;
    let (lo, hi) = epd_core::loss::SCALE_RANGE;
    for scale in [1e200, f64::MAX, lo / 10.0, 0.0, -1.0, f64::NAN] {
        for loss in [Loss::Cauchy { scale }, Loss::Huber { scale }] {
            match opts().with_loss(loss) {
                Err(EpdError::InvalidOption(m)) => assert!(m.contains("must lie in"), "{m}"),
                other => panic!("{scale}: {other:?}"),
            }
        }
    }
    let truth = epd_core::Params {
        d_max: 0.49,
        d_min: 0.48,
        roll: 0.3,
        pitch: 0.02,
        yaw: -0.03,
        dy: 0.02,
        dz: -0.01,
    };
    let pts = common::cloud(&truth, 160, 120, 6.0, 0.02, 0, 3);
    for m in [Method::MlEpd, Method::CEpd] {
        let ls = estimate(&pts, m, &opts()).unwrap();
        for loss in [Loss::Cauchy { scale: hi }, Loss::Huber { scale: hi }] {
            let robust = estimate(&pts, m, &opts().with_loss(loss).unwrap()).unwrap();
            assert!(
                robust.status.is_converged(),
                "{m:?} {loss:?}: {:?}",
                robust.status
            );
            let (a, b) = (ls.params.to_array(), robust.params.to_array());
            for (x, y) in a.iter().zip(b) {
                assert!(
                    (x - y).abs() <= 1e-9 * x.abs().max(1.0),
                    "{m:?} {loss:?}: {a:?} vs {b:?}"
                );
            }
        }
    }
}
