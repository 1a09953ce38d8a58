//! Sharded runs (`bench-harness SCENARIO --shard K/N`) and their merge (`bench-harness
//! merge D_1 … D_N --out M`).
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
//! SHA-256, seed, trials, methods and the code that ran) and [`RECORDS_FILE`]: one JSON
//! object per trial and line, in the unsharded order, every floating-point value as the
//! integer of its IEEE-754 bit pattern ([`f64::to_bits`]), so nothing is lost to
//! decimal text. No `summary.csv` and no plots: those of a part would mislead.
//!
//! # The merge
//!
//! [`merge`] reads the manifests first and refuses, with [`MergeError`] (nothing
//! written), shards of different scenarios, seeds, trial counts or code, a shard given
//! twice, a missing shard or a shard count that differs. It then rebuilds each setting's
//! trials in the unsharded order from the records and writes `trials.csv` and
//! `summary.csv` with the very functions an unsharded run uses, on the same values in
//! the same order: the files are bit-identical to an unsharded run's, apart from the
//! timings (`time_ms` in `trials.csv`, the `time_ms` rows of `summary.csv`). It adds the
//! plots and `metadata.json` (with the shards' folders, machines and wall times). At
//! most one setting's trials are held in memory, as in an unsharded run.
//!
//! Pipeline scenarios (`[pipeline]`) cannot be sharded: every frame is corrected by one
//! depth table fitted to all the rig's frames, so their parts are not independent.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use epd_core::{FitOutcome, Method, N_PARAMS, ParamErrors, Params, Sigmas};
use epd_frame::shard::ShardSpec;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::output::{
    INTERRUPTED, Interrupted, MANIFEST_FILE, RECORDS_FILE, StagedFiles, create_new, finish,
    write_new, write_run, wrote,
};
use crate::provenance::{cpu_model, git_provenance, profile};
use crate::run::{
    RunOptions, RunReport, SummaryRow, TRIAL_COLUMNS, TrialRunner, finish_run, metadata,
    progress_bar, summarise, trial_rows,
};
use crate::scenario::{MAX_SCENARIO_BYTES, Scenario};
use crate::trial::{MethodRecord, TrialRecord};

/// The `format` of a [`ShardManifest`] this version writes and reads.
pub const SHARD_FORMAT: &str = "bench-harness-shard/1";
/// The partition, as named in a manifest.
pub const PARTITION: &str = "round-robin";

/// Largest manifest read (bytes).
const MAX_MANIFEST_BYTES: u64 = 1 << 20;
/// Longest line of a records file (bytes).
const MAX_RECORD_BYTES: u64 = 16 << 20;
/// With more shards than this, the merge reopens each records file once per setting
/// instead of keeping them all open (a process may open only so many files).
const KEEP_OPEN: usize = 256;

/// What made a shard: `bench-harness`'s version, the git commit of its workspace (when
/// it ran in one), the build profile and the SHA-256 of the executable itself (when it
/// could be read). Two shards merge only when all four agree.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CodeVersion {
    /// The crate version.
    pub crate_version: String,
    /// `git rev-parse HEAD` of the workspace the binary was built from, if any.
    pub git_commit: Option<String>,
    /// `dev` or `release`.
    pub profile: String,
    /// SHA-256 (hex) of the running executable, if it could be read.
    pub executable_sha256: Option<String>,
}

impl CodeVersion {
    /// The code of this process.
    pub fn current() -> Self {
        // /proc/self/exe opens the running program even when its file has been replaced
        // since it started (a rebuild during a long shard); the path is the fallback.
        let executable_sha256 = File::open("/proc/self/exe")
            .or_else(|_| std::env::current_exe().and_then(File::open))
            .ok()
            .and_then(|f| sha256_of(f).ok());
        Self {
            crate_version: env!("CARGO_PKG_VERSION").to_string(),
            git_commit: git_provenance().0,
            profile: profile().to_string(),
            executable_sha256,
        }
    }
}

impl std::fmt::Display for CodeVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let short = |s: &Option<String>| {
            s.as_deref()
                .map_or("unknown".to_string(), |c| c.chars().take(12).collect())
        };
        write!(
            f,
            "bench-harness {} (commit {}, {} build, executable sha256 {})",
            self.crate_version,
            short(&self.git_commit),
            self.profile,
            short(&self.executable_sha256)
        )
    }
}

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

