//! A version-1 depth table's (range × intensity) own uncertainty in the reported 1-σ:
//! each bin mean's standard error, shared by every point whose interpolation read the bin,
//! propagated through the fit (issue 24). Checked against what it stands for: the
//! diameters refitted after each bin's value is moved by its standard error.

use std::borrow::Cow;

use epd_core::DepthTable;
use epd_core::calibration::Axis;
use epd_frame::{CalibrationTable, EstimateConfig, EstimateSettings, FrameInput, measure_frame};

/// Wall points of a round 20" pipe (R = 0.242 m) seen from 30 mm and −20 mm off its
/// axis over a cone of rays, their ranges jittered by a deterministic ±0.5 mm, and an
/// intensity 500·cos θ/r² (cos θ at the wall).
fn frame() -> (Vec<[f64; 3]>, Vec<f64>) {
    let (pts, inten, _) = frame_and_incidence();
    (pts, inten)
}

/// [`frame`] with each point's cos θ at the wall.
fn frame_and_incidence() -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
    let (rad, dy, dz) = (0.242, 0.03, -0.02);
    let mut pts = vec![];
    let mut inten = vec![];
    let mut cosines = vec![];
    for a in 0..120 {
        for b in 0..60 {
            let phi = std::f64::consts::TAU * a as f64 / 120.0;
            let tilt = 0.15 + 1.0 * b as f64 / 60.0;
            let d = [1.0, tilt * phi.cos(), tilt * phi.sin()];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let u = [d[0] / n, d[1] / n, d[2] / n];
            let qa = u[1] * u[1] + u[2] * u[2];
            let qb = dy * u[1] + dz * u[2];
            let qc = dy * dy + dz * dz - rad * rad;
            let t = (-qb + (qb * qb - qa * qc).sqrt()) / qa;
            // The wall's normal at the hit, (0, y, z)/R in the pipe's frame.
            let (wy, wz) = (dy + t * u[1], dz + t * u[2]);
            let cos = ((u[1] * wy + u[2] * wz) / rad).abs();
            let jitter = 5e-4 * (((a * 61 + b * 17) % 11) as f64 / 5.0 - 1.0);
            let r = t + jitter;
            pts.push([u[0] * r, u[1] * r, u[2] * r]);
            inten.push(500.0 * cos / (t * t));
            cosines.push(cos);
        }
    }
    (pts, inten, cosines)
}

/// A 5 × 3 table over the frame's ranges and intensities, offsets 0, spreads 5 mm,
/// counts from 30 to 170 and two empty bins (which take a filled neighbour's values).
fn table(pts: &[[f64; 3]], inten: &[f64]) -> DepthTable {
    let r: Vec<f64> = pts
        .iter()
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .collect();
    let span = |v: &mut dyn Iterator<Item = f64>| {
        v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        })
    };
    let (r0, r1) = span(&mut r.iter().copied());
    let (i0, i1) = span(&mut inten.iter().map(|i| i.ln()));
    let (nr, ni) = (5, 3);
    let mut count: Vec<u64> = (0..nr * ni).map(|k| 30 + 10 * k as u64).collect();
    count[1] = 0;
    count[3 * ni + 2] = 0;
    let t = DepthTable {
        range: Axis {
            lo: r0 - 0.01,
            hi: r1 + 0.01,
            n: nr,
        },
        log_intensity: Axis {
            lo: i0 - 0.01,
            hi: i1 + 0.01,
            n: ni,
        },
        offset_m: vec![0.0; nr * ni],
        spread_m: vec![0.005; nr * ni],
        count,
    };
    t.validate().expect("a valid table");
    t
}

fn config(t: &DepthTable) -> EstimateConfig {
    let mut cfg = EstimateConfig::new(&EstimateSettings {
        geometry: false,
        loss: "none".into(),
        ..EstimateSettings::default()
    })
    .expect("settings");
    cfg.calibration = Some(CalibrationTable {
        table: t.clone(),
        known: (0.484, 0.484),
        frames: 1,
        n_observations: 1000,
        incidence: None,
        rigs: vec![((0.484, 0.484), 1)],
        spans: None,
    });
    cfg.weighted = false;
    cfg
}

/// (Dmax, Dmin) and their 1-σ (m).
fn measure(t: &DepthTable, pts: &[[f64; 3]], inten: &[f64]) -> ([f64; 2], [f64; 2]) {
    let e = measure_frame(
        FrameInput {
            points: Cow::Borrowed(pts),
            intensity: Some(inten),
            sigma: None,
            read_ms: 0.0,
        },
        &config(t),
    )
    .expect("a result");
    let est = &e.estimate;
    assert!(est.status.is_converged(), "{}", est.status.name());
    (
        [est.params.d_max, est.params.d_min],
        [
            est.sigma[0].expect("a 1-σ of Dmax"),
            est.sigma[1].expect("a 1-σ of Dmin"),
        ],
    )
}

