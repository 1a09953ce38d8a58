//! Shard folders as an attacker or a careless user leaves them (issue 27): edited,
//! swapped or truncated records, FIFOs in place of files, absurd manifests. Each is
//! refused by `merge` (exit 2, nothing written), promptly, naming the file and, where it
//! can be found, the line.

mod common;

use common::{bin, temp_dir};
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

/// One setting, four trials, two methods.
const TINY: &str = r#"
name = "tiny"
seed = 2
trials = 4
methods = ["c-epd", "ml-epd"]
points = 1000
"#;

/// The same shape, another seed: its records look alike.
const TWIN: &str = r#"
name = "tiny"
seed = 2
trials = 4
methods = ["c-epd", "ml-epd"]
points = 1001
"#;

/// The longest a refusal may take.
const PROMPT: Duration = Duration::from_secs(30);

fn shard(dir: &Path, scenario: &str, name: &str, spec: &str) -> PathBuf {
    let s = dir.join(format!("{name}.toml"));
    std::fs::write(&s, scenario).unwrap();
    let out = dir.join(format!("{name}-{}", spec.replace('/', "of")));
    let o = bin()
        .arg(&s)
        .args(["--shard", spec, "-q", "--threads", "1", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// A copy of shard folder `from` as `to`.
fn copy(from: &Path, to: &Path) -> PathBuf {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
    to.to_path_buf()
}

/// `merge dirs --out out`, killed after PROMPT (a hang fails the test).
fn merge(dirs: &[&Path], out: &Path) -> Output {
    let mut child = bin()
        .arg("merge")
        .args(dirs)
        .arg("--out")
        .arg(out)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > PROMPT {
            let _ = child.kill();
            let _ = child.wait();
            panic!("merge still running after {PROMPT:?}: it hangs");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// A refused merge: exit 2, every needle in the message, nothing written.
fn refused(dirs: &[&Path], out: &Path, needles: &[&str]) -> String {
    let o = merge(dirs, out);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{needles:?}: {err}");
    for n in needles {
        assert!(err.contains(n), "`{n}` not in: {err}");
    }
    assert!(err.len() < 4000, "a message of {} bytes", err.len());
    assert!(!out.exists(), "{needles:?}: wrote {}", out.display());
    err
}

fn mkfifo(p: &Path) {
    let _ = std::fs::remove_file(p);
    let o = std::process::Command::new("mkfifo")
        .arg(p)
        .output()
        .unwrap();
    assert!(o.status.success());
}

/// The first float of the first `"estimate":[…]` in `records`, one digit changed.
fn edit_estimate(records: &str) -> String {
    let at = records.find("\"estimate\":[").expect("an estimate") + "\"estimate\":[".len();
    let mut b = records.as_bytes().to_vec();
    // The third digit of the bit pattern: a change of the value's mantissa or exponent.
    let k = at + 2;
    b[k] = if b[k] == b'1' { b'2' } else { b'1' };
    String::from_utf8(b).unwrap()
}

#[test]
fn edited_records_are_refused_with_the_file_and_the_line() {
    let dir = temp_dir("forged-edit");
    let (a1, a2) = (shard(&dir, TINY, "t", "1/2"), shard(&dir, TINY, "t", "2/2"));
    let out = dir.join("merged");
    let good = merge(&[&a1, &a2], &out);
    assert!(
        good.status.success(),
        "{}",
        String::from_utf8_lossy(&good.stderr)
    );
    std::fs::remove_dir_all(&out).unwrap();

    // One digit of an estimate (issue 27: Dmax 2379.21 mm merged beside err_dmax 3.45).
    let edited = copy(&a2, &dir.join("edited"));
    let records = std::fs::read_to_string(edited.join("shard-trials.jsonl")).unwrap();
    std::fs::write(edited.join("shard-trials.jsonl"), edit_estimate(&records)).unwrap();
    refused(
        &[&a1, &edited],
        &out,
        &[
            "shard-trials.jsonl",
            "changed after the shard ran",
            "line 1",
            "c-epd",
        ],
    );
    // Its manifest's hash made to match: still refused, by the record's own consistency.
    let rehashed = copy(&edited, &dir.join("rehashed"));
    let bytes = std::fs::read(rehashed.join("shard-trials.jsonl")).unwrap();
    let sha = sha256_hex(&bytes);
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a2.join("shard.json")).unwrap()).unwrap();
    let old = m["records_sha256"].as_str().unwrap();
    let manifest = std::fs::read_to_string(a2.join("shard.json"))
        .unwrap()
        .replace(old, &sha);
    std::fs::write(rehashed.join("shard.json"), manifest).unwrap();
    refused(
        &[&a1, &rehashed],
        &out,
        &["shard-trials.jsonl line 1", "errors are not its estimate"],
    );

    // The records of another scenario of the same shape.
    let twin = shard(&dir, TWIN, "twin", "2/2");
    let swapped = copy(&a2, &dir.join("swapped"));
    std::fs::copy(
        twin.join("shard-trials.jsonl"),
        swapped.join("shard-trials.jsonl"),
    )
    .unwrap();
    refused(
        &[&a1, &swapped],
        &out,
        &["shard-trials.jsonl", "changed after the shard ran"],
    );

    // A line that does not parse, a line removed, an extra blank line.
    let broken = copy(&a2, &dir.join("broken"));
    std::fs::write(
        broken.join("shard-trials.jsonl"),
        records.replacen("\"truth\"", "\"truht\"", 1),
    )
    .unwrap();
    refused(
        &[&a1, &broken],
        &out,
        &["shard-trials.jsonl", "line 1: not a trial record"],
    );
    let first = records.lines().next().unwrap();
    std::fs::write(broken.join("shard-trials.jsonl"), format!("{first}\n")).unwrap();
    refused(&[&a1, &broken], &out, &["shard-trials.jsonl is", "bytes"]);
    std::fs::write(broken.join("shard-trials.jsonl"), format!("{records}\n")).unwrap();
    refused(&[&a1, &broken], &out, &["shard-trials.jsonl"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// SHA-256 (hex) with the same crate the harness uses.
fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// A FIFO in place of any file of a shard is refused at once (issue 27: `open()` blocked
/// for 13 minutes and signals were ignored).
#[cfg(unix)]
#[test]
fn fifos_in_a_shard_folder_are_refused_without_blocking() {
    let dir = temp_dir("forged-fifo");
    let (a1, a2) = (shard(&dir, TINY, "t", "1/2"), shard(&dir, TINY, "t", "2/2"));
    let out = dir.join("merged");
    // Shard 1's scenario.toml is the one the merge reads.
    for file in ["shard-trials.jsonl", "shard.json", "scenario.toml"] {
        let d = copy(&a1, &dir.join(format!("fifo-{file}")));
        mkfifo(&d.join(file));
        let t0 = Instant::now();
        refused(&[&d, &a2], &out, &[file, "FIFO"]);
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "{file}: {:?}",
            t0.elapsed()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Manifests with absurd counts: refused at once, without iterating or allocating by them.
#[test]
fn absurd_manifests_are_refused_promptly() {
    let dir = temp_dir("forged-manifest");
    let a1 = shard(&dir, TINY, "t", "1/2");
    let out = dir.join("merged");
    let manifest = std::fs::read_to_string(a1.join("shard.json")).unwrap();
    let set = |name: &str, key: &str, value: &str| {
        let mut m: serde_json::Value = serde_json::from_str(&manifest).unwrap();
        m[key] = serde_json::from_str(value).unwrap();
        if key == "shards" {
            // Shard 1 of that many has one of the 4 trials.
            m["n_trials"] = serde_json::json!(1);
        }
        let d = copy(&a1, &dir.join(name));
        std::fs::write(d.join("shard.json"), serde_json::to_string(&m).unwrap()).unwrap();
        d
    };
    // 2⁶⁴ − 1 shards: the missing ones are counted, not listed one by one.
    let d = set("n-max", "shards", "18446744073709551615");
    refused(
        &[&d],
        &out,
        &[
            "18446744073709551614 of 18446744073709551615 shards missing",
            "and 18446744073709551604 more",
        ],
    );
    // 10¹⁸ trials per setting (n_trials made to agree).
    let mut m: serde_json::Value = serde_json::from_str(&manifest).unwrap();
    m["trials_per_setting"] = serde_json::json!(1_000_000_000_000_000_000u64);
    m["n_trials"] = serde_json::json!(500_000_000_000_000_000u64);
    let d = copy(&a1, &dir.join("trials-max"));
    std::fs::write(d.join("shard.json"), serde_json::to_string(&m).unwrap()).unwrap();
    refused(&[&d], &out, &["1000000 trials each"]);
    // A records length beyond what its trials can hold.
    let d = set("bytes-max", "records_bytes", "18446744073709551615");
    let a2 = shard(&dir, TINY, "t", "2/2");
    refused(
        &[&d, &a2],
        &out,
        &["shard-trials.jsonl holds 18446744073709551615 bytes"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}
