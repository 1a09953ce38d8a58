//! The paper's §4.2 experiment with rigs of one and two sizes (issue 24): depth tables
//! from a 20" rig and from 20" + 30" rigs (`epd calibrate`'s defaults: 30 × 12 × 16
//! bins over range × intensity × incidence, `passes` passes), applied to frames of 16" to
//! 30" pipes under tof-sim's Helios2 model; per size and table the calibrated
//! mean-diameter error, the reported 1-σ, whether it covers, and the share of points
//! outside the table's support (in `summary.csv` its mean over the frames measured; a
//! frame whose measurement fails reports none; one too far outside the support to be
//! corrected is measured uncorrected, `epd estimate`'s answer). A scenario with a
//! `[calibration_transfer]` table
//! ([`TransferScenario`]; `scenarios/calibration_transfer.toml`) run by `bench-harness`
//! writes `frames.csv`, `summary.csv`, `calibration_transfer.png`, `scenario.toml` and
//! `metadata.json`.

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use epd_core::calibration::{CalibrationFrame, RigFrames};
use epd_frame::rig::{RigSettings, calibrate_rig_sizes};
use epd_frame::{EstimateConfig, EstimateSettings, FrameInput, measure_frame};
use epd_io::csv::num;
use tof_sim::settings::{PoseOverride, SimulateSettings, Simulator};

use crate::experiment::{Experiment, Finished, Refused, Request};
use crate::output::{INTERRUPTED, Interrupted, StagedFiles, write_new, write_run};
use crate::plots::{Figure, Panel, Series, render};
use crate::provenance::Metadata;
use crate::scenario::ScenarioError;

mod scenario;

pub use scenario::{MAX_FRAMES_PER_SIZE, TransferScenario};

impl Experiment for TransferScenario {
    fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        TransferScenario::parse(path, source)
    }

    fn name(&self) -> &str {
        &self.name
    }

    /// Neither `--trials` (the frames are `calibration_transfer.frames_per_size`) nor
    /// `--shard`.
    fn check(&self, request: &Request) -> Result<(), Refused> {
        if request.trials.is_some() || request.shard.is_some() {
            return Err(Refused(
                "--trials and --shard do not apply to a calibration-transfer run (set \
                 calibration_transfer.frames_per_size)"
                    .into(),
            ));
        }
        Ok(())
    }

    fn run(&self, out: &Path, request: &Request) -> anyhow::Result<Finished> {
        let report = write_run(out, |dir| stage(self, dir, request.progress))?;
        Ok(Finished {
            what: format!(
                "{}: 2 tables × {} sizes × {} frames",
                self.name,
                SIZES_IN.len(),
                self.frames_per_size
            ),
            wall_time_s: report.wall_time_s,
            errors: None,
        })
    }
}

/// What a run wrote.
struct Report {
    files: Vec<PathBuf>,
    wall_time_s: f64,
}

impl StagedFiles for Report {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }
}

/// The pipe sizes measured (nominal OD, inch).
pub const SIZES_IN: [f64; 8] = [16.0, 18.0, 20.0, 22.0, 24.0, 26.0, 28.0, 30.0];

/// Wall thickness of every pipe (mm), as `epd simulate`'s default.
pub const WALL_MM: f64 = 12.0;

/// Frames per rig.
const RIG_FRAMES: u64 = 6;

/// The inner diameter (m) of a pipe of nominal OD `od_in` (inch) and a [`WALL_MM`] wall.
pub fn inner_diameter_m(od_in: f64) -> f64 {
    (od_in * 25.4 - 2.0 * WALL_MM) * 1e-3
}

/// The experiment's simulator: `epd simulate --sensor helios2` (the realistic Helios2
/// error model, every point of the frame) in a pipe of nominal OD `od_in` (inch), a
/// [`WALL_MM`] wall and `ovality`, its poses and noise drawn from `seed`.
pub fn simulator(od_in: f64, ovality: f64, seed: u64) -> anyhow::Result<Simulator> {
    Simulator::new(&SimulateSettings {
        seed,
        sigma: 0.03,
        od_in,
        ovality,
        wall_mm: WALL_MM,
        points: None,
        outliers: 0.0,
        noise: tof_sim::NoiseModel::Range,
        helios2: true,
        pose: PoseOverride::default(),
        feature: None,
    })
    .map_err(|e| anyhow::anyhow!("{e}"))
}

/// The experiment's rig settings: `epd calibrate`'s defaults (30 × 12 × 16 bins over
/// range × intensity × incidence, the rays meeting the wall at 0.5–2 m, 30 points a
/// bin) for a round 20" rig, with `passes` passes.
pub fn rig_settings(passes: u32) -> RigSettings {
    RigSettings {
        known_id_mm: inner_diameter_m(20.0) * 1e3,
        known_dmin_mm: None,
        min_range: 0.5,
        max_range: 2.0,
        range_bins: 30,
        intensity_bins: 12,
        incidence_bins: 16,
        min_count: 30,
        passes,
    }
}

