//! The scenario runner behind `bench-harness`: TOML scenarios of three experiments, each
//! in its folder and run through one [`experiment::Experiment`] flow — a sweep of one
//! variable over simulated ToF frames ([`sweep`]: `trials.csv`, `summary.csv`, plots; in
//! shards and merged), the paper's pipeline run ([`pipeline`]) and the approach to an
//! elbow or a tee ([`approach`]) — written as a whole into one output folder
//! ([`output`]) with one `metadata.json` ([`provenance`]).
#![deny(missing_docs)]

pub mod approach;
pub mod calibration_transfer;
mod defaults;
pub mod experiment;
pub mod output;
pub mod pipeline;
pub mod plots;
pub mod provenance;
pub mod route;
pub mod scenario;
pub mod stats;
pub mod sweep;

pub use scenario::ScenarioError;
pub use sweep::scenario::Scenario;
pub use sweep::summary::SummaryRow;
pub use sweep::{RunOptions, RunReport, run};
