//! Files written whole: a reader sees the previous file or the new one, never a part.
//!
//! [`Output`] (and [`write_file_atomic`] over it) writes into an exclusively created
//! temporary file beside the target (`.epd-output-XXXXXX` or `.epd-io-XXXXXX`:
//! unpredictable name, mode 0644, never a planted link), flushes and fsyncs it, renames it
//! over the target and fsyncs the folder so that the rename itself survives a crash.
//! [`create_new`], [`finish`] and [`sync_dir`] are the same steps for a folder of new
//! files that is swapped into place as a whole (the bench harness's runs).
//!
//! # What is replaced, what is written through
//!
//! [`output_kind`] decides, before anything is written:
//! - a new path, a regular file, a link to a regular file, a dangling link: replaced by the
//!   rename (a link is replaced, never followed, so a planted link cannot redirect the
//!   write);
//! - a character device (`/dev/null`, a terminal) or a FIFO, or a link to one
//!   (`/dev/stdout`, `/dev/fd/N`, bash's `>(…)`), and a link in `/dev` or `/proc` whatever
//!   it leads to (`/dev/stdout` when standard output is a file): written through, opened
//!   for appending, never created, truncated or replaced;
//! - a folder, a block device, a socket, or a link to one: refused.
//!
//! # Temporary files are never left behind
//!
//! Each live temporary file is registered ([`remove_pending_temporaries`]) and holds an
//! advisory lock (`flock`). A program that handles SIGINT, SIGTERM and SIGHUP calls
//! [`remove_pending_temporaries`] from its handler (the `epd` tool does), so an
//! interrupted write leaves nothing. A process killed outright (SIGKILL, power loss)
//! releases its lock; the next [`Output`] made in the same folder removes such
//! leftovers: files named as this module names them, regular, unmodified for
//! [`STALE_AFTER`], whose lock can be taken — never a live writer's, in any process
//! ([`remove_stale_temporaries`]).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use crate::WriteError;

/// The name prefixes of this module's temporary files: [`Output`]s made by the `epd`
/// tool's `-o` (`.epd-output-`) and by [`write_file_atomic`] (`.epd-io-`).
pub const TEMP_PREFIXES: [&str; 2] = [".epd-output-", ".epd-io-"];

/// A temporary file this young is never taken for stale: a live writer locks its file
/// right after creating it (microseconds), and 10 s leaves room for a slow disk and for
/// the clocks of a network file system. The bench harness's staging folders use the
/// same rule.
pub const STALE_AFTER: Duration = Duration::from_secs(10);

/// The temporary files being written, removed by [`remove_pending_temporaries`].
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn pending() -> MutexGuard<'static, Vec<PathBuf>> {
    PENDING.lock().unwrap_or_else(|e| e.into_inner())
}

/// Remove every temporary file being written, and keep any from being renamed into place
/// afterwards: for a signal handler (run on an ordinary thread, e.g. by `signal-hook`'s
/// iterator) just before the process ends. A write that was renamed before is complete;
/// the others are removed. Blocks further renames, and new temporary files, for the rest
/// of the process's life: a thread that then starts, commits or drops an output waits
/// until the process ends. Returns how many files were removed.
pub fn remove_pending_temporaries() -> usize {
    let guard = pending();
    let removed = guard
        .iter()
        .filter(|p| std::fs::remove_file(p).is_ok())
        .count();
    // Held until the process ends: no rename can follow the removal.
    std::mem::forget(guard);
    removed
}

/// The folder a path's file lives in (`.` for a bare file name).
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// How an output path is written (see the module).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A temporary file renamed over the path.
    Replace,
    /// Opened for appending and written in place: a character device, a FIFO, or a link
    /// to one, or a link in `/dev` or `/proc`.
    Through,
}

