//! Whether the folders given to `merge` are the N shards of one run: each manifest read
//! and checked, then all of them against each other. Refusals are [`MergeError`]s.

use std::collections::HashMap;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use epd_frame::shard::ShardSpec;

use super::super::scenario::{MAX_SWEEP_VALUES, MAX_TRIALS};
use super::super::shard::{PARTITION, SHARD_FORMAT, ShardManifest, shard_trial_count};
use crate::output::MANIFEST_FILE;

/// Largest manifest read (bytes).
const MAX_MANIFEST_BYTES: u64 = 1 << 20;

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
    #[error("{count} of {n} shards missing: {} (given {given} folders)", list(missing, *count, *n))]
    Missing {
        /// The first `SHOWN_MISSING` missing K's.
        missing: Vec<u64>,
        /// How many are missing.
        count: u64,
        /// N.
        n: u64,
        /// Folders given.
        given: usize,
    },
    /// `--out` is one of the shards.
    #[error("--out {0}: is one of the shard folders; the merge would replace it")]
    OutIsInput(PathBuf),
}

/// Missing shards named in a message at most.
const SHOWN_MISSING: usize = 10;

/// `[2, 5, 7]` (of `count` missing) of 8 → `shard 2/8, 5/8, 7/8`, at most
/// [`SHOWN_MISSING`] shown.
fn list(ks: &[u64], count: u64, n: u64) -> String {
    let shown: Vec<String> = ks
        .iter()
        .take(SHOWN_MISSING)
        .map(|k| format!("{k}/{n}"))
        .collect();
    let more = count.saturating_sub(shown.len() as u64);
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

/// Open `path` if it is a regular file, never waiting on a FIFO
/// ([`epd_io::read::open_regular`]); a missing file is an error of kind `NotFound`.
pub(super) fn open_regular(path: &Path) -> std::io::Result<(File, u64)> {
    std::fs::metadata(path)?;
    epd_io::read::open_regular(path).map_err(std::io::Error::other)
}

/// Read at most `limit` bytes of the regular file `path` ([`open_regular`]); `None`
/// when it holds more (known from its length before it is read).
pub(super) fn read_capped(path: &Path, limit: u64) -> std::io::Result<Option<Vec<u8>>> {
    let (file, len) = open_regular(path)?;
    if len > limit {
        return Ok(None);
    }
    let mut bytes = Vec::new();
    file.take(limit + 1).read_to_end(&mut bytes)?;
    Ok((bytes.len() as u64 <= limit).then_some(bytes))
}

/// Read and check one shard folder's manifest.
pub(super) fn read_manifest(dir: &Path) -> Result<ShardManifest, MergeError> {
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
    if m.settings > MAX_SWEEP_VALUES || m.trials_per_setting > MAX_TRIALS {
        return Err(damaged(format!(
            "{MANIFEST_FILE} says {} settings × {} trials: a scenario has at most \
             {MAX_SWEEP_VALUES} settings and {MAX_TRIALS} trials each",
            m.settings, m.trials_per_setting
        )));
    }
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
pub(super) fn check_shards(
    dirs: &[PathBuf],
    manifests: &[ShardManifest],
) -> Result<(), MergeError> {
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
    // Every K in the manifests is ≤ n, and distinct: n − seen of 1 … n are missing. The
    // first few are found among the first seen + SHOWN_MISSING numbers (n may be 2⁶⁴ − 1).
    let count = n - seen.len() as u64;
    if count > 0 {
        let missing: Vec<u64> = (1..=n)
            .filter(|k| !seen.contains_key(k))
            .take(SHOWN_MISSING)
            .collect();
        return Err(MergeError::Missing {
            missing,
            count,
            n,
            given: dirs.len(),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_shards_are_listed() {
        let e = MergeError::Missing {
            missing: vec![2, 4],
            count: 2,
            n: 4,
            given: 2,
        };
        assert_eq!(
            e.to_string(),
            "2 of 4 shards missing: shard 2/4, 4/4 (given 2 folders)"
        );
    }
}
