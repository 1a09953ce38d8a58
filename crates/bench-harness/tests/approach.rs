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