/// Whether a file type is one written through (a character device or a FIFO).
#[cfg(unix)]
fn is_stream(t: std::fs::FileType) -> bool {
    use std::os::unix::fs::FileTypeExt;
    t.is_char_device() || t.is_fifo()
}
#[cfg(not(unix))]
fn is_stream(_: std::fs::FileType) -> bool {
    false
}

/// Whether `path` lies in a folder of the system's devices or of the process's own
/// descriptors (`/dev`, `/proc`), where nothing is ever renamed.
fn in_system_folder(path: &Path) -> bool {
    let dir = parent_of(path);
    let dir = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    dir.starts_with("/dev") || dir.starts_with("/proc")
}

/// What a file type is, for a refusal.
fn what_it_is(t: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a folder"
    } else {
        "not a regular file"
    }
}

/// How `path` is written as an output (see the module), or why it cannot be one (a
/// folder, a block device, a socket, or a link to one).
pub fn output_kind(path: &Path) -> Result<OutputKind, String> {
    let Ok(meta) = std::fs::symlink_metadata(path) else {
        // Absent (or not visible): created by the rename; a real error shows then.
        return Ok(OutputKind::Replace);
    };
    let t = meta.file_type();
    if t.is_file() {
        return Ok(OutputKind::Replace);
    }
    if is_stream(t) {
        return Ok(OutputKind::Through);
    }
    if !t.is_symlink() {
        return Err(format!(
            "exists and is {}, not a regular file; name a new or regular file, a \
             character device or a pipe",
            what_it_is(t)
        ));
    }
    match std::fs::metadata(path) {
        // A dangling link: replaced.
        Err(_) => Ok(OutputKind::Replace),
        Ok(m) if is_stream(m.file_type()) => Ok(OutputKind::Through),
        Ok(m) if m.is_file() && in_system_folder(path) => Ok(OutputKind::Through),
        Ok(m) if m.is_file() => Ok(OutputKind::Replace),
        Ok(m) => Err(format!(
            "is a link to {}, not a regular file; name a new or regular file, a \
             character device or a pipe",
            what_it_is(m.file_type())
        )),
    }
}

/// A temporary file being written: registered for [`remove_pending_temporaries`] and
/// removed on drop unless renamed into place.
struct Temporary {
    /// Its path, as registered.
    path: PathBuf,
    /// The file (`None` once renamed into place).
    file: Option<tempfile::NamedTempFile>,
    /// The path it replaces.
    target: PathBuf,
}

impl Drop for Temporary {
    fn drop(&mut self) {
        // Removed (the NamedTempFile, if still there, removes its file) and unregistered
        // under the list's lock: a signal handler's removal either comes first and removes
        // the file, or comes after and finds it gone. Unregistered first and removed after,
        // a signal in between left the file behind.
        let mut list = pending();
        drop(self.file.take());
        list.retain(|p| *p != self.path);
    }
}

/// An output file being written (see the module): a temporary file renamed over the
/// target by [`Output::commit`] (removed if dropped before), or the target itself when it
/// is written through.
pub struct Output {
    writer: BufWriter<File>,
    temporary: Option<Temporary>,
}

