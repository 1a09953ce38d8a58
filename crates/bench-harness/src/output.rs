//! A run's output folder, shared by every kind of run (a sweep, a shard, a merge, a
//! pipeline, an approach) and importing none of them: the write helpers, the names a
//! run folder may hold, the interrupt flag and the staging folder that takes the output
//! folder's place as a whole ([`write_run`]).
//!
//! # A run's files land as one set
//!
//! Every file of a run ([`RUN_FILES`]) is written into a staging folder, `.run-XXXXXX`,
//! created exclusively, with an unpredictable name, beside the output folder (same file
//! system), by `tempfile`; inside it files are created with `O_EXCL` (`create_new`), so
//! no link planted anywhere is ever followed. When every file is written and synced, the
//! staging folder takes the output folder's place:
//!
//! - no output folder yet: one `rename`;
//! - on Linux: one `renameat2(RENAME_EXCHANGE)` swaps the two folders atomically, then
//!   the previous run, now at the staging name, is removed. A reader sees the whole
//!   previous run or the whole new one, never a mix and never no folder;
//! - elsewhere (or a file system without the exchange): the previous folder is renamed
//!   into a fresh `.old-XXXXXX`, the staging folder renamed into place, the old one
//!   removed. For the instant between the two renames there is no output folder.
//!
//! The output folder is replaced as a whole, so it must be absent, empty, or hold a
//! previous run: `metadata.json` and nothing but [`RUN_FILES`] (or the temporary files
//! of earlier versions). Anything else (`--out ~`, a user's notes beside the results, a
//! sub-folder, a link) is refused with [`OutputRefused`] before anything is written.
//!
//! An interrupted run (SIGINT, SIGTERM: [`INTERRUPTED`], checked between batches of
//! trials and before the swap) or a failed one returns through normal returns, so its
//! staging folder is removed by its `TempDir` and the previous run is untouched. Each
//! live run holds an advisory lock (`flock`) on its staging folder; after SIGKILL or a
//! power loss the folder stays, and the next run in the same parent folder removes such
//! leftovers: `.run-`/`.old-` folders older than 10 s, holding only run files, whose
//! lock it can take (so never a live run's, in any process).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;

/// Set (by a signal handler) to stop a run at the next batch of trials.
pub static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// The run was interrupted: nothing was written.
#[derive(Debug, thiserror::Error)]
#[error("interrupted: the previous results, if any, are untouched")]
pub struct Interrupted;

/// Create `path` (which must not exist) for writing; the error names the file.
pub(crate) fn create_new(path: &Path) -> anyhow::Result<BufWriter<File>> {
    epd_io::atomic::create_new(path).with_context(|| format!("cannot create {}", path.display()))
}

/// Flush and sync a file written with [`create_new`]; the error names the file.
pub(crate) fn finish(w: BufWriter<File>, path: &Path) -> anyhow::Result<PathBuf> {
    epd_io::atomic::finish(w).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path.to_path_buf())
}

/// Write `bytes` to the new file `path` (in a run's staging folder).
pub fn write_new(path: &Path, bytes: &[u8]) -> anyhow::Result<PathBuf> {
    let mut w = create_new(path)?;
    w.write_all(bytes)
        .with_context(|| format!("cannot write {}", path.display()))?;
    finish(w, path)
}

/// An I/O error writing `p`, naming it.
pub(crate) fn wrote(p: &Path) -> impl Fn(std::io::Error) -> anyhow::Error + '_ {
    move |e| anyhow::Error::new(e).context(format!("cannot write {}", p.display()))
}

/// A CSV file of a run (in its staging folder), written a record at a time through
/// [`epd_io::csv`]: the workspace's one quoting rule, numbers as [`epd_io::csv::num`]
/// gives them. Errors name the file.
pub(crate) struct CsvFile {
    path: PathBuf,
    w: BufWriter<File>,
}

impl CsvFile {
    /// Create the new file `path` with the header `columns`.
    pub(crate) fn create(path: &Path, columns: &[&str]) -> anyhow::Result<Self> {
        let mut file = Self {
            path: path.to_path_buf(),
            w: create_new(path)?,
        };
        file.row(columns)?;
        Ok(file)
    }

    /// Write one record: `fields`, quoted where the rule says, and `\n`.
    pub(crate) fn row<I, T>(&mut self, fields: I) -> anyhow::Result<()>
    where
        I: IntoIterator<Item = T>,
        T: AsRef<[u8]>,
    {
        writeln!(self.w, "{}", epd_io::csv::line(fields)).map_err(wrote(&self.path))
    }

