//! Helpers shared by the bench-harness tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The `bench-harness` binary.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bench-harness"))
}

/// The workspace root.
pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[path = "../../../epd-io/tests/common/temp_dir.rs"]
mod temp;
#[allow(unused_imports)]
pub use temp::{TempDir, temp_dir};

/// A CSV file read with the `csv` crate (quoted fields as written): the header and the
/// rows.
pub fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut r = csv::Reader::from_path(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let header = r.headers().unwrap().iter().map(String::from).collect();
    let rows = r
        .records()
        .map(|rec| rec.unwrap().iter().map(String::from).collect())
        .collect();
    (header, rows)
}
