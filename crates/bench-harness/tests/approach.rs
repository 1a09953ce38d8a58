//! Approach scenarios (`[approach]`): the files, and a second run into the same folder
//! replacing the first (its files are a run's, not the user's).

mod common;

use common::{bin, temp_dir};

#[test]
fn an_approach_run_replaces_its_own_results() {
    let dir = temp_dir("approach");
    let file = dir.join("elbow.toml");
    std::fs::write(
        &file,
        "name = \"elbow_small\"\nseed = 3\n\n[approach]\nkind = \"elbow\"\n\
         distances_m = [1.0]\nframes = 1\nsigma_m = 0.01\n",
    )
    .unwrap();
    let out = dir.join("out");
    let mut first = Vec::new();
    for run in 0..2 {
        let o = bin()
            .arg(&file)
            .arg("--out")
            .arg(&out)
            .arg("-q")
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "run {run}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let frames = std::fs::read_to_string(out.join("frames.csv")).unwrap();
        for f in [
            "approach.csv",
            "confusion.csv",
            "approach.png",
            "metadata.json",
            "scenario.toml",
        ] {
            assert!(out.join(f).is_file(), "{f} missing");
        }
        let rows: Vec<&str> = frames.lines().skip(1).collect();
        // One frame, plain and surveyed; the survey finds the elbow 1 m ahead.
        assert_eq!(rows.len(), 2, "{frames}");
        assert!(rows[1].contains(",true,bend_ahead,"), "{frames}");
        // The confusion matrix counts the survey's reading: one row per geometry,
        // the frame under its reading, zeros elsewhere.
        let confusion = std::fs::read_to_string(out.join("confusion.csv")).unwrap();
        let mut lines = confusion.lines();
        assert_eq!(lines.next(), Some("true_scene,distance_m,geometry,count"));
        let cells: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        let read = rows[1].split(',').nth(3).unwrap();
        assert!(cells.len() >= 4, "{confusion}");
        for c in &cells {
            assert_eq!((c[0], c[1]), ("elbow", "1"), "{confusion}");
            let want = if c[2] == read { "1" } else { "0" };
            assert_eq!(c[3], want, "{confusion}");
        }
        assert_eq!(cells.iter().filter(|c| c[2] == read).count(), 1);
        if run == 0 {
            first = frames.into_bytes();
        } else {
            assert_eq!(first, frames.into_bytes(), "the rerun differs");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// SIGTERM stops an approach run at the next distance (each distance's frames are a
/// batch, as a sweep's trials are): of 40 distances, at most one more begins after the
/// signal (the one begun before it finishes), the run exits 130 saying so and leaves
/// no output. Before, the run went on through every distance.
#[test]
fn a_signal_stops_an_approach_run_at_the_next_distance() {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let dir = temp_dir("approach-signal");
    let file = dir.join("long.toml");
    let distances: Vec<String> = (0..40)
        .map(|i| format!("{:.2}", 3.0 - 0.05 * i as f64))
        .collect();
    std::fs::write(
        &file,
        format!(
            "name = \"elbow_long\"\nseed = 3\n\n[approach]\nkind = \"elbow\"\n\
             distances_m = [{}]\nframes = 1\nsigma_m = 0.01\n",
            distances.join(", ")
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let mut child = bin()
        .arg(&file)
        .args(["--threads", "1", "--out"])
        .arg(&out)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let mut begun = 0;
    for line in lines.by_ref() {
        if line.unwrap().contains("m ahead") {
            begun += 1;
            if begun == 2 {
                break;
            }
        }
    }
    assert_eq!(begun, 2, "the run ended before its second distance");
    let k = std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(k.success());
    let rest: Vec<String> = lines.map(|l| l.unwrap()).collect();
    let status = child.wait().unwrap();
    let after = rest.iter().filter(|l| l.contains("m ahead")).count();
    assert!(
        after <= 1,
        "{after} distances begun after the signal: {rest:?}"
    );
    assert_eq!(status.code(), Some(130), "{rest:?}");
    assert!(rest.iter().any(|l| l.contains("interrupted")), "{rest:?}");
    assert!(!out.exists(), "an interrupted run wrote {}", out.display());
}
