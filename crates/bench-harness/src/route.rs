//! The route of a pipeline run: pipe along the robot's odometer with fittings (tees and
//! elbows, as in the paper's Fig. 9b) at given distances, what a sensor at distance x
//! sees of it, and the ground truth of the geometry ahead.
//!
//! The odometer distance x runs along the pipeline's centreline (through an elbow it is
//! the arc length). A fitting occupies [`Fitting::at_m`, [`Fitting::end_m`]): a tee's main
//! run of length 2·b with its branch (diameter b) at the middle, or an elbow of
//! centreline radius R and angle α (arc R·α). Between fittings the pipe is straight.
//!
//! A frame at x is cast in a local [`Pipeline`] that starts just behind the sensor (the
//! camera looks forward; nothing behind it is in view) and holds every fitting that
//! begins within the sensor's range: the sensor sits at PCS x = 0 of its straight (or,
//! inside an elbow, on the centreline at angle (x − x₀)/R into it, the mesh re-expressed
//! in that centreline frame: [`LabeledMesh::express_in`]).

use tof_sim::pipeline::{LabeledMesh, MeshResolution, SegmentFrame};
use tof_sim::{Pipeline, Segment};

/// What a fitting is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FittingKind {
    /// A T-junction: a branch of this inner diameter (m) leaving the main wall.
    Tee {
        /// Branch inner diameter b (m).
        branch_diameter: f64,
    },
    /// An elbow of centreline radius R (m) turning by α (rad).
    Elbow {
        /// Centreline bend radius R (m).
        radius: f64,
        /// Bend angle α (rad).
        angle: f64,
    },
}

/// A fitting on the route.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fitting {
    /// Tee or elbow.
    pub kind: FittingKind,
    /// Odometer distance where it begins (m): the tee's main run, the elbow's start plane.
    pub at_m: f64,
    /// Direction φ (rad) in the incoming straight's PCS: toward (0, cos φ, sin φ) — the
    /// branch of a tee, the centre of curvature of an elbow ([`Segment`]).
    pub direction: f64,
}

impl Fitting {
    /// Its length along the odometer (m): 2·b for a tee, R·α for an elbow.
    pub fn length(&self) -> f64 {
        match self.kind {
            FittingKind::Tee { branch_diameter } => 2.0 * branch_diameter,
            FittingKind::Elbow { radius, angle } => radius * angle,
        }
    }

    /// Odometer distance where it ends (m).
    pub fn end_m(&self) -> f64 {
        self.at_m + self.length()
    }

    /// Where the straight pipe before it ends (m): the elbow's start plane, or the near
    /// edge of the tee's opening, x₀ + L/2 − b/2 ([`Pipeline::straight_until`]).
    pub fn straight_ends_m(&self) -> f64 {
        match self.kind {
            FittingKind::Tee { branch_diameter } => self.at_m + 0.5 * branch_diameter,
            FittingKind::Elbow { .. } => self.at_m,
        }
    }

    /// The survey's name for the geometry when this fitting lies ahead.
    pub fn ahead_name(&self) -> &'static str {
        match self.kind {
            FittingKind::Tee { .. } => "tee_ahead",
            FittingKind::Elbow { .. } => "bend_ahead",
        }
    }

    /// The pipeline segment.
    pub fn segment(&self) -> Segment {
        match self.kind {
            FittingKind::Tee { branch_diameter } => Segment::Tee {
                length: 2.0 * branch_diameter,
                branch_diameter,
                direction: self.direction,
            },
            FittingKind::Elbow { radius, angle } => Segment::Bend {
                radius,
                angle,
                direction: self.direction,
            },
        }
    }
}

/// The ground truth of what a sensor at x sees ahead, in the survey's terms
/// (`epd_core::segment::Layout` names).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthAhead {
    /// `straight`, `bend_ahead`, `tee_ahead` or `in_bend`.
    pub geometry: &'static str,
    /// Distance (m) from the sensor along the axis to where the straight pipe ends; may
    /// be ≤ 0 beside a tee's opening. `None` when straight or in a bend.
    pub straight_until_m: Option<f64>,
}