/// A round rig of nominal OD `od_in` (inch) and a [`WALL_MM`] wall, seen in `frames`.
pub fn round_rig<'a>(od_in: f64, frames: &'a [CalibrationFrame<'a>]) -> RigFrames<'a> {
    let d = inner_diameter_m(od_in);
    RigFrames {
        known: (d, d),
        frames,
    }
}

/// One frame's points and intensities, and its true (Dmax, Dmin) (m).
type Frame = (Vec<[f64; 3]>, Vec<f64>, (f64, f64));

fn frames(od_in: f64, ovality: f64, seed: u64, n: u64) -> anyhow::Result<Vec<Frame>> {
    let sim = simulator(od_in, ovality, seed)?;
    let mut f = tof_sim::Frame::empty();
    (0..n)
        .map(|k| {
            sim.frame(k, &mut f).map_err(|e| anyhow::anyhow!("{e}"))?;
            let t = epd_core::canonicalize(&f.truth);
            Ok((
                f.measured.clone(),
                f.intensity.iter().map(|&v| f64::from(v)).collect(),
                (t.d_max, t.d_min),
            ))
        })
        .collect()
}

fn as_cal(v: &[Frame]) -> Vec<CalibrationFrame<'_>> {
    v.iter()
        .map(|f| CalibrationFrame {
            points: &f.0,
            intensity: &f.1,
        })
        .collect()
}

/// Append one CSV record and its newline to `text` (quoted as CSV quotes: the rigs' names
/// hold a `"`).
fn record<I, T>(text: &mut String, fields: I)
where
    I: IntoIterator<Item = T>,
    T: AsRef<[u8]>,
{
    text.push_str(&epd_io::csv::line(fields));
    text.push('\n');
}