/// Why shards cannot be merged (a usage error: nothing is written).
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// No folder was given.
    #[error("no shard folders given: bench-harness merge D_1 … D_N --out M")]
    NoShards,
    /// A folder is not a shard's.
    #[error(
        "{dir}: not a shard folder ({why}); make shards with `bench-harness SCENARIO --shard K/N --out DIR`"
    )]
    NotAShard {
        /// The folder.
        dir: PathBuf,
        /// What is missing.
        why: String,
    },
    /// A shard's files are damaged or not what its manifest says.
    #[error("{dir}: damaged shard: {why}")]
    Damaged {
        /// The folder.
        dir: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// Made by different code.
    #[error("shards of different code versions: {a} was made by {a_code}, {b} by {b_code}")]
    Code {
        /// One folder.
        a: PathBuf,
        /// Its code.
        a_code: String,
        /// Another.
        b: PathBuf,
        /// Its code.
        b_code: String,
    },
    /// The merge itself is different code from the shards'.
    #[error(
        "the merge is {merge_code} but the shards were made by {shard_code}: merge with the \
         binary that made the shards"
    )]
    MergeCode {
        /// This process's code.
        merge_code: String,
        /// The shards'.
        shard_code: String,
    },
    /// Different seeds.
    #[error("shards with different seeds: {a} has seed {a_seed}, {b} has seed {b_seed}")]
    Seed {
        /// One folder.
        a: PathBuf,
        /// Its seed.
        a_seed: u64,
        /// Another.
        b: PathBuf,
        /// Its seed.
        b_seed: u64,
    },
    /// Different trials per setting (`--trials`).
    #[error(
        "shards with different trials per setting: {a} ran {a_trials}, {b} ran {b_trials} \
         (--trials must be the same for every shard)"
    )]
    Trials {
        /// One folder.
        a: PathBuf,
        /// Its trials per setting.
        a_trials: usize,
        /// Another.
        b: PathBuf,
        /// Its trials per setting.
        b_trials: usize,
    },
    /// Different scenarios.
    #[error("shards of different scenarios: {a} ran {a_scenario}, {b} ran {b_scenario}")]
    Scenario {
        /// One folder.
        a: PathBuf,
        /// Its scenario: name, file and SHA-256.
        a_scenario: String,
        /// Another.
        b: PathBuf,
        /// Its scenario: name, file and SHA-256.
        b_scenario: String,
    },
    /// Different shard counts.
    #[error("shard counts differ: {a} is shard {a_k}/{a_n}, {b} is shard {b_k}/{b_n}")]
    Count {
        /// One folder.
        a: PathBuf,
        /// Its K.
        a_k: u64,
        /// Its N.
        a_n: u64,
        /// Another.
        b: PathBuf,
        /// Its K.
        b_k: u64,
        /// Its N.
        b_n: u64,
    },
    /// The same shard twice.
    #[error("shard {k}/{n} given twice: {a} and {b}")]
    Duplicate {
        /// K.
        k: u64,
        /// N.
        n: u64,
        /// One folder.
        a: PathBuf,
        /// The other.
        b: PathBuf,
    },
    /// Shards missing.
    #[error("{} of {n} shards missing: {} (given {given} folders)", missing.len(), list(missing, *n))]
    Missing {
        /// The missing K's.
        missing: Vec<u64>,
        /// N.
        n: u64,
        /// Folders given.
        given: usize,
    },
    /// `--out` is one of the shards.
    #[error("--out {0}: is one of the shard folders; the merge would replace it")]
    OutIsInput(PathBuf),
}

/// `[2, 5, 7]` of 8 → `shard 2/8, 5/8, 7/8`, at most 10 shown.
fn list(ks: &[u64], n: u64) -> String {
    let shown: Vec<String> = ks.iter().take(10).map(|k| format!("{k}/{n}")).collect();
    let more = ks.len().saturating_sub(shown.len());
    format!(
        "shard {}{}",
        shown.join(", "),
        if more > 0 {
            format!(" and {more} more")
        } else {
            String::new()
        }
    )
}

/// SHA-256 (hex) of everything `r` yields.
fn sha256_of(mut r: impl Read) -> std::io::Result<String> {
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = r.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(hex(&h.finalize()))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 (hex) of a scenario's text.
pub fn scenario_sha256(source: &str) -> String {
    hex(&Sha256::digest(source.as_bytes()))
}

/// The host's name, if known.
fn host_name() -> Option<String> {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
}

/// One method of a trial as stored in [`RECORDS_FILE`]: floats as their bit patterns.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct WireMethod {
    method: String,
    status: Option<FitOutcome>,
    message: String,
    iterations: usize,
    time_ms: u64,
    estimate: Option<[u64; N_PARAMS]>,
    sigma: [Option<u64>; N_PARAMS],
    errors: Option<[u64; 8]>,
}

/// One trial as stored in [`RECORDS_FILE`]: floats as their bit patterns.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct WireTrial {
    setting: usize,
    trial: usize,
    n_points: usize,
    truth: [u64; N_PARAMS],
    crb: [Option<u64>; N_PARAMS],
    error: Option<String>,
    methods: Vec<WireMethod>,
}

