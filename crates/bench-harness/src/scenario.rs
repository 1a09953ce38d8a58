//! What every kind of scenario file shares: its error type ([`ScenarioError`], naming the
//! file and the key at fault), its size limit, how its text is read and the check of its
//! `name`. Each experiment's own keys are read in its folder (`sweep/scenario.rs`,
//! `pipeline/scenario.rs`, `approach/scenario.rs`).

use std::path::{Path, PathBuf};

/// A scenario that cannot be used, with the file and the key at fault.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The file cannot be read.
    #[error("cannot read scenario `{path}`: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// TOML syntax, an unknown key or a wrong type (the toml crate names the key and line).
    #[error("scenario `{path}`: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// The file is larger than [`MAX_SCENARIO_BYTES`].
    #[error("scenario `{path}` is larger than {MAX_SCENARIO_BYTES} bytes: not a scenario file")]
    TooLarge {
        /// The file.
        path: PathBuf,
    },
    /// A value outside its range.
    #[error("scenario `{path}`: `{key}` {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The dotted key.
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// Largest scenario file (bytes): a 10 000-value sweep takes about 60 KB.
pub const MAX_SCENARIO_BYTES: u64 = 16 << 20;

/// The text of a scenario read from `reader` (a file, standard input); `path` names it
/// in errors. At most [`MAX_SCENARIO_BYTES`] are read, so `/dev/zero` is an error, not a
/// machine out of memory.
pub fn read_source(path: &Path, reader: impl std::io::Read) -> Result<String, ScenarioError> {
    use std::io::Read;
    let mut source = String::new();
    reader
        .take(MAX_SCENARIO_BYTES + 1)
        .read_to_string(&mut source)
        .map_err(|source| ScenarioError::Read {
            path: path.to_path_buf(),
            source,
        })?;
    if source.len() as u64 > MAX_SCENARIO_BYTES {
        return Err(ScenarioError::TooLarge {
            path: path.to_path_buf(),
        });
    }
    Ok(source)
}

/// A scenario error: the key and what is wrong with it.
pub(crate) type KeyError = (String, String);

/// The [`KeyError`] of `key`: `msg`.
pub(crate) fn key_err(key: &str, msg: String) -> KeyError {
    (key.to_string(), msg)
}

/// `name` becomes a folder: not empty, no path separator, not `.` or `..`.
pub(crate) fn check_name(name: &str) -> Result<(), KeyError> {
    if name.is_empty() || name.contains(['/', '\\']) || name == "." || name == ".." {
        return Err(key_err(
            "name",
            format!("= \"{name}\": must be a plain folder name"),
        ));
    }
    Ok(())
}
