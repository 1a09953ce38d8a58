//! The pipe wall placed in the sensor frame, cast through parry's `Ray`/`RayCast`.

use epd_core::Params;
use nalgebra::{UnitQuaternion, Vector3};
use parry3d_f64::glamx::{DQuat, DVec3};
use parry3d_f64::math::Pose;
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::TriMesh;

use crate::contamination::{Contamination, Hit, Placed};
use crate::elliptic_cylinder::EllipticCylinder;
use crate::error::SimError;
use crate::mesh::tube_mesh;
use crate::pipeline::{LabeledMesh, MeshResolution, Part, PartKind, Pipeline};
use crate::pose::check_inside;

/// Which geometry stands for the pipe's inner wall.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum WallModel {
    /// The exact elliptic cylinder (closed-form ray cast).
    #[default]
    Exact,
    /// A triangle mesh of the ellipse with this many segments around.
    Mesh {
        /// Vertices around the cross-section.
        segments: usize,
    },
}

/// The wall geometry in the PCS.
enum Wall {
    Exact(EllipticCylinder),
    Mesh(Box<TriMesh>),
    Labeled(Box<LabeledMesh>),
}

/// The label of every hit on a wall that is one straight pipe.
const ONE_PIPE: Part = Part {
    segment: 0,
    kind: PartKind::Straight,
};

/// A pipe wall seen from the sensor: the geometry in the PCS and its pose in the SCS,
/// the inverse of eq. (3): x_S = Rᵀ(x_P − [0, δy, δz]).
pub struct Scene {
    wall: Wall,
    /// PCS → SCS.
    pose: Pose,
    /// The true β.
    truth: Params,
    /// A floor layer, an obstacle, a dent, a partial view ([`Scene::with_contamination`]).
    contamination: Option<Box<Placed>>,
}

/// nalgebra → glam at this crate's boundary.
fn to_glam(v: &Vector3<f64>) -> DVec3 {
    DVec3::new(v.x, v.y, v.z)
}

impl Scene {
    /// The pipe of diameters `truth.d_max`, `truth.d_min` seen from the pose in `truth`,
    /// as the chosen wall model. A mesh spans the PCS X range [−1 m, `length`].
    pub fn new(truth: &Params, wall: WallModel, length: f64) -> Result<Self, SimError> {
        if !(truth.is_finite() && truth.d_max > 0.0 && truth.d_min > 0.0) {
            return Err(SimError::invalid(
                "pipe",
                format!("{truth:?}"),
                "diameters must be finite and > 0",
            ));
        }
        check_inside(truth)?;
        let (a, b) = (truth.d_max / 2.0, truth.d_min / 2.0);
        let wall = match wall {
            WallModel::Exact => Wall::Exact(EllipticCylinder::new(a, b)),
            WallModel::Mesh { segments } => {
                Wall::Mesh(Box::new(tube_mesh(a, b, -1.0, length, segments, 2, None)?))
            }
        };
        // R (SCS → PCS) as a quaternion; the pipe's pose in the SCS is its inverse.
        let q = UnitQuaternion::from_rotation_matrix(&truth.rotation()).inverse();
        let rot = DQuat::from_xyzw(q.i, q.j, q.k, q.w);
        let t = -(q * Vector3::new(0.0, truth.dy, truth.dz));
        Ok(Self {
            wall,
            pose: Pose::from_parts(to_glam(&t), rot),
            truth: *truth,
            contamination: None,
        })
    }

    /// This scene with `contamination` ([`crate::contamination`]): a floor layer, an
    /// obstacle, a dent, a partial view, placed in the PCS of `truth`'s pipe. From then
    /// on every cast ([`Scene::cast`], [`Scene::cast_with_normal`],
    /// [`Scene::cast_labeled`]) stops at the first of the wall and those objects, and
    /// [`Scene::in_view`] says which hits the camera sees. Refused, naming the field:
    /// a value out of its range (see each type), a layer or obstacle that holds the
    /// sensor, a dent that reaches it, a dent on a meshed wall, any contamination of a
    /// pipeline scene (its floor would follow the bends: not modelled). A
    /// [`Contamination::default`] (all `None`) leaves the scene as it was.
    pub fn with_contamination(mut self, contamination: Contamination) -> Result<Self, SimError> {
        if contamination == Contamination::default() {
            self.contamination = None;
            return Ok(self);
        }
        if self.is_labeled() {
            return Err(SimError::invalid(
                "contamination",
                "on a pipeline scene",
                "applies to one straight pipe (Scene::new or Scene::with_mesh)",
            ));
        }
        let t = &self.truth;
        let placed = Placed::new(
            contamination,
            t.d_max / 2.0,
            t.d_min / 2.0,
            *t.rotation().matrix(),
            Vector3::new(0.0, t.dy, t.dz),
            matches!(self.wall, Wall::Exact(_)),
        )?;
        self.contamination = Some(Box::new(placed));
        Ok(self)
    }

