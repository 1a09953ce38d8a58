//! The merge of a sharded run's folders (`bench-harness merge D_1 … D_N --out M`).
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
//! The checks of the shards before anything is read are in `merge/check.rs`; each
//! shard's records file is then checked against the length and SHA-256 its manifest
//! records (`verify_records`), and each record against itself as it is read
//! ([`TrialRecord::check_consistent`]): an edited or swapped records file is refused,
//! naming the file and, where it can be found, the line.

use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use epd_core::Method;

use super::record::TrialRecord;
use super::rows::{TRIAL_COLUMNS, write_trial_rows};
use super::run::{RunReport, finish_run};
use super::scenario::Scenario;
use super::shard::ShardManifest;
use super::summary::{SummaryRow, summarise};
use crate::output::{
    CsvFile, INTERRUPTED, Interrupted, MANIFEST_FILE, RECORDS_FILE, StagedFiles, write_run,
};
use crate::provenance::{CodeVersion, Metadata, hex, scenario_sha256, sha256_of};
use crate::scenario::MAX_SCENARIO_BYTES;
pub use check::MergeError;
use check::{check_shards, open_regular, read_capped, read_manifest};
use sha2::{Digest, Sha256};

mod check;

/// Longest line of a records file (bytes).
const MAX_RECORD_BYTES: u64 = 16 << 20;
/// With more shards than this, the merge reopens each records file once per setting
/// instead of keeping them all open (a process may open only so many files).
const KEEP_OPEN: usize = 256;

