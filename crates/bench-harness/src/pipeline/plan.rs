//! Where each frame of a pipeline run is taken: the pose drifting along the odometer
//! ([`Drift`]), the frames in driving order ([`FramePlan`]), and each frame cast on the
//! straight pipe or on the local pipeline around a fitting.

use rand::RngExt;
use tof_sim::noise::{Stream, stream};
use tof_sim::{Frame, FrameSeed, Noise, Pipe, Scene, Subsample, WallModel, simulate};

use epd_core::Params;

use super::PipelineScenario;
use crate::route::{Fitting, local_mesh};

/// The smooth pose along the distance x (m): roll = roll₀ + k·x; pitch, yaw = T·sin, T·cos
/// of 2πx/P_T (different phases and a 1.3 × longer yaw period); δy, δz = A·sin of
/// 2πx/P_A (δz on a 0.77 × shorter period); the phases drawn from the seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drift {
    /// Roll rate (rad/m).
    pub roll_per_m: f64,
    /// Tilt amplitude T (rad).
    pub tilt: f64,
    /// Tilt period P_T (m).
    pub tilt_period_m: f64,
    /// Offset amplitude A (m).
    pub offset: f64,
    /// Offset period P_A (m).
    pub offset_period_m: f64,
}

impl Drift {
    /// The pose at distance x in `pipe`, phases from (seed, `leg`).
    pub fn pose(&self, pipe: &Pipe, seed: u64, leg: u64, x: f64) -> Params {
        let mut rng = stream(seed, leg, 0, Stream::Pose, 0);
        let tau = std::f64::consts::TAU;
        let ph: [f64; 5] = std::array::from_fn(|_| rng.random_range(0.0..tau));
        let roll = epd_core::params::wrap_pi(ph[0] + self.roll_per_m * x);
        Params {
            d_max: pipe.d_max(),
            d_min: pipe.d_min(),
            roll,
            pitch: self.tilt * (tau * x / self.tilt_period_m + ph[1]).sin(),
            yaw: self.tilt * (tau * x / (1.3 * self.tilt_period_m) + ph[2]).cos(),
            dy: self.offset * (tau * x / self.offset_period_m + ph[3]).sin(),
            dz: self.offset * (tau * x / (0.77 * self.offset_period_m) + ph[4]).sin(),
        }
    }
}

impl PipelineScenario {
    /// Every frame of the run in driving order: each section's frames, then (when
    /// fittings lie between two sections) the frames the robot records on its way from
    /// one section to the next, at the same spacing.
    pub fn plans(&self) -> Vec<FramePlan> {
        let n = self.sections.len();
        let mut plans = Vec::new();
        for (si, sec) in self.sections.iter().enumerate() {
            let leg = si as u64 + 1;
            let last = sec.start_m + (self.frames_per_section as f64 - 1.0) * self.frame_spacing_m;
            for k in 0..self.frames_per_section {
                plans.push(FramePlan {
                    place: si,
                    drift_leg: leg,
                    seed_leg: leg,
                    index: k,
                    x: sec.start_m + k as f64 * self.frame_spacing_m,
                    pipe: sec.pipe,
                });
            }
            let Some(next) = self.sections.get(si + 1) else {
                continue;
            };
            let gap: Vec<&Fitting> = self
                .route
                .fittings
                .iter()
                .filter(|f| f.at_m > last && f.at_m < next.start_m)
                .collect();
            let Some(change) = gap.last().map(|f| f.end_m()) else {
                continue;
            };
            let mut j = 1;
            loop {
                let x = last + j as f64 * self.frame_spacing_m;
                if x > next.start_m - 0.5 * self.frame_spacing_m {
                    break;
                }
                plans.push(FramePlan {
                    place: n + si,
                    drift_leg: leg,
                    seed_leg: TRANSIT_LEG + si as u64,
                    index: j - 1,
                    x,
                    // The pipe changes to the next section's after the gap's last fitting.
                    pipe: if x < change { sec.pipe } else { next.pipe },
                });
                j += 1;
            }
        }
        plans
    }

