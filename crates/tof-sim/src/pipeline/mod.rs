//! A pipeline: straight sections, bends (elbows) and tees chained one after another, as a
//! labelled triangle mesh for the ray caster, with the exact geometry it stands for as
//! ground truth.
//!
//! # Frames
//!
//! Everything is expressed in the PCS of the **first** straight section (X along its
//! axis, Y along its major axis, Z along its minor axis, metres), in which eq. (3) places
//! the sensor at [0, δy, δz]: a [`Params`](epd_core::Params) pose places the sensor
//! relative to the first straight, exactly as for a single pipe.
//!
//! Each segment k has a *segment frame* ([`SegmentFrame`]): an origin on the centreline
//! where the segment starts and a rotation whose columns are the segment's local axes in
//! the PCS — local X along the centreline (the direction of travel), local Y and Z the
//! transported major and minor axes of the cross-section. The first segment starts at
//! [`Pipeline::start_x`] on the PCS X axis with the identity rotation; each segment's end
//! frame is the next one's start frame:
//!
//! - a straight (or a tee's main run) of length L moves the origin by L along local X;
//! - a bend of centreline radius R, angle α and direction φ turns toward the unit vector
//!   n = cos φ·Y + sin φ·Z of its start frame (the centre of curvature is c = o + R·n):
//!   the frame turns by α about the binormal b = X × n (right-handed), which carries X to
//!   cos α·X + sin α·n, and the origin moves to o + R(1 − cos α)·n + R sin α·X. This is the
//!   frame's parallel transport along a planar arc, so the cross-section does not twist.
//!
//! # Geometry
//!
//! - Straights and tee main runs: the elliptic cylinder y²/a² + z²/b² = 1 of the segment
//!   frame (a = `d_max`/2, b = `d_min`/2), for local x ∈ [0, L].
//! - Bends: the part of the ring torus (epd_core's [`Torus`]: centre c, axis b, major
//!   radius R, minor radius r = [`Pipeline::bend_tube_radius`]) between the start and end
//!   planes, i.e. the points whose angle about b, measured from the start radius
//!   −n toward X, lies in [0, α]. A torus has a circular cross-section, so an oval pipe
//!   (d_max ≠ d_min) steps from the ellipse to the circle in the joint plane.
//! - Tees: the main run's elliptic cylinder with an opening where a circular branch of
//!   diameter `branch_diameter` leaves toward n = cos φ·Y + sin φ·Z from the main axis at
//!   local x = L/2; the branch is the cylinder of points within the branch radius of the
//!   axis through [L/2, 0, 0] along n, on its side of the main axis, up to
//!   [`BRANCH_LENGTH`] beyond the main wall.
//! - Both ends of the pipeline are open: a ray leaving through them meets nothing.
//!   Segments that run into each other (a pipeline folding back on itself) are not
//!   detected.

use std::f64::consts::PI;

use epd_core::torus::Torus;
use nalgebra::{Rotation3, Unit, Vector3};

use crate::error::{Rule, SimError, first_broken};

mod frame;
mod mesh;

pub use frame::{BendTruth, BranchTruth, SegmentFrame};
pub use mesh::{LabeledMesh, MeshResolution};

/// How far (m) a tee's branch runs beyond the main wall, along its axis, from the wall
/// point farthest from the main axis in its direction: the branch ends open there.
pub const BRANCH_LENGTH: f64 = 1.5;

/// One piece of a pipeline, in the frame where it starts (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Segment {
    /// A straight pipe of the pipeline's elliptic cross-section.
    Straight {
        /// Length along the axis (m), > 0.
        length: f64,
    },
    /// A bend (elbow) of circular cross-section ([`Pipeline::bend_tube_radius`]).
    Bend {
        /// Centreline bend radius R (m), e.g. 1.5·D for a long-radius elbow; must exceed
        /// every tube radius.
        radius: f64,
        /// Bend angle α (rad), in (0, π], e.g. π/2.
        angle: f64,
        /// Direction φ (rad): the turn is toward the unit vector (0, cos φ, sin φ) of the
        /// incoming segment's frame, i.e. the centre of curvature lies on that side.
        /// φ = 0 turns toward +Y (right, for a sensor with zero roll), φ = π/2 toward +Z
        /// (up).
        direction: f64,
    },
    /// A straight main run of this length with a branch leaving its wall at the middle.
    Tee {
        /// Length of the main run (m), > `branch_diameter`.
        length: f64,
        /// Inner diameter of the (circular) branch (m), > 0 and not wider than the main
        /// pipe across the branch.
        branch_diameter: f64,
        /// Direction φ (rad): the branch leaves toward (0, cos φ, sin φ) of the segment's
        /// frame, at local x = length/2.
        direction: f64,
    },
}

