//! `epd calibrate`: frames of a pipe of known diameter → the depth-calibration table.

use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use epd_core::calibration::Support;
use epd_core::calibration::{CalibrationFrame, CalibrationSettings, RigFrames};
use epd_frame::InputConfig;
use epd_frame::input::{intensity, read_input};
use epd_frame::read::PointCloud;
use epd_frame::rig::{RigSettings, calibrate_rig_sizes, parse_rigs};
use epd_frame::table::CalibrationTable;
use rayon::prelude::*;

use epd_io::name::shown;
use epd_io::stderr_line;

use crate::args::CalibrateArgs;
use crate::{check_output_path, progress, start_threads, usage};

/// The rigs to calibrate from: each one's known diameters (m) and frame files.
type Rigs = Vec<((f64, f64), Vec<std::path::PathBuf>)>;

/// Check `epd calibrate`'s arguments (exit 2 on a bad one): the rig's settings as the
/// library checks them, the rigs (FILE… with --known-id-mm, or --rigs RIGS.toml), files
/// only, and an output path that may be replaced.
fn check_args(a: &CalibrateArgs) -> anyhow::Result<(CalibrationSettings, Rigs)> {
    let rigs: Rigs = match &a.rigs {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| usage(format!("--rigs {}: cannot read: {e}", shown(path))))?;
            let base = path.parent().unwrap_or(Path::new("."));
            parse_rigs(&text, base)
                .map_err(|e| usage(format!("--rigs {}: {e}", shown(path))))?
                .into_iter()
                .map(|r| (r.known, r.files))
                .collect()
        }
        None => Vec::new(),
    };
    let first = rigs.first().map(|r| r.0);
    let settings = RigSettings {
        known_id_mm: a
            .known_id_mm
            .or(first.map(|k| k.0 * 1e3))
            .unwrap_or(f64::NAN),
        known_dmin_mm: a.known_dmin_mm.or(first.map(|k| k.1 * 1e3)),
        min_range: a.min_range,
        max_range: a.max_range,
        range_bins: a.range_bins,
        intensity_bins: a.intensity_bins,
        incidence_bins: a.incidence_bins,
        min_count: a.min_count,
        passes: a.passes,
    }
    .check()
    .map_err(|e| usage(e.to_string()))?;
    let rigs = if rigs.is_empty() {
        vec![(settings.known, a.files.clone())]
    } else {
        rigs
    };
    let all: Vec<std::path::PathBuf> = rigs.iter().flat_map(|r| r.1.iter().cloned()).collect();
    if all.iter().any(|f| f.as_os_str() == "-") {
        return Err(usage("calibrate reads files only (no `-`)"));
    }
    check_output_path(&a.out, &all, "--out")?;
    Ok((settings, rigs))
}

/// Every calibration file's points and intensities (the table is binned by intensity),
/// read in parallel, or why not.
fn read_calibration_files(
    a: &CalibrateArgs,
    files: &[std::path::PathBuf],
) -> Vec<Result<(PointCloud, Vec<f64>), String>> {
    let input: InputConfig = (&a.input).into();
    let bar = progress(a.quiet, files.len());
    let read = files
        .par_iter()
        .with_max_len(1)
        .map(|p| {
            let r = read_input(p, &input).and_then(|c| {
                let i = intensity(&c, "the table is binned by intensity")?;
                Ok((c, i))
            });
            bar.inc(1);
            r
        })
        .collect();
    bar.finish_and_clear();
    read
}

/// Print each frame's fitted pose (unless `quiet`) and add the frames whose fit failed
/// to `failed`.
fn report_calibration_fits(
    names: &[String],
    fits: &[Result<epd_core::Estimate, epd_core::EpdError>],
    quiet: bool,
    failed: &mut Vec<String>,
) {
    let deg = 180.0 / std::f64::consts::PI;
    for (name, fit) in names.iter().zip(fits) {
        match fit {
            Ok(est) => {
                if !quiet {
                    let p = est.params;
                    stderr_line!(
                        "{name}: pose roll {:.2}° pitch {:.3}° yaw {:.3}° δy {:.1} mm δz {:.1} mm, \
                         {} points",
                        p.roll * deg,
                        p.pitch * deg,
                        p.yaw * deg,
                        p.dy * 1e3,
                        p.dz * 1e3,
                        est.n_points,
                    );
                }
            }
            Err(e) => failed.push(format!("{name}: {e}")),
        }
    }
}

