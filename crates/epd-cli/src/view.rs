//! `epd view FILE --out frame.png`: one frame measured as `epd estimate` measures it, and
//! its points drawn over the fitted wall unrolled (distance along the pipe axis × clock
//! angle seen from the sensor), coloured by their residual (`epd_frame::export`).

use std::process::ExitCode;

use anyhow::Context;
use epd_io::stderr_line;

use crate::args::ViewArgs;
use crate::estimate::fit_config;
use crate::{check_output_path, usage};

/// The default colour scale's limit in RMS residuals: 3, so noise of a well-fitted frame
/// spans the scale and a dent or a deposit beyond three σ saturates.
pub const DEFAULT_LIMIT_RMS: f64 = 3.0;

/// The most points drawn (a uniform stride over the rest): 400 000, about a third of the
/// picture's pixels, enough to cover a Helios2 frame (640 × 480) whole.
pub const MAX_DRAWN: usize = 400_000;

/// The quantiles of the points' places along the axis that bound the picture: 0.5 % and
/// 99 %, so that the few rays that graze the fitted wall's extension far away (past a bend,
/// through the pipe's open end) do not squeeze the wall the camera saw into a sliver.
pub const DRAWN_QUANTILES: (f64, f64) = (0.005, 0.99);

pub fn run_view(a: &ViewArgs) -> anyhow::Result<ExitCode> {
    let cfg = fit_config(&a.fit)?;
    if let Some(l) = a.limit_mm
        && !(l > 0.0 && l <= epd_io::plot::MAX_VALUE_LIMIT)
    {
        return Err(usage(format!(
            "--limit-mm {l:e}: expected a length in mm above 0 and at most {:e}",
            epd_io::plot::MAX_VALUE_LIMIT
        )));
    }
    if a.file.as_os_str() == "-" || epd_frame::bag::is_bag(&a.file) {
        return Err(usage(
            "epd view: give one point-cloud file (PLY, PCD, CSV…), not standard input or a bag",
        ));
    }
    check_output_path(&a.out, std::slice::from_ref(&a.file), "--out")?;
    let (report, fitted) = epd_frame::export::fit_file(&a.file, &cfg);
    let f = fitted.map_err(|e| anyhow::anyhow!("{}: {e}", report.shown_file()))?;
    let rms = report
        .outcome
        .as_ref()
        .ok()
        .and_then(|e| e.rms_residual_mm)
        .unwrap_or(1.0);
    // A noise-free frame's rms may be 0: the scale then spans the smallest positive length.
    let limit = a.limit_mm.unwrap_or(
        (DEFAULT_LIMIT_RMS * rms).clamp(f64::MIN_POSITIVE, epd_io::plot::MAX_VALUE_LIMIT),
    );
    let stride = f.points.len().div_ceil(MAX_DRAWN).max(1);
    // Along the axis: the stretch where most points meet the wall (past a bend, the
    // straight wall's extension is met by grazing rays tens of metres on).
    let mut along: Vec<f64> = f
        .unrolled
        .iter()
        .map(|u| u.0)
        .filter(|x| x.is_finite())
        .collect();
    along.sort_by(f64::total_cmp);
    let at = |q: f64| {
        along
            .get(((along.len().max(1) - 1) as f64 * q).round() as usize)
            .copied()
    };
    let (x0, x1) = (
        at(DRAWN_QUANTILES.0).unwrap_or(f64::NEG_INFINITY),
        at(DRAWN_QUANTILES.1).unwrap_or(f64::INFINITY),
    );
    let points: Vec<(f64, f64, f64)> = f
        .unrolled
        .iter()
        .zip(&f.residual_mm)
        .step_by(stride)
        .filter(|(u, _)| (x0..=x1).contains(&u.0))
        .map(|(u, r)| (u.0, u.1, *r))
        .collect();
    let p = f.params;
    let title = format!(
        "{}: residuals over the fitted wall (Dmax {:.1} mm, Dmin {:.1} mm, rms {:.2} mm)",
        report.shown_file(),
        p.d_max * 1e3,
        p.d_min * 1e3,
        rms
    );
    let png = epd_io::plot::value_map(&epd_io::plot::ValueMap {
        name: "frame.png".into(),
        title,
        points: &points,
        limit,
        x_label: "distance along the pipe axis from the sensor (m)",
        y_label: "clock angle seen from the sensor (deg: 0 up, 90 right)",
        y_range: (0.0, 360.0),
        value_label: "range residual (mm, + beyond the wall)",
    })?;
    epd_io::atomic::write_bytes_atomic(&a.out, &png.bytes)
        .with_context(|| format!("cannot write {}", epd_io::name::shown(&a.out)))?;
    stderr_line!(
        "{}: {} points drawn, colour scale ±{limit:.2} mm",
        epd_io::name::shown(&a.out),
        points.len()
    );
    Ok(ExitCode::SUCCESS)
}
