//! Sharded runs (`bench-harness SCENARIO --shard K/N`); their merge is [`super::merge`].
//!
//!
//! # The partition
//!
//! The scenario's trials are numbered across the whole run in the order of
//! `trials.csv`: g = setting index × trials per setting + trial. Trial g goes to shard
//! (g mod N) + 1 (a round robin), so every shard gets the same number of trials (± 1)
//! and the same mix of settings, whatever each setting costs. A trial's pose and noise
//! depend on (seed, trial, setting index) only, so a shard computes exactly the values
//! the unsharded run computes for the same trials.
//!
//! # A shard's folder
//!
//! Written as a whole like a run's (see [`crate::output`]): `trials.csv` (the shard's rows,
//! in the unsharded order; for reading, not for merging), `scenario.toml`,
//! `metadata.json`, [`MANIFEST_FILE`] (a [`ShardManifest`]: which shard, the scenario's
//! SHA-256, seed, trials, methods, the code that ran and the records file's SHA-256 and
//! length) and [`RECORDS_FILE`]: one JSON
//! object per trial and line ([`super::record::TrialRecord`]), in the unsharded order,
//! every floating-point value as the integer of its IEEE-754 bit pattern
//! ([`f64::to_bits`]), so nothing is lost to decimal text. No `summary.csv` and no plots:
//! those of a part would mislead.
//!
//!
//! Pipeline scenarios (`[pipeline]`) cannot be sharded: every frame is corrected by one
//! depth table fitted to all the rig's frames, so their parts are not independent.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use epd_frame::shard::ShardSpec;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::rows::{TRIAL_COLUMNS, write_trial_rows};
use super::run::{RunOptions, RunReport, metadata};
use super::runner::{TrialRunner, progress_bar};
use super::scenario::Scenario;
use crate::output::{
    CsvFile, INTERRUPTED, Interrupted, MANIFEST_FILE, RECORDS_FILE, StagedFiles, create_new,
    finish, write_new, write_run, wrote,
};
use crate::provenance::{
    CodeVersion, Metadata, cpu_model, git_provenance, hex, host_name, scenario_sha256,
};

/// The `format` of a [`ShardManifest`] this version writes and reads (version 2 added
/// `records_sha256` and `records_bytes`).
pub const SHARD_FORMAT: &str = "bench-harness-shard/2";
/// The partition, as named in a manifest.
pub const PARTITION: &str = "round-robin";

/// A shard's manifest ([`MANIFEST_FILE`]): what the merge checks before reading any
/// trial.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardManifest {
    /// [`SHARD_FORMAT`].
    pub format: String,
    /// K, from 1.
    pub shard: u64,
    /// N.
    pub shards: u64,
    /// [`PARTITION`].
    pub partition: String,
    /// The scenario's `name`.
    pub scenario: String,
    /// The scenario file as given to the shard's run.
    pub scenario_file: String,
    /// SHA-256 (hex) of the scenario's text.
    pub scenario_sha256: String,
    /// The scenario's seed.
    pub seed: u64,
    /// Trials per setting (the scenario's, or `--trials`).
    pub trials_per_setting: usize,
    /// Settings (swept values) in the scenario.
    pub settings: usize,
    /// The methods, in the scenario's order.
    pub methods: Vec<String>,
    /// Trials in this shard (lines of [`RECORDS_FILE`]).
    pub n_trials: usize,
    /// SHA-256 (hex) of [`RECORDS_FILE`] as the shard wrote it: the merge refuses
    /// records that differ.
    pub records_sha256: String,
    /// Length of [`RECORDS_FILE`] (bytes).
    pub records_bytes: u64,
    /// Trials or estimates of this shard that could not be made (status `error`).
    pub trial_errors: usize,
    /// The code that ran.
    pub code: CodeVersion,
    /// Whether tracked files of the workspace differed from `code.git_commit`.
    pub git_dirty: Option<bool>,
    /// Worker threads.
    pub threads: usize,
    /// The machine's CPU.
    pub cpu_model: String,
    /// The host's name, if known.
    pub host: Option<String>,
    /// Wall time of the shard's run (s).
    pub wall_time_s: f64,
}

/// Trials of a run of `settings × trials` that go to `shard`.
pub fn shard_trial_count(shard: ShardSpec, settings: usize, trials: usize) -> usize {
    let total = settings as u128 * trials as u128;
    let first = u128::from(shard.k() - 1);
    if first >= total {
        0
    } else {
        ((total - first).div_ceil(u128::from(shard.n()))) as usize
    }
}

/// What a shard wrote to its [`RECORDS_FILE`].
struct WrittenRecords {
    /// Trials (lines).
    n_trials: usize,
    /// Trials or estimates with an error.
    trial_errors: usize,
    /// SHA-256 (hex) of the file.
    sha256: String,
    /// Its length (bytes).
    bytes: u64,
}

/// A shard written into its staging folder.
struct StagedShard {
    files: Vec<PathBuf>,
    wall_time_s: f64,
    trial_errors: usize,
}

impl StagedFiles for StagedShard {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }
}

/// Run shard `shard` of `scenario` into `options.out` (see the module doc): the trials
/// g with g mod N = K − 1. The report's `summary` is empty: a shard has none.
pub fn run_shard(
    scenario: &Scenario,
    options: &RunOptions,
    shard: ShardSpec,
) -> anyhow::Result<RunReport> {
    let start = Instant::now();
    let trials = options.checked_trials(scenario)?;
    let staged = write_run(&options.out, |dir| {
        stage_shard(scenario, options.progress, trials, shard, dir, start)
    })?;
    Ok(RunReport {
        summary: Vec::new(),
        files: staged.files,
        wall_time_s: staged.wall_time_s,
        trial_errors: staged.trial_errors,
    })
}

