//! An approach scenario: the `[approach]` table as written, checked into the feature ahead
//! ([`Feature`]), the pipe and the run's size; and the pipeline whose straight section ends
//! a given distance ahead.

use std::path::Path;

use serde::Deserialize;
use tof_sim::{Pipe, Pipeline, Segment};

use crate::scenario::ScenarioError;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    name: String,
    #[serde(default)]
    seed: u64,
    approach: Keys,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Keys {
    kind: String,
    distances_m: Vec<f64>,
    frames: usize,
    sigma_m: f64,
    #[serde(default = "crate::defaults::nominal_od_in")]
    nominal_od_in: f64,
    #[serde(default = "crate::defaults::wall_mm")]
    wall_mm: f64,
    #[serde(default = "crate::defaults::ovality")]
    ovality: f64,
    #[serde(default = "crate::defaults::bend_radius_d")]
    bend_radius_d: f64,
    #[serde(default = "crate::defaults::bend_angle_deg")]
    bend_angle_deg: f64,
    #[serde(default = "default_direction_deg")]
    direction_deg: f64,
    #[serde(default = "default_branch_diameter_mm")]
    branch_diameter_mm: f64,
}

/// `approach.direction_deg`: the turn (or branch) toward 40° in the PCS, a harness
/// default, as the committed `scenarios/elbow_approach.toml` and `tee_pass.toml` set it.
fn default_direction_deg() -> f64 {
    40.0
}

/// `approach.branch_diameter_mm`: a tee's 300 mm branch, as the committed
/// `scenarios/tee_pass.toml` and the pipeline run's tee.
fn default_branch_diameter_mm() -> f64 {
    300.0
}

impl Keys {
    /// The feature ahead, checked against `pipe`; else (key, message).
    fn feature(&self, pipe: &Pipe) -> Result<Feature, (&'static str, String)> {
        match self.kind.as_str() {
            "elbow" => {
                let radius = self.bend_radius_d * pipe.outer_diameter();
                if !(radius > 0.6 * pipe.d_max() && radius.is_finite()) {
                    return Err((
                        "approach.bend_radius_d",
                        format!(
                            "{}: the bend radius must exceed the tube's",
                            self.bend_radius_d
                        ),
                    ));
                }
                if !(self.bend_angle_deg > 0.0 && self.bend_angle_deg <= 180.0) {
                    return Err((
                        "approach.bend_angle_deg",
                        format!("{}: must lie in (0, 180]", self.bend_angle_deg),
                    ));
                }
                Ok(Feature::Elbow {
                    radius,
                    angle: self.bend_angle_deg.to_radians(),
                })
            }
            "tee" => {
                let d = self.branch_diameter_mm * 1e-3;
                if !(d > 0.0 && d <= pipe.d_min()) {
                    return Err((
                        "approach.branch_diameter_mm",
                        format!(
                            "{}: must be > 0 and at most the pipe's",
                            self.branch_diameter_mm
                        ),
                    ));
                }
                Ok(Feature::Tee { branch_diameter: d })
            }
            other => Err(("approach.kind", format!("`{other}`: expected elbow or tee"))),
        }
    }

    /// The run's size and noise: distances in (0, 20] m, 1 to 1000 frames, σ ≤ 0.2 m.
    fn check_run(&self) -> Result<(), (&'static str, String)> {
        if self.distances_m.is_empty() || self.distances_m.iter().any(|d| !(*d > 0.0 && *d <= 20.0))
        {
            return Err((
                "approach.distances_m",
                format!("{:?}: one or more distances in (0, 20] m", self.distances_m),
            ));
        }
        if !(1..=1000).contains(&self.frames) {
            return Err((
                "approach.frames",
                format!("{}: must lie in [1, 1000]", self.frames),
            ));
        }
        if !(self.sigma_m >= 0.0 && self.sigma_m <= 0.2) {
            return Err((
                "approach.sigma_m",
                format!("{}: must lie in [0, 0.2] m", self.sigma_m),
            ));
        }
        Ok(())
    }
}

/// What the sensor approaches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Feature {
    /// A bend of centreline radius `radius` (m) and `angle` (rad).
    Elbow {
        /// Centreline radius (m).
        radius: f64,
        /// Bend angle (rad).
        angle: f64,
    },
    /// A tee whose branch has this diameter (m).
    Tee {
        /// Branch diameter (m).
        branch_diameter: f64,
    },
}

