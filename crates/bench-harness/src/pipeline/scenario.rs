//! A pipeline scenario checked: its sections, fittings (the route), rig and drift, each
//! key in its range, every pose along the way inside its pipe. The tables as written are
//! read in [`keys`].

use std::path::{Path, PathBuf};

use tof_sim::{MeshResolution, Pipe, Sensor, ToFPhysics};

use super::plan::Drift;
use crate::route::{Fitting, Route};
use crate::scenario::{KeyError, ScenarioError, check_name, key_err};
use keys::{File, FittingFile, PipelineFile};

mod keys;
#[cfg(test)]
mod tests;

/// A straight section, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct Section {
    /// Its name in the CSV files.
    pub name: String,
    /// The pipe.
    pub pipe: Pipe,
    /// Odometer distance of the first frame (m).
    pub start_m: f64,
}

/// A checked pipeline scenario.
#[derive(Clone, Debug)]
pub struct PipelineScenario {
    /// `name`: the default output folder's name.
    pub name: String,
    /// `seed`.
    pub seed: u64,
    /// Frames per section.
    pub frames_per_section: usize,
    /// Odometer distance between frames (m).
    pub frame_spacing_m: f64,
    /// The estimators' gate on the model range (m).
    pub range_gate: (f64, f64),
    /// The camera.
    pub sensor: Sensor,
    /// Its error model.
    pub physics: ToFPhysics,
    /// The straight sections, in driving order.
    pub sections: Vec<Section>,
    /// The calibration rig's pipe (known diameter).
    pub rig: Pipe,
    /// Calibration frames.
    pub rig_frames: usize,
    /// Table bins (range, intensity).
    pub table_bins: (usize, usize),
    /// Bins of the incidence axis (`pipeline.rig.incidence_bins`); 0: the range ×
    /// intensity table alone corrects the frames.
    pub incidence_bins: usize,
    /// Passes of the calibration's alternating refinement.
    pub calibration_passes: usize,
    /// The pose along the distance.
    pub drift: Drift,
    /// The pose along the rig (the drift with the rig's offset amplitude).
    pub rig_drift: Drift,
    /// Tees and elbows along the odometer, between the sections.
    pub route: Route,
    /// How frames that see a fitting are meshed.
    pub mesh: MeshResolution,
    /// The file's text.
    pub source: String,
    /// The file.
    pub path: PathBuf,
}

/// The fittings as a [`Route`], checked: kinds and sizes, in driving order without
/// overlaps, each between two sections' frames (the sections are straight pipe), each
/// tee's branch no wider than the narrower neighbouring section. Errors name the key.
fn parse_route(
    files: &[FittingFile],
    sections: &[Section],
    frames: usize,
    spacing: f64,
) -> Result<Route, KeyError> {
    let span = |s: &Section| (s.start_m, s.start_m + (frames as f64 - 1.0) * spacing);
    if !files.is_empty() && sections.windows(2).any(|w| span(&w[0]).1 >= w[1].start_m) {
        return Err(key_err(
            "pipeline.section",
            "with fittings, the sections must follow each other along the odometer without \
             overlapping frames"
                .into(),
        ));
    }
    let mut route = Route::default();
    for (k, f) in files.iter().enumerate() {
        let bad =
            |field: &str, m: String| Err(key_err(&format!("pipeline.fitting[{k}].{field}"), m));
        if !f.at_m.is_finite() {
            return bad("at_m", format!("= {}: must be finite", f.at_m));
        }
        if !f.direction_deg.is_finite() {
            return bad("direction_deg", "must be finite".into());
        }
        let (a, b) = f
            .neighbours(sections)
            .map_err(|m| key_err(&format!("pipeline.fitting[{k}].at_m"), m))?;
        let fitting = Fitting {
            kind: f.kind(k, a, b)?,
            at_m: f.at_m,
            direction: f.direction_deg.to_radians(),
        };
        if fitting.at_m <= span(a).1 || fitting.end_m() >= b.start_m {
            return bad(
                "at_m",
                format!(
                    "= {}: the fitting ({:.2} m long) must lie between section {}'s last frame \
                     ({:.2} m) and section {}'s first ({:.2} m)",
                    f.at_m,
                    fitting.length(),
                    a.name,
                    span(a).1,
                    b.name,
                    b.start_m
                ),
            );
        }
        if let Some(prev) = route.fittings.last()
            && prev.end_m() > fitting.at_m
        {
            return bad(
                "at_m",
                format!(
                    "= {}: overlaps the fitting before it (ends at {:.3} m); list them in driving order",
                    f.at_m,
                    prev.end_m()
                ),
            );
        }
        route.fittings.push(fitting);
    }
    Ok(route)
}

