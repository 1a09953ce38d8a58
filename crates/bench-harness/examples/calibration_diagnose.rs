//! Why a depth table from 20" + 30" rigs is off at 24" and 30" (issue 24): tables made
//! several ways, applied several ways, to frames of 20", 24" and 30" pipes under
//! tof-sim's Helios2 model. `cargo run --release -p bench-harness --example
//! calibration_diagnose -- [FRAMES_PER_SIZE]` (default 4) prints, per table × size, the
//! mean-diameter error (mm, mean and sd over the frames) with the incidence iterated as
//! `epd estimate` does and with cos θ from the true pose, and the share of points outside
//! the support; before that each rig frame's fitted sensor offset and tilt against the
//! truth, and the table's error against the simulator's own systematic error at the test
//! points in 0.15 m range bands from 0.5 m (`tableerr`: mean mm, thousands of points).
//! The tables: one rig (20", 30"), both, both with the bridged bins left outside, both
//! from the rigs' true poses, 30" from its true poses, and both without the incidence
//! axis. The environment sets the bins and passes: `RBINS` (30), `IBINS` (12), `CBINS`
//! (16), `PASSES` (`epd calibrate`'s default); a value that is not a number is the default.

use std::borrow::Cow;

use bench_harness::calibration_transfer::{rig_settings, round_rig, simulator};
use epd_core::calibration::{
    CalibrationFrame, IncidenceBins, IncidenceTable, Support, incidences, offsets_with_incidence,
};
use epd_core::{Method, Params, estimate, estimate_weighted};
use epd_frame::rig::{RigSettings, calibrate_rig_sizes};
use epd_frame::{CalibrationTable, EstimateConfig, EstimateSettings, FrameInput, measure_frame};

struct Frame {
    exact: Vec<[f64; 3]>,
    points: Vec<[f64; 3]>,
    intensity: Vec<f64>,
    truth: Params,
}

fn frames(od_in: f64, ovality: f64, seed: u64, n: u64) -> anyhow::Result<Vec<Frame>> {
    let sim = simulator(od_in, ovality, seed)?;
    let mut f = tof_sim::Frame::empty();
    (0..n)
        .map(|k| {
            sim.frame(k, &mut f).map_err(|e| anyhow::anyhow!("{e}"))?;
            Ok(Frame {
                exact: f.exact.clone(),
                points: f.measured.clone(),
                intensity: f.intensity.iter().map(|&v| f64::from(v)).collect(),
                truth: f.truth,
            })
        })
        .collect()
}

fn cal(v: &[Frame]) -> Vec<CalibrationFrame<'_>> {
    v.iter()
        .map(|f| CalibrationFrame {
            points: &f.points,
            intensity: &f.intensity,
        })
        .collect()
}

/// The number in environment variable `k`, else `d`.
fn env(k: &str, d: usize) -> usize {
    std::env::var(k)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}

/// The incidence table from observations at the rigs' true poses (no pose fitted).
fn oracle(
    rigs: &[&[Frame]],
    settings: &epd_core::calibration::CalibrationSettings,
) -> anyhow::Result<IncidenceTable> {
    let mut obs = Vec::new();
    for r in rigs {
        for f in r.iter() {
            obs.extend(offsets_with_incidence(
                &f.points,
                &f.intensity,
                &f.truth,
                settings.gate,
            )?);
        }
    }
    let bins = IncidenceBins::spanning(
        &obs,
        (settings.bins.0, settings.bins.1, settings.incidence_bins),
        settings.gate,
        settings.min_count,
    )?;
    Ok(IncidenceTable::build(&obs, &bins)?)
}

