//! Where each segment of a [`Pipeline`](super::Pipeline) starts ([`SegmentFrame`]) and
//! the exact geometry of its bends and tees as ground truth ([`BendTruth`],
//! [`BranchTruth`]); the frames are derived in the parent module's documentation.

use epd_core::torus::Torus;
use nalgebra::{Rotation3, Unit, Vector3};

#[cfg(doc)]
use super::Pipeline;
use super::Segment;

/// A segment's start: `origin` on the centreline (PCS, m) and `rotation` whose columns
/// are the segment's local X (along the centreline), Y and Z axes in the PCS, so that a
/// local point maps to the PCS as x_P = origin + rotation·x_local.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegmentFrame {
    /// The centreline point where the segment starts (PCS, m).
    pub origin: Vector3<f64>,
    /// Local → PCS rotation.
    pub rotation: Rotation3<f64>,
}

impl SegmentFrame {
    /// The unit centreline direction (local X) in the PCS.
    pub fn axis(&self) -> Vector3<f64> {
        self.rotation.matrix().column(0).into()
    }

    /// A local point in the PCS: origin + rotation·local.
    pub fn to_pcs(&self, local: &Vector3<f64>) -> Vector3<f64> {
        self.origin + self.rotation * local
    }

    /// A PCS point in local coordinates: rotationᵀ·(p − origin).
    pub fn to_local(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation.inverse() * (p - self.origin)
    }

    /// The frame at the end of `segment` starting here (the chaining rule of the module
    /// documentation).
    pub fn after(&self, segment: &Segment) -> SegmentFrame {
        match *segment {
            Segment::Straight { length } | Segment::Tee { length, .. } => SegmentFrame {
                origin: self.origin + self.axis() * length,
                rotation: self.rotation,
            },
            Segment::Bend {
                radius,
                angle,
                direction,
            } => {
                let (c, turn) = self.bend_centre_and_turn(radius, angle, direction);
                SegmentFrame {
                    origin: c + turn * (self.origin - c),
                    rotation: turn * self.rotation,
                }
            }
        }
    }

    /// The centre of curvature c = o + R·n and the rotation by `angle` about b = X × n of
    /// a bend starting here.
    pub(super) fn bend_centre_and_turn(
        &self,
        radius: f64,
        angle: f64,
        direction: f64,
    ) -> (Vector3<f64>, Rotation3<f64>) {
        let n = self.rotation * Vector3::new(0.0, direction.cos(), direction.sin());
        let b = Unit::new_normalize(self.axis().cross(&n));
        (
            self.origin + n * radius,
            Rotation3::from_axis_angle(&b, angle),
        )
    }
}

/// The ground truth of one bend, in the PCS.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BendTruth {
    /// Index of the bend in [`Pipeline::segments`].
    pub segment: u16,
    /// Centreline bend radius R (m).
    pub radius: f64,
    /// Bend angle α (rad).
    pub angle: f64,
    /// Direction φ (rad) in the incoming frame (see [`Segment::Bend`]).
    pub direction: f64,
    /// The frame where the bend starts.
    pub start: SegmentFrame,
    /// The frame where it ends (the next segment's start).
    pub end: SegmentFrame,
    /// The whole torus the bend is a part of: centre = centre of curvature, axis = the
    /// binormal X × n (the bend plane's normal), R, r = [`Pipeline::bend_tube_radius`].
    pub torus: Torus,
}

impl BendTruth {
    /// The angle (rad) of a PCS point about the torus axis, measured from the start
    /// radius (from the centre toward the start of the centreline) toward the direction of
    /// travel: 0 in the start plane, α in the end plane; in (−π, π].
    pub fn angle_of(&self, p: &Vector3<f64>) -> f64 {
        let v = p - self.torus.centre;
        let x = self.start.axis();
        let out = (self.start.origin - self.torus.centre) / self.radius;
        v.dot(&x).atan2(v.dot(&out))
    }

    /// Whether a PCS point lies between the bend's start and end planes (its
    /// [`BendTruth::angle_of`] is in [0, α]).
    pub fn contains_angle(&self, p: &Vector3<f64>) -> bool {
        let t = self.angle_of(p);
        (0.0..=self.angle).contains(&t)
    }
}

/// The ground truth of one tee's branch, in the PCS.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BranchTruth {
    /// Index of the tee in [`Pipeline::segments`].
    pub segment: u16,
    /// Where the branch axis meets the main axis (PCS, m): the tee's local [L/2, 0, 0].
    pub origin: Vector3<f64>,
    /// The branch axis direction (PCS, unit): the tee's local (0, cos φ, sin φ).
    pub axis: Unit<Vector3<f64>>,
    /// The branch's inner diameter (m).
    pub diameter: f64,
    /// Distance (m) from `origin` along `axis` to the branch's open end.
    pub length: f64,
    /// The tee's frame.
    pub frame: SegmentFrame,
}