/// Pipe with fittings along the odometer, in driving order, none overlapping.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Route {
    /// The fittings, sorted by [`Fitting::at_m`].
    pub fittings: Vec<Fitting>,
}

/// How far behind the sensor (m) a local pipeline starts.
const BEHIND_M: f64 = 0.5;

impl Route {
    /// The elbow containing x and the angle (rad) into it, if any.
    pub fn in_elbow(&self, x: f64) -> Option<(&Fitting, f64)> {
        self.fittings.iter().find_map(|f| match f.kind {
            FittingKind::Elbow { radius, .. } if f.at_m <= x && x < f.end_m() => {
                Some((f, (x - f.at_m) / radius))
            }
            _ => None,
        })
    }

    /// Fittings a sensor at x can see: those not yet behind it (ending past x) and
    /// beginning within `view` metres.
    fn in_view(&self, x: f64, view: f64) -> impl Iterator<Item = &Fitting> {
        self.fittings
            .iter()
            .filter(move |f| f.end_m() > x && f.at_m < x + view)
    }

    /// What a sensor at x sees, as the survey should report it: in a bend; the first
    /// fitting ahead whose straight end lies within `view` metres; or straight.
    pub fn truth(&self, x: f64, view: f64) -> TruthAhead {
        if self.in_elbow(x).is_some() {
            return TruthAhead {
                geometry: "in_bend",
                straight_until_m: None,
            };
        }
        match self
            .fittings
            .iter()
            .find(|f| f.end_m() > x && f.straight_ends_m() - x <= view)
        {
            Some(f) => TruthAhead {
                geometry: f.ahead_name(),
                straight_until_m: Some(f.straight_ends_m() - x),
            },
            None => TruthAhead {
                geometry: "straight",
                straight_until_m: None,
            },
        }
    }

    /// Whether a sensor at x sees any fitting within `view` metres.
    pub fn sees_fitting(&self, x: f64, view: f64) -> bool {
        self.in_view(x, view).next().is_some()
    }

    /// The local pipeline of a sensor at x (cross-section `d_max` × `d_min`) and the
    /// centreline frame the sensor sits in, in that pipeline's PCS (the identity at the
    /// origin in a straight; a frame inside the elbow otherwise). `None` when no fitting
    /// lies within `view` metres: the plain straight pipe.
    pub fn local(
        &self,
        x: f64,
        view: f64,
        d_max: f64,
        d_min: f64,
    ) -> Option<(Pipeline, SegmentFrame)> {
        if !self.sees_fitting(x, view) {
            return None;
        }
        let elbow = self.in_elbow(x);
        // Start behind the sensor, and behind the fitting the sensor stands in.
        let mut start = x - BEHIND_M;
        if let Some(f) = self.fittings.iter().find(|f| f.at_m <= x && x < f.end_m()) {
            start = start.min(f.at_m - BEHIND_M);
        }
        let mut cursor = start;
        let mut segments = Vec::new();
        for f in self.in_view(x, view) {
            if f.at_m > cursor {
                segments.push(Segment::Straight {
                    length: f.at_m - cursor,
                });
            }
            segments.push(f.segment());
            cursor = f.end_m();
        }
        segments.push(Segment::Straight {
            length: (x + view + BEHIND_M - cursor).max(BEHIND_M),
        });
        let pipeline = Pipeline {
            d_max,
            d_min,
            bend_diameter: None,
            start_x: start - x,
            segments,
        };
        let origin = SegmentFrame {
            origin: nalgebra::Vector3::zeros(),
            rotation: nalgebra::Rotation3::identity(),
        };
        let frame = match elbow {
            // In the local PCS the elbow starts at x₀ − x; the sensor is θ into it.
            Some((f, theta)) => {
                let at = SegmentFrame {
                    origin: nalgebra::Vector3::new(f.at_m - x, 0.0, 0.0),
                    ..origin
                };
                let mut partial = f.segment();
                if let Segment::Bend { angle, .. } = &mut partial {
                    *angle = theta;
                }
                at.after(&partial)
            }
            None => origin,
        };
        Some((pipeline, frame))
    }
}