    /// Flush and sync the file; its path.
    pub(crate) fn finish(self) -> anyhow::Result<PathBuf> {
        finish(self.w, &self.path)
    }

    /// The new file `path` whole: the header `columns`, one record per item of `rows`,
    /// flushed and synced; its path.
    pub(crate) fn write_all<R, I, T>(
        path: &Path,
        columns: &[&str],
        rows: R,
    ) -> anyhow::Result<PathBuf>
    where
        R: IntoIterator<Item = I>,
        I: IntoIterator<Item = T>,
        T: AsRef<[u8]>,
    {
        let mut csv = Self::create(path, columns)?;
        for r in rows {
            csv.row(r)?;
        }
        csv.finish()
    }
}

/// The output folder may not be used (a usage error: nothing was written).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct OutputRefused(String);

/// The files a sweep run writes; with [`PIPELINE_FILES`], [`APPROACH_FILES`],
/// [`TRANSFER_FILES`] and [`SHARD_FILES`], the only names an output folder
/// holding a previous run may contain (with the temporary files of earlier versions,
/// `.trials.csv.tmp<PID>`).
pub const RUN_FILES: &[&str] = &[
    "trials.csv",
    "summary.csv",
    "scenario.toml",
    "metadata.json",
    "diameter_error.png",
    "dmean_error.png",
    "pose_error.png",
    "time.png",
    "std_vs_crb.png",
    "coverage.png",
];

/// The figure a sweep over `sampling` adds to [`RUN_FILES`] (issue 25's `realtime.png`).
pub const SAMPLING_FILES: &[&str] = &["realtime.png"];

/// The files of a pipeline run (a scenario with `[pipeline]`).
pub const PIPELINE_FILES: &[&str] = &[
    "scenario.toml",
    "metadata.json",
    "profile.csv",
    "sections.csv",
    "depth_table.json",
    "diameters.png",
    "section_errors.png",
    "profile.png",
    "weights.png",
];

/// The files of an approach run (a scenario with `[approach]`).
pub const APPROACH_FILES: &[&str] = &[
    "scenario.toml",
    "metadata.json",
    "frames.csv",
    "approach.csv",
    "confusion.csv",
    "approach.png",
];

/// The files of a calibration-transfer run (a scenario with `[calibration_transfer]`).
pub const TRANSFER_FILES: &[&str] = &[
    "scenario.toml",
    "metadata.json",
    "frames.csv",
    "summary.csv",
    "calibration_transfer.png",
];

/// A shard's manifest file (`--shard K/N`).
pub const MANIFEST_FILE: &str = "shard.json";
/// A shard's exact per-trial values: one JSON object per trial and line.
pub const RECORDS_FILE: &str = "shard-trials.jsonl";

/// The files a shard writes besides `trials.csv`, `scenario.toml` and `metadata.json`.
pub const SHARD_FILES: &[&str] = &[MANIFEST_FILE, RECORDS_FILE];

/// Whether `name` is a file a run writes, or a temporary file an earlier version left
/// (`.<file>.tmp<PID>`).
fn is_run_file(name: &str) -> bool {
    RUN_FILES.contains(&name)
        || SAMPLING_FILES.contains(&name)
        || PIPELINE_FILES.contains(&name)
        || APPROACH_FILES.contains(&name)
        || TRANSFER_FILES.contains(&name)
        || SHARD_FILES.contains(&name)
        || name.strip_prefix('.').is_some_and(|rest| {
            RUN_FILES.iter().any(|f| {
                rest.strip_prefix(f)
                    .and_then(|r| r.strip_prefix(".tmp"))
                    .is_some_and(|pid| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()))
            })
        })
}

/// The names in `dir` that a run did not write (files or links with other names, and
/// any folder), or `None` when `dir` holds a previous run (`metadata.json` and nothing
/// but run files) or nothing at all. Links are looked at, never followed.
fn foreign_entries(dir: &Path) -> anyhow::Result<Option<Vec<String>>> {
    let mut foreign = Vec::new();
    let mut any = false;
    let mut metadata = false;
    let entries =
        std::fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))?;
    for e in entries {
        let e = e.with_context(|| format!("cannot read {}", dir.display()))?;
        any = true;
        let name = e.file_name().to_string_lossy().into_owned();
        let kind = e
            .file_type()
            .with_context(|| format!("cannot read {}", e.path().display()))?;
        if kind.is_dir() || !is_run_file(&name) {
            foreign.push(name);
        } else if name == "metadata.json" {
            metadata = true;
        }
    }
    Ok(if !any || (foreign.is_empty() && metadata) {
        None
    } else {
        if foreign.is_empty() {
            foreign.push("(no metadata.json)".into());
        }
        foreign.sort();
        Some(foreign)
    })
}

