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

/// Observations of two "rig sizes" along their own curves cos θ = R/r (I ∝ cos θ/r²),
/// an error linear in (r, ln I, ln cos θ).
fn two_rigs(radii: &[f64]) -> Vec<IncidenceObservation> {
    let f = |r: f64, li: f64, lc: f64| 0.004 * r - 0.002 * li + 0.01 * lc;
    let mut obs = vec![];
    for &rad in radii {
        for a in 0..3000 {
            let r = 0.5 + 1.5 * (a as f64 + 0.5) / 3000.0;
            for spread in [-0.02, 0.0, 0.02] {
                let c = (rad / r) * (1.0 + spread);
                let i = 500.0 * c / (r * r);
                obs.push(IncidenceObservation {
                    obs: Observation {
                        model_range_m: r,
                        intensity: i,
                        // A tiny deterministic jitter gives every bin a spread.
                        offset_m: f(r, i.ln(), c.ln()) + 1e-5 * ((a % 7) as f64 - 3.0),
                    },
                    cos_incidence: c,
                });
            }
        }
    }
    obs
}

/// The support: points on a rig's curve are observed, points between two rigs' curves
/// are bridged (corrected), points beyond every rig's curve are outside (not corrected,
/// counted, left out as NaN).
#[test]
fn the_incidence_table_corrects_inside_its_support_only() {
    let one = two_rigs(&[0.242]);
    let both = two_rigs(&[0.242, 0.369]);
    let bins =
        |o: &[IncidenceObservation]| IncidenceBins::spanning(o, (10, 8, 8), (0.5, 2.0), 5).unwrap();
    let t1 = IncidenceTable::build(&one, &bins(&one)).unwrap();
    let t2 = IncidenceTable::build(&both, &bins(&both)).unwrap();
    t1.validate().unwrap();
    t2.validate().unwrap();
    assert!(t2.support.contains(&Support::Bridged));
    // A 24" wall point (R = 0.293 m) at 1.2 m: between the two rigs, outside the one.
    let (r, c): (f64, f64) = (1.2, 0.293 / 1.2);
    let i = 500.0 * c / (r * r);
    assert!(t2.covers(r, i, c));
    assert!(!t1.covers(r, i, c));
    // On the one rig's own curve: covered, and the value is the error to a few bins'
    // curvature of the mean (the error is linear).
    let (r0, c0): (f64, f64) = (1.2, 0.242 / 1.2);
    let i0 = 500.0 * c0 / (r0 * r0);
    let truth = 0.004 * r0 - 0.002 * i0.ln() + 0.01 * c0.ln();
    let got = t1.lookup(r0, i0.ln(), c0.ln()).unwrap().offset_m;
    assert!((got - truth).abs() < 5e-4, "{got} vs {truth}");
    // Correction: moved inside, NaN and counted outside.
    let mut pts = vec![[r0, 0.0, 0.0], [r, 0.0, 0.0], [0.0; 3]];
    let corr = t1.correct(&mut pts, &[i0, i, 1.0], &[c0, c, 0.5]).unwrap();
    assert_eq!((corr.moved, corr.outside), (1, 1));
    assert!(pts[1][0].is_nan() && corr.bin[1].is_none() && corr.bin[0].is_some());
    assert!((pts[0][0] - (r0 - got)).abs() < 1e-4, "{:?}", pts[0]);
    assert_eq!(pts[2], [0.0; 3]);
}

/// Between two rig sizes the bridged bins interpolate: the error of a 24" wall (R =
/// 0.293 m), which neither rig showed, is read from the table of a 20" and a 30" rig
/// (24 × 24 intensity × incidence bins, so that a gap of bridged bins lies between
/// them) to within the table's own resolution: a bin's mean is the error at its points'
/// centroid, up to half a bin from the centre where the interpolation places it, so the
/// bound is Σ |∂f/∂x|·(bin width)/2 over the three axes.
#[test]
fn bridged_bins_interpolate_an_error_linear_across_the_gap() {
    let both = two_rigs(&[0.242, 0.369]);
    let bins = IncidenceBins::spanning(&both, (10, 24, 24), (0.5, 2.0), 5).unwrap();
    let t = IncidenceTable::build(&both, &bins).unwrap();
    let width = |a: &Axis| (a.hi - a.lo) / a.n as f64;
    let bound = 0.5
        * (0.004 * width(&t.range)
            + 0.002 * width(&t.log_intensity)
            + 0.01 * width(&t.log_cos_incidence));
    let mut bridged = 0;
    for k in 0..11 {
        let r = 0.8 + 0.1 * k as f64;
        let c = 0.293 / r;
        let i = 500.0 * c / (r * r);
        let truth = 0.004 * r - 0.002 * i.ln() + 0.01 * c.ln();
        let look = t.lookup(r, i.ln(), c.ln()).unwrap();
        bridged += usize::from(t.support[look.bin] == Support::Bridged);
        assert!(
            (look.offset_m - truth).abs() < bound,
            "r {r}: {} vs {truth} (bound {bound})",
            look.offset_m
        );
    }
    assert!(
        bridged >= 6,
        "the 24\" wall should lie in bridged bins: {bridged} of 11"
    );
}

/// The propagated covariance of a range error shared by every point matches the change
/// of the refitted diameters when the points are moved by it (finite difference).
#[test]
fn a_shared_range_error_propagates_as_a_refit_moves_the_diameters() {
    use crate::estimate::{EstimateOptions, Method, estimate};
    // A round 20" pipe, sensor off the axis: wall points over a cone of rays.
    let (rad, dy, dz) = (0.242, 0.03, -0.02);
    let mut pts = vec![];
    for a in 0..120 {
        for b in 0..60 {
            let phi = std::f64::consts::TAU * a as f64 / 120.0;
            let tilt = 0.15 + 1.0 * b as f64 / 60.0;
            let d = [1.0, tilt * phi.cos(), tilt * phi.sin()];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let (uy, uz) = (d[1] / n, d[2] / n);
            let qa = uy * uy + uz * uz;
            let qb = dy * uy + dz * uz;
            let qc = dy * dy + dz * dz - rad * rad;
            let t = (-qb + (qb * qb - qa * qc).sqrt()) / qa;
            // The wall point relative to the sensor: the point in the SCS.
            pts.push([d[0] / n * t, uy * t, uz * t]);
        }
    }
    let opts = EstimateOptions::default();
    let fit = |p: &[[f64; 3]]| estimate(p, Method::MlEpd, &opts).unwrap();
    let base = fit(&pts);
    let delta = 0.001;
    let moved: Vec<[f64; 3]> = pts
        .iter()
        .map(|p| {
            let r = norm(p);
            let f = (r + delta) / r;
            [p[0] * f, p[1] * f, p[2] * f]
        })
        .collect();
    let shifted = fit(&moved);
    let shift = vec![Some((0u32, delta)); pts.len()];
    let cov = shared_error_cov(&pts, &shift, 1, &base.params).unwrap();
    for k in 0..2 {
        let fd = [
            shifted.params.d_max - base.params.d_max,
            shifted.params.d_min - base.params.d_min,
        ][k];
        let lin = cov[k][k].sqrt();
        assert!(
            fd.abs() > 1e-4,
            "a shared range error moves the diameters: {fd}"
        );
        assert!(
            (lin - fd.abs()).abs() < 0.1 * fd.abs(),
            "diameter {k}: propagated {lin} vs refit {fd}"
        );
    }
}