/// One line on the written table: its bins, how many hold data, what it was made from and
/// the range of its offsets.
fn print_table_summary(out: &Path, cal: &CalibrationTable) {
    let t = &cal.table;
    let filled = t.count.iter().filter(|&&c| c > 0).count();
    let (lo, hi) = t
        .offset_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let rigs: Vec<String> = cal
        .rigs
        .iter()
        .map(|((a, _), n)| format!("{:.1} mm × {n}", a * 1e3))
        .collect();
    let incidence = cal.incidence.as_ref().map_or(String::new(), |i| {
        let observed = i
            .support
            .iter()
            .filter(|s| **s == Support::Observed)
            .count();
        let bridged = i.support.iter().filter(|s| **s == Support::Bridged).count();
        format!(
            "; × {} incidence bins: {observed} observed, {bridged} bridged",
            i.log_cos_incidence.n
        )
    });
    stderr_line!(
        "{}: {} × {} bins ({filled} filled){incidence} from {} frames ({}) and {} points; \
         offsets {:.1} to {:.1} mm",
        shown(out),
        t.range.n,
        t.log_intensity.n,
        cal.frames,
        rigs.join(", "),
        cal.n_observations,
        lo * 1e3,
        hi * 1e3
    );
}

pub fn run_calibrate(a: &CalibrateArgs) -> anyhow::Result<ExitCode> {
    let (settings, rigs) = check_args(a)?;
    start_threads(a.threads)?;
    // Every frame is read first: the table and the poses are refined together.
    let all: Vec<std::path::PathBuf> = rigs.iter().flat_map(|r| r.1.iter().cloned()).collect();
    let read = read_calibration_files(a, &all);
    let mut failed = Vec::new();
    let mut names = Vec::new();
    let mut per_rig: Vec<Vec<CalibrationFrame<'_>>> = vec![Vec::new(); rigs.len()];
    let mut at = 0;
    for (k, (_, files)) in rigs.iter().enumerate() {
        for (path, r) in files.iter().zip(&read[at..at + files.len()]) {
            match r {
                Ok((c, i)) => {
                    names.push(shown(path));
                    per_rig[k].push(CalibrationFrame {
                        points: &c.points,
                        intensity: i,
                    });
                }
                Err(e) => failed.push(format!("{}: {e}", shown(path))),
            }
        }
        at += files.len();
    }
    let out = shown(&a.out);
    if per_rig.iter().all(|f| f.is_empty()) {
        print_skipped(&failed);
        anyhow::bail!("no frame could be read: no table written to {out}");
    }
    let rig_frames: Vec<RigFrames<'_>> = rigs
        .iter()
        .zip(&per_rig)
        .filter(|(_, f)| !f.is_empty())
        .map(|(r, f)| RigFrames {
            known: r.0,
            frames: f,
        })
        .collect();
    let rig = calibrate_rig_sizes(&rig_frames, &settings)
        .with_context(|| format!("no table written to {out}"))?;
    // The table first: a diagnostic that cannot be written (a closed standard error)
    // never costs the output.
    epd_io::atomic::write_bytes_atomic(&a.out, rig.table.to_json().as_bytes())?;
    report_calibration_fits(&names, &rig.fits, a.quiet, &mut failed);
    print_skipped(&failed);
    if !a.quiet {
        let j = rig.joint;
        stderr_line!(
            "poses refined jointly with the table: χ² {:.1} → {:.1} over {} points in {} \
             steps",
            j.chi2.0,
            j.chi2.1,
            j.n_points,
            j.steps
        );
        print_table_summary(&a.out, &rig.table);
    }
    Ok(if failed.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// One line per skipped frame, control characters escaped.
fn print_skipped(failed: &[String]) {
    for f in failed {
        stderr_line!("skipped {}", epd_io::name::escape_controls(f));
    }
}
