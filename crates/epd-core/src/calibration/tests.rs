//! Unit tests of the depth table and the rig.

use super::table::{clipped_mean, norm};
use super::*;

fn bins(nr: usize, ni: usize) -> TableBins {
    TableBins {
        range: Axis {
            lo: 0.5,
            hi: 2.0,
            n: nr,
        },
        log_intensity: Axis {
            lo: 0.0,
            hi: 6.0,
            n: ni,
        },
        min_count: 10,
    }
}

/// A smooth known error: the table reproduces it at the bin centres exactly and in
/// between to the interpolation error of a linear function (zero).
#[test]
fn linear_error_is_reproduced_everywhere() {
    let f = |r: f64, li: f64| 0.004 * r - 0.001 * li + 0.002;
    let mut obs = vec![];
    for a in 0..300 {
        for b in 0..60 {
            let r = 0.5 + 1.5 * (a as f64 + 0.5) / 300.0;
            let li = 6.0 * (b as f64 + 0.5) / 60.0;
            obs.push(Observation {
                model_range_m: r,
                intensity: li.exp(),
                offset_m: f(r, li),
            });
        }
    }
    let t = DepthTable::build(&obs, &bins(15, 6)).unwrap();
    assert!(t.count.iter().all(|&c| c > 0));
    // Within the outer centres the bilinear interpolation of a linear function is
    // exact up to the mean within a bin (also exact: the bins sample it evenly).
    for (r, li) in [(0.6, 0.6), (1.23, 2.7), (1.9, 5.4)] {
        let got = t.offset_at(r, f64::exp(li));
        assert!(
            (got - f(r, li)).abs() < 1e-9,
            "{r} {li}: {got} vs {}",
            f(r, li)
        );
    }
    // Beyond the outer centres the table is constant.
    assert_eq!(t.offset_at(0.1, 1.0), t.offset_at(0.5, 1.0));
    assert_eq!(t.offset_at(9.0, 1e9), t.offset_at(2.0, 6f64.exp()));
}

#[test]
fn robust_mean_ignores_flying_pixels_and_spread_is_sigma() {
    // Deterministic "noise": a symmetric comb of ±σ·z values, plus 5 % gross errors.
    let mut v: Vec<f64> = (0..2000)
        .map(|k| {
            let z = (k as f64 + 0.5) / 2000.0;
            0.003 + 0.01 * inverse_normal(z)
        })
        .collect();
    v.extend(std::iter::repeat_n(1.0, 100));
    let (m, s) = clipped_mean(&mut v);
    assert!((m - 0.003).abs() < 2e-4, "{m}");
    // The MAD is not deaf to 5 % one-sided contamination: its median moves into the
    // tail, ≈ +6 % here (without the gross errors it is exact to 0.2 %).
    assert!((s - 0.01).abs() < 8e-4, "{s}");
    let mut clean: Vec<f64> = v[..].iter().copied().filter(|x| *x < 0.5).collect();
    let (_, s0) = clipped_mean(&mut clean);
    assert!((s0 - 0.01).abs() < 2e-5, "{s0}");
}