fn bits7(a: [f64; N_PARAMS]) -> [u64; N_PARAMS] {
    a.map(f64::to_bits)
}

fn sigma_bits(s: &Sigmas) -> [Option<u64>; N_PARAMS] {
    s.map(|v| v.map(f64::to_bits))
}

fn error_array(e: &ParamErrors) -> [f64; 8] {
    [
        e.d_max, e.d_min, e.d_mean, e.roll, e.pitch, e.yaw, e.dy, e.dz,
    ]
}

impl From<&TrialRecord> for WireTrial {
    fn from(t: &TrialRecord) -> Self {
        Self {
            setting: t.setting,
            trial: t.trial,
            n_points: t.n_points,
            truth: bits7(t.truth.to_array()),
            crb: sigma_bits(&t.crb),
            error: t.error.clone(),
            methods: t
                .methods
                .iter()
                .map(|m| WireMethod {
                    method: m.method.name().to_string(),
                    status: m.status,
                    message: m.message.clone(),
                    iterations: m.iterations,
                    time_ms: m.time_ms.to_bits(),
                    estimate: m.estimate.map(|p| bits7(p.to_array())),
                    sigma: sigma_bits(&m.sigma),
                    errors: m.errors.map(|e| error_array(&e).map(f64::to_bits)),
                })
                .collect(),
        }
    }
}

impl WireTrial {
    /// The record, checked against the scenario's methods.
    fn into_record(self, methods: &[Method]) -> Result<TrialRecord, String> {
        if self.methods.len() != methods.len() {
            return Err(format!(
                "trial {} of setting {} has {} methods, the scenario {}",
                self.trial,
                self.setting,
                self.methods.len(),
                methods.len()
            ));
        }
        let f = f64::from_bits;
        let sig = |s: [Option<u64>; N_PARAMS]| s.map(|v| v.map(f));
        let mut out = Vec::with_capacity(methods.len());
        for (w, &m) in self.methods.into_iter().zip(methods) {
            if w.method != m.name() {
                return Err(format!(
                    "trial {} of setting {}: method `{}` where the scenario has `{}`",
                    self.trial,
                    self.setting,
                    w.method,
                    m.name()
                ));
            }
            out.push(MethodRecord {
                method: m,
                status: w.status,
                message: w.message,
                iterations: w.iterations,
                time_ms: f(w.time_ms),
                estimate: w.estimate.map(|a| Params::from_array(a.map(f))),
                sigma: sig(w.sigma),
                errors: w.errors.map(|e| {
                    let e = e.map(f);
                    ParamErrors {
                        d_max: e[0],
                        d_min: e[1],
                        d_mean: e[2],
                        roll: e[3],
                        pitch: e[4],
                        yaw: e[5],
                        dy: e[6],
                        dz: e[7],
                    }
                }),
            });
        }
        Ok(TrialRecord {
            setting: self.setting,
            trial: self.trial,
            n_points: self.n_points,
            truth: Params::from_array(self.truth.map(f)),
            crb: sig(self.crb),
            methods: out,
            error: self.error,
        })
    }
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
        n_trials: usize,
        trial_errors: usize,
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
            n_trials,
            trial_errors,
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
) -> serde_json::Map<String, serde_json::Value> {
    let mut meta = metadata(scenario, trials, wall_time_s);
    meta.insert("shard".into(), shard.to_string().into());
    meta.insert(
        "sharding".into(),
        format!(
            "one shard of a sharded run: trial g = setting index × trials + trial is in shard \
             (g mod N) + 1; {n_trials} trials here. Merge the N shard folders with \
             `bench-harness merge D_1 … D_N --out M`"
        )
        .into(),
    );
    meta
}

