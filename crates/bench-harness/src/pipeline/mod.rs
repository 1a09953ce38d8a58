//! A pipeline run: the paper's experiment (§4.2, Figs. 9–12) with a simulated Helios2.
//!
//! A robot drives along a pipeline; its odometer gives the distance x, and its pose in
//! the pipe drifts smoothly with x (roll creeping, the offsets and the tilt wandering on
//! periods of metres) instead of being drawn afresh per frame. Each straight section is
//! a pipe of nominal outer diameter and wall thickness; the camera is the realistic ToF
//! model of `tof_sim::physics` (amplitude-dependent noise, invalid pixels, wiggling,
//! amplitude offset, multipath). Before the run, frames recorded in a calibration rig
//! (a pipe of known diameter, not one of the sections) give a depth table
//! ([`epd_core::DepthTable`]). Every section frame is then estimated by every method on
//! the points whose model range lies in the gate, without and with the table.
//!
//! `ml-epd-w` is ML-EPD with each range residual weighted by 1/σᵢ² (heteroscedastic
//! maximum likelihood): σᵢ from the sensor model's amplitude law without the table
//! (the camera's σ(A) known), from the table's spread at the point's range and
//! intensity with it.
//!
//! Files: `profile.csv` (one row per frame × method × calibrated: a caliper tool's pipe
//! tally), `sections.csv` (one row per section × method × calibrated), `depth_table.json`,
//! and the figures `diameters.png` (Fig. 11), `section_errors.png` (Fig. 12),
//! `profile.png` and `weights.png`.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::Context;
use rayon::prelude::*;

use crate::experiment::{Experiment, Finished, Refused, Request};
use crate::output::{INTERRUPTED, Interrupted, StagedFiles, write_new, write_run};
use crate::scenario::ScenarioError;
use files::{metadata, table_file, write_profile, write_sections};
use rows::{FrameStatus, ProfileRow, RunTables, calibrate, frame_rows};
use summary::summarise;

pub use files::{PROFILE_COLUMNS, SECTION_COLUMNS};
pub use plan::{Drift, FramePlan};
pub use scenario::{PipelineScenario, Section};
pub use summary::{SectionRow, t95};

mod figures;
mod files;
mod plan;
mod rows;
mod scenario;
mod summary;

/// The estimators of a pipeline run, by their names in the CSV files.
pub const METHODS: [&str; 4] = ["c-epd", "ru-epd", "ml-epd", "ml-epd-w"];

/// A pipeline run: whole (no `--trials`, no `--shard`).
impl Experiment for PipelineScenario {
    fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        PipelineScenario::parse(path, source)
    }

    fn name(&self) -> &str {
        &self.name
    }

    /// Neither `--trials` (the frames are `pipeline.frames_per_section`) nor `--shard`
    /// (every frame is corrected by one table fitted to all the rig's frames).
    fn check(&self, request: &Request) -> Result<(), Refused> {
        if request.trials.is_some() {
            return Err(Refused(
                "--trials does not apply to a pipeline run (set pipeline.frames_per_section)"
                    .into(),
            ));
        }
        if let Some(shard) = request.shard {
            return Err(Refused(format!(
                "--shard {shard}: a pipeline run cannot be sharded: every frame is corrected by \
                 one depth table fitted to all the rig's frames, so its parts are not \
                 independent; run it whole"
            )));
        }
        Ok(())
    }

    fn run(&self, out: &Path, request: &Request) -> anyhow::Result<Finished> {
        let report = run_pipeline(self, out, request.progress)?;
        Ok(Finished {
            what: format!(
                "{}: {} sections × {} frames",
                self.name,
                self.sections.len(),
                self.frames_per_section
            ),
            wall_time_s: report.wall_time_s,
            errors: (report.errors > 0).then(|| {
                format!(
                    "{} estimates returned an error (status `error` in profile.csv)",
                    report.errors
                )
            }),
        })
    }
}

/// What a pipeline run wrote.
#[derive(Debug)]
pub struct PipelineReport {
    /// Files written.
    pub files: Vec<PathBuf>,
    /// Wall time (s).
    pub wall_time_s: f64,
    /// Estimates that returned an error (status `error`).
    pub errors: usize,
    /// The section rows, as written.
    pub sections: Vec<SectionRow>,
}

impl StagedFiles for PipelineReport {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }
}

/// Run a pipeline scenario into `out` (replaced as a whole, see [`crate::output`]).
pub fn run_pipeline(
    s: &PipelineScenario,
    out: &Path,
    progress: bool,
) -> anyhow::Result<PipelineReport> {
    write_run(out, |dir| stage(s, dir, progress))
}

fn stage(s: &PipelineScenario, dir: &Path, progress: bool) -> anyhow::Result<PipelineReport> {
    let start = Instant::now();
    let say = |m: &str| {
        if progress {
            epd_io::stderr_line!("{}: {m}", s.name);
        }
    };
    say(&format!("calibration rig: {} frames", s.rig_frames));
    let (tables, n_obs) = calibrate(s).context("the calibration rig")?;
    let table = &tables.plain;
    let filled = table.count.iter().filter(|&&c| c > 0).count();
    say(&format!(
        "depth table: {} × {} bins{}, {filled} filled, from {n_obs} points",
        table.range.n,
        table.log_intensity.n,
        match &tables.incidence {
            Some(t) => format!(" (and × {} incidence bins)", t.log_cos_incidence.n),
            None => String::new(),
        }
    ));
    let rows = estimate_run(s, &tables, &say)?;
    let mut files = vec![write_profile(dir, s, &rows)?];
    let sections = summarise(s, &rows);
    files.push(write_sections(dir, &sections)?);
    files.push(write_new(&dir.join("scenario.toml"), s.source.as_bytes())?);
    files.push(write_new(
        &dir.join("depth_table.json"),
        table_file(&tables, n_obs, s).to_json().as_bytes(),
    )?);
    for png in figures::plot_pipeline(s, &rows, &sections)? {
        files.push(write_new(&dir.join(&png.name), &png.bytes)?);
    }
    let errors = rows
        .iter()
        .filter(|r| r.status == FrameStatus::Error)
        .count();
    let wall_time_s = start.elapsed().as_secs_f64();
    files.push(metadata(s, wall_time_s, filled, n_obs).write(dir)?);
    Ok(PipelineReport {
        files,
        wall_time_s,
        errors,
        sections,
    })
}

/// Every frame of the run ([`PipelineScenario::plans`]) by every method, place by place
/// (the frames of a place in parallel), in driving order; stops between places when the
/// run is interrupted.
fn estimate_run(
    s: &PipelineScenario,
    table: &RunTables,
    say: &dyn Fn(&str),
) -> anyhow::Result<Vec<ProfileRow>> {
    let mut rows = Vec::new();
    let plans = s.plans();
    let mut places: Vec<usize> = plans.iter().map(|p| p.place).collect();
    places.dedup();
    for place in places {
        if INTERRUPTED.load(Ordering::SeqCst) {
            return Err(Interrupted.into());
        }
        let here: Vec<&FramePlan> = plans.iter().filter(|p| p.place == place).collect();
        say(&format!("{}: {} frames", s.place_name(place), here.len()));
        let done: Vec<anyhow::Result<Vec<ProfileRow>>> = here
            .into_par_iter()
            .with_max_len(1)
            .map(|p| frame_rows(s, table, p))
            .collect();
        for d in done {
            rows.extend(d?);
        }
    }
    Ok(rows)
}
