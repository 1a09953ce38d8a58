//! The scenario file of the calibration-transfer experiment: `name`, `seed` and a
//! `[calibration_transfer]` table.

use std::path::Path;

use serde::Deserialize;

use crate::scenario::ScenarioError;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    name: String,
    #[serde(default)]
    seed: u64,
    calibration_transfer: Keys,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Keys {
    frames_per_size: u64,
    #[serde(default = "default_passes")]
    passes: u32,
}

/// `epd calibrate --passes`'s default.
fn default_passes() -> u32 {
    epd_frame::rig::DEFAULT_PASSES
}

/// Most test frames per pipe size: a frame costs about a tenth of a second to simulate
/// and measure, so 1000 per size (16 000 frames over the two tables) is hours, past any
/// use of this figure; more is refused before anything runs.
pub const MAX_FRAMES_PER_SIZE: u64 = 1000;

/// A checked calibration-transfer scenario.
#[derive(Clone, Debug)]
pub struct TransferScenario {
    /// The run's name (its default output folder).
    pub name: String,
    /// Added to every seed of the run's frames (0: the committed results').
    pub seed: u64,
    /// Test frames per pipe size.
    pub frames_per_size: u64,
    /// Passes of the rigs' pose/table refinement (`epd calibrate --passes`).
    pub passes: u32,
    /// The scenario's text, copied into the output folder.
    pub source: String,
}

impl TransferScenario {
    /// Read and check a scenario given as text (`path` names it in errors).
    pub fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        let invalid = |key: &str, message: String| ScenarioError::Invalid {
            path: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        let f: File = toml::from_str(source).map_err(|e| ScenarioError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let k = f.calibration_transfer;
        if !(1..=MAX_FRAMES_PER_SIZE).contains(&k.frames_per_size) {
            return Err(invalid(
                "calibration_transfer.frames_per_size",
                format!(
                    "{} is outside [1, {MAX_FRAMES_PER_SIZE}]",
                    k.frames_per_size
                ),
            ));
        }
        let max = epd_frame::rig::MAX_PASSES;
        if !(1..=max).contains(&k.passes) {
            return Err(invalid(
                "calibration_transfer.passes",
                format!("{} is outside [1, {max}]", k.passes),
            ));
        }
        Ok(Self {
            name: f.name,
            seed: f.seed,
            frames_per_size: k.frames_per_size,
            passes: k.passes,
            source: source.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<TransferScenario, ScenarioError> {
        TransferScenario::parse(Path::new("t.toml"), text)
    }

    #[test]
    fn keys_are_read_and_checked() {
        let s = parse("name = \"t\"\n[calibration_transfer]\nframes_per_size = 5\n").unwrap();
        assert_eq!((s.seed, s.frames_per_size), (0, 5));
        assert_eq!(s.passes, epd_frame::rig::DEFAULT_PASSES);
        for (text, key) in [
            ("frames_per_size = 0", "frames_per_size"),
            ("frames_per_size = 1001", "frames_per_size"),
            ("frames_per_size = 5\npasses = 0", "passes"),
        ] {
            let e = parse(&format!("name = \"t\"\n[calibration_transfer]\n{text}\n"))
                .expect_err(text)
                .to_string();
            assert!(e.contains(key), "{text}: {e}");
        }
        let e = parse("name = \"t\"\n[calibration_transfer]\nframes_per_size = 5\nrigs = 2\n")
            .expect_err("unknown key")
            .to_string();
        assert!(e.contains("rigs"), "{e}");
    }
}