/// Which kind of wall a ray hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum PartKind {
    /// A straight section's elliptic cylinder (or a tee's main run, or the joint step of
    /// an oval pipe into a bend: see [`Pipeline::mesh`]).
    Straight,
    /// A bend's torus.
    Bend,
    /// A tee's branch cylinder.
    Branch,
}

/// What a ray hit: the index of the segment in [`Pipeline::segments`] and the kind of
/// wall. Scenes that are not pipelines label every hit `{ segment: 0, kind: Straight }`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Part {
    /// Index into [`Pipeline::segments`].
    pub segment: u16,
    /// The kind of wall.
    pub kind: PartKind,
}

/// A pipeline in the PCS of its first straight section (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct Pipeline {
    /// Major inner diameter of the straight sections (m), along local Y (PCS Y for the
    /// first straight).
    pub d_max: f64,
    /// Minor inner diameter of the straight sections (m), along local Z.
    pub d_min: f64,
    /// Inner diameter of the bends (m); `None`: (d_max + d_min)/2. A torus has a circular
    /// cross-section.
    pub bend_diameter: Option<f64>,
    /// PCS x where the first segment begins (m), e.g. −1 m: behind the sensor, which sits
    /// at x = 0.
    pub start_x: f64,
    /// The segments, in order from `start_x`.
    pub segments: Vec<Segment>,
}

impl Pipeline {
    /// A pipeline with one bend: a straight from `start_x` to `bend_start_x`, the bend,
    /// and a straight of `after` metres; oval cross-section `d_max` × `d_min`, the bends'
    /// diameter the default.
    pub fn with_one_bend(
        d_max: f64,
        d_min: f64,
        start_x: f64,
        bend_start_x: f64,
        bend: Segment,
        after: f64,
    ) -> Self {
        Self {
            d_max,
            d_min,
            bend_diameter: None,
            start_x,
            segments: vec![
                Segment::Straight {
                    length: bend_start_x - start_x,
                },
                bend,
                Segment::Straight { length: after },
            ],
        }
    }

    /// Check every field; the error names the first bad one (`pipeline.d_max`,
    /// `pipeline.segments[2].radius`, …).
    pub fn validate(&self) -> Result<(), SimError> {
        use Rule::{Finite, Positive};
        let bend = self
            .bend_diameter
            .map(|d| ("pipeline.bend_diameter", d, Positive));
        let fields = [
            ("pipeline.d_max", self.d_max, Positive),
            ("pipeline.d_min", self.d_min, Positive),
        ]
        .into_iter()
        .chain(bend)
        .chain([("pipeline.start_x", self.start_x, Finite)]);
        if let Some((field, value, rule)) = first_broken(fields) {
            return Err(SimError::invalid(field, value, rule.reason()));
        }
        if self.segments.is_empty() || self.segments.len() > usize::from(u16::MAX) + 1 {
            return Err(SimError::invalid(
                "pipeline.segments",
                self.segments.len(),
                "must hold 1 to 65536 segments",
            ));
        }
        for (index, s) in self.segments.iter().enumerate() {
            if let Some((field, value, rule)) = first_broken(self.segment_checks(s)) {
                return Err(SimError::InvalidSegment {
                    index,
                    field,
                    value: value.to_string(),
                    reason: rule.reason(),
                });
            }
        }
        Ok(())
    }

    /// The checks of one segment of this pipeline, in checking order: (field, value,
    /// rule). A bend's radius exceeds every tube radius (the bend's and the straight's
    /// half-axes); a tee's branch fits across the main pipe and within its length.
    fn segment_checks(&self, s: &Segment) -> Vec<(&'static str, f64, Rule)> {
        use Rule::{Finite, Holds, Positive};
        let (a, b) = (self.d_max / 2.0, self.d_min / 2.0);
        match *s {
            Segment::Straight { length } => vec![("length", length, Positive)],
            Segment::Bend {
                radius,
                angle,
                direction,
            } => {
                let r = self.bend_tube_radius();
                let clear = radius.is_finite() && radius > r.max(a).max(b);
                vec![
                    (
                        "radius",
                        radius,
                        Holds(
                            clear,
                            "must be finite and exceed every tube radius (bend and straight)",
                        ),
                    ),
                    (
                        "angle",
                        angle,
                        Holds(angle > 0.0 && angle <= PI, "must lie in (0, π]"),
                    ),
                    ("direction", direction, Finite),
                ]
            }
            Segment::Tee {
                length,
                branch_diameter: d,
                direction,
            } => {
                // The main pipe's inner width across the branch (along u2 = X × n).
                let u2 = (-direction.sin(), direction.cos());
                let half_width = 1.0 / ((u2.0 / a).powi(2) + (u2.1 / b).powi(2)).sqrt();
                vec![
                    ("direction", direction, Finite),
                    ("branch_diameter", d, Positive),
                    (
                        "branch_diameter",
                        d,
                        Holds(
                            !(d > 2.0 * half_width),
                            "must not exceed the main pipe's inner width across the branch",
                        ),
                    ),
                    (
                        "length",
                        length,
                        Holds(
                            length.is_finite() && length > d,
                            "must be finite and exceed the branch diameter",
                        ),
                    ),
                ]
            }
        }
    }

