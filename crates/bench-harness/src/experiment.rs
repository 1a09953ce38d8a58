//! One flow for every experiment. A scenario file is one of four kinds ([`Kind`]): a
//! sweep ([`crate::sweep`]), a pipeline run ([`crate::pipeline`], a `[pipeline]` table),
//! an approach run ([`crate::approach`], an `[approach]` table) or a calibration-transfer
//! run ([`crate::calibration_transfer`], a `[calibration_transfer]` table). Each implements
//! [`Experiment`], so `bench-harness` reads, checks and runs any of them the same way:
//!
//! 1. [`Experiment::parse`] the scenario's text (a [`ScenarioError`] names the key);
//! 2. [`Experiment::check`] what the command line asks ([`Request`]: `--trials`,
//!    `--shard`) against what the experiment can do;
//! 3. [`Experiment::run`] into the output folder (by default
//!    [`Experiment::default_output`]), replaced as a whole ([`crate::output`]);
//! 4. report what ran ([`Finished`]), and the errors that make the exit code 1.

use std::path::{Path, PathBuf};

use epd_frame::shard::ShardSpec;

use crate::output::default_output;
use crate::scenario::ScenarioError;

/// What the command line asks of a run, whatever the experiment.
#[derive(Clone, Copy, Debug, Default)]
pub struct Request {
    /// `--trials N`: trials per setting instead of the scenario's.
    pub trials: Option<usize>,
    /// `--shard K/N`: only the K-th of N parts of the run.
    pub shard: Option<ShardSpec>,
    /// Show progress on stderr (not `--quiet`).
    pub progress: bool,
}

/// A request the experiment cannot serve: a usage error (nothing is written).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Refused(pub String);

/// What a finished run reports.
#[derive(Clone, Debug, PartialEq)]
pub struct Finished {
    /// What ran, as the line on stderr begins (`NAME: 2 settings × 30 trials`); the wall
    /// time and the output folder follow it.
    pub what: String,
    /// Wall time of the run (s).
    pub wall_time_s: f64,
    /// When trials or estimates could not be made at all: the sentence that says how many
    /// and where (the exit code is then 1).
    pub errors: Option<String>,
}

/// An experiment: a kind of scenario file, checked, and the run it makes.
pub trait Experiment: Sized {
    /// Read and check a scenario of this kind given as text (`path` names it in errors).
    fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError>;

    /// The scenario's `name`: the default output folder's, and the prefix of messages.
    fn name(&self) -> &str;

    /// Refuse what `request` asks that this experiment cannot do (checked before any
    /// worker starts or anything is written).
    fn check(&self, request: &Request) -> Result<(), Refused>;

    /// The output folder when `--out` is not given: `target/results/<name>/`
    /// ([`default_output`]).
    fn default_output(&self, _request: &Request) -> PathBuf {
        default_output(self.name())
    }

    /// Run into `out` (replaced as a whole when the run succeeds), as `request` asks.
    fn run(&self, out: &Path, request: &Request) -> anyhow::Result<Finished>;
}

/// The kind of a scenario file, by its tables.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// No `[pipeline]` or `[approach]` table: one variable swept ([`crate::Scenario`]).
    Sweep,
    /// A `[pipeline]` table ([`crate::pipeline::PipelineScenario`]).
    Pipeline,
    /// An `[approach]` table ([`crate::approach::ApproachScenario`]).
    Approach,
    /// A `[calibration_transfer]` table
    /// ([`crate::calibration_transfer::TransferScenario`]).
    CalibrationTransfer,
}

impl Kind {
    /// The kind of the scenario text `source`: `[pipeline]` first, then `[approach]`, then
    /// `[calibration_transfer]`, else a sweep (whose parser then reports what is wrong with a text that is no TOML).
    pub fn of(source: &str) -> Self {
        let tables = toml::from_str::<toml::Table>(source).ok();
        let has = |key: &str| tables.as_ref().is_some_and(|t| t.contains_key(key));
        if has("pipeline") {
            Kind::Pipeline
        } else if has("approach") {
            Kind::Approach
        } else if has("calibration_transfer") {
            Kind::CalibrationTransfer
        } else {
            Kind::Sweep
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kind_is_read_from_the_tables() {
        assert_eq!(Kind::of("name = \"a\"\n[sweep]\n"), Kind::Sweep);
        assert_eq!(Kind::of("name = \"a\"\n[pipeline]\n"), Kind::Pipeline);
        assert_eq!(Kind::of("name = \"a\"\n[approach]\n"), Kind::Approach);
        assert_eq!(Kind::of("[approach]\n[pipeline]\n"), Kind::Pipeline);
        assert_eq!(
            Kind::of("name = \"a\"\n[calibration_transfer]\n"),
            Kind::CalibrationTransfer
        );
        assert_eq!(Kind::of("not toml ["), Kind::Sweep);
    }
}