fn stats(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|e| (e - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
    (m, sd)
}

fn main() -> anyhow::Result<()> {
    let n: u64 = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(4);
    let rig20 = frames(20.0, 0.0, 7, 6)?;
    let rig30 = frames(30.0, 0.0, 17, 6)?;
    let (c20, c30) = (cal(&rig20), cal(&rig30));
    let settings = RigSettings {
        range_bins: env("RBINS", 30),
        intensity_bins: env("IBINS", 12),
        incidence_bins: env("CBINS", 16),
        ..rig_settings(env("PASSES", epd_frame::rig::DEFAULT_PASSES as usize) as u32)
    }
    .check()?;
    let (r20, r30) = (round_rig(20.0, &c20), round_rig(30.0, &c30));
    let t20 = calibrate_rig_sizes(&[r20], &settings)?;
    let t30 = calibrate_rig_sizes(&[r30], &settings)?;
    let t2030 = calibrate_rig_sizes(&[r20, r30], &settings)?;
    // The rigs' fitted poses against the truth.
    let both: Vec<&Frame> = rig20.iter().chain(rig30.iter()).collect();
    for (name, t, fr) in [
        ("20", &t20, rig20.iter().collect::<Vec<_>>()),
        ("30", &t30, rig30.iter().collect()),
        ("20+30", &t2030, both),
    ] {
        for (fit, f) in t.fits.iter().zip(fr.iter()) {
            if let Ok(e) = fit {
                let off = |p: &Params| p.dy.hypot(p.dz) * 1e3;
                let tilt = |p: &Params| (p.pitch.cos() * p.yaw.cos()).acos().to_degrees();
                eprintln!(
                    "rig {name}: sensor off axis {:.2} mm (true {:.2}), tilt {:.3} deg (true {:.3})",
                    off(&e.params),
                    off(&f.truth),
                    tilt(&e.params),
                    tilt(&f.truth)
                );
            }
        }
    }
    let mut tables: Vec<(String, CalibrationTable)> = vec![
        ("20".into(), t20.table.clone()),
        ("30".into(), t30.table.clone()),
        ("20+30".into(), t2030.table.clone()),
    ];
    let mut nb = t2030.table.clone();
    if let Some(it) = nb.incidence.as_mut() {
        for s in it.support.iter_mut() {
            if *s == Support::Bridged {
                *s = Support::Outside;
            }
        }
    }
    tables.push(("20+30 no-bridge".into(), nb));
    let mut o = t2030.table.clone();
    o.incidence = Some(oracle(&[&rig20, &rig30], &settings)?);
    tables.push(("20+30 oracle-pose".into(), o));
    let mut o30 = t30.table.clone();
    o30.incidence = Some(oracle(&[&rig30], &settings)?);
    tables.push(("30 oracle-pose".into(), o30));
    let mut v1 = t2030.table.clone();
    v1.incidence = None;
    tables.push(("20+30 v1".into(), v1));
    let sizes = [20.0, 24.0, 30.0];
    let tests: Vec<Vec<Frame>> = sizes
        .iter()
        .enumerate()
        .map(|(s, &od)| frames(od, 0.02, 100 + s as u64, n))
        .collect::<anyhow::Result<_>>()?;
    // The table's error against the simulator's own systematic error at each test
    // point (looked up at its true range, intensity and incidence), by range.
    let phys = tof_sim::ToFPhysics::helios2();
    for (name, table) in &tables {
        let Some(it) = &table.incidence else { continue };
        for (od, test) in sizes.iter().zip(&tests) {
            let mut acc = [(0.0f64, 0usize); 10];
            for f in test {
                let Some(g) = epd_core::residual::Geometry::new(&f.truth) else {
                    continue;
                };
                for ((x, m), &i) in f.exact.iter().zip(&f.points).zip(&f.intensity) {
                    let rho = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
                    if !(rho.is_finite() && i > 0.0 && m.iter().any(|v| *v != 0.0)) {
                        continue;
                    }
                    let Some(c) = g.cos_incidence(x) else {
                        continue;
                    };
                    let truth = phys.systematic_error(rho, phys.amplitude(rho, c));
                    let Some(l) = it.lookup(rho, i.ln(), c.ln()) else {
                        continue;
                    };
                    let k = (((rho - 0.5) / 0.15).floor() as isize).clamp(0, 9) as usize;
                    acc[k].0 += (l.offset_m - truth) * 1e3;
                    acc[k].1 += 1;
                }
            }
            let cells: Vec<String> = acc
                .iter()
                .map(|(s, n)| format!("{:+.2}({})", s / (*n).max(1) as f64, n / 1000))
                .collect();
            println!("tableerr {name} {od}: {}", cells.join(" "));
        }
    }
    println!("table,size,std_mean,std_sd,truecos_mean,truecos_sd,outside");
    for (name, table) in &tables {
        let mut cfg = EstimateConfig::new(&EstimateSettings {
            geometry: false,
            ..EstimateSettings::default()
        })?;
        cfg.calibration = Some(table.clone());
        for (od, test) in sizes.iter().zip(&tests) {
            let (mut a, mut b, mut out) = (vec![], vec![], 0.0);
            for f in test {
                let t = epd_core::canonicalize(&f.truth);
                let r = measure_frame(
                    FrameInput {
                        points: Cow::Borrowed(&f.points),
                        intensity: Some(&f.intensity),
                        sigma: None,
                        read_ms: 0.0,
                    },
                    &cfg,
                );
                if let Ok(e) = r
                    && e.estimate.status.is_converged()
                {
                    a.push((e.estimate.d_mean() - 0.5 * (t.d_max + t.d_min)) * 1e3);
                    out += e.calibration_outside.unwrap_or(f64::NAN);
                }
                if let Some(it) = &table.incidence {
                    let cos = incidences(&f.points, &f.truth);
                    let mut p = f.points.clone();
                    let c = it.correct(&mut p, &f.intensity, &cos)?;
                    let e = if cfg.weighted {
                        estimate_weighted(&p, &c.sigma_m, Method::MlEpd, &cfg.options)
                    } else {
                        estimate(&p, Method::MlEpd, &cfg.options)
                    };
                    if let Ok(e) = e {
                        b.push((e.d_mean() - 0.5 * (t.d_max + t.d_min)) * 1e3);
                    }
                }
            }
            let ((am, asd), (bm, bsd)) = (stats(&a), stats(&b));
            println!(
                "{name},{od},{am:+.3},{asd:.3},{bm:+.3},{bsd:.3},{:.3}",
                out / a.len().max(1) as f64
            );
        }
    }
    Ok(())
}
