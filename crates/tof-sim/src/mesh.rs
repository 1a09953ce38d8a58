//! Triangle meshes of pipe walls: geometries without a closed-form ray cast (and a
//! cross-check of the exact shape).

use parry3d_f64::math::Vector;
use parry3d_f64::shape::TriMesh;

use crate::error::SimError;

/// The factor (1 + 1/cos(π/n))/2 by which the vertices of a closed ring of `n` segments
/// are pushed out from the curve, so that its chords straddle the curve: a circle of
/// radius R is then within −R(1 − cos(π/n))/2 … +R(1/cos(π/n) − 1)/2 of its polygon.
pub fn straddle_factor(n: usize) -> f64 {
    0.5 * (1.0 + 1.0 / (std::f64::consts::PI / n as f64).cos())
}

/// The inner wall of an elliptic cylinder (PCS: axis X, semi-axes `a` along Y and `b`
/// along Z) from x = `x0` to `x1`, tessellated with `segments` vertices around and
/// `rings` rings along (straight walls need 2). `radius_at(x, φ)` may perturb the
/// radius (a dent); `None` keeps the ellipse.
///
/// The vertices sit slightly outside the curve, by the factor (1 + 1/cos(π/n))/2, so the
/// flat facets straddle it: the radial error is ±½ of a chord's sagitta (about
/// ±R·π²/(4n²)) instead of 0…−R·π²/(2n²).
pub fn tube_mesh(
    a: f64,
    b: f64,
    x0: f64,
    x1: f64,
    segments: usize,
    rings: usize,
    deform: Option<&dyn Fn(f64, f64) -> f64>,
) -> Result<TriMesh, SimError> {
    if segments < 3 || rings < 2 || !(x1 > x0) {
        return Err(SimError::Mesh(format!(
            "need ≥ 3 segments, ≥ 2 rings and x1 > x0 (got {segments}, {rings}, {x0}..{x1})"
        )));
    }
    let straddle = straddle_factor(segments);
    let mut vertices = Vec::with_capacity(segments * rings);
    for r in 0..rings {
        let x = x0 + (x1 - x0) * r as f64 / (rings - 1) as f64;
        for s in 0..segments {
            let phi = std::f64::consts::TAU * s as f64 / segments as f64;
            let scale = straddle * deform.map_or(1.0, |f| f(x, phi));
            vertices.push(Vector::new(x, a * phi.cos() * scale, b * phi.sin() * scale));
        }
    }
    let mut indices = Vec::with_capacity(2 * segments * (rings - 1));
    for r in 0..rings - 1 {
        for s in 0..segments {
            let i0 = (r * segments + s) as u32;
            let i1 = (r * segments + (s + 1) % segments) as u32;
            let j0 = i0 + segments as u32;
            let j1 = i1 + segments as u32;
            indices.push([i0, i1, j1]);
            indices.push([i0, j1, j0]);
        }
    }
    TriMesh::new(vertices, indices).map_err(|e| SimError::Mesh(format!("{e:?}")))
}
