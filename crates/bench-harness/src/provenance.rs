//! What ran: the commit and dirty flag the binary was built from, its build profile and
//! the machine's CPU, as every run's `metadata.json` records them (`Metadata`, the one
//! writer of that file for every experiment) and a shard's manifest ([`CodeVersion`]).

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use sha2::{Digest, Sha256};

use crate::output::write_new;

/// A run's `metadata.json`, written with its keys sorted: the keys every experiment
/// records ([`Metadata::new`]) and the experiment's own ([`Metadata::with`]).
#[derive(Clone, Debug)]
pub(crate) struct Metadata(Map<String, Value>);

impl Metadata {
    /// What every run records: the scenario's `scenario` (name) and `seed`, the code that
    /// ran (`crate_version`, `git_commit`, `git_dirty`, `profile`), the worker `threads`
    /// and the run's `wall_time_s`.
    pub(crate) fn new(scenario: &str, seed: u64, wall_time_s: f64) -> Self {
        let (git_commit, git_dirty) = git_provenance();
        Self(Map::new())
            .with("scenario", scenario)
            .with("seed", seed)
            .with("crate_version", env!("CARGO_PKG_VERSION"))
            .with("git_commit", git_commit)
            .with("git_dirty", git_dirty)
            .with("profile", profile())
            .with("threads", rayon::current_num_threads())
            .with("wall_time_s", wall_time_s)
    }

    /// The metadata with `key` set to `value` (replacing a value it had).
    pub(crate) fn with(mut self, key: &str, value: impl Into<Value>) -> Self {
        self.0.insert(key.to_string(), value.into());
        self
    }

    /// The metadata with the machine's CPU (`cpu_model`).
    pub(crate) fn with_cpu(self) -> Self {
        self.with("cpu_model", cpu_model())
    }

    /// Write `metadata.json` into `dir` (a run's staging folder).
    pub(crate) fn write(&self, dir: &Path) -> anyhow::Result<PathBuf> {
        write_new(
            &dir.join("metadata.json"),
            serde_json::to_string_pretty(&self.0)?.as_bytes(),
        )
    }
}

/// Seconds since the Unix epoch, now (0 on a clock before it).
pub(crate) fn unix_now_s() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// The CPU's model name (`/proc/cpuinfo`; `unknown` where there is none).
pub(crate) fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}

/// The commit of the workspace the binary was built from and whether its tracked files
/// differed from it then, recorded by `build.rs` (`None` when built outside a git checkout).
pub(crate) fn git_provenance() -> (Option<String>, Option<bool>) {
    (
        option_env!("EPD_GIT_COMMIT").map(str::to_string),
        option_env!("EPD_GIT_DIRTY").map(|d| d == "true"),
    )
}

/// The build profile of this binary: `dev` or `release`.
pub(crate) fn profile() -> &'static str {
    if cfg!(debug_assertions) {
        "dev"
    } else {
        "release"
    }
}

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
    /// The code of this process (found once: the running program does not change, and
    /// hashing it takes a read of the whole executable).
    pub fn current() -> Self {
        static CURRENT: std::sync::OnceLock<CodeVersion> = std::sync::OnceLock::new();
        CURRENT
            .get_or_init(|| {
                // /proc/self/exe opens the running program even when its file has been
                // replaced since it started (a rebuild during a long shard); the path is
                // the fallback.
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
            })
            .clone()
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

/// SHA-256 (hex) of everything `r` yields.
pub(crate) fn sha256_of(mut r: impl Read) -> std::io::Result<String> {
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

/// Lower-case hex of `bytes`.
pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 (hex) of a scenario's text.
pub fn scenario_sha256(source: &str) -> String {
    hex(&Sha256::digest(source.as_bytes()))
}

/// The host's name, if known.
pub(crate) fn host_name() -> Option<String> {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metadata_holds_the_common_keys_sorted() {
        let dir = tempfile::tempdir().unwrap();
        Metadata::new("x", 7, 1.5)
            .with("kind", "approach")
            .with("seed", 8u64)
            .write(dir.path())
            .unwrap();
        let text = std::fs::read_to_string(dir.path().join("metadata.json")).unwrap();
        let v: Value = serde_json::from_str(&text).unwrap();
        let keys: Vec<&String> = v.as_object().unwrap().keys().collect();
        assert_eq!(
            keys,
            [
                "crate_version",
                "git_commit",
                "git_dirty",
                "kind",
                "profile",
                "scenario",
                "seed",
                "threads",
                "wall_time_s"
            ]
        );
        assert_eq!(v["seed"], 8);
        assert!(text.starts_with("{\n  \"crate_version\""), "{text}");
    }
}