impl ShardManifest {
    /// The manifest of shard `shard` of `scenario` run with `trials` per setting:
    /// `n_trials` trials written, `trial_errors` of them with an error, in `wall_time_s`.
    fn new(
        scenario: &Scenario,
        shard: ShardSpec,
        trials: usize,
        written: &WrittenRecords,
        wall_time_s: f64,
    ) -> Self {
        let (_, git_dirty) = git_provenance();
        ShardManifest {
            format: SHARD_FORMAT.into(),
            shard: shard.k(),
            shards: shard.n(),
            partition: PARTITION.into(),
            scenario: scenario.name.clone(),
            scenario_file: scenario.path.display().to_string(),
            scenario_sha256: scenario_sha256(&scenario.source),
            seed: scenario.seed,
            trials_per_setting: trials,
            settings: scenario.sweeps.len(),
            methods: scenario.sweeps[0]
                .1
                .methods
                .iter()
                .map(|m| m.name().to_string())
                .collect(),
            n_trials: written.n_trials,
            records_sha256: written.sha256.clone(),
            records_bytes: written.bytes,
            trial_errors: written.trial_errors,
            code: CodeVersion::current(),
            git_dirty,
            threads: rayon::current_num_threads(),
            cpu_model: cpu_model(),
            host: host_name(),
            wall_time_s,
        }
    }
}

/// A shard's `metadata.json`: a run's, with the shard and how the trials were split.
fn shard_metadata(
    scenario: &Scenario,
    trials: usize,
    shard: ShardSpec,
    n_trials: usize,
    wall_time_s: f64,
) -> Metadata {
    metadata(scenario, trials, wall_time_s)
        .with("shard", shard.to_string())
        .with(
            "sharding",
            format!(
                "one shard of a sharded run: trial g = setting index × trials + trial is in \
                 shard (g mod N) + 1; {n_trials} trials here. Merge the N shard folders with \
                 `bench-harness merge D_1 … D_N --out M`"
            ),
        )
}

fn stage_shard(
    scenario: &Scenario,
    progress: bool,
    trials: usize,
    shard: ShardSpec,
    dir: &Path,
    start: Instant,
) -> anyhow::Result<StagedShard> {
    let mut trials_csv = CsvFile::create(&dir.join("trials.csv"), TRIAL_COLUMNS)?;
    let records_path = dir.join(RECORDS_FILE);
    let mut records = create_new(&records_path)?;
    let settings = scenario.sweeps.len();
    let n_trials = shard_trial_count(shard, settings, trials);
    let bar = progress_bar(progress, n_trials as u64);
    let runner = TrialRunner::new(scenario, &bar);
    let mut trial_errors = 0;
    let mut written = 0;
    let mut hash = Sha256::new();
    let mut bytes = 0u64;
    for (si, (value, _)) in scenario.sweeps.iter().enumerate() {
        let ts: Vec<usize> = (0..trials)
            .filter(|&t| shard.owns(si as u64 * trials as u64 + t as u64))
            .collect();
        runner.run_setting(si, &ts, |t| {
            write_trial_rows(&mut trials_csv, &scenario.sweep_variable, value, &t)?;
            let mut line = serde_json::to_vec(&t)?;
            line.push(b'\n');
            hash.update(&line);
            bytes += line.len() as u64;
            records.write_all(&line).map_err(wrote(&records_path))?;
            trial_errors += t.errors();
            written += 1;
            Ok(())
        })?;
    }
    bar.finish_and_clear();
    if INTERRUPTED.load(Ordering::SeqCst) {
        return Err(Interrupted.into());
    }
    debug_assert_eq!(written, n_trials);
    let mut files = vec![trials_csv.finish()?, finish(records, &records_path)?];
    files.push(write_new(
        &dir.join("scenario.toml"),
        scenario.source.as_bytes(),
    )?);
    let wall_time_s = start.elapsed().as_secs_f64();
    let records_written = WrittenRecords {
        n_trials: written,
        trial_errors,
        sha256: hex(&hash.finalize()),
        bytes,
    };
    let manifest = ShardManifest::new(scenario, shard, trials, &records_written, wall_time_s);
    files.push(write_new(
        &dir.join(MANIFEST_FILE),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?);
    files.push(shard_metadata(scenario, trials, shard, n_trials, wall_time_s).write(dir)?);
    Ok(StagedShard {
        files,
        wall_time_s,
        trial_errors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trial_counts_add_up_to_the_run() {
        for (settings, trials) in [(5usize, 100usize), (1, 1), (3, 7), (2, 0)] {
            for n in [1u64, 2, 3, 4, 7, 1000] {
                let total: usize = (1..=n)
                    .map(|k| shard_trial_count(ShardSpec::new(k, n).unwrap(), settings, trials))
                    .sum();
                assert_eq!(total, settings * trials, "{settings}×{trials} in {n}");
                for k in 1..=n {
                    let s = ShardSpec::new(k, n).unwrap();
                    let owned = (0..(settings * trials) as u64)
                        .filter(|&g| s.owns(g))
                        .count();
                    assert_eq!(shard_trial_count(s, settings, trials), owned);
                }
            }
        }
    }
}