/// Refuse an output folder that is a link, not a folder, or holds something other than
/// a previous run: a run replaces its output folder as a whole (`--out ~` must not
/// delete a home).
fn check_output_folder(out: &Path) -> anyhow::Result<()> {
    if out.file_name().is_none() {
        return Err(OutputRefused(format!(
            "--out {}: name a folder (not `.`, `..` or `/`): it is replaced as a whole",
            out.display()
        ))
        .into());
    }
    let meta = match std::fs::symlink_metadata(out) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", out.display())),
    };
    if !meta.is_dir() {
        return Err(OutputRefused(format!(
            "{} exists and is not a folder (a link is not followed): choose another --out",
            out.display()
        ))
        .into());
    }
    if let Some(foreign) = foreign_entries(out)? {
        let shown: Vec<&str> = foreign.iter().take(5).map(String::as_str).collect();
        let more = foreign.len().saturating_sub(shown.len());
        return Err(OutputRefused(format!(
            "{} holds files that are not a bench-harness run ({}{}); a run replaces its \
             output folder as a whole: choose an empty or new --out",
            out.display(),
            shown.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        ))
        .into());
    }
    Ok(())
}

/// Lock `dir` (an advisory `flock` on the folder itself) for as long as the returned
/// handle lives: a staging folder whose lock can be taken belongs to no live run.
fn lock_dir(dir: &Path) -> anyhow::Result<File> {
    let f = File::open(dir).with_context(|| format!("cannot open {}", dir.display()))?;
    f.try_lock()
        .map_err(|e| match e {
            std::fs::TryLockError::Error(e) => e,
            std::fs::TryLockError::WouldBlock => std::io::ErrorKind::WouldBlock.into(),
        })
        .with_context(|| format!("cannot lock {}", dir.display()))?;
    Ok(f)
}

/// Whether `name` is a staging (`.run-XXXXXX`) or old-run (`.old-XXXXXX`) folder name.
fn is_staging_name(name: &str) -> bool {
    epd_io::atomic::is_temporary_name_of(name, &[".run-", ".old-"])
}

/// Remove the staging and old-run folders that killed runs (SIGKILL, power loss) left
/// beside the output folder, in `parent`. A folder is removed only when its name is
/// one this program makes, it is a real folder (not a link), it is older than
/// [`epd_io::atomic::STALE_AFTER`] (the temporary files' rule:
/// [`epd_io::atomic::stale_entries`]), it holds nothing but run files (an old run one
/// level down), and no live run holds its lock. Best effort: what cannot be removed
/// stays. Returns how many were removed.
fn remove_stale(parent: &Path) -> usize {
    let mut removed = 0;
    for (path, meta) in epd_io::atomic::stale_entries(parent, is_staging_name) {
        if !meta.is_dir() || !holds_only_run_files(&path) {
            continue;
        }
        let Ok(lock) = lock_dir(&path) else {
            continue;
        };
        if std::fs::remove_dir_all(&path).is_ok() {
            removed += 1;
        }
        drop(lock);
    }
    removed
}

/// Whether `dir` holds nothing but run files, or one folder (an old run) that does.
fn holds_only_run_files(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    let mut folders = 0;
    for e in entries {
        let Ok(e) = e else { return false };
        let Ok(kind) = e.file_type() else {
            return false;
        };
        let name = e.file_name();
        if kind.is_dir() {
            folders += 1;
            if folders > 1 || !matches!(foreign_entries(&e.path()), Ok(None)) {
                return false;
            }
        } else if !is_run_file(&name.to_string_lossy()) {
            return false;
        }
    }
    true
}

/// Flush a folder's entries to disk (renames and new files in it).
fn sync_dir(dir: &Path) -> anyhow::Result<()> {
    epd_io::atomic::sync_dir(dir)
        .with_context(|| format!("cannot sync the folder {}", dir.display()))
}

/// The permissions of a new output folder: the previous one's, or `0777 & !umask`
/// (tempfile makes the staging folder with the process's defaults already).
#[cfg(unix)]
fn keep_mode(staged: &Path, out: &Path) -> anyhow::Result<()> {
    if let Ok(m) = std::fs::symlink_metadata(out)
        && m.is_dir()
    {
        std::fs::set_permissions(staged, m.permissions())
            .with_context(|| format!("cannot set the permissions of {}", staged.display()))?;
    }
    Ok(())
}