impl Output {
    /// Start writing `path` with temporary files named `prefix` + 6 random characters
    /// (one of [`TEMP_PREFIXES`]). Stale temporary files of dead processes in the same
    /// folder are removed first ([`remove_stale_temporaries`]). An output that cannot be
    /// one ([`output_kind`]) is an error of kind `InvalidInput`.
    pub fn create(path: &Path, prefix: &str) -> std::io::Result<Self> {
        let kind = output_kind(path)
            .map_err(|why| std::io::Error::new(std::io::ErrorKind::InvalidInput, why))?;
        if kind == OutputKind::Through {
            let f = std::fs::OpenOptions::new().append(true).open(path)?;
            return Ok(Output {
                writer: BufWriter::new(f),
                temporary: None,
            });
        }
        let dir = parent_of(path);
        remove_stale_temporaries(dir);
        let mut builder = tempfile::Builder::new();
        builder.prefix(prefix);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            // A results file for the user, not a secret: rw-r--r-- (umask applies).
            builder.permissions(std::fs::Permissions::from_mode(0o644));
        }
        // Created and registered under the list's lock, so that a signal handler's
        // removal ([`remove_pending_temporaries`]) comes before the file exists or finds
        // it registered (created outside the lock, a signal between the creation and the
        // registration left the file behind); on an error it is removed, unregistered.
        let (file, handle) = {
            let mut list = pending();
            let file = builder.tempfile_in(dir)?;
            let handle = file.reopen()?;
            list.push(file.path().to_path_buf());
            (file, handle)
        };
        // Locked so that no other process takes it for stale (on a file system without
        // locks a cleaner cannot lock it either: it stays).
        let tmp_path = file.path().to_path_buf();
        let _ = file.as_file().try_lock();
        let writer = BufWriter::new(handle);
        Ok(Output {
            writer,
            temporary: Some(Temporary {
                path: tmp_path,
                file: Some(file),
                target: path.to_path_buf(),
            }),
        })
    }

    /// Whether the output is written through (a device, a pipe), not replaced.
    pub fn is_through(&self) -> bool {
        self.temporary.is_none()
    }

    /// The temporary file's path while it is written (none when written through).
    pub fn temporary_path(&self) -> Option<&Path> {
        self.temporary.as_ref().map(|t| t.path.as_path())
    }

    /// The writer (buffered).
    pub fn writer(&mut self) -> &mut BufWriter<File> {
        &mut self.writer
    }

    /// Flush, fsync, rename over the target (holding the list of pending temporary
    /// files, so a signal handler's removal either comes first or finds nothing), fsync
    /// the folder. Written through: flushed only.
    pub fn commit(self) -> std::io::Result<()> {
        self.commit_with(sync_dir)
    }

    /// [`Output::commit`] with the folder's fsync given (a test records or fails it).
    fn commit_with(
        self,
        sync_folder: impl FnOnce(&Path) -> std::io::Result<()>,
    ) -> std::io::Result<()> {
        let Output {
            writer,
            mut temporary,
        } = self;
        let f = writer.into_inner().map_err(|e| e.into_error())?;
        let Some(t) = temporary.as_mut() else {
            return Ok(());
        };
        f.sync_all()?;
        drop(f);
        {
            let mut list = pending();
            if let Some(file) = t.file.take() {
                file.persist(&t.target).map_err(|e| e.error)?;
            }
            list.retain(|p| *p != t.path);
        }
        sync_folder(parent_of(&t.target))
    }
}

impl Write for Output {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.writer.write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.writer.write_all(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.writer.flush()
    }
}

/// Whether `name` is one of `prefixes` followed by 6 letters or digits: a temporary
/// name made of a fixed prefix and `tempfile`'s 6 random characters, as this module names
/// its files ([`TEMP_PREFIXES`]) and the bench harness its staging folders.
pub fn is_temporary_name_of(name: &str, prefixes: &[&str]) -> bool {
    prefixes.iter().any(|p| {
        name.strip_prefix(p)
            .is_some_and(|r| r.len() == 6 && r.bytes().all(|b| b.is_ascii_alphanumeric()))
    })
}

/// Whether `name` is one of this module's temporary file names: a prefix of
/// [`TEMP_PREFIXES`] and 6 letters or digits.
fn is_temporary_name(name: &str) -> bool {
    is_temporary_name_of(name, &TEMP_PREFIXES)
}

/// The entries of `dir` a killed writer may have left: those whose (UTF-8) name `is_ours`
/// accepts and that are unmodified for [`STALE_AFTER`], each with its own metadata (a
/// link is not followed). An entry that cannot be read is passed over, and a `dir` that
/// cannot be read has none. The caller decides what of them to remove (their kind, their
/// lock).
pub fn stale_entries(
    dir: &Path,
    is_ours: impl Fn(&str) -> bool,
) -> impl Iterator<Item = (PathBuf, std::fs::Metadata)> {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(move |e| e.file_name().to_str().is_some_and(&is_ours))
        .filter_map(|e| {
            let path = e.path();
            let meta = std::fs::symlink_metadata(&path).ok()?;
            let old_enough = meta
                .modified()
                .ok()
                .and_then(|m| m.elapsed().ok())
                .is_some_and(|age| age >= STALE_AFTER);
            old_enough.then_some((path, meta))
        })
}