/// A checked approach scenario.
#[derive(Clone, Debug)]
pub struct ApproachScenario {
    /// `name`: the default output folder's name.
    pub name: String,
    /// `seed`.
    pub seed: u64,
    /// The feature ahead.
    pub feature: Feature,
    /// Distances from the sensor to the straight section's end (m).
    pub distances_m: Vec<f64>,
    /// Frames per distance.
    pub frames: usize,
    /// Range noise σ (m).
    pub sigma_m: f64,
    /// The straight pipe.
    pub pipe: Pipe,
    /// The turn's (or branch's) direction in the PCS (rad).
    pub direction: f64,
    /// The file's text.
    pub source: String,
}

impl ApproachScenario {
    /// Check an approach scenario given as text (`path` names it in errors).
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
        let k = f.approach;
        let pipe = Pipe {
            nominal_od_in: k.nominal_od_in,
            wall_thickness: k.wall_mm * 1e-3,
            ovality: k.ovality,
        };
        pipe.validate()
            .map_err(|e| invalid("approach.nominal_od_in/wall_mm/ovality", e.to_string()))?;
        let feature = k.feature(&pipe).map_err(|(key, m)| invalid(key, m))?;
        k.check_run().map_err(|(key, m)| invalid(key, m))?;
        Ok(Self {
            name: f.name,
            seed: f.seed,
            feature,
            distances_m: k.distances_m,
            frames: k.frames,
            sigma_m: k.sigma_m,
            pipe,
            direction: k.direction_deg.to_radians(),
            source: source.to_string(),
        })
    }

    /// The pipeline whose straight section ends `distance` ahead of the sensor.
    pub fn pipeline(&self, distance: f64) -> Pipeline {
        let (d_max, d_min) = (self.pipe.d_max(), self.pipe.d_min());
        match self.feature {
            Feature::Elbow { radius, angle } => Pipeline::with_one_bend(
                d_max,
                d_min,
                -1.0,
                distance,
                Segment::Bend {
                    radius,
                    angle,
                    direction: self.direction,
                },
                6.0,
            ),
            Feature::Tee { branch_diameter } => {
                // The opening's near edge at `distance`: a tee of length 2·b centred
                // b/2 + radius past it.
                let len = 2.0 * branch_diameter;
                let first = 1.0 + distance - (0.5 * len - 0.5 * branch_diameter);
                Pipeline {
                    d_max,
                    d_min,
                    bend_diameter: None,
                    start_x: -1.0,
                    segments: vec![
                        Segment::Straight { length: first },
                        Segment::Tee {
                            length: len,
                            branch_diameter,
                            direction: self.direction,
                        },
                        Segment::Straight { length: 6.0 },
                    ],
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::Kind;

    const OK: &str = "name = \"a\"\n[approach]\nkind = \"elbow\"\ndistances_m = [1.0]\nframes = 1\nsigma_m = 0.0\n";

    #[test]
    fn parses_and_refuses_with_the_key() {
        let p = Path::new("a.toml");
        assert_eq!(Kind::of(OK), Kind::Approach);
        let s = ApproachScenario::parse(p, OK).unwrap();
        assert!(matches!(s.feature, Feature::Elbow { .. }));
        assert_eq!(s.pipeline(1.0).straight_until(), Some(1.0));
        for (bad, key) in [
            (OK.replace("elbow", "wye"), "approach.kind"),
            (OK.replace("[1.0]", "[]"), "approach.distances_m"),
            (OK.replace("frames = 1", "frames = 0"), "approach.frames"),
            (
                OK.replace("sigma_m = 0.0", "sigma_m = -1.0"),
                "approach.sigma_m",
            ),
        ] {
            let e = ApproachScenario::parse(p, &bad).unwrap_err().to_string();
            assert!(e.contains(key), "{e}");
        }
        let tee = OK.replace("elbow", "tee");
        let s = ApproachScenario::parse(p, &tee).unwrap();
        let want = s.pipeline(0.7).straight_until().unwrap();
        assert!((want - 0.7).abs() < 1e-12, "{want}");
    }
}