#[cfg(not(unix))]
fn keep_mode(_staged: &Path, _out: &Path) -> anyhow::Result<()> {
    Ok(())
}

/// Exchange the folders `a` and `b` in one step (Linux `renameat2(RENAME_EXCHANGE)`).
/// `Ok(false)`: the file system or kernel cannot.
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<bool> {
    use rustix::fs::{CWD, RenameFlags, renameat_with};
    match renameat_with(CWD, a, CWD, b, RenameFlags::EXCHANGE) {
        Ok(()) => Ok(true),
        Err(e) if e == rustix::io::Errno::INVAL || e == rustix::io::Errno::NOSYS => Ok(false),
        Err(e) => Err(e.into()),
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_a: &Path, _b: &Path) -> std::io::Result<bool> {
    Ok(false)
}

/// Replace `out` by the finished staging folder (see the module doc).
fn swap_into_place(staging: tempfile::TempDir, out: &Path, parent: &Path) -> anyhow::Result<()> {
    swap_with(staging, out, parent, exchange)
}

/// [`swap_into_place`] with the atomic exchange given (`Ok(false)`: not available).
fn swap_with(
    staging: tempfile::TempDir,
    out: &Path,
    parent: &Path,
    exchange: fn(&Path, &Path) -> std::io::Result<bool>,
) -> anyhow::Result<()> {
    let staged = staging.path().to_path_buf();
    keep_mode(&staged, out)?;
    sync_dir(&staged)?;
    let moved = || format!("cannot move the results into {}", out.display());
    let exists = std::fs::symlink_metadata(out).is_ok();
    if !exists {
        std::fs::rename(&staged, out).with_context(moved)?;
        // The folder is gone from the staging name: nothing for the TempDir to remove.
        let _ = staging.keep();
    } else if exchange(&staged, out).with_context(moved)? {
        // The previous run now sits at the staging name, and goes with it.
        drop(staging);
    } else {
        // No atomic exchange here: move the previous run aside, then the new one in.
        // For the instant between the two renames there is no output folder.
        let old = tempfile::Builder::new()
            .prefix(".old-")
            .tempdir_in(parent)
            .with_context(|| format!("cannot create a folder in {}", parent.display()))?;
        let _old_lock = lock_dir(old.path())?;
        let previous = old.path().join("previous");
        std::fs::rename(out, &previous)
            .with_context(|| format!("cannot move the previous run {} aside", out.display()))?;
        if let Err(e) = std::fs::rename(&staged, out) {
            // Put the previous run back; the staging folder goes with its TempDir.
            let _ = std::fs::rename(&previous, out);
            return Err(e).with_context(moved);
        }
        let _ = staging.keep();
        drop(old);
    }
    sync_dir(parent)
}

/// The workspace the binary was built from, when it is still there.
fn workspace_root() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let root = root.canonicalize().ok()?;
    root.join("Cargo.toml").is_file().then_some(root)
}

/// The default output folder of a scenario: `target/results/<name>/` of the workspace
/// (ignored by git, so the user's runs never touch the committed `results/`), or
/// `results/<name>/` in the current folder when the binary runs outside its workspace.
pub fn default_output(name: &str) -> PathBuf {
    match workspace_root() {
        Some(root) => root.join("target").join("results").join(name),
        None => PathBuf::from("results").join(name),
    }
}

/// What a staging function hands back: the files it wrote (in the staging folder).
pub trait StagedFiles {
    /// The files written, as paths in the staging folder.
    fn files_mut(&mut self) -> &mut Vec<PathBuf>;

    /// Whether an error of the staging function is a refusal (a usage error, named as
    /// such: nothing is written) rather than a failed run. An [`Interrupted`] run
    /// always is; by default nothing else.
    fn is_refusal(_e: &anyhow::Error) -> bool {
        false
    }
}

