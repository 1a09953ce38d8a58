//! The pipe wall placed in the sensor frame, cast through parry's `Ray`/`RayCast`.

use epd_core::Params;
use nalgebra::{UnitQuaternion, Vector3};
use parry3d_f64::glamx::{DQuat, DVec3};
use parry3d_f64::math::Pose;
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::TriMesh;

use crate::elliptic_cylinder::EllipticCylinder;
use crate::error::SimError;
use crate::mesh::tube_mesh;
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
}

/// A pipe wall seen from the sensor: the geometry in the PCS and its pose in the SCS,
/// the inverse of eq. (3): x_S = Rᵀ(x_P − [0, δy, δz]).
pub struct Scene {
    wall: Wall,
    /// PCS → SCS.
    pose: Pose,
    /// The true β.
    truth: Params,
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
        })
    }

    /// A scene over a custom mesh of the wall given in the PCS (a dented pipe, an
    /// elbow…); `truth` places it and is reported with the frames.
    pub fn with_mesh(truth: &Params, mesh: TriMesh) -> Result<Self, SimError> {
        let mut s = Self::new(truth, WallModel::Exact, 1.0)?;
        s.wall = Wall::Mesh(Box::new(mesh));
        Ok(s)
    }

    /// The true β.
    pub fn truth(&self) -> &Params {
        &self.truth
    }

    /// Range (m) along the unit direction `dir` (SCS) from the sensor origin to the wall,
    /// up to `max_range`, through parry's `RayCast`.
    pub fn cast(&self, dir: &Vector3<f64>, max_range: f64) -> Option<f64> {
        let ray = Ray::new(DVec3::ZERO, to_glam(dir));
        match &self.wall {
            Wall::Exact(c) => c.cast_ray(&self.pose, &ray, max_range, false),
            Wall::Mesh(m) => m.cast_ray(&self.pose, &ray, max_range, false),
        }
    }

    /// [`Scene::cast`] with the wall normal, through parry's `cast_ray_and_get_normal`:
    /// the range (m) and the cosine of the incidence angle θ between the ray and the wall
    /// normal, cos θ = |d·n| ∈ [0, 1] (the gradient normal of the exact cylinder, the hit
    /// triangle's normal for a mesh).
    pub fn cast_with_normal(&self, dir: &Vector3<f64>, max_range: f64) -> Option<(f64, f64)> {
        let d = to_glam(dir);
        let ray = Ray::new(DVec3::ZERO, d);
        let hit = match &self.wall {
            Wall::Exact(c) => c.cast_ray_and_get_normal(&self.pose, &ray, max_range, false),
            Wall::Mesh(m) => m.cast_ray_and_get_normal(&self.pose, &ray, max_range, false),
        }?;
        let cos = (hit.normal.dot(d) / d.length()).abs().min(1.0);
        Some((hit.time_of_impact, cos))
    }
}
