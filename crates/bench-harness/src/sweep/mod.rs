//! A sweep: one variable of a scenario swept over simulated frames, every method on the
//! same clouds. Its trials (in parallel, or one at a time for timings) are streamed to
//! `trials.csv`, their statistics to `summary.csv`, with metadata and plots; a run can be
//! split into shards and merged again.
//!
//! Its folder is written through [`crate::output`]: every file into a staging folder,
//! which then takes the output folder's place as a whole.
//!
//! - [`run`](mod@run): a whole run, setting by setting;
//! - [`scenario`]: the scenario file, checked into [`scenario::Setting`]s;
//! - [`trial`]: one trial (a frame, every method), made into a [`record::TrialRecord`];
//! - [`record`]: a trial's record, one row of `trials.csv` per method, and a shard's
//!   records file;
//! - `runner`: the trials of a setting in batches;
//! - [`rows`]: the columns and rows of `trials.csv` and `summary.csv`;
//! - [`summary`]: the statistics of a setting ([`summary::SummaryRow`]);
//! - [`figures`]: the PNGs drawn from the summary;
//! - [`shard`] and [`merge`]: a run in parts and their merge.

use std::path::{Path, PathBuf};

use crate::experiment::{Experiment, Finished, Refused, Request};
use crate::output::default_output;
use crate::scenario::ScenarioError;
use scenario::Scenario;

pub use run::{RunOptions, RunReport, run, trial_errors_note};

pub mod figures;
pub mod merge;
pub mod record;
pub mod rows;
pub mod run;
mod runner;
pub mod scenario;
pub mod shard;
pub mod summary;
pub mod trial;

/// A sweep, whole or one shard of it (`--shard K/N`, with `--trials` or not).
impl Experiment for Scenario {
    fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        Scenario::parse(path, source)
    }

    fn name(&self) -> &str {
        &self.name
    }

    /// `--trials` within the limits of the scenario's size.
    fn check(&self, request: &Request) -> Result<(), Refused> {
        match request.trials {
            Some(t) => self
                .check_trials("--trials", t)
                .map_err(|e| Refused(e.to_string())),
            None => Ok(()),
        }
    }

    /// `target/results/<name>/`, or `<name>-shard-K-of-N/` for a shard.
    fn default_output(&self, request: &Request) -> PathBuf {
        match request.shard {
            None => default_output(&self.name),
            Some(s) => default_output(&format!("{}-shard-{}-of-{}", self.name, s.k(), s.n())),
        }
    }

    fn run(&self, out: &Path, request: &Request) -> anyhow::Result<Finished> {
        let options = RunOptions {
            out: out.to_path_buf(),
            trials: request.trials,
            progress: request.progress,
        };
        let report = match request.shard {
            None => run(self, &options)?,
            Some(shard) => shard::run_shard(self, &options, shard)?,
        };
        let per_setting = request.trials.unwrap_or(self.trials);
        let part = request.shard.map_or(String::new(), |s| {
            let n = shard::shard_trial_count(s, self.sweeps.len(), per_setting);
            format!(" shard {s}: {n} trials of")
        });
        Ok(Finished {
            what: format!(
                "{}{part}: {} settings × {per_setting} trials",
                self.name,
                self.sweeps.len()
            ),
            wall_time_s: report.wall_time_s,
            errors: trial_errors_note(report.trial_errors),
        })
    }
}
