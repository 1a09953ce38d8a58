//! Scenario files as an attacker or a careless user writes them (issue 27): too large,
//! one very long line, a FIFO. Each is refused with a short message naming the limit.

mod common;

use common::{bin, temp_dir};
use std::time::{Duration, Instant};

/// A refusal: exit 2, `needles` in a message of at most 2 KB, within `time`.
fn refused(path: &std::path::Path, needles: &[&str], time: Duration) {
    let t0 = Instant::now();
    let o = bin()
        .arg(path)
        .args(["--out"])
        .arg(path.with_extension("out"))
        .output()
        .unwrap();
    let dt = t0.elapsed();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{}", &err[..err.len().min(400)]);
    assert!(err.len() <= 2048, "a message of {} bytes", err.len());
    for n in needles {
        assert!(err.contains(n), "`{n}` not in: {err}");
    }
    assert!(dt < time, "{dt:?}");
}

/// A one-line 16 MiB scenario (issue 27: a 16 MB message, 1.5 GB and 5.8 s to refuse).
#[test]
fn a_scenario_over_the_size_limit_is_refused_by_its_size() {
    let dir = temp_dir("scen-big");
    let p = dir.join("big.toml");
    let mut text = String::from("name = \"");
    text.push_str(&"a".repeat(16 << 20));
    std::fs::write(&p, text).unwrap();
    refused(
        &p,
        &["larger than 1048576 bytes (1 MiB)"],
        Duration::from_secs(5),
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A one-line scenario just under the limit with a syntax error at its end, and one with
/// a key a megabyte long: the message names the line and is cut.
#[test]
fn a_long_line_is_cut_in_the_message() {
    let dir = temp_dir("scen-line");
    let p = dir.join("line.toml");
    let mut text = String::from("name = \"x\"\nvalues = [");
    while text.len() < (1 << 20) - 100 {
        text.push_str("0.125, ");
    }
    text.push_str("oops]\n");
    std::fs::write(&p, &text).unwrap();
    refused(&p, &["line 2", "more characters"], Duration::from_secs(20));
    let key = "k".repeat((1 << 20) - 100);
    std::fs::write(&p, format!("name = \"x\"\n{key} = 1\n")).unwrap();
    refused(&p, &["more characters"], Duration::from_secs(20));
    let _ = std::fs::remove_dir_all(&dir);
}