    /// The scene's contamination, if any ([`Scene::with_contamination`]).
    pub fn contamination(&self) -> Option<&Contamination> {
        self.contamination.as_deref().map(|p| &p.parts)
    }

    /// Whether the camera sees the hit at `range` (m) along the unit SCS ray `dir`: its
    /// clock angle (PCS) lies in the contamination's [`crate::ViewSector`]; always true
    /// without one.
    pub fn in_view(&self, dir: &Vector3<f64>, range: f64) -> bool {
        self.contamination
            .as_deref()
            .is_none_or(|p| p.in_view(dir, range))
    }

    /// A scene over a custom mesh of the wall given in the PCS (a dented pipe, an
    /// elbow…); `truth` places it and is reported with the frames.
    pub fn with_mesh(truth: &Params, mesh: TriMesh) -> Result<Self, SimError> {
        let mut s = Self::new(truth, WallModel::Exact, 1.0)?;
        s.wall = Wall::Mesh(Box::new(mesh));
        Ok(s)
    }

    /// A scene inside `pipeline` ([`crate::pipeline`]), meshed at `resolution`, the sensor
    /// placed by `truth` (eq. 3) in the PCS of the pipeline's first straight section.
    /// `truth.d_max` and `truth.d_min` must equal the pipeline's (the first straight's
    /// cross-section, which the estimator is scored against), and the sensor, at PCS
    /// [0, δy, δz], must lie inside the first straight: strictly within its cross-section
    /// and with `start_x` < 0 < the end of the first run of straights and tees
    /// ([`Pipeline::first_run_end`]). Hits are labelled ([`Scene::cast_labeled`]) and
    /// frames of this scene carry [`crate::Frame::part`].
    pub fn pipeline(
        truth: &Params,
        pipeline: &Pipeline,
        resolution: &MeshResolution,
    ) -> Result<Self, SimError> {
        pipeline.validate()?;
        if truth.d_max != pipeline.d_max || truth.d_min != pipeline.d_min {
            return Err(SimError::invalid(
                "pipeline.d_max/d_min",
                format!(
                    "{}/{} (truth {}/{})",
                    pipeline.d_max, pipeline.d_min, truth.d_max, truth.d_min
                ),
                "must equal the truth's diameters (the first straight's cross-section)",
            ));
        }
        if !(pipeline.start_x < 0.0 && pipeline.first_run_end() > 0.0) {
            return Err(SimError::invalid(
                "pipeline.start_x",
                pipeline.start_x,
                "the sensor (PCS x = 0) must lie inside the first straight section: start_x < 0 < its end",
            ));
        }
        let mesh = pipeline.mesh(resolution)?;
        Self::with_labeled_mesh(truth, mesh)
    }

    /// A scene over a labelled mesh of walls given in the PCS (see
    /// [`crate::pipeline::Pipeline::mesh`]); `truth` places it. The labels must be one per
    /// triangle.
    pub fn with_labeled_mesh(truth: &Params, mesh: LabeledMesh) -> Result<Self, SimError> {
        if mesh.labels.len() != mesh.mesh.num_triangles() {
            return Err(SimError::Mesh(format!(
                "{} labels for {} triangles",
                mesh.labels.len(),
                mesh.mesh.num_triangles()
            )));
        }
        let mut s = Self::new(truth, WallModel::Exact, 1.0)?;
        s.wall = Wall::Labeled(Box::new(mesh));
        Ok(s)
    }

    /// Whether hits carry pipeline labels (a scene from [`Scene::pipeline`] or
    /// [`Scene::with_labeled_mesh`]).
    pub fn is_labeled(&self) -> bool {
        matches!(self.wall, Wall::Labeled(_))
    }

    /// The true β.
    pub fn truth(&self) -> &Params {
        &self.truth
    }

    /// Range (m) along the unit direction `dir` (SCS) from the sensor origin to the wall,
    /// up to `max_range`, through parry's `RayCast`.
    /// With a contamination, the first of the wall and its objects.
    pub fn cast(&self, dir: &Vector3<f64>, max_range: f64) -> Option<f64> {
        if let Some(p) = &self.contamination {
            return self
                .contaminated_cast(p, dir, max_range, false)
                .map(|h| h.range);
        }
        self.cast_wall(dir, max_range)
    }