/// The most frames between sections in a run: 10⁵, 20 km of pipe at the default 0.2 m
/// spacing, days of simulation on this machine; the plan of a run stays a few MB.
pub const MAX_TRANSIT_FRAMES: usize = 100_000;

impl PipelineScenario {
    /// Check a pipeline scenario given as text (`path` names it in errors).
    pub fn parse(path: &Path, source: &str) -> Result<Self, ScenarioError> {
        let f: File = toml::from_str(source).map_err(|e| ScenarioError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim_end().to_string(),
        })?;
        Self::check(&f, path, source).map_err(|(key, message)| ScenarioError::Invalid {
            path: path.to_path_buf(),
            key,
            message,
        })
    }

    /// File units → a checked scenario, or (key, message). Checked in the order of the
    /// steps below, so a file with several errors names the first.
    fn check(f: &File, path: &Path, source: &str) -> Result<Self, KeyError> {
        let p = &f.pipeline;
        check_name(&f.name)?;
        let range_gate = p.gate()?;
        let physics = p.physics()?;
        let sections = p.sections()?;
        let rig = p.rig.pipe()?;
        let drift = p.drift.to_drift()?;
        let rig_drift = p.rig.drift(drift)?;
        let mesh = p.mesh()?;
        let route = parse_route(
            &p.fitting,
            &sections,
            p.frames_per_section,
            p.frame_spacing_m,
        )?;
        let scenario = Self {
            name: f.name.clone(),
            seed: f.seed,
            frames_per_section: p.frames_per_section,
            frame_spacing_m: p.frame_spacing_m,
            range_gate,
            sensor: Sensor::helios2(),
            physics,
            sections,
            rig,
            rig_frames: p.rig.frames,
            table_bins: (p.rig.range_bins, p.rig.intensity_bins),
            incidence_bins: p.rig.incidence_bins,
            calibration_passes: p.rig.passes,
            drift,
            rig_drift,
            route,
            mesh,
            source: source.to_string(),
            path: path.to_path_buf(),
        };
        scenario.check_transit_frames()?;
        scenario.check_sensor_inside(p)?;
        Ok(scenario)
    }

    /// The frames between sections (recorded through the fittings every
    /// `frame_spacing_m`) are at most [`MAX_TRANSIT_FRAMES`] in all, counted before any
    /// is planned: sections 10³⁰⁰ m apart, or a spacing of 10⁻³⁰⁰ m, would plan frames
    /// until the memory runs out.
    fn check_transit_frames(&self) -> Result<(), KeyError> {
        let spacing = self.frame_spacing_m;
        let mut total = 0.0;
        for pair in self.sections.windows(2) {
            let last = pair[0].start_m + (self.frames_per_section as f64 - 1.0) * spacing;
            let gap = (pair[1].start_m - last) / spacing;
            if gap > 0.0 {
                total += gap.ceil();
            }
        }
        if !(total <= MAX_TRANSIT_FRAMES as f64) {
            return Err(key_err(
                "pipeline.frame_spacing_m",
                format!(
                    "= {spacing}: {total:e} frames between the sections at this spacing; at \
                     most {MAX_TRANSIT_FRAMES} (move the sections closer, or space the \
                     frames wider)"
                ),
            ));
        }
        Ok(())
    }

    /// Every pose along the way (the rig's frames, then the run's) must leave the sensor
    /// inside its pipe; else the offset amplitude that takes it out (`p`'s value).
    fn check_sensor_inside(&self, p: &PipelineFile) -> Result<(), KeyError> {
        let plans = self.plans();
        let legs = std::iter::once((
            0,
            self.rig,
            (0..self.rig_frames).map(|k| self.rig_distance(k)).collect(),
        ))
        .chain(plans.iter().map(|p| (p.drift_leg, p.pipe, vec![p.x])));
        for (leg, pipe, xs) in legs {
            for x in xs {
                let pose = self.drift_of(leg).pose(&pipe, self.seed, leg, x);
                if !pose.sensor_inside() {
                    let (key, v, leg) = if leg == 0 {
                        (
                            "pipeline.rig.offset_mm",
                            p.rig.offset_mm,
                            "the rig".to_string(),
                        )
                    } else {
                        let name = &self.sections[leg as usize - 1].name;
                        (
                            "pipeline.drift.offset_mm",
                            p.drift.offset_mm,
                            format!("section {name}"),
                        )
                    };
                    return Err(key_err(
                        key,
                        format!("= {v}: at {x:.2} m the sensor leaves the pipe of {leg}"),
                    ));
                }
            }
        }
        Ok(())
    }
}