fn stage_shard(
    scenario: &Scenario,
    progress: bool,
    trials: usize,
    shard: ShardSpec,
    dir: &Path,
    start: Instant,
) -> anyhow::Result<StagedShard> {
    let trials_path = dir.join("trials.csv");
    let records_path = dir.join(RECORDS_FILE);
    let mut trials_csv = create_new(&trials_path)?;
    let mut records = create_new(&records_path)?;
    writeln!(trials_csv, "{}", TRIAL_COLUMNS.join(",")).map_err(wrote(&trials_path))?;
    let settings = scenario.sweeps.len();
    let n_trials = shard_trial_count(shard, settings, trials);
    let bar = progress_bar(progress, n_trials as u64);
    let runner = TrialRunner::new(scenario, &bar);
    let mut trial_errors = 0;
    let mut written = 0;
    for (si, (value, _)) in scenario.sweeps.iter().enumerate() {
        let ts: Vec<usize> = (0..trials)
            .filter(|&t| shard.owns(si as u64 * trials as u64 + t as u64))
            .collect();
        runner.run_setting(si, &ts, |t| {
            trial_rows(&mut trials_csv, &scenario.sweep_variable, value, &t)
                .map_err(wrote(&trials_path))?;
            serde_json::to_writer(&mut records, &WireTrial::from(&t))
                .map_err(std::io::Error::from)
                .and_then(|()| records.write_all(b"\n"))
                .map_err(wrote(&records_path))?;
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
    let mut files = vec![
        finish(trials_csv, &trials_path)?,
        finish(records, &records_path)?,
    ];
    files.push(write_new(
        &dir.join("scenario.toml"),
        scenario.source.as_bytes(),
    )?);
    let wall_time_s = start.elapsed().as_secs_f64();
    let manifest = ShardManifest::new(scenario, shard, trials, written, trial_errors, wall_time_s);
    files.push(write_new(
        &dir.join(MANIFEST_FILE),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?);
    let meta = shard_metadata(scenario, trials, shard, n_trials, wall_time_s);
    files.push(write_new(
        &dir.join("metadata.json"),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?);
    Ok(StagedShard {
        files,
        wall_time_s,
        trial_errors,
    })
}

/// Where and how to merge.
#[derive(Clone, Debug)]
pub struct MergeOptions {
    /// The output folder (replaced as a whole, like a run's).
    pub out: PathBuf,
}

/// Read at most `limit` bytes of `path`; `None` when there are more.
fn read_capped(path: &Path, limit: u64) -> std::io::Result<Option<Vec<u8>>> {
    let mut bytes = Vec::new();
    File::open(path)?.take(limit + 1).read_to_end(&mut bytes)?;
    Ok((bytes.len() as u64 <= limit).then_some(bytes))
}

/// Read and check one shard folder's manifest.
fn read_manifest(dir: &Path) -> Result<ShardManifest, MergeError> {
    let not_a_shard = |why: String| MergeError::NotAShard {
        dir: dir.to_path_buf(),
        why,
    };
    let damaged = |why: String| MergeError::Damaged {
        dir: dir.to_path_buf(),
        why,
    };
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => return Err(not_a_shard("not a folder".into())),
        Err(e) => return Err(not_a_shard(format!("cannot read it: {e}"))),
    }
    let path = dir.join(MANIFEST_FILE);
    let bytes = match read_capped(&path, MAX_MANIFEST_BYTES) {
        Ok(Some(b)) => b,
        Ok(None) => return Err(damaged(format!("{MANIFEST_FILE} is too large"))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let what = if dir.join("summary.csv").exists() {
                "it holds a whole run: no "
            } else {
                "no "
            };
            return Err(not_a_shard(format!("{what}{MANIFEST_FILE}")));
        }
        Err(e) => return Err(damaged(format!("cannot read {MANIFEST_FILE}: {e}"))),
    };
    // The format first, so that a later version's manifest is named as such.
    let format = serde_json::from_slice::<serde_json::Value>(&bytes)
        .ok()
        .and_then(|v| v.get("format").and_then(|f| f.as_str()).map(String::from));
    if let Some(f) = format.as_deref()
        && f != SHARD_FORMAT
    {
        return Err(damaged(format!(
            "{MANIFEST_FILE} is of format `{f}`; this bench-harness reads `{SHARD_FORMAT}`"
        )));
    }
    let m: ShardManifest =
        serde_json::from_slice(&bytes).map_err(|e| damaged(format!("{MANIFEST_FILE}: {e}")))?;
    if ShardSpec::new(m.shard, m.shards).is_err() {
        return Err(damaged(format!(
            "{MANIFEST_FILE} says shard {}/{}",
            m.shard, m.shards
        )));
    }
    if m.partition != PARTITION {
        return Err(damaged(format!(
            "{MANIFEST_FILE}: partition `{}`, expected `{PARTITION}`",
            m.partition
        )));
    }
    let shard = ShardSpec::new(m.shard, m.shards).map_err(|e| damaged(e.to_string()))?;
    let expected = shard_trial_count(shard, m.settings, m.trials_per_setting);
    if m.n_trials != expected {
        return Err(damaged(format!(
            "{MANIFEST_FILE} counts {} trials; shard {shard} of {} settings × {} trials has {expected}",
            m.n_trials, m.settings, m.trials_per_setting
        )));
    }
    Ok(m)
}

/// Check that the shards belong to one run and are all there; the first error found,
/// most telling first (code, seed, trials, scenario, count, duplicates, missing).
fn check_shards(dirs: &[PathBuf], manifests: &[ShardManifest]) -> Result<(), MergeError> {
    let (a, m0) = (&dirs[0], &manifests[0]);
    // The first other shard that differs from the first in `differs`.
    let first_other = |differs: fn(&ShardManifest, &ShardManifest) -> bool| {
        dirs.iter()
            .zip(manifests)
            .skip(1)
            .find(|(_, m)| differs(m, m0))
            .map(|(b, m)| (a.clone(), b.clone(), m))
    };
    if let Some((a, b, m)) = first_other(|m, m0| m.code != m0.code) {
        return Err(MergeError::Code {
            a,
            a_code: m0.code.to_string(),
            b,
            b_code: m.code.to_string(),
        });
    }
    if let Some((a, b, m)) = first_other(|m, m0| m.seed != m0.seed) {
        return Err(MergeError::Seed {
            a,
            a_seed: m0.seed,
            b,
            b_seed: m.seed,
        });
    }
    if let Some((a, b, m)) = first_other(|m, m0| m.trials_per_setting != m0.trials_per_setting) {
        return Err(MergeError::Trials {
            a,
            a_trials: m0.trials_per_setting,
            b,
            b_trials: m.trials_per_setting,
        });
    }
    let scenario_differs = |m: &ShardManifest, m0: &ShardManifest| {
        m.scenario_sha256 != m0.scenario_sha256 || m.scenario != m0.scenario
    };
    if let Some((a, b, m)) = first_other(scenario_differs) {
        let what = |m: &ShardManifest| {
            format!(
                "`{}` ({}, sha256 {})",
                m.scenario,
                m.scenario_file,
                m.scenario_sha256.chars().take(16).collect::<String>()
            )
        };
        return Err(MergeError::Scenario {
            a,
            a_scenario: what(m0),
            b,
            b_scenario: what(m),
        });
    }
    if let Some((a, b, m)) = first_other(|m, m0| m.shards != m0.shards) {
        return Err(MergeError::Count {
            a,
            a_k: m0.shard,
            a_n: m0.shards,
            b,
            b_k: m.shard,
            b_n: m.shards,
        });
    }
    check_complete(dirs, manifests, m0.shards)
}

/// Every shard 1 … `n` given once: the first shard given twice, else the missing ones.
fn check_complete(dirs: &[PathBuf], manifests: &[ShardManifest], n: u64) -> Result<(), MergeError> {
    let mut seen: HashMap<u64, &PathBuf> = HashMap::new();
    for (d, m) in dirs.iter().zip(manifests) {
        if let Some(first) = seen.insert(m.shard, d) {
            return Err(MergeError::Duplicate {
                k: m.shard,
                n: m.shards,
                a: first.clone(),
                b: d.clone(),
            });
        }
    }
    let missing: Vec<u64> = (1..=n).filter(|k| !seen.contains_key(k)).collect();
    if !missing.is_empty() {
        return Err(MergeError::Missing {
            missing,
            n,
            given: dirs.len(),
        });
    }
    Ok(())
}

/// Reads one shard's records, one setting at a time.
struct RecordReader {
    dir: PathBuf,
    path: PathBuf,
    /// Bytes consumed so far.
    offset: u64,
    /// Lines consumed so far.
    line: usize,
    /// The open file, positioned at `offset`, when kept open.
    open: Option<BufReader<File>>,
}

impl RecordReader {
    fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_path_buf(),
            path: dir.join(RECORDS_FILE),
            offset: 0,
            line: 0,
            open: None,
        }
    }

    fn damaged(&self, why: String) -> anyhow::Error {
        MergeError::Damaged {
            dir: self.dir.clone(),
            why: format!("{RECORDS_FILE} line {}: {why}", self.line + 1),
        }
        .into()
    }

    /// The records of setting `setting` (the next ones in the file), leaving the
    /// next setting's unread; the file is kept open when `keep_open`.
    fn take_setting(
        &mut self,
        setting: usize,
        methods: &[Method],
        keep_open: bool,
    ) -> anyhow::Result<Vec<TrialRecord>> {
        let mut reader = match self.open.take() {
            Some(r) => r,
            None => {
                let mut f = File::open(&self.path).map_err(|e| MergeError::Damaged {
                    dir: self.dir.clone(),
                    why: format!("cannot read {RECORDS_FILE}: {e}"),
                })?;
                f.seek(SeekFrom::Start(self.offset))?;
                BufReader::new(f)
            }
        };
        let mut out = Vec::new();
        let mut buf = Vec::new();
        loop {
            buf.clear();
            let n = (&mut reader)
                .take(MAX_RECORD_BYTES + 1)
                .read_until(b'\n', &mut buf)
                .map_err(|e| self.damaged(format!("cannot read: {e}")))?;
            if n == 0 {
                break;
            }
            if buf.last() != Some(&b'\n') {
                return Err(self.damaged(if n as u64 > MAX_RECORD_BYTES {
                    "longer than 16 MiB".into()
                } else {
                    "cut short (no end of line)".into()
                }));
            }
            let wire: WireTrial = serde_json::from_slice(&buf)
                .map_err(|e| self.damaged(format!("not a trial record: {e}")))?;
            if wire.setting > setting {
                // The next setting's: read again then (the reader is dropped unless
                // kept, and a kept one is moved back to this line).
                reader.seek(SeekFrom::Start(self.offset))?;
                break;
            }
            let record = wire.into_record(methods).map_err(|e| self.damaged(e))?;
            self.offset += n as u64;
            self.line += 1;
            out.push(record);
        }
        if keep_open {
            self.open = Some(reader);
        }
        Ok(out)
    }
}

/// Merge shard folders `dirs` (any order) into `options.out`, as one unsharded run of
/// their scenario (see the module doc). Refusals are [`MergeError`]s (nothing written).
pub fn merge(dirs: &[PathBuf], options: &MergeOptions) -> anyhow::Result<RunReport> {
    let start = Instant::now();
    if dirs.is_empty() {
        return Err(MergeError::NoShards.into());
    }
    let manifests = dirs
        .iter()
        .map(|d| read_manifest(d))
        .collect::<Result<Vec<_>, _>>()?;
    check_shards(dirs, &manifests)?;
    let here = CodeVersion::current();
    if here != manifests[0].code {
        return Err(MergeError::MergeCode {
            merge_code: here.to_string(),
            shard_code: manifests[0].code.to_string(),
        }
        .into());
    }
    if let Ok(out) = options.out.canonicalize()
        && dirs
            .iter()
            .any(|d| d.canonicalize().is_ok_and(|d| d == out))
    {
        return Err(MergeError::OutIsInput(options.out.clone()).into());
    }
    // Shard K's folder at index K − 1.
    let mut order: Vec<usize> = (0..dirs.len()).collect();
    order.sort_by_key(|&i| manifests[i].shard);
    let first = &dirs[order[0]];
    let m0 = &manifests[order[0]];
    let damaged = |why: String| MergeError::Damaged {
        dir: first.clone(),
        why,
    };
    let scenario_path = first.join("scenario.toml");
    let text = match read_capped(&scenario_path, MAX_SCENARIO_BYTES) {
        Ok(Some(b)) => {
            String::from_utf8(b).map_err(|_| damaged("scenario.toml is not UTF-8".into()))?
        }
        Ok(None) => return Err(damaged("scenario.toml is too large".into()).into()),
        Err(e) => return Err(damaged(format!("cannot read scenario.toml: {e}")).into()),
    };
    if scenario_sha256(&text) != m0.scenario_sha256 {
        return Err(damaged(format!(
            "scenario.toml is not the scenario the shard ran (its sha256 differs from {MANIFEST_FILE}'s)"
        ))
        .into());
    }
    let scenario = Scenario::parse(Path::new(&m0.scenario_file), &text)
        .map_err(|e| damaged(format!("scenario.toml: {e}")))?;
    let methods = scenario.sweeps[0].1.methods.clone();
    let names: Vec<String> = methods.iter().map(|m| m.name().to_string()).collect();
    if scenario.sweeps.len() != m0.settings || names != m0.methods || scenario.seed != m0.seed {
        return Err(damaged(format!(
            "scenario.toml has {} settings and methods {names:?}, {MANIFEST_FILE} {} and {:?}",
            scenario.sweeps.len(),
            m0.settings,
            m0.methods
        ))
        .into());
    }
    let trials = m0.trials_per_setting;
    let shards: Vec<(&PathBuf, &ShardManifest)> =
        order.iter().map(|&i| (&dirs[i], &manifests[i])).collect();
    let staged = write_run(&options.out, |dir| {
        stage_merge(&scenario, &methods, trials, &shards, dir, start)
    })?;
    Ok(RunReport {
        summary: staged.summary,
        files: staged.files,
        wall_time_s: staged.wall_time_s,
        trial_errors: staged.trial_errors,
    })
}

/// A merge written into its staging folder.
struct StagedMerge {
    summary: Vec<SummaryRow>,
    files: Vec<PathBuf>,
    wall_time_s: f64,
    trial_errors: usize,
}

impl StagedFiles for StagedMerge {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }

    /// Refused shards are a usage error, named as such (nothing is written).
    fn is_refusal(e: &anyhow::Error) -> bool {
        e.is::<MergeError>()
    }
}

fn stage_merge(
    scenario: &Scenario,
    methods: &[Method],
    trials: usize,
    shards: &[(&PathBuf, &ShardManifest)],
    dir: &Path,
    start: Instant,
) -> anyhow::Result<StagedMerge> {
    let n = shards.len();
    let keep_open = n <= KEEP_OPEN;
    let mut readers: Vec<RecordReader> = shards.iter().map(|(d, _)| RecordReader::new(d)).collect();
    let trials_path = dir.join("trials.csv");
    let mut trials_csv = create_new(&trials_path)?;
    writeln!(trials_csv, "{}", TRIAL_COLUMNS.join(",")).map_err(wrote(&trials_path))?;
    let mut summary = Vec::new();
    let mut trial_errors = 0;
    for (si, (value, setting)) in scenario.sweeps.iter().enumerate() {
        if INTERRUPTED.load(Ordering::SeqCst) {
            return Err(Interrupted.into());
        }
        // Each shard's records of this setting, in trial order, taken from the front.
        let mut parts: Vec<std::vec::IntoIter<TrialRecord>> = Vec::with_capacity(n);
        for r in &mut readers {
            parts.push(r.take_setting(si, methods, keep_open)?.into_iter());
        }
        let results = interleave(&mut parts, shards, scenario, si, trials, |record| {
            trial_rows(&mut trials_csv, &scenario.sweep_variable, value, record)
                .map_err(wrote(&trials_path))?;
            trial_errors += record.errors();
            Ok(())
        })?;
        summary.extend(summarise(value, &setting.methods, &results));
    }
    // Nothing may follow the last setting.
    for r in &mut readers {
        let rest = r.take_setting(usize::MAX, methods, false)?;
        if let Some(extra) = rest.first() {
            return Err(MergeError::Damaged {
                dir: r.dir.clone(),
                why: format!(
                    "{RECORDS_FILE}: a record of setting {} after the scenario's {} settings",
                    extra.setting,
                    scenario.sweeps.len()
                ),
            }
            .into());
        }
    }
    let mut files = vec![finish(trials_csv, &trials_path)?];
    let extra = merge_metadata(shards);
    let (rest, wall_time_s) = finish_run(scenario, &summary, trials, dir, start, extra)?;
    files.extend(rest);
    Ok(StagedMerge {
        summary,
        files,
        wall_time_s,
        trial_errors,
    })
}

/// Setting `si`'s records in the unsharded run's order, trial g = si × trials + t taken
/// from shard (g mod N) + 1's `parts`, each passed to `emit` as it is taken; an error if
/// one is missing or out of order, or if a shard has records left over.
fn interleave(
    parts: &mut [std::vec::IntoIter<TrialRecord>],
    shards: &[(&PathBuf, &ShardManifest)],
    scenario: &Scenario,
    si: usize,
    trials: usize,
    mut emit: impl FnMut(&TrialRecord) -> anyhow::Result<()>,
) -> anyhow::Result<Vec<TrialRecord>> {
    let n = shards.len();
    let value = &scenario.sweeps[si].0;
    let mut results: Vec<TrialRecord> = Vec::with_capacity(trials);
    for t in 0..trials {
        let g = si as u64 * trials as u64 + t as u64;
        let k = (g % n as u64) as usize;
        let record = parts[k].next().filter(|r| r.trial == t && r.setting == si);
        let Some(record) = record else {
            return Err(MergeError::Damaged {
                dir: shards[k].0.clone(),
                why: format!(
                    "{RECORDS_FILE}: trial {t} of setting {si} ({} = {value}) is missing or out of order",
                    scenario.sweep_variable
                ),
            }
            .into());
        };
        emit(&record)?;
        results.push(record);
    }
    for (k, rest) in parts.iter_mut().enumerate() {
        if let Some(extra) = rest.next() {
            return Err(MergeError::Damaged {
                dir: shards[k].0.clone(),
                why: format!(
                    "{RECORDS_FILE}: trial {} of setting {si} does not belong to shard {}/{n}",
                    extra.trial,
                    k + 1
                ),
            }
            .into());
        }
    }
    Ok(results)
}

/// What a merged run's `metadata.json` adds to a run's: the shards, how the trials were
/// split, and each shard's own times, threads and host.
fn merge_metadata(
    shards: &[(&PathBuf, &ShardManifest)],
) -> serde_json::Map<String, serde_json::Value> {
    let n = shards.len();
    let shard_times: Vec<f64> = shards.iter().map(|(_, m)| m.wall_time_s).collect();
    let mut extra = serde_json::Map::new();
    extra.insert("shards".into(), n.into());
    extra.insert(
        "sharding".into(),
        format!(
            "merged from {n} shards (bench-harness merge); trial g = setting index × trials + \
             trial was run by shard (g mod N) + 1. wall_time_s and threads are the merge's; \
             each shard's are under merged_from"
        )
        .into(),
    );
    extra.insert(
        "shard_wall_time_s_sum".into(),
        shard_times.iter().sum::<f64>().into(),
    );
    extra.insert(
        "shard_wall_time_s_max".into(),
        shard_times.iter().copied().fold(0.0, f64::max).into(),
    );
    extra.insert(
        "merged_from".into(),
        shards
            .iter()
            .map(|(d, m)| {
                serde_json::json!({
                    "dir": d.display().to_string(),
                    "shard": format!("{}/{}", m.shard, m.shards),
                    "n_trials": m.n_trials,
                    "wall_time_s": m.wall_time_s,
                    "threads": m.threads,
                    "cpu_model": m.cpu_model,
                    "host": m.host,
                    "git_dirty": m.git_dirty,
                })
            })
            .collect::<Vec<_>>()
            .into(),
    );
    extra
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

    #[test]
    fn records_round_trip_bit_for_bit() {
        let nan_payload = f64::from_bits(0x7ff8_0000_0000_1234);
        let record = TrialRecord {
            setting: 2,
            trial: 17,
            n_points: 306_001,
            truth: Params::from_array([0.1 + 0.2, 1e-300, -0.0, 5e-324, 1.0 / 3.0, -2.5, 7.0]),
            crb: [
                Some(1e-7),
                None,
                Some(f64::INFINITY),
                None,
                None,
                None,
                Some(nan_payload),
            ],
            methods: vec![
                MethodRecord {
                    method: Method::CEpd,
                    status: Some(FitOutcome::Implausible),
                    message: "a \"quoted\", multi\nline message".into(),
                    iterations: 12,
                    time_ms: 2.718_281_828_459_1,
                    estimate: Some(Params::from_array([0.49, 0.48, 0.1, 0.2, 0.3, 0.01, -0.02])),
                    sigma: [None, Some(1e-5), None, None, None, None, Some(2e-5)],
                    errors: Some(ParamErrors {
                        d_max: 1e-4,
                        d_min: -2e-4,
                        d_mean: -5e-5,
                        roll: 0.1,
                        pitch: f64::NAN,
                        yaw: -0.0,
                        dy: 1e-3,
                        dz: 2e-3,
                    }),
                },
                MethodRecord {
                    method: Method::MlEpd,
                    status: None,
                    message: "no estimate".into(),
                    iterations: 0,
                    time_ms: 0.0,
                    estimate: None,
                    sigma: [None; N_PARAMS],
                    errors: None,
                },
            ],
            error: Some("x".into()),
        };
        let line = serde_json::to_string(&WireTrial::from(&record)).unwrap();
        assert!(!line.contains('\n'));
        let back: WireTrial = serde_json::from_str(&line).unwrap();
        let back = back.into_record(&[Method::CEpd, Method::MlEpd]).unwrap();
        // Bit for bit, NaN payloads and signed zeros included.
        let again = serde_json::to_string(&WireTrial::from(&back)).unwrap();
        assert_eq!(line, again);
        assert_eq!(
            back.truth.to_array().map(f64::to_bits),
            record.truth.to_array().map(f64::to_bits)
        );
        assert_eq!(back.methods[0].message, record.methods[0].message);
        assert_eq!(
            back.methods[0].time_ms.to_bits(),
            record.methods[0].time_ms.to_bits()
        );
        // The scenario's methods must match, in order.
        let w: WireTrial = serde_json::from_str(&line).unwrap();
        assert!(w.into_record(&[Method::MlEpd, Method::CEpd]).is_err());
        let w: WireTrial = serde_json::from_str(&line).unwrap();
        assert!(w.into_record(&[Method::CEpd]).is_err());
        // The status is written by serde as the name of `trials.csv` (`error` is no
        // status: a missing estimate is `null`), and an unknown name is refused.
        assert!(line.contains(r#""status":"implausible""#), "{line}");
        assert!(line.contains(r#""status":null"#), "{line}");
        let bad = line.replace("implausible", "fine");
        let e = serde_json::from_str::<WireTrial>(&bad)
            .err()
            .expect("refused");
        assert!(e.to_string().contains("unknown variant `fine`"), "{e}");
    }

    #[test]
    fn statuses_are_written_with_their_names() {
        for o in FitOutcome::ALL {
            let json = serde_json::to_string(&o).unwrap();
            assert_eq!(json, format!("\"{}\"", o.name()));
            assert_eq!(serde_json::from_str::<FitOutcome>(&json).unwrap(), o);
        }
        let names = FitOutcome::ALL.map(FitOutcome::name);
        assert_eq!(
            names,
            [
                "converged",
                "iteration_limit",
                "degenerate",
                "implausible",
                "lack_of_fit"
            ]
        );
    }

    #[test]
    fn missing_shards_are_listed() {
        let e = MergeError::Missing {
            missing: vec![2, 4],
            n: 4,
            given: 2,
        };
        assert_eq!(
            e.to_string(),
            "2 of 4 shards missing: shard 2/4, 4/4 (given 2 folders)"
        );
    }
}
