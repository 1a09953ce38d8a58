//! Records, when the binary is built, the git commit of the workspace it is built from and
//! whether the tracked files differed from that commit: `metadata.json`'s `git_commit` and
//! `git_dirty` describe the code that ran, not the working tree at run time. Outside a git
//! checkout (or without git) neither is set and the metadata writes `null`.

use std::path::Path;
use std::process::Command;

fn git(root: &Path, args: &[&str]) -> Option<String> {
    let out = Command::new("git")
        .arg("-C")
        .arg(root)
        .args(args)
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    let manifest = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into());
    let root = Path::new(&manifest).join("../..");
    if let Some(commit) = git(&root, &["rev-parse", "HEAD"]) {
        println!("cargo:rustc-env=EPD_GIT_COMMIT={commit}");
    }
    if let Some(status) = git(&root, &["status", "--porcelain", "--untracked-files=no"]) {
        println!("cargo:rustc-env=EPD_GIT_DIRTY={}", !status.is_empty());
    }
    // Run again when the commit moves (HEAD, the branch's ref, the index) or a tracked
    // file may have changed (every tracked top-level entry but the ignored target/).
    if let Some(dir) = git(&root, &["rev-parse", "--absolute-git-dir"]) {
        println!("cargo:rerun-if-changed={dir}/HEAD");
        println!("cargo:rerun-if-changed={dir}/index");
    }
    if let (Some(common), Some(branch)) = (
        git(
            &root,
            &["rev-parse", "--path-format=absolute", "--git-common-dir"],
        ),
        git(&root, &["symbolic-ref", "-q", "HEAD"]),
    ) {
        println!("cargo:rerun-if-changed={common}/{branch}");
        println!("cargo:rerun-if-changed={common}/packed-refs");
    }
    if let Some(files) = git(&root, &["ls-tree", "--name-only", "HEAD"]) {
        for entry in files.lines() {
            println!("cargo:rerun-if-changed={}", root.join(entry).display());
        }
    }
}
