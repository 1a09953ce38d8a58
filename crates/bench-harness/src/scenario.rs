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
    #[error("scenario `{path}`: {}", clip(message))]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// The file is larger than [`MAX_SCENARIO_BYTES`].
    #[error(
        "scenario `{path}` is larger than {MAX_SCENARIO_BYTES} bytes (1 MiB), the most a \
         scenario file may hold: not a scenario file"
    )]
    TooLarge {
        /// The file.
        path: PathBuf,
    },
    /// A value outside its range.
    #[error("scenario `{path}`: `{}` {}", clip(key), clip(message))]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The dotted key.
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// Largest scenario file (bytes): 1 MiB. The largest valid scenario is a sweep of
/// [`MAX_SWEEP_VALUES`](crate::sweep::scenario::MAX_SWEEP_VALUES) values, each at most
/// a float's 24 characters and `, `: about 260 KB; the rest of a scenario is a few
/// hundred bytes. A file of 1 MiB is parsed or refused in a fraction of a second and
/// about 100 MB of memory (16 MiB took 5.8 s and 1.5 GB).
pub const MAX_SCENARIO_BYTES: u64 = 1 << 20;

/// Longest line of a message about a scenario (characters): the toml crate echoes the
/// line at fault, which may be the whole file; past this a line is cut, saying how much
/// was left out.
pub const MAX_MESSAGE_LINE_CHARS: usize = 200;

/// Most lines of a message about a scenario.
pub const MAX_MESSAGE_LINES: usize = 20;

/// `message` with each line cut to [`MAX_MESSAGE_LINE_CHARS`] characters and at most
/// [`MAX_MESSAGE_LINES`] lines, each cut saying how many characters or lines it left out.
pub fn clip(message: &str) -> String {
    let mut out = String::new();
    let lines: Vec<&str> = message.lines().collect();
    for (k, line) in lines.iter().take(MAX_MESSAGE_LINES).enumerate() {
        if k > 0 {
            out.push('\n');
        }
        match line.char_indices().nth(MAX_MESSAGE_LINE_CHARS) {
            None => out.push_str(line),
            Some((cut, _)) => {
                let rest = line[cut..].chars().count();
                out.push_str(&line[..cut]);
                out.push_str(&format!("… ({rest} more characters)"));
            }
        }
    }
    if lines.len() > MAX_MESSAGE_LINES {
        out.push_str(&format!(
            "\n… ({} more lines)",
            lines.len() - MAX_MESSAGE_LINES
        ));
    }
    out
}

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

/// `name` becomes a folder and is printed: not empty, no path separator, not `.` or `..`,
/// no control character (a newline or an escape sequence would rewrite the terminal that
/// shows the run's progress; the message shows them escaped).
pub(crate) fn check_name(name: &str) -> Result<(), KeyError> {
    if name.is_empty()
        || name.contains(['/', '\\'])
        || name == "."
        || name == ".."
        || name.chars().any(char::is_control)
    {
        return Err(key_err(
            "name",
            format!(
                "= \"{}\": must be a plain folder name (no path separator, no control \
                 character)",
                epd_io::name::escape_controls(name)
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A name with a newline or an escape sequence is refused, shown escaped.
    #[test]
    fn control_characters_are_no_folder_name() {
        for name in ["a\nb", "a\u{1b}[31mb", "tab\there"] {
            let (key, msg) = check_name(name).expect_err(name);
            assert_eq!(key, "name");
            assert!(!msg.chars().any(char::is_control), "{msg:?}");
        }
        assert!(check_name("sigma_sweep-2").is_ok());
    }

    #[test]
    fn long_lines_and_many_lines_are_cut() {
        assert_eq!(clip("short\nlines"), "short\nlines");
        let long = format!(
            "{}é{}",
            "a".repeat(MAX_MESSAGE_LINE_CHARS - 1),
            "b".repeat(50)
        );
        let c = clip(&long);
        assert!(c.ends_with("é… (50 more characters)"), "{c}");
        let many = vec!["l"; MAX_MESSAGE_LINES + 5].join("\n");
        let c = clip(&many);
        assert_eq!(c.lines().count(), MAX_MESSAGE_LINES + 1);
        assert!(c.ends_with("… (5 more lines)"), "{c}");
    }
}
