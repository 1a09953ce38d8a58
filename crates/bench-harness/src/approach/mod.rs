//! `[approach]` scenarios: the sensor approaching an elbow or a tee (issue 12). For each
//! distance from the sensor to the straight section's end, frames from the paper's
//! random poses in a pipeline (`tof_sim::Pipeline`), each estimated by ML-EPD with the
//! Cauchy loss on every point (`segmented = false`) and by the survey
//! (`epd_core::segment::survey`, `segmented = true`), scored against the pipeline's
//! ground truth.
//!
//! ```toml
//! name = "elbow_approach"
//! seed = 12
//! [approach]
//! kind = "elbow"                # or "tee"
//! distances_m = [6.0, 3.0, 2.0, 1.0, 0.5, 0.3]
//! frames = 6
//! sigma_m = 0.03                # range noise along the rays
//! nominal_od_in = 20.0
//! wall_mm = 12.0
//! ovality = 0.02
//! bend_radius_d = 1.5           # elbow: centreline radius in nominal diameters
//! bend_angle_deg = 90.0
//! direction_deg = 40.0          # the turn (or branch) toward this PCS angle
//! branch_diameter_mm = 300.0    # tee
//! ```
//!
//! Files: `frames.csv` (one row per distance × frame × segmented: `distance_m, frame,
//! segmented, geometry, dmean_err_mm, straight_until_m, straight_until_err_mm,
//! bend_radius_mm, bend_radius_err_pct, direction_err_deg`), `approach.csv` (one row
//! per distance × segmented: `distance_m, segmented, n_frames, n_found, dmean_bias_mm,
//! dmean_range_mm, straight_until_err_max_mm, bend_radius_err_max_pct`), `confusion.csv`
//! (one row per distance × geometry the survey can report: `true_scene, distance_m,
//! geometry, count`, the survey's readings of that distance's frames), `approach.png`,
//! `scenario.toml`, `metadata.json`.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::Context;
use rayon::prelude::*;

use crate::experiment::{Experiment, Finished, Refused, Request};
use crate::output::{INTERRUPTED, Interrupted, StagedFiles, write_new, write_run};
use crate::provenance::Metadata;
use crate::scenario::ScenarioError;
use frames::{frame_rows, write_frames_csv};
use summary::{confusion, summarise, write_approach_csv, write_confusion_csv};

pub use frames::{FRAME_COLUMNS, FrameRow};
pub use scenario::{ApproachScenario, Feature};
pub use summary::{APPROACH_COLUMNS, ApproachRow, CONFUSION_COLUMNS, ConfusionRow};

mod figures;
mod frames;
mod scenario;
mod summary;

/// An approach run: whole (no `--trials`, no `--shard`).
impl Experiment for ApproachScenario {
    fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        ApproachScenario::parse(path, source)
    }

    fn name(&self) -> &str {
        &self.name
    }

    /// Neither `--trials` (the frames are `approach.frames`) nor `--shard`.
    fn check(&self, request: &Request) -> Result<(), Refused> {
        if request.trials.is_some() || request.shard.is_some() {
            return Err(Refused(
                "--trials and --shard do not apply to an approach run (set approach.frames)".into(),
            ));
        }
        Ok(())
    }

    fn run(&self, out: &Path, request: &Request) -> anyhow::Result<Finished> {
        let report = run_approach(self, out, request.progress)?;
        Ok(Finished {
            what: format!(
                "{}: {} distances × {} frames",
                self.name,
                self.distances_m.len(),
                self.frames
            ),
            wall_time_s: report.wall_time_s,
            errors: None,
        })
    }
}

/// What an approach run wrote.
#[derive(Debug)]
pub struct ApproachReport {
    /// The files, in the output folder.
    pub files: Vec<PathBuf>,
    /// The summary rows.
    pub rows: Vec<ApproachRow>,
    /// Wall time (s).
    pub wall_time_s: f64,
}

impl StagedFiles for ApproachReport {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }
}

/// Run the scenario into `out` (replaced whole when the run succeeds).
pub fn run_approach(
    s: &ApproachScenario,
    out: &Path,
    progress: bool,
) -> anyhow::Result<ApproachReport> {
    write_run(out, |dir| stage(s, dir, progress))
}

fn stage(s: &ApproachScenario, dir: &Path, progress: bool) -> anyhow::Result<ApproachReport> {
    let start = Instant::now();
    let mut rows = Vec::new();
    for di in 0..s.distances_m.len() {
        // A signal stops the run before the next distance's frames (their batch is the
        // unit of work, as a sweep's batch of trials is).
        if INTERRUPTED.load(Ordering::SeqCst) {
            return Err(Interrupted.into());
        }
        if progress {
            epd_io::stderr_line!(
                "{}: {} m ahead, {} frames",
                s.name,
                s.distances_m[di],
                s.frames
            );
        }
        let done: Vec<anyhow::Result<[FrameRow; 2]>> = (0..s.frames)
            .into_par_iter()
            .with_max_len(1)
            .map(|k| frame_rows(s, di, k))
            .collect();
        for d in done {
            rows.extend(d.with_context(|| format!("{} m ahead", s.distances_m[di]))?);
        }
    }
    let mut files = vec![write_frames_csv(dir, &rows)?];
    let summary = summarise(s, &rows);
    files.push(write_approach_csv(dir, &summary)?);
    files.push(write_confusion_csv(dir, &confusion(s, &rows))?);
    files.push(write_new(&dir.join("scenario.toml"), s.source.as_bytes())?);
    let png = figures::plot_approach(s, &rows)?;
    files.push(write_new(&dir.join(&png.name), &png.bytes)?);
    let wall_time_s = start.elapsed().as_secs_f64();
    files.push(
        Metadata::new(&s.name, s.seed, wall_time_s)
            .with("kind", "approach")
            .write(dir)?,
    );
    Ok(ApproachReport {
        files,
        rows: summary,
        wall_time_s,
    })
}