    /// The name of a place in the CSV files: a section's, or `A..B` between sections A
    /// and B.
    pub fn place_name(&self, place: usize) -> String {
        let n = self.sections.len();
        match self.sections.get(place) {
            Some(s) => s.name.clone(),
            None => format!(
                "{}..{}",
                self.sections[place - n].name,
                self.sections[place - n + 1].name
            ),
        }
    }

    /// Where rig frame k is taken: the frames span one period of the offset's drift,
    /// so the sensor sits off the axis in every direction (a pose error the fit trades
    /// for a systematic error then averages out of the table instead of entering it).
    pub(crate) fn rig_distance(&self, k: usize) -> f64 {
        k as f64 * self.rig_drift.offset_period_m / self.rig_frames as f64
    }

    /// The drift of a leg: the rig's (leg 0) or the sections'.
    pub(crate) fn drift_of(&self, leg: u64) -> &Drift {
        if leg == 0 {
            &self.rig_drift
        } else {
            &self.drift
        }
    }

    pub(crate) fn noise(&self) -> Noise {
        Noise {
            physics: Some(self.physics),
            ..Noise::none()
        }
    }

    /// A rig frame: the straight rig pipe.
    pub(crate) fn rig_frame(&self, index: usize, x: f64) -> anyhow::Result<Frame> {
        let truth = self.rig_drift.pose(&self.rig, self.seed, 0, x);
        let scene = Scene::new(&truth, WallModel::Exact, self.sensor.max_range)?;
        self.cast(&scene, 0, index)
    }

    pub(crate) fn cast(&self, scene: &Scene, leg: u64, index: usize) -> anyhow::Result<Frame> {
        Ok(simulate(
            &self.sensor,
            scene,
            &self.noise(),
            Subsample::All,
            FrameSeed {
                seed: self.seed,
                trial: index as u64,
                sweep_index: leg,
            },
        )?)
    }

    /// A frame of the run: the exact straight pipe when no fitting is in the sensor's
    /// range, else the local pipeline ([`Route::local`]) meshed. Returns the truth (in an
    /// elbow: the pose about the centreline frame, the bend's round diameter), the frame
    /// and the local pipeline.
    pub(crate) fn frame(
        &self,
        plan: &FramePlan,
    ) -> anyhow::Result<(Params, Frame, Option<tof_sim::Pipeline>)> {
        let mut truth =
            self.drift_of(plan.drift_leg)
                .pose(&plan.pipe, self.seed, plan.drift_leg, plan.x);
        let view = self.sensor.max_range;
        let local = self
            .route
            .local(plan.x, view, plan.pipe.d_max(), plan.pipe.d_min());
        let scene = match &local {
            None => Scene::new(&truth, WallModel::Exact, self.sensor.max_range)?,
            Some((p, f)) => {
                if self.route.in_elbow(plan.x).is_some() {
                    let d = 2.0 * p.bend_tube_radius();
                    (truth.d_max, truth.d_min) = (d, d);
                }
                Scene::with_labeled_mesh(&truth, local_mesh(p, f, &self.mesh)?)?
            }
        };
        let frame = self.cast(&scene, plan.seed_leg, plan.index)?;
        Ok((truth, frame, local.map(|l| l.0)))
    }
}

/// `FrameSeed::sweep_index` of the frames between sections A and A + 1: this + A.
const TRANSIT_LEG: u64 = 1000;

/// Where and how one frame of the run is taken.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FramePlan {
    /// A section's index, or `n_sections + A` between sections A and A + 1.
    pub place: usize,
    /// The drift's leg (its phases): the section's, continued between sections.
    pub drift_leg: u64,
    /// The frame's noise stream (`FrameSeed::sweep_index`).
    pub seed_leg: u64,
    /// Frame index within its place.
    pub index: usize,
    /// Odometer distance (m).
    pub x: f64,
    /// The pipe at x.
    pub pipe: Pipe,
}
