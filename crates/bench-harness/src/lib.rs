//! The scenario runner behind `bench-harness`: TOML scenarios (README, Scenario files)
//! that sweep one variable over simulated ToF frames, every listed estimator on the same
//! clouds, written to `trials.csv`, `summary.csv`, metadata and PNG plots in the paper's
//! style; a run split into shards (`--shard K/N`) and their merge ([`shard`]).
#![deny(missing_docs)]

pub mod approach;
mod defaults;
pub mod output;
pub mod pipeline;
pub mod plots;
mod provenance;
pub mod route;
pub mod run;
pub mod scenario;
pub mod shard;
pub mod stats;
pub mod trial;

pub use run::{RunOptions, RunReport, SummaryRow, run};
pub use scenario::{Scenario, ScenarioError};
