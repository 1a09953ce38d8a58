//! Files written whole: a reader sees the previous file or the new one, never a part.
//!
//! [`write_file_atomic`] writes into an exclusively created temporary file beside the
//! target (unpredictable name, mode 0644, never a planted link), flushes and fsyncs it,
//! renames it over the target and fsyncs the folder so that the rename itself survives a
//! crash. [`create_new`], [`finish`] and [`sync_dir`] are the same steps for a folder of
//! new files that is swapped into place as a whole (the bench harness's runs).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::WriteError;

/// The folder a path's file lives in (`.` for a bare file name).
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// Write a file whole: into a temporary file beside it, synced, then renamed over it,
/// then the folder synced. On any error the temporary file is removed and `path` is
/// untouched; the error names `path`.
pub fn write_file_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<(), WriteError> {
    let dir = parent_of(path);
    let run = || -> std::io::Result<()> {
        let mut builder = tempfile::Builder::new();
        builder.prefix(".epd-io-");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            builder.permissions(std::fs::Permissions::from_mode(0o644));
        }
        let tmp = builder.tempfile_in(dir)?;
        let mut f = BufWriter::new(tmp.reopen()?);
        write(&mut f)?;
        f.flush()?;
        f.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        tmp.persist(path).map_err(|e| e.error)?;
        sync_dir(dir)
    };
    run().map_err(|e| WriteError::io(path.display().to_string(), e))
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
}