/// The 1-σ a version-1 table adds (the reported one against the same table with bins of
/// 10¹² times the points: standard errors 10⁶ times smaller) equals, within 10 %, the
/// root sum of squares of the diameters' changes when each filled bin's value (and the
/// empty bins that copy it) is moved by that bin's standard error, spread/√count, and the
/// frame measured again.
#[test]
fn a_version_1_tables_standard_errors_propagate_as_refits_move_the_diameters() {
    let (pts, inten) = frame();
    let t = table(&pts, &inten);
    let (d0, s_with) = measure(&t, &pts, &inten);
    let mut exact = t.clone();
    exact.count.iter_mut().for_each(|c| *c *= 1_000_000_000_000);
    let (_, s_fit) = measure(&exact, &pts, &inten);
    let src = t.source_bins().expect("filled bins");
    let mut refit = [0.0f64; 2];
    for b in 0..t.offset_m.len() {
        if t.count[b] == 0 {
            continue;
        }
        let se = t.spread_m[b] / (t.count[b] as f64).sqrt();
        let mut moved = t.clone();
        for (k, s) in src.iter().enumerate() {
            if *s == b {
                moved.offset_m[k] += se;
            }
        }
        let (d, _) = measure(&moved, &pts, &inten);
        for a in 0..2 {
            refit[a] += (d[a] - d0[a]).powi(2);
        }
    }
    for a in 0..2 {
        let propagated = (s_with[a].powi(2) - s_fit[a].powi(2)).max(0.0).sqrt();
        let refit = refit[a].sqrt();
        eprintln!(
            "diameter {a}: propagated {:.4} mm, refit {:.4} mm, fit alone {:.4} mm",
            propagated * 1e3,
            refit * 1e3,
            s_fit[a] * 1e3
        );
        assert!(
            refit > 1e-5,
            "the bins' errors move diameter {a}: {refit} m"
        );
        assert!(
            (propagated - refit).abs() < 0.1 * refit,
            "diameter {a}: propagated {propagated} m vs refit {refit} m (1-σ {} with the \
             table's errors, {} without)",
            s_with[a],
            s_fit[a]
        );
    }
}

/// A frame mostly outside an incidence table's support, at the rig's own size: the
/// table observed only the nearest 35 % of the frame's ranges (a 3 mm offset),
/// so 65 % of the points are left out of the fit. The correction's whole effect on each
/// diameter, |D_corrected − D_raw|, is in its 1-σ (`add_transfer_uncertainty`), and
/// `status_reason` says so; without it the 1-σ (the fit's and the bins' standard errors)
/// is far below that effect.
#[test]
fn a_frame_mostly_outside_the_support_carries_the_corrections_effect_in_its_1_sigma() {
    use epd_core::calibration::{
        IncidenceBins, IncidenceObservation, IncidenceTable, Observation, TableBins,
    };
    let (pts, inten, cosines) = frame_and_incidence();
    let range = |p: &[f64; 3]| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    let mut sorted: Vec<f64> = pts.iter().map(range).collect();
    sorted.sort_by(f64::total_cmp);
    let near = sorted[sorted.len() * 35 / 100];
    let obs: Vec<IncidenceObservation> = pts
        .iter()
        .zip(&inten)
        .zip(&cosines)
        .filter(|((p, _), _)| range(p) < near)
        .enumerate()
        .map(|(k, ((p, &i), &c))| IncidenceObservation {
            obs: Observation {
                model_range_m: range(p),
                intensity: i,
                // 3 mm, scattered by ±0.5 mm so that each bin has a spread.
                offset_m: 0.003 + 5e-4 * ((k % 11) as f64 / 5.0 - 1.0),
            },
            cos_incidence: c,
        })
        .collect();
    let bins = IncidenceBins::spanning(&obs, (4, 3, 3), (0.0, 100.0), 30).expect("bins");
    let inc = IncidenceTable::build(&obs, &bins).expect("an incidence table");
    let plain_obs: Vec<Observation> = obs.iter().map(|o| o.obs).collect();
    let plain = DepthTable::build(
        &plain_obs,
        &TableBins::spanning(&plain_obs, 4, 3).expect("plain bins"),
    )
    .expect("a plain table");
    let settings = EstimateSettings {
        geometry: false,
        loss: "none".into(),
        ..EstimateSettings::default()
    };
    let measure = |table: Option<CalibrationTable>| {
        let mut cfg = EstimateConfig::new(&settings).expect("settings");
        cfg.calibration = table;
        cfg.weighted = false;
        measure_frame(
            FrameInput {
                points: Cow::Borrowed(&pts),
                intensity: Some(&inten),
                sigma: None,
                read_ms: 0.0,
            },
            &cfg,
        )
        .expect("a result")
    };
    let raw = measure(None).estimate;
    let mut cal = CalibrationTable::plain(plain, (0.484, 0.484), 1, obs.len() as u64);
    cal.incidence = Some(inc);
    let e = measure(Some(cal));
    let out = e.calibration_outside.expect("a fraction outside");
    assert!((0.5..0.9).contains(&out), "{out}");
    assert!(e.outside_in_sigma && e.uncorrected.is_none() && e.size_outside_rigs.is_none());
    let est = &e.estimate;
    let effect = [
        (est.params.d_max - raw.params.d_max).abs(),
        (est.params.d_min - raw.params.d_min).abs(),
    ];
    for k in 0..2 {
        let sigma = est.sigma[k].expect("a 1-σ");
        eprintln!(
            "diameter {k}: the correction's effect {:.3} mm, 1-σ {:.3} mm",
            effect[k] * 1e3,
            sigma * 1e3
        );
        // The correction moves the diameters by millimetres (a 3 mm offset), far above
        // the fit's own 1-σ on 7200 points jittered by ±0.5 mm.
        assert!(effect[k] > 1e-3, "{k}: {}", effect[k]);
        assert!(
            sigma >= effect[k],
            "{k}: 1-σ {sigma} below the effect {}",
            effect[k]
        );
    }
    let report = epd_frame::FileReport {
        file: "f.ply".into(),
        file_bytes: None,
        outcome: Ok(e),
        message: None,
    }
    .json();
    assert!(report.contains("the correction's whole effect"), "{report}");
}