    /// The tube radius r of the bends (m): `bend_diameter`/2, by default (d_max + d_min)/4.
    pub fn bend_tube_radius(&self) -> f64 {
        self.bend_diameter
            .unwrap_or(0.5 * (self.d_max + self.d_min))
            / 2.0
    }

    /// The start frame of every segment, then the frame at the pipeline's open end: one
    /// more entry than `segments` (entry k + 1 = the end of segment k). Meaningful for a
    /// valid pipeline ([`Pipeline::validate`]); never panics.
    pub fn frames(&self) -> Vec<SegmentFrame> {
        let mut f = SegmentFrame {
            origin: Vector3::new(self.start_x, 0.0, 0.0),
            rotation: Rotation3::identity(),
        };
        let mut out = Vec::with_capacity(self.segments.len() + 1);
        out.push(f);
        for s in &self.segments {
            f = f.after(s);
            out.push(f);
        }
        out
    }

    /// PCS x (m) where the first straight section ends: the start plane of the first bend,
    /// or — if a tee comes first — the near edge of its branch opening, x_tee + L/2 − r_b
    /// (where the branch cylinder's wall first cuts the main wall; the main wall is the
    /// first straight's elliptic cylinder for every x below it). Straights and tees keep
    /// the first straight's axis, so every segment up to there lies along PCS X. `None`
    /// when the pipeline holds neither (the first straight runs to the open end).
    pub fn straight_until(&self) -> Option<f64> {
        let mut x = self.start_x;
        for s in &self.segments {
            match *s {
                Segment::Straight { length } => x += length,
                Segment::Bend { .. } => return Some(x),
                Segment::Tee {
                    length,
                    branch_diameter,
                    ..
                } => return Some(x + 0.5 * length - 0.5 * branch_diameter),
            }
        }
        None
    }

    /// PCS x (m) where the first run of straights and tees along PCS X ends: the first
    /// bend's start, or the pipeline's open end.
    pub fn first_run_end(&self) -> f64 {
        let mut x = self.start_x;
        for s in &self.segments {
            match *s {
                Segment::Straight { length } | Segment::Tee { length, .. } => x += length,
                Segment::Bend { .. } => break,
            }
        }
        x
    }

    /// The ground truth of every bend, in order.
    pub fn bends(&self) -> Vec<BendTruth> {
        let frames = self.frames();
        let r = self.bend_tube_radius();
        let mut out = Vec::new();
        for (i, s) in self.segments.iter().enumerate() {
            if let Segment::Bend {
                radius,
                angle,
                direction,
            } = *s
            {
                let f = frames[i];
                let (c, _) = f.bend_centre_and_turn(radius, angle, direction);
                let n = f.rotation * Vector3::new(0.0, direction.cos(), direction.sin());
                out.push(BendTruth {
                    segment: i as u16,
                    radius,
                    angle,
                    direction,
                    start: f,
                    end: frames[i + 1],
                    torus: Torus {
                        centre: c,
                        axis: Unit::new_normalize(f.axis().cross(&n)),
                        major_radius: radius,
                        minor_radius: r,
                    },
                });
            }
        }
        out
    }

    /// The first bend, if any.
    pub fn first_bend(&self) -> Option<BendTruth> {
        self.bends().into_iter().next()
    }

    /// The ground truth of every tee's branch, in order.
    pub fn branches(&self) -> Vec<BranchTruth> {
        let frames = self.frames();
        let (a, b) = (self.d_max / 2.0, self.d_min / 2.0);
        let mut out = Vec::new();
        for (i, s) in self.segments.iter().enumerate() {
            if let Segment::Tee {
                length,
                branch_diameter,
                direction,
            } = *s
            {
                let f = frames[i];
                let n = Vector3::new(0.0, direction.cos(), direction.sin());
                // The main wall's distance from the axis along n.
                let reach = 1.0 / ((n.y / a).powi(2) + (n.z / b).powi(2)).sqrt();
                out.push(BranchTruth {
                    segment: i as u16,
                    origin: f.to_pcs(&Vector3::new(0.5 * length, 0.0, 0.0)),
                    axis: Unit::new_normalize(f.rotation * n),
                    diameter: branch_diameter,
                    length: reach + BRANCH_LENGTH,
                    frame: f,
                });
            }
        }
        out
    }
}
