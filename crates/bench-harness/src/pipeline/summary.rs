//! The statistics of a pipeline run: one [`SectionRow`] per section, method and
//! calibration, with the 95 % interval of the mean wall from Student's t.

use super::rows::ProfileRow;
use super::{METHODS, PipelineScenario};

/// One row of `sections.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct SectionRow {
    /// Section name.
    pub section: String,
    /// Nominal wall (mm), the x of the figures.
    pub wall_true_mm: f64,
    /// Method name.
    pub method: &'static str,
    /// Whether the depth table was applied.
    pub calibrated: bool,
    /// Converged frames.
    pub n_frames: usize,
    /// Frames without a result.
    pub n_failed: usize,
    /// Mean estimated wall (OD − mean ID)/2 (mm).
    pub wall_est_mm: f64,
    /// Half-width of its 95 % confidence interval (mm).
    pub wall_ci95_mm: f64,
    /// Statistics of the per-frame errors (mm): Dmax, Dmin, mean diameter.
    pub dmax: crate::stats::Stats,
    /// See `dmax`.
    pub dmin: crate::stats::Stats,
    /// See `dmax`.
    pub dmean: crate::stats::Stats,
    /// RMS over frames of the Cramér–Rao 1-σ of Dmax, Dmin (mm).
    pub crb: (f64, f64),
}

/// Two-sided 95 % quantile of Student's t with ν degrees of freedom (the exact 0.975
/// quantile, [`crate::stats::student_t_quantile`]).
pub fn t95(nu: f64) -> f64 {
    crate::stats::student_t_quantile(0.975, nu)
}

pub(super) fn summarise(s: &PipelineScenario, rows: &[ProfileRow]) -> Vec<SectionRow> {
    let mut out = Vec::new();
    for (si, sec) in s.sections.iter().enumerate() {
        let od = sec.pipe.outer_diameter();
        let id = sec.pipe.inner_diameter();
        for calibrated in [false, true] {
            for method in METHODS {
                let sel: Vec<&ProfileRow> = rows
                    .iter()
                    .filter(|r| r.section == si && r.method == method && r.calibrated == calibrated)
                    .collect();
                let ok: Vec<(&ProfileRow, (f64, f64))> =
                    sel.iter().filter_map(|r| r.d.map(|d| (*r, d))).collect();
                let mm = |f: &dyn Fn(&ProfileRow, (f64, f64)) -> f64| -> Vec<f64> {
                    ok.iter().map(|&(r, d)| 1e3 * f(r, d)).collect()
                };
                let walls: Vec<f64> = mm(&|_, d| (od - 0.5 * (d.0 + d.1)) / 2.0);
                let w = crate::stats::Stats::of(&walls);
                let n = w.n as f64;
                let ci = if w.n >= 2 {
                    t95(n - 1.0) * w.std / n.sqrt()
                } else {
                    f64::NAN
                };
                let rms = |v: Vec<f64>| {
                    let v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
                    if v.is_empty() {
                        f64::NAN
                    } else {
                        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
                    }
                };
                out.push(SectionRow {
                    section: sec.name.clone(),
                    wall_true_mm: sec.pipe.wall_thickness * 1e3,
                    method,
                    calibrated,
                    n_frames: ok.len(),
                    n_failed: sel.len() - ok.len(),
                    wall_est_mm: w.mean,
                    wall_ci95_mm: ci,
                    dmax: crate::stats::Stats::of(&mm(&|r, d| d.0 - r.truth.0)),
                    dmin: crate::stats::Stats::of(&mm(&|r, d| d.1 - r.truth.1)),
                    dmean: crate::stats::Stats::of(&mm(&|_, d| 0.5 * (d.0 + d.1) - id)),
                    crb: (
                        rms(sel
                            .iter()
                            .map(|r| r.crb.0.map_or(f64::NAN, |v| v * 1e3))
                            .collect()),
                        rms(sel
                            .iter()
                            .map(|r| r.crb.1.map_or(f64::NAN, |v| v * 1e3))
                            .collect()),
                    ),
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn student_t_quantiles() {
        // Tables: t(0.975; 9) = 2.262, 49 → 2.010, 1000 → 1.962.
        for (nu, t) in [(9.0, 2.262_157), (49.0, 2.009_575), (1000.0, 1.962_339)] {
            assert!((t95(nu) - t).abs() / t < 2e-3, "{nu}: {}", t95(nu));
        }
    }
}