/// The run into the staging folder `dir`: the rigs' tables, then every test frame of
/// every size measured with each; a signal stops it before the next size.
fn stage(s: &TransferScenario, dir: &Path, progress: bool) -> anyhow::Result<Report> {
    let start = Instant::now();
    let (per_size, passes, seed) = (s.frames_per_size, s.passes, s.seed);
    let rig20 = frames(20.0, 0.0, seed + 7, RIG_FRAMES)?;
    let rig30 = frames(30.0, 0.0, seed + 17, RIG_FRAMES)?;
    let (c20, c30) = (as_cal(&rig20), as_cal(&rig30));
    let settings = rig_settings(passes).check()?;
    let (r20, r30) = (round_rig(20.0, &c20), round_rig(30.0, &c30));
    let tables = [
        ("20\" rig", calibrate_rig_sizes(&[r20], &settings)?.table),
        (
            "20\" + 30\" rigs",
            calibrate_rig_sizes(&[r20, r30], &settings)?.table,
        ),
    ];
    let mut rows = String::from(
        "rigs,size_in,frame,status,err_d_mean_mm,err_d_max_mm,err_d_min_mm,sigma_d_max_mm,\
         sigma_d_min_mm,covered,calibration_outside,uncorrected\n",
    );
    let mut summary = String::from(
        "rigs,size_in,frames,with_result,mean_err_d_mean_mm,sd_err_d_mean_mm,\
         mean_sigma_d_mean_mm,covered,mean_calibration_outside,uncorrected\n",
    );
    let mut series: Vec<Series> = Vec::new();
    for (k, (name, table)) in tables.iter().enumerate() {
        let mut cfg = EstimateConfig::new(&EstimateSettings {
            geometry: false,
            ..EstimateSettings::default()
        })?;
        cfg.calibration = Some(table.clone());
        let mut points = Vec::new();
        for (si, &od) in SIZES_IN.iter().enumerate() {
            if INTERRUPTED.load(Ordering::SeqCst) {
                return Err(Interrupted.into());
            }
            if progress {
                epd_io::stderr_line!("{}: {name}, {od}\" pipe, {per_size} frames", s.name);
            }
            let test = frames(od, 0.02, seed + 100 + si as u64, per_size)?;
            let (mut errs, mut sig, mut covered, mut outside) = (vec![], vec![], 0, vec![]);
            // Frames measured on their raw points, too far outside the support.
            let mut n_uncorrected = 0usize;
            for (j, (p, i, truth)) in test.iter().enumerate() {
                let r = measure_frame(
                    FrameInput {
                        points: Cow::Borrowed(p),
                        intensity: Some(i),
                        sigma: None,
                        read_ms: 0.0,
                    },
                    &cfg,
                );
                let Ok(e) = r else {
                    record(
                        &mut rows,
                        [*name, &od.to_string(), &j.to_string(), "error"]
                            .into_iter()
                            .chain(["", "", "", "", "", "false", "", ""]),
                    );
                    continue;
                };
                let est = &e.estimate;
                let out_frac = e.calibration_outside.unwrap_or(f64::NAN);
                if out_frac.is_finite() {
                    outside.push(out_frac);
                }
                if !est.status.is_converged() {
                    let (status, outside) = (est.status.name(), num(out_frac));
                    record(
                        &mut rows,
                        [*name, &od.to_string(), &j.to_string(), status]
                            .into_iter()
                            .chain(["", "", "", "", "", "false", &outside, ""]),
                    );
                    continue;
                }
                let (ea, eb) = (est.params.d_max - truth.0, est.params.d_min - truth.1);
                let (sa, sb) = (est.sigma[0].unwrap_or(0.0), est.sigma[1].unwrap_or(0.0));
                let cov = ea.abs() <= sa && eb.abs() <= sb;
                covered += usize::from(cov);
                let em = 0.5 * (ea + eb);
                errs.push(em * 1e3);
                sig.push(est.sigma_d_mean().unwrap_or(f64::NAN) * 1e3);
                let mm = |v: f64| format!("{:.4}", v * 1e3);
                record(
                    &mut rows,
                    [
                        name.to_string(),
                        od.to_string(),
                        j.to_string(),
                        "converged".into(),
                        mm(em),
                        mm(ea),
                        mm(eb),
                        mm(sa),
                        mm(sb),
                        cov.to_string(),
                        format!("{out_frac:.4}"),
                        e.uncorrected.is_some().to_string(),
                    ],
                );
                n_uncorrected += usize::from(e.uncorrected.is_some());
            }
            let n = errs.len();
            let (mean, sd) = {
                let st = crate::stats::Stats::of(&errs);
                (st.mean, st.std)
            };
            let ms = crate::stats::Stats::of(&sig).mean;
            record(
                &mut summary,
                [
                    name.to_string(),
                    od.to_string(),
                    per_size.to_string(),
                    n.to_string(),
                    format!("{mean:.4}"),
                    format!("{sd:.4}"),
                    format!("{ms:.4}"),
                    covered.to_string(),
                    // Over the frames measured: a frame whose measurement failed reports
                    // no fraction.
                    format!("{:.4}", crate::stats::Stats::of(&outside).mean),
                    n_uncorrected.to_string(),
                ],
            );
            if n > 0 {
                points.push((od + 0.15 * (k as f64 - 0.5), mean, mean - ms, mean + ms));
            }
        }
        series.push(Series {
            name: name.to_string(),
            colour: if k == 0 {
                plotters::style::RGBColor(200, 60, 40)
            } else {
                plotters::style::RGBColor(40, 90, 200)
            },
            points,
            bars: true,
            marker_triangle: k == 1,
            dashed: false,
            band: false,
            markers_only: false,
        });
    }
    let mut files = vec![
        write_new(&dir.join("frames.csv"), rows.as_bytes())?,
        write_new(&dir.join("summary.csv"), summary.as_bytes())?,
        write_new(&dir.join("scenario.toml"), s.source.as_bytes())?,
    ];
    let png = render(
        Figure::linear(
            "calibration_transfer.png",
            "Calibrated mean-diameter error against pipe size (tof-sim Helios2)".into(),
            (1, 1),
            (900, 560),
            "pipe nominal OD (inch)",
        ),
        &[Panel {
            title: "mean over frames, bars: mean reported 1-σ of the mean diameter".into(),
            y_label: "Dmean error (mm)".into(),
            series: &series,
        }],
    )?;
    files.push(write_new(&dir.join(&png.name), &png.bytes)?);
    let wall_time_s = start.elapsed().as_secs_f64();
    files.push(
        Metadata::new(&s.name, s.seed, wall_time_s)
            .with("kind", "calibration_transfer")
            .with("frames_per_size", per_size)
            .with("passes", passes)
            .write(dir)?,
    );
    Ok(Report { files, wall_time_s })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--trials` and `--shard` are refused before anything runs; the plain request is
    /// not.
    #[test]
    fn the_request_is_checked() {
        let s = TransferScenario::parse(
            Path::new("t.toml"),
            "name = \"t\"\n[calibration_transfer]\nframes_per_size = 1\n",
        )
        .unwrap();
        assert!(s.check(&Request::default()).is_ok());
        let trials = Request {
            trials: Some(3),
            ..Request::default()
        };
        let shard = Request {
            shard: Some("1/2".parse().unwrap()),
            ..Request::default()
        };
        for r in [trials, shard] {
            let e = s.check(&r).expect_err("refused").to_string();
            assert!(e.contains("frames_per_size"), "{e}");
        }
    }
}