/// The mesh of a local pipeline as seen from `frame` ([`Route::local`]).
pub fn local_mesh(
    pipeline: &Pipeline,
    frame: &SegmentFrame,
    resolution: &MeshResolution,
) -> Result<LabeledMesh, tof_sim::SimError> {
    let mut mesh = pipeline.mesh(resolution)?;
    if frame.origin != nalgebra::Vector3::zeros()
        || frame.rotation != nalgebra::Rotation3::identity()
    {
        mesh.express_in(frame);
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn route() -> Route {
        Route {
            fittings: vec![
                Fitting {
                    kind: FittingKind::Tee {
                        branch_diameter: 0.3,
                    },
                    at_m: 12.0,
                    direction: 0.0,
                },
                Fitting {
                    kind: FittingKind::Elbow {
                        radius: 0.762,
                        angle: std::f64::consts::FRAC_PI_2,
                    },
                    at_m: 17.0,
                    direction: 0.0,
                },
            ],
        }
    }

    #[test]
    fn truth_along_the_route() {
        let r = route();
        let t = r.truth(5.0, 6.0);
        assert_eq!(t.geometry, "straight");
        // The tee's opening starts at 12 + 0.3 − 0.15 = 12.15 m.
        let t = r.truth(9.0, 6.0);
        assert_eq!(t.geometry, "tee_ahead");
        assert!((t.straight_until_m.unwrap() - 3.15).abs() < 1e-12);
        // Beside the opening: still the tee, its edge behind the sensor.
        let t = r.truth(12.4, 6.0);
        assert_eq!(t.geometry, "tee_ahead");
        assert!(t.straight_until_m.unwrap() < 0.0);
        assert_eq!(r.truth(13.0, 6.0).geometry, "bend_ahead");
        assert_eq!(r.truth(17.5, 6.0).geometry, "in_bend");
        let end = 17.0 + 0.762 * std::f64::consts::FRAC_PI_2;
        assert_eq!(r.truth(end + 0.01, 6.0).geometry, "straight");
    }

    #[test]
    fn local_pipelines_put_the_fittings_where_the_route_has_them() {
        let r = route();
        assert!(r.local(2.0, 6.0, 0.49, 0.48).is_none());
        let (p, f) = r.local(9.0, 6.0, 0.49, 0.48).unwrap();
        assert_eq!(f.origin, nalgebra::Vector3::zeros());
        assert!((p.straight_until().unwrap() - 3.15).abs() < 1e-12);
        p.validate().unwrap();
        // Inside the tee's main run, past the opening's near edge.
        let (p, _) = r.local(12.2, 6.0, 0.49, 0.48).unwrap();
        assert!(p.start_x < -0.2 - BEHIND_M + 1e-12);
        assert!((p.straight_until().unwrap() - (12.15 - 12.2)).abs() < 1e-12);
        // Inside the elbow: the sensor frame sits on the centreline, θ into the bend,
        // at distance R from the centre of curvature, its X along the tangent.
        let x = 17.0 + 0.762 * 0.5;
        let (p, f) = r.local(x, 6.0, 0.49, 0.48).unwrap();
        p.validate().unwrap();
        let bend = p.first_bend().unwrap();
        let c = bend.torus.centre;
        assert!(((f.origin - c).norm() - 0.762).abs() < 1e-12);
        assert!((bend.angle_of(&f.origin) - 0.5).abs() < 1e-12);
        assert!(f.axis().dot(&(f.origin - c)).abs() < 1e-12);
    }
}