/// Remove the temporary files that killed writers (SIGKILL, power loss) left in `dir`: a
/// file is removed only when its name is one this module makes, it is a regular file
/// (not a link), unmodified for [`STALE_AFTER`], and its lock can be taken (no live
/// process, this one included, is writing it). Best effort: what cannot be removed
/// stays. Returns how many were removed.
pub fn remove_stale_temporaries(dir: &Path) -> usize {
    let mut removed = 0;
    for (path, meta) in stale_entries(dir, is_temporary_name) {
        if !meta.is_file() {
            continue;
        }
        let mut open = std::fs::OpenOptions::new();
        open.read(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            open.custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
        }
        let Ok(f) = open.open(&path) else {
            continue;
        };
        if f.try_lock().is_ok() && std::fs::remove_file(&path).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Write a file whole (see the module): into a temporary file beside it, synced, then
/// renamed over it, then the folder synced; a device or pipe is written through. On any
/// error the temporary file is removed and `path` is untouched; the error names `path`.
pub fn write_file_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<(), WriteError> {
    let run = || -> std::io::Result<()> {
        let mut out = Output::create(path, ".epd-io-")?;
        write(out.writer())?;
        out.commit()
    };
    run().map_err(|e| WriteError::io(crate::name::shown(path), e))
}

/// [`write_file_atomic`] of bytes.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    write_file_atomic(path, |w| w.write_all(bytes))
}

/// Create `path`, which must not exist (`O_EXCL`: never through a planted link), for
/// buffered writing.
pub fn create_new(path: &Path) -> std::io::Result<BufWriter<File>> {
    let f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)?;
    Ok(BufWriter::new(f))
}

/// Flush a file made by [`create_new`] and fsync it.
pub fn finish(w: BufWriter<File>) -> std::io::Result<()> {
    w.into_inner().map_err(|e| e.into_error())?.sync_all()
}