/// Where and how to merge.
#[derive(Clone, Debug)]
pub struct MergeOptions {
    /// The output folder (replaced as a whole, like a run's).
    pub out: PathBuf,
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
    open: Option<BufReader<std::fs::File>>,
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
                let (mut f, _) = open_regular(&self.path).map_err(|e| MergeError::Damaged {
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
            let record: TrialRecord = serde_json::from_slice(&buf)
                .map_err(|e| self.damaged(format!("not a trial record: {e}")))?;
            if record.setting > setting {
                // The next setting's: read again then (the reader is dropped unless
                // kept, and a kept one is moved back to this line).
                reader.seek(SeekFrom::Start(self.offset))?;
                break;
            }
            record.check_methods(methods).map_err(|e| self.damaged(e))?;
            record.check_consistent().map_err(|e| self.damaged(e))?;
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
    for (dir, m) in &shards {
        verify_scenario(dir, m)?;
        verify_records(dir, m, &methods)?;
    }
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

/// Check that a shard's `scenario.toml` is the scenario its manifest names (its SHA-256):
/// every shard's, not only the one the merge reads.
fn verify_scenario(dir: &Path, m: &ShardManifest) -> Result<(), MergeError> {
    let damaged = |why: String| MergeError::Damaged {
        dir: dir.to_path_buf(),
        why,
    };
    let text = match read_capped(&dir.join("scenario.toml"), MAX_SCENARIO_BYTES) {
        Ok(Some(b)) => b,
        Ok(None) => return Err(damaged("scenario.toml is too large".into())),
        Err(e) => return Err(damaged(format!("cannot read scenario.toml: {e}"))),
    };
    if hex(&Sha256::digest(&text)) != m.scenario_sha256 {
        return Err(damaged(format!(
            "scenario.toml is not the scenario the shard ran (its sha256 differs from \
             {MANIFEST_FILE}'s)"
        )));
    }
    Ok(())
}

/// Check a shard's records against its manifest before anything is merged: its
/// [`RECORDS_FILE`] a regular file of the length and SHA-256 the manifest records.
/// Records that differ are refused naming the first line that does not parse or
/// disagrees with itself ([`TrialRecord::check_consistent`]), when one does.
fn verify_records(dir: &Path, m: &ShardManifest, methods: &[Method]) -> Result<(), MergeError> {
    let damaged = |why: String| MergeError::Damaged {
        dir: dir.to_path_buf(),
        why,
    };
    let path = dir.join(RECORDS_FILE);
    if m.records_bytes > (m.n_trials as u64).saturating_mul(MAX_RECORD_BYTES + 1) {
        return Err(damaged(format!(
            "{MANIFEST_FILE} says {RECORDS_FILE} holds {} bytes, more than {} records of at \
             most {MAX_RECORD_BYTES} bytes",
            m.records_bytes, m.n_trials
        )));
    }
    let (file, len) =
        open_regular(&path).map_err(|e| damaged(format!("cannot read {RECORDS_FILE}: {e}")))?;
    let differs = |what: String| {
        let line = first_bad_line(&path, methods)
            .map(|l| format!("; {RECORDS_FILE} {l}"))
            .unwrap_or_default();
        damaged(format!(
            "{RECORDS_FILE} {what}: the records were changed after the shard ran{line}"
        ))
    };
    if len != m.records_bytes {
        return Err(differs(format!(
            "is {len} bytes, {MANIFEST_FILE} says {}",
            m.records_bytes
        )));
    }
    let sha = sha256_of(file.take(len))
        .map_err(|e| damaged(format!("cannot read {RECORDS_FILE}: {e}")))?;
    if sha != m.records_sha256 {
        return Err(differs(format!(
            "has SHA-256 {}…, {MANIFEST_FILE} says {}…",
            &sha[..16],
            m.records_sha256.chars().take(16).collect::<String>()
        )));
    }
    Ok(())
}

/// The first line of a records file that is not a trial record of `methods` agreeing
/// with itself, and why (`line N: …`); `None` when every line is one.
fn first_bad_line(path: &Path, methods: &[Method]) -> Option<String> {
    let (file, _) = open_regular(path).ok()?;
    let mut reader = BufReader::new(file);
    let mut buf = Vec::new();
    for line in 1.. {
        buf.clear();
        let n = (&mut reader)
            .take(MAX_RECORD_BYTES + 1)
            .read_until(b'\n', &mut buf)
            .ok()?;
        if n == 0 {
            return None;
        }
        let why = match serde_json::from_slice::<TrialRecord>(&buf) {
            Err(e) => Some(format!("not a trial record: {e}")),
            Ok(r) => r
                .check_methods(methods)
                .and_then(|()| r.check_consistent())
                .err(),
        };
        if let Some(why) = why {
            return Some(format!("line {line}: {why}"));
        }
    }
    None
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
    let mut trials_csv = CsvFile::create(&dir.join("trials.csv"), TRIAL_COLUMNS)?;
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
            write_trial_rows(&mut trials_csv, &scenario.sweep_variable, value, record)?;
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
    let mut files = vec![trials_csv.finish()?];
    let (rest, wall_time_s) = finish_run(scenario, &summary, trials, dir, start, |meta| {
        merge_metadata(meta, shards)
    })?;
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

/// A merged run's `metadata.json`: a run's `meta` with the shards, how the trials were
/// split, and each shard's own times, threads and host.
fn merge_metadata(meta: Metadata, shards: &[(&PathBuf, &ShardManifest)]) -> Metadata {
    let n = shards.len();
    let shard_times: Vec<f64> = shards.iter().map(|(_, m)| m.wall_time_s).collect();
    let merged_from: Vec<serde_json::Value> = shards
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
        .collect();
    meta.with("shards", n)
        .with(
            "sharding",
            format!(
                "merged from {n} shards (bench-harness merge); trial g = setting index × trials \
                 + trial was run by shard (g mod N) + 1. wall_time_s and threads are the \
                 merge's; each shard's are under merged_from"
            ),
        )
        .with("shard_wall_time_s_sum", shard_times.iter().sum::<f64>())
        .with(
            "shard_wall_time_s_max",
            shard_times.iter().copied().fold(0.0, f64::max),
        )
        .with("merged_from", merged_from)
}