/// Acklam-free inverse normal by bisection of erf (test only).
fn inverse_normal(p: f64) -> f64 {
    let cdf = |x: f64| 0.5 * (1.0 + erf(x / std::f64::consts::SQRT_2));
    let (mut lo, mut hi) = (-10.0, 10.0);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if cdf(mid) < p { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

fn erf(x: f64) -> f64 {
    // Abramowitz & Stegun 7.1.26 is too coarse for a test oracle; integrate instead.
    let n = 2000;
    let h = x / n as f64;
    let f = |t: f64| (-t * t).exp();
    let mut s = f(0.0) + f(x);
    for k in 1..n {
        s += f(k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 };
    }
    s * h / 3.0 * 2.0 / std::f64::consts::PI.sqrt()
}

#[test]
fn empty_bins_take_the_nearest_filled_bin() {
    // Observations only in range bin 0 (intensity bin 0) and range bin 3 (bin 1).
    let mut obs = vec![];
    for k in 0..20 {
        // ± 1 mm of noise about the bin's offset.
        let e = if k % 2 == 0 { 0.001 } else { -0.001 };
        obs.push(Observation {
            model_range_m: 0.6,
            intensity: 1.5,
            offset_m: 0.01 + e,
        });
        obs.push(Observation {
            model_range_m: 1.9,
            intensity: 3f64.exp(),
            offset_m: -0.02 + e,
        });
    }
    let t = DepthTable::build(&obs, &bins(4, 2)).unwrap();
    assert_eq!(t.count, vec![20, 0, 0, 0, 0, 0, 0, 20]);
    // Row 0: bin (0, 1) from (0, 0); row 3: (3, 0) from (3, 1); the empty rows 1
    // and 2 from their nearest filled rows, 0 and 3.
    let (a, b) = (t.offset_m[0], t.offset_m[7]);
    assert!((a - 0.01).abs() < 1e-12 && (b + 0.02).abs() < 1e-12);
    assert_eq!(&t.offset_m[..4], &[a, a, a, a]);
    assert_eq!(&t.offset_m[4..], &[b, b, b, b]);
    assert!(t.validate().is_ok());
    // Only the observed bins are covered; filled ones and points off the axes are not.
    assert!(t.covers(0.6, 1.5) && t.covers(1.9, 3f64.exp()));
    assert!(!t.covers(0.6, 3f64.exp()) && !t.covers(1.0, 1.5));
    assert!(!t.covers(2.1, 3f64.exp()) && !t.covers(0.6, 1e4) && !t.covers(0.6, 0.0));
    // No observation at all: refused with a reason.
    let e = DepthTable::build(&[], &bins(4, 2)).unwrap_err().to_string();
    assert!(e.contains("no bin"), "{e}");
}

#[test]
fn correction_moves_points_along_their_ray() {
    let obs: Vec<Observation> = (0..100)
        .map(|k| Observation {
            model_range_m: 0.5 + 1.5 * k as f64 / 100.0,
            intensity: 10.0,
            offset_m: 0.02 + if k % 2 == 0 { 0.001 } else { -0.001 },
        })
        .collect();
    let b = TableBins {
        min_count: 1,
        ..bins(1, 1)
    };
    let t = DepthTable::build(&obs, &b).unwrap();
    let mut pts = [[1.0, 0.2, -0.1], [0.0, 0.0, 0.0], [f64::NAN, 1.0, 1.0]];
    let before = pts;
    let mut again = pts;
    let moved = t.correct(&mut pts, &[10.0, 10.0, 10.0]).unwrap();
    assert_eq!(moved, 1);
    let (m2, sig) = t.correct_with_sigmas(&mut again, &[10.0; 3]).unwrap();
    assert_eq!(m2, 1);
    assert_eq!(again[0], pts[0]);
    assert_eq!(sig[0], t.sigma_at(norm(&pts[0]), 10.0));
    assert!(sig[1].is_nan() && sig[2].is_nan());
    let r0 = norm(&before[0]);
    assert!((norm(&pts[0]) - (r0 - 0.02)).abs() < 1e-12);
    assert!((t.true_range(1.3, 10.0) - 1.28).abs() < 1e-12);
    // Without a usable intensity a valid point cannot be corrected: it becomes NaN.
    let mut q = [[1.0, 0.2, -0.1], [1.0, 0.1, 0.1]];
    assert_eq!(t.correct(&mut q, &[0.0, f64::NAN]).unwrap(), 0);
    assert!(q.iter().all(|p| p[0].is_nan()));
    // Same direction.
    let c = (0..3).map(|k| pts[0][k] * before[0][k]).sum::<f64>() / (norm(&pts[0]) * r0);
    assert!((c - 1.0).abs() < 1e-12);
    assert_eq!(pts[1], [0.0; 3]);
    assert!(pts[2][0].is_nan());
    assert!(t.correct(&mut pts, &[1.0]).is_err());
}

/// The tabulated inverse that `correct` uses agrees with the fixed-point solution
/// of ρ + T(ρ, I) = r to 20 µm on a table with wiggles and an intensity trend.
#[test]
fn tabulated_inverse_matches_the_fixed_point() {
    let f = |r: f64, li: f64| 0.03 + 0.02 * r + 0.006 * (4.19 * r).sin() - 0.003 * li;
    let mut obs = vec![];
    for a in 0..600 {
        for b in 0..40 {
            let r = 0.5 + 1.5 * (a as f64 + 0.5) / 600.0;
            let li = 1.0 + 6.0 * (b as f64 + 0.5) / 40.0;
            obs.push(Observation {
                model_range_m: r,
                intensity: li.exp(),
                offset_m: f(r, li),
            });
        }
    }
    let b = TableBins {
        range: Axis {
            lo: 0.5,
            hi: 2.0,
            n: 30,
        },
        log_intensity: Axis {
            lo: 1.0,
            hi: 7.0,
            n: 12,
        },
        min_count: 10,
    };
    let t = DepthTable::build(&obs, &b).unwrap();
    let inv = t.inverse();
    let mut worst: f64 = 0.0;
    for k in 0..5000 {
        let r = 0.3 + 2.2 * (k as f64 * 0.618_034).fract();
        let li = 0.5 + 7.0 * (k as f64 * 0.414_214).fract();
        let exact = t.true_range(r, li.exp());
        // The fixed point holds to its own tolerance.
        assert!((exact + t.offset_at(exact, li.exp()) - r).abs() < 2e-5);
        worst = worst.max((inv.true_range(r, li) - exact).abs());
    }
    assert!(worst < 2e-5, "{worst}");
}

#[test]
fn corrupt_tables_are_refused() {
    let obs: Vec<Observation> = (0..100)
        .map(|k| Observation {
            model_range_m: 0.5 + 1.5 * k as f64 / 100.0,
            intensity: 10.0,
            offset_m: if k % 2 == 0 { 0.001 } else { -0.001 },
        })
        .collect();
    let mut t = DepthTable::build(
        &obs,
        &TableBins {
            min_count: 1,
            ..bins(2, 1)
        },
    )
    .unwrap();
    t.offset_m.pop();
    assert!(t.validate().unwrap_err().to_string().contains("offsets"));
    t.offset_m.push(f64::NAN);
    assert!(
        t.validate()
            .unwrap_err()
            .to_string()
            .contains("not a depth error")
    );
    *t.offset_m.last_mut().unwrap() = 1e300;
    assert!(
        t.validate()
            .unwrap_err()
            .to_string()
            .contains("not a depth error")
    );
    *t.offset_m.last_mut().unwrap() = 0.0;
    t.spread_m[0] = 0.0;
    assert!(t.validate().unwrap_err().to_string().contains("spread"));
    t.spread_m[0] = 0.01;
    t.range.lo = -5.0;
    assert!(t.validate().unwrap_err().to_string().contains("range axis"));
    t.range.lo = 0.5;
    t.log_intensity.hi = 1e308;
    assert!(
        t.validate()
            .unwrap_err()
            .to_string()
            .contains("log-intensity")
    );
}

/// A table of `nr × ni` bins over [0.5, 2] m × [1, 7] whose offset is a smooth function
/// (as `DepthTable::validate` accepts it).
fn smooth_table(nr: usize, ni: usize) -> DepthTable {
    let range = Axis {
        lo: 0.5,
        hi: 2.0,
        n: nr,
    };
    let log_intensity = Axis {
        lo: 1.0,
        hi: 7.0,
        n: ni,
    };
    let cells = nr * ni;
    let offset_m = (0..cells)
        .map(|k| {
            let (i, j) = ((k / ni) as f64 / nr as f64, (k % ni) as f64 / ni as f64);
            0.01 + 0.006 * (12.0 * i).sin() - 0.003 * j
        })
        .collect();
    let t = DepthTable {
        range,
        log_intensity,
        offset_m,
        spread_m: vec![0.01; cells],
        count: vec![40; cells],
    };
    t.validate().expect("a valid table");
    t
}

/// Points of a frame in a pipe: ranges 0.6 to 1.9 m, intensities e^1.5 to e^6.5.
fn frame_points(n: usize) -> (Vec<[f64; 3]>, Vec<f64>) {
    (0..n)
        .map(|k| {
            let u = (k as f64 * 0.618_034).fract();
            let v = (k as f64 * 0.414_214).fract();
            let r = 0.6 + 1.3 * u;
            let dir = [0.8, 0.6 * (6.0 * v).cos(), 0.6 * (6.0 * v).sin()];
            ([r * dir[0], r * dir[1], r * dir[2]], (1.5 + 5.0 * v).exp())
        })
        .unzip()
}

/// A table too fine for the tabulated inverse within MAX_INVERSE_CELLS (issue 27: 200 000
/// intensity bins made the inverse allocate 65 537 × 200 000 values and abort the
/// process) is tabulated on a coarser grid: bounded, and as close to the fixed point as a
/// real table's inverse.
#[test]
fn a_table_too_fine_to_tabulate_is_tabulated_coarser() {
    for (nr, ni) in [(1, 200_000), (1 << 20, 1), (1024, 1024), (30, 12)] {
        let t = smooth_table(nr, ni);
        let inv = t.inverse();
        assert!(inv.rho.len() <= MAX_INVERSE_CELLS, "{nr} × {ni}");
        let (mut pts, i) = frame_points(5000);
        let before = pts.clone();
        let (moved, sigma) = t.correct_with_sigmas(&mut pts, &i).unwrap();
        assert_eq!(moved, pts.len());
        let mut worst: f64 = 0.0;
        for ((p, q), (&ik, &s)) in pts.iter().zip(&before).zip(i.iter().zip(&sigma)) {
            worst = worst.max((norm(p) - t.true_range(norm(q), ik)).abs());
            assert!((s - 0.01).abs() < 1e-15, "{s}");
        }
        // 50 µm: the 30 × 12 table's own tabulated inverse is 29 µm off its fixed point
        // here (its offsets wiggle within a few bins).
        assert!(worst < 5e-5, "{nr} × {ni}: {worst}");
    }
}

#[test]
fn bin_counts_and_axis_spans_beyond_the_limits_are_refused() {
    let mut t = smooth_table(4, 2);
    t.range.n = MAX_TABLE_BINS;
    let e = t.validate().unwrap_err().to_string();
    assert!(e.contains("at most 1048576 (2²⁰) bins"), "{e}");
    t.range.n = usize::MAX;
    let e = t.validate().unwrap_err().to_string();
    assert!(e.contains("1048576"), "{e}");
    // A range axis 1e-9 m wide cannot have been measured.
    let mut t = smooth_table(4, 2);
    t.range.hi = t.range.lo + 1e-9;
    let e = t.validate().unwrap_err().to_string();
    assert!(
        e.contains("range axis") && e.contains("at least 0.001"),
        "{e}"
    );
    let mut t = smooth_table(4, 2);
    t.log_intensity.hi = t.log_intensity.lo + 1e-6;
    let e = t.validate().unwrap_err().to_string();
    assert!(e.contains("log-intensity axis"), "{e}");
}

/// Points counted within both axes, and invalid ones not at all.
#[test]
fn points_within_the_axes_are_counted() {
    let t = smooth_table(4, 2);
    let pts = [
        [1.0, 0.0, 0.0],
        [3.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0; 3],
        [f64::NAN, 0.0, 0.0],
    ];
    let i = [10.0, 10.0, 1e9, 10.0, 10.0];
    assert_eq!(t.within_axes(&pts, &i), (3, 1));
    assert_eq!(t.within_axes(&pts[1..], &i[1..]), (2, 0));
}