/// Fsync a folder, so that the files created or renamed in it survive a crash. A no-op
/// where folders cannot be opened (not Unix).
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        File::open(dir)?.sync_all()
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_the_previous_file_and_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_bytes_atomic(&path, b"first").unwrap();
        let e = write_file_atomic(&path, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("disk full"))
        })
        .unwrap_err();
        assert!(e.to_string().contains("a.txt"), "{e}");
        assert!(e.to_string().contains("disk full"), "{e}");
        assert_eq!(std::fs::read(&path).unwrap(), b"first");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "the temporary file is removed");
    }

    #[test]
    fn create_new_refuses_an_existing_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.csv");
        let mut w = create_new(&path).unwrap();
        w.write_all(b"x\n").unwrap();
        finish(w).unwrap();
        sync_dir(dir.path()).unwrap();
        assert_eq!(
            create_new(&path).unwrap_err().kind(),
            std::io::ErrorKind::AlreadyExists
        );
        assert_eq!(std::fs::read(&path).unwrap(), b"x\n");
    }

    /// The folder is fsynced after the rename (the renamed file is in place when it is),
    /// once, and a failed fsync is the commit's error; a folder that cannot be opened is
    /// an error of `sync_dir`.
    #[test]
    fn the_folder_is_synced_after_the_rename_and_its_error_returned() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.json");
        let mut out = Output::create(&target, ".epd-output-").unwrap();
        out.write_all(b"new\n").unwrap();
        let mut synced = Vec::new();
        out.commit_with(|d| {
            synced.push((d.to_path_buf(), std::fs::read(&target).ok()));
            sync_dir(d)
        })
        .unwrap();
        assert_eq!(
            synced,
            [(dir.path().to_path_buf(), Some(b"new\n".to_vec()))]
        );
        // The fsync's error is the commit's (the file is in place: the rename is done).
        let mut out = Output::create(&target, ".epd-output-").unwrap();
        out.write_all(b"newer\n").unwrap();
        let e = out
            .commit_with(|_| Err(std::io::Error::other("fsync: input/output error")))
            .unwrap_err();
        assert!(e.to_string().contains("fsync"), "{e}");
        assert_eq!(std::fs::read(&target).unwrap(), b"newer\n");
        assert!(sync_dir(&dir.path().join("missing")).is_err());
        sync_dir(dir.path()).unwrap();
    }

    /// A character device, and a link to one, is written through: never replaced.
    #[cfg(unix)]
    #[test]
    fn a_device_or_a_link_to_one_is_written_through() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("null-link");
        std::os::unix::fs::symlink("/dev/null", &link).unwrap();
        for p in [Path::new("/dev/null"), link.as_path()] {
            assert_eq!(output_kind(p), Ok(OutputKind::Through), "{}", p.display());
            write_bytes_atomic(p, b"result\n").unwrap();
        }
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "no temporary file beside the link");
        // A link to a regular file (outside /dev and /proc) is replaced, not followed.
        let target = dir.path().join("target.txt");
        std::fs::write(&target, b"keep").unwrap();
        let to_file = dir.path().join("to-file");
        std::os::unix::fs::symlink(&target, &to_file).unwrap();
        assert_eq!(output_kind(&to_file), Ok(OutputKind::Replace));
        write_bytes_atomic(&to_file, b"new").unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"keep");
        assert_eq!(std::fs::read(&to_file).unwrap(), b"new");
        // A folder and a link to one are refused.
        let to_dir = dir.path().join("to-dir");
        std::os::unix::fs::symlink(dir.path(), &to_dir).unwrap();
        for p in [dir.path(), to_dir.as_path()] {
            let e = write_bytes_atomic(p, b"x").unwrap_err().to_string();
            assert!(e.contains("folder"), "{e}");
        }
    }

    /// A temporary file left by a dead writer is removed by the next output in its
    /// folder; a live writer's (locked) or a young one stays.
    #[test]
    fn stale_temporaries_are_removed_and_live_ones_kept() {
        let dir = tempfile::tempdir().unwrap();
        let old = std::time::SystemTime::now() - Duration::from_secs(3600);
        let make = |name: &str| {
            let p = dir.path().join(name);
            let f = File::create(&p).unwrap();
            f.set_modified(old).unwrap();
            (p, f)
        };
        let (dead, f) = make(".epd-output-aB3xYz");
        drop(f);
        let (dead_io, f) = make(".epd-io-Q1w2E3");
        drop(f);
        let (live, held) = make(".epd-output-L1v3Ok");
        held.try_lock().unwrap();
        let (other, f) = make(".epd-output-notours");
        drop(f);
        let young = dir.path().join(".epd-output-Y0ung1");
        File::create(&young).unwrap();
        let out = Output::create(&dir.path().join("result.csv"), ".epd-output-").unwrap();
        assert!(!dead.exists() && !dead_io.exists(), "stale files removed");
        assert!(live.exists(), "a locked file is a live writer's");
        assert!(other.exists(), "not a name this module makes");
        assert!(young.exists(), "too young to be taken for stale");
        // The new output's own file is live: another cleaner leaves it.
        let mine = out.temporary_path().unwrap().to_path_buf();
        File::options()
            .write(true)
            .open(&mine)
            .unwrap()
            .set_modified(old)
            .unwrap();
        assert_eq!(remove_stale_temporaries(dir.path()), 0);
        assert!(mine.exists());
        out.commit().unwrap();
        assert!(!mine.exists() && dir.path().join("result.csv").exists());
        drop(held);
    }
}