/// Write a run into `out` through a staging folder (see the module doc): `stage`
/// writes every file into the folder it is given, and the folder then replaces `out`
/// as a whole. The returned files are renamed to their place in `out`.
pub fn write_run<T: StagedFiles>(
    out: &Path,
    stage: impl FnOnce(&Path) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    check_output_folder(out)?;
    std::fs::create_dir_all(&parent)
        .with_context(|| format!("cannot create {}", parent.display()))?;
    remove_stale(&parent);
    let staging = tempfile::Builder::new()
        .prefix(".run-")
        .tempdir_in(&parent)
        .with_context(|| format!("cannot create a staging folder in {}", parent.display()))?;
    // Held until the run ends: the next runs know this staging folder is alive.
    let _lock = lock_dir(staging.path())?;
    let mut staged = match stage(staging.path()) {
        Ok(s) => s,
        Err(e) if e.is::<Interrupted>() || T::is_refusal(&e) => return Err(e),
        Err(e) => {
            return Err(e.context(format!(
                "the run into {} failed (the previous results, if any, are untouched)",
                out.display()
            )));
        }
    };
    if INTERRUPTED.load(Ordering::SeqCst) {
        return Err(Interrupted.into());
    }
    swap_into_place(staging, out, &parent)?;
    let files = staged.files_mut();
    *files = files
        .iter()
        .filter_map(|f| f.file_name().map(|n| out.join(n)))
        .collect();
    Ok(staged)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn folder_with(parent: &Path, name: &str, text: &str) -> PathBuf {
        let d = parent.join(name);
        std::fs::create_dir_all(&d).unwrap();
        for f in ["trials.csv", "metadata.json"] {
            std::fs::write(d.join(f), text).unwrap();
        }
        d
    }

    fn entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn swaps_replace_the_previous_run_with_or_without_an_atomic_exchange() {
        let parent = tempfile::tempdir().unwrap();
        let out = folder_with(parent.path(), "out", "old");
        let no_exchange: fn(&Path, &Path) -> std::io::Result<bool> = |_, _| Ok(false);
        for (i, how) in [exchange, no_exchange].into_iter().enumerate() {
            let staging = tempfile::Builder::new()
                .prefix(".run-")
                .tempdir_in(parent.path())
                .unwrap();
            let text = format!("new {i}");
            std::fs::write(staging.path().join("trials.csv"), &text).unwrap();
            std::fs::write(staging.path().join("metadata.json"), &text).unwrap();
            swap_with(staging, &out, parent.path(), how).unwrap();
            assert_eq!(
                std::fs::read_to_string(out.join("trials.csv")).unwrap(),
                text
            );
            assert_eq!(entries(parent.path()), vec!["out".to_string()]);
        }
        // No previous run: a plain rename.
        std::fs::remove_dir_all(&out).unwrap();
        let staging = tempfile::Builder::new()
            .prefix(".run-")
            .tempdir_in(parent.path())
            .unwrap();
        std::fs::write(staging.path().join("metadata.json"), "x").unwrap();
        swap_into_place(staging, &out, parent.path()).unwrap();
        assert_eq!(entries(&out), vec!["metadata.json".to_string()]);
        assert_eq!(entries(parent.path()), vec!["out".to_string()]);
    }

    #[test]
    fn run_file_names_and_staging_names() {
        for n in RUN_FILES {
            assert!(is_run_file(n));
        }
        assert!(is_run_file(".trials.csv.tmp1234"));
        for n in [
            "notes.txt",
            ".trials.csv.tmp",
            ".trials.csv.tmpx",
            ".bashrc",
            "trials.csv~",
        ] {
            assert!(!is_run_file(n), "{n}");
        }
        assert!(is_staging_name(".run-a1B2c3") && is_staging_name(".old-zzzzzz"));
        for n in [
            ".run-",
            ".run-abc",
            ".run-abcdefg",
            ".run-ab/cde",
            "run-abcdef",
        ] {
            assert!(!is_staging_name(n), "{n}");
        }
    }

    #[test]
    fn stale_folders_are_removed_only_when_dead_old_and_ours() {
        let parent = tempfile::tempdir().unwrap();
        let p = parent.path();
        let old = std::time::SystemTime::now() - std::time::Duration::from_secs(3600);
        let backdate = |d: &Path| File::open(d).unwrap().set_modified(old).unwrap();
        let dead = folder_with(p, ".run-dead00", "x");
        let old_run = p.join(".old-dead00");
        std::fs::create_dir(&old_run).unwrap();
        folder_with(&old_run, "previous", "x");
        let live = folder_with(p, ".run-live00", "x");
        // Too young to be taken for stale (its run may not hold the lock yet).
        folder_with(p, ".run-young0", "x");
        let users = folder_with(p, ".run-users0", "x");
        std::fs::write(users.join("notes.txt"), "mine").unwrap();
        let other = folder_with(p, "results", "x");
        for d in [&dead, &old_run, &live, &users, &other] {
            backdate(d);
        }
        let _held = lock_dir(&live).unwrap();
        assert_eq!(remove_stale(p), 2);
        assert_eq!(
            entries(p),
            vec![".run-live00", ".run-users0", ".run-young0", "results"]
        );
    }
}