    /// The wall's range along `dir`, contamination aside.
    fn cast_wall(&self, dir: &Vector3<f64>, max_range: f64) -> Option<f64> {
        let ray = Ray::new(DVec3::ZERO, to_glam(dir));
        match &self.wall {
            Wall::Exact(c) => c.cast_ray(&self.pose, &ray, max_range, false),
            Wall::Mesh(m) => m.cast_ray(&self.pose, &ray, max_range, false),
            Wall::Labeled(m) => m.mesh.cast_ray(&self.pose, &ray, max_range, false),
        }
    }

    /// [`Scene::cast`] with the wall normal, through parry's `cast_ray_and_get_normal`:
    /// the range (m) and the cosine of the incidence angle θ between the ray and the wall
    /// normal, cos θ = |d·n| ∈ [0, 1] (the gradient normal of the exact cylinder, the hit
    /// triangle's normal for a mesh).
    /// With a contamination, the first of the wall and its objects, with that surface's
    /// normal.
    pub fn cast_with_normal(&self, dir: &Vector3<f64>, max_range: f64) -> Option<(f64, f64)> {
        if let Some(p) = &self.contamination {
            let h = self.contaminated_cast(p, dir, max_range, true)?;
            let cos = (h.normal.dot(&p.to_pcs(dir)) / dir.norm()).abs().min(1.0);
            return Some((h.range, cos));
        }
        self.cast_wall_with_normal(dir, max_range)
    }

    /// The contaminated scene's first hit along `dir`, with its PCS normal if
    /// `with_normal` (else zero).
    fn contaminated_cast(
        &self,
        p: &Placed,
        dir: &Vector3<f64>,
        max_range: f64,
        with_normal: bool,
    ) -> Option<Hit> {
        p.cast(dir, max_range, with_normal, |limit| {
            if !with_normal {
                return self.cast_wall(dir, limit).map(|range| Hit {
                    range,
                    normal: Vector3::zeros(),
                });
            }
            let ray = Ray::new(DVec3::ZERO, to_glam(dir));
            let hit = match &self.wall {
                Wall::Exact(c) => c.cast_ray_and_get_normal(&self.pose, &ray, limit, false),
                Wall::Mesh(m) => m.cast_ray_and_get_normal(&self.pose, &ray, limit, false),
                Wall::Labeled(m) => m
                    .mesh
                    .cast_ray_and_get_normal(&self.pose, &ray, limit, false),
            }?;
            let n = Vector3::new(hit.normal.x, hit.normal.y, hit.normal.z);
            Some(Hit {
                range: hit.time_of_impact,
                normal: p.to_pcs(&n),
            })
        })
    }

    /// The wall's range and incidence along `dir`, contamination aside.
    fn cast_wall_with_normal(&self, dir: &Vector3<f64>, max_range: f64) -> Option<(f64, f64)> {
        let d = to_glam(dir);
        let ray = Ray::new(DVec3::ZERO, d);
        let hit = match &self.wall {
            Wall::Exact(c) => c.cast_ray_and_get_normal(&self.pose, &ray, max_range, false),
            Wall::Mesh(m) => m.cast_ray_and_get_normal(&self.pose, &ray, max_range, false),
            Wall::Labeled(m) => m
                .mesh
                .cast_ray_and_get_normal(&self.pose, &ray, max_range, false),
        }?;
        let cos = (hit.normal.dot(d) / d.length()).abs().min(1.0);
        Some((hit.time_of_impact, cos))
    }

    /// [`Scene::cast_with_normal`] with what the ray hit: (range (m), cos θ, part). The
    /// part is the hit triangle's label for a pipeline scene, and
    /// `Part { segment: 0, kind: Straight }` for a scene of one straight pipe (exact or
    /// meshed, or a custom mesh from [`Scene::with_mesh`]).
    pub fn cast_labeled(&self, dir: &Vector3<f64>, max_range: f64) -> Option<(f64, f64, Part)> {
        let Wall::Labeled(m) = &self.wall else {
            return self
                .cast_with_normal(dir, max_range)
                .map(|(r, c)| (r, c, ONE_PIPE));
        };
        let d = to_glam(dir);
        let ray = Ray::new(DVec3::ZERO, d);
        let hit = m
            .mesh
            .cast_ray_and_get_normal(&self.pose, &ray, max_range, false)?;
        let cos = (hit.normal.dot(d) / d.length()).abs().min(1.0);
        let part = *m.labels.get(hit.subshape as usize)?;
        Some((hit.time_of_impact, cos, part))
    }
}
