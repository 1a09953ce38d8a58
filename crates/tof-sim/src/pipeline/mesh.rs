//! The labelled triangle mesh of a [`Pipeline`] for the ray caster: how finely it is
//! tessellated ([`MeshResolution`], with its faceting bound), the mesh with a [`Part`]
//! per triangle ([`LabeledMesh`]), and the rings of straights, bends and tees.

use std::f64::consts::{PI, TAU};

use nalgebra::{Rotation3, Unit, UnitQuaternion, Vector3};
use parry3d_f64::glamx::{DQuat, DVec3};
use parry3d_f64::math::Pose;
use parry3d_f64::math::Vector;
use parry3d_f64::shape::TriMesh;

use super::{BRANCH_LENGTH, Part, PartKind, Pipeline, Segment, SegmentFrame};
use crate::error::SimError;
use crate::mesh::straddle_factor;

/// How finely [`Pipeline::mesh`] tessellates. Radial faceting error (see
/// [`MeshResolution::faceting_bound`]): ±½ sagitta around every cross-section and ±½
/// sagitta along the bends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshResolution {
    /// Vertices around every cross-section (straights, bends, branches), ≥ 8.
    pub segments: usize,
    /// Largest angle (rad) between two rings of a bend, in (0, 0.1].
    pub bend_step: f64,
    /// Largest distance (m) between two rings of a straight or a branch. Straight walls
    /// are exact with two rings; shorter triangles only keep the ray cast's bounding
    /// volumes tight.
    pub straight_ring_spacing: f64,
    /// Largest distance (m) between two rings of a tee's main run across the branch
    /// opening: the opening's edge is jagged by up to one such cell.
    pub tee_ring_spacing: f64,
}

impl Default for MeshResolution {
    /// 1024 segments around, 0.25° between bend rings, 0.1 m rings along straights,
    /// 2 mm across tee openings. In a 20" pipe (r = 244 mm) with a 90° 1.5·D elbow
    /// (R = 762 mm) and 8 m of straights: 0.9 M triangles, built in 0.55 s (peak 0.56 GB),
    /// a 640×480 frame cast in 0.25–0.32 s on 2 cores; error along the wall normal
    /// ≤ 1.77 µm (the [`MeshResolution::faceting_bound`]), so range errors ≤ 0.1 mm
    /// wherever the incidence is below 89° — measured over whole frames: median 0.9 µm,
    /// 99.99 % below 19 µm, at most 2 pixels of 307 200 above 0.1 mm (grazing rays,
    /// cos θ < 0.008). See `tests/pipeline.rs`.
    fn default() -> Self {
        Self {
            segments: 1024,
            bend_step: 0.25f64.to_radians(),
            straight_ring_spacing: 0.1,
            tee_ring_spacing: 0.002,
        }
    }
}

impl MeshResolution {
    /// 2048 segments around and 0.125° between bend rings: a quarter of the default's
    /// faceting error (0.44 µm in the 20" pipe with a 1.5·D bend) for 3.6× the triangles
    /// (3.3 M for a 90° elbow with 8 m of straights: built in 2 s, 1.8 GB at peak).
    pub fn fine() -> Self {
        Self {
            segments: 2048,
            bend_step: 0.125f64.to_radians(),
            ..Self::default()
        }
    }

    /// Check every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SimError> {
        if !(8..=1 << 16).contains(&self.segments) {
            return Err(SimError::invalid(
                "mesh.segments",
                self.segments,
                "must lie in [8, 65536]",
            ));
        }
        if !(self.bend_step > 0.0 && self.bend_step <= 0.1) {
            return Err(SimError::invalid(
                "mesh.bend_step",
                self.bend_step,
                "must lie in (0, 0.1] rad",
            ));
        }
        if !(self.straight_ring_spacing > 0.0 && self.straight_ring_spacing.is_finite()) {
            return Err(SimError::invalid(
                "mesh.straight_ring_spacing",
                self.straight_ring_spacing,
                "must be a finite number > 0",
            ));
        }
        if !(self.tee_ring_spacing > 0.0 && self.tee_ring_spacing.is_finite()) {
            return Err(SimError::invalid(
                "mesh.tee_ring_spacing",
                self.tee_ring_spacing,
                "must be a finite number > 0",
            ));
        }
        Ok(())
    }

    /// Bound (m) on the distance between the mesh and the exact wall of a bend of
    /// centreline radius `bend_radius` and tube radius `r` (straights: `bend_radius` =
    /// ∞ gives the first term only), measured along the wall normal:
    ///
    /// e = r·(1/cos(π/n) − 1)/2 + (R + r)·(1/cos(Δθ/2) − 1)/2,
    ///
    /// n = `segments`, Δθ the bend's ring step (at most `bend_step`). Around a
    /// cross-section the vertices sit at r·(1 + 1/cos(π/n))/2, so the flat facets
    /// straddle the circle: they lie within −r(1 − cos(π/n))/2 … +r(1/cos(π/n) − 1)/2 of
    /// it. Along a bend, the vertices are pushed away from the torus axis by the same
    /// factor for the ring step, so the chords of every circle of radius ρ ≤ R + r about
    /// the axis straddle it likewise. The two errors add at worst. (An ellipse's
    /// tessellation by its parameter angle has the circle's error scaled by at most
    /// (a/b)²: use the larger semi-axis for r.)
    pub fn faceting_bound(&self, r: f64, bend_radius: f64, bend_angle: f64) -> f64 {
        let n = self.segments as f64;
        let around = r * (1.0 / (PI / n).cos() - 1.0) / 2.0;
        if !bend_radius.is_finite() {
            return around;
        }
        let step = bend_angle / (bend_angle / self.bend_step).ceil().max(1.0);
        around + (bend_radius + r) * (1.0 / (step / 2.0).cos() - 1.0) / 2.0
    }
}

/// A triangle mesh of walls with a [`Part`] label per triangle: `labels[i]` is the part
/// of triangle i (parry's sub-shape id of a ray hit).
pub struct LabeledMesh {
    /// The mesh (in the PCS for [`Pipeline::mesh`]).
    pub mesh: TriMesh,
    /// One label per triangle.
    pub labels: Vec<Part>,
}

impl LabeledMesh {
    /// Re-express the mesh in the local coordinates of `frame` (given in the mesh's
    /// current coordinates): every vertex p becomes Rᵀ·(p − o), with o and R the frame's
    /// origin and rotation ([`SegmentFrame::to_local`]). A sensor placed at the origin of
    /// the result looks along the frame's X, e.g. from inside a bend:
    /// `SegmentFrame::after(&Segment::Bend { angle: θ, .. })` is the centreline frame θ
    /// into it. Labels are unchanged.
    pub fn express_in(&mut self, frame: &SegmentFrame) {
        let q = UnitQuaternion::from_rotation_matrix(&frame.rotation).inverse();
        let t = -(q * frame.origin);
        let pose = Pose::from_parts(
            DVec3::new(t.x, t.y, t.z),
            DQuat::from_xyzw(q.i, q.j, q.k, q.w),
        );
        self.mesh.transform_vertices(&pose);
    }
}

impl Pipeline {
    /// The labelled triangle mesh of the whole pipeline, in the PCS.
    ///
    /// - Straights: rings of `res.segments` vertices at the ellipse's parameter angles
    ///   φ_j = 2πj/n, (a cos φ_j, b sin φ_j) scaled by (1 + 1/cos(π/n))/2 as
    ///   [`crate::mesh::tube_mesh`] does, every `straight_ring_spacing` along.
    /// - Bends: rings of the circle of radius r at the same angles (so ring vertex j of a
    ///   bend and of the straight it joins lie in the same direction), at arc angles
    ///   θ_i = iα/N, N = ⌈α/`bend_step`⌉, each vertex pushed away from the torus axis by
    ///   (1 + 1/cos(Δθ/2))/2 (see [`MeshResolution::faceting_bound`]); the rings stay in
    ///   their planes.
    /// - Joints: consecutive straights share their ring; a ring of a straight and of a bend
    ///   (or of two bends) in the same joint plane are joined by a flat strip of triangles in
    ///   that plane, so the mesh is closed: for an oval pipe it is the step from the ellipse
    ///   to the circle, up to |d_max − d_bend|/2 wide (labelled as the straight or tee it
    ///   adjoins, the earlier bend between two bends); for a round pipe it is a sliver of
    ///   the straddle offsets (µm).
    /// - Tees: the main run has rings every `tee_ring_spacing` over the opening and drops
    ///   every triangle whose three vertices lie in the branch footprint (the main wall
    ///   inside the branch cylinder); the branch tube starts on the exact intersection curve
    ///   of the two cylinders and runs to its open end. Kept triangles with a vertex inside
    ///   the footprint overlap the opening by less than one cell (≈ `tee_ring_spacing` ×
    ///   2πa/n): rays through that rim hit the main wall (labelled Straight) instead of
    ///   entering the branch. Nothing is left open between the two.
    pub fn mesh(&self, res: &MeshResolution) -> Result<LabeledMesh, SimError> {
        self.validate()?;
        res.validate()?;
        self.check_mesh_size(res)?;
        let frames = self.frames();
        let n = res.segments;
        let rings = Rings {
            res,
            angles: (0..n)
                .map(|j| {
                    let phi = TAU * j as f64 / n as f64;
                    (phi.cos(), phi.sin())
                })
                .collect(),
            st: straddle_factor(n),
            a: self.d_max / 2.0,
            b: self.d_min / 2.0,
            r: self.bend_tube_radius(),
        };
        let mut m = Builder::default();
        // The previous segment's last ring and its label; `true` if it is an ellipse ring
        // (straight or tee) that the next straight may share.
        let mut prev: Option<(Vec<u32>, Part, bool)> = None;
        for (k, seg) in self.segments.iter().enumerate() {
            let (f, segment) = (&frames[k], k as u16);
            prev = Some(match *seg {
                Segment::Straight { length } => {
                    rings.straight(&mut m, f, segment, length, prev.take())
                }
                Segment::Bend {
                    radius,
                    angle,
                    direction,
                } => rings.bend(&mut m, f, segment, (radius, angle, direction), prev.take()),
                Segment::Tee {
                    length,
                    branch_diameter,
                    direction,
                } => rings.tee(
                    &mut m,
                    f,
                    segment,
                    (length, branch_diameter, direction),
                    prev.take(),
                ),
            });
        }
        m.build()
    }

    /// Refuse meshes that would not fit in memory: building one peaks at about 0.6 kB a
    /// triangle (parry's bounding-volume tree included; 530 MB for 0.9 M measured), so
    /// at most 8·10⁶ triangles, estimated from the rings each segment will have.
    fn check_mesh_size(&self, res: &MeshResolution) -> Result<(), SimError> {
        let mut estimate = 0.0;
        for s in &self.segments {
            estimate += match *s {
                Segment::Straight { length } => length / res.straight_ring_spacing + 2.0,
                Segment::Bend { angle, .. } => angle / res.bend_step + 2.0,
                Segment::Tee {
                    length,
                    branch_diameter,
                    ..
                } => {
                    length / res.straight_ring_spacing
                        + branch_diameter / res.tee_ring_spacing
                        + (BRANCH_LENGTH + self.d_max.max(self.d_min)) / res.straight_ring_spacing
                        + 8.0
                }
            };
        }
        let triangles = estimate * 2.0 * res.segments as f64;
        if triangles > 8e6 {
            return Err(SimError::Mesh(format!(
                "about {triangles:.3e} triangles: coarsen the mesh resolution (at most 8e6)"
            )));
        }
        Ok(())
    }
}

/// What every segment's rings share in [`Pipeline::mesh`]: the resolution, the ring
/// angles φ_j = 2πj/n as (cos φ_j, sin φ_j), the straddle factor, the ellipse's
/// semi-axes a, b and the bend tube's radius r (m).
struct Rings<'a> {
    res: &'a MeshResolution,
    angles: Vec<(f64, f64)>,
    st: f64,
    a: f64,
    b: f64,
    r: f64,
}

/// The previous segment's last ring, its label, and whether it is an ellipse ring.
type Joint = Option<(Vec<u32>, Part, bool)>;

impl Rings<'_> {
    /// The straddled ellipse ring at local x of frame `f`.
    fn ellipse_ring(&self, m: &mut Builder, f: &SegmentFrame, x: f64) -> Vec<u32> {
        let (a, b, st) = (self.a, self.b, self.st);
        self.angles
            .iter()
            .map(|&(c, s)| m.vertex(&f.to_pcs(&Vector3::new(x, a * c * st, b * s * st))))
            .collect()
    }

    /// The first ellipse ring of a straight or tee: the previous ellipse ring itself, or
    /// a new one joined to a bend's ring by a strip labelled `straight` (the step belongs
    /// to this segment).
    fn first_ellipse_ring(
        &self,
        m: &mut Builder,
        f: &SegmentFrame,
        straight: Part,
        prev: Joint,
    ) -> Vec<u32> {
        match prev {
            Some((ring, _, true)) => ring,
            Some((ring, _, false)) => {
                let own = self.ellipse_ring(m, f, 0.0);
                m.strip(&ring, &own, straight);
                own
            }
            None => self.ellipse_ring(m, f, 0.0),
        }
    }

    /// A straight of `length`: ellipse rings every `straight_ring_spacing` or less.
    fn straight(
        &self,
        m: &mut Builder,
        f: &SegmentFrame,
        segment: u16,
        length: f64,
        prev: Joint,
    ) -> (Vec<u32>, Part, bool) {
        let straight = Part {
            segment,
            kind: PartKind::Straight,
        };
        let first = self.first_ellipse_ring(m, f, straight, prev);
        let rings = (length / self.res.straight_ring_spacing).ceil().max(1.0) as usize;
        let mut last = first;
        for i in 1..=rings {
            let ring = self.ellipse_ring(m, f, length * i as f64 / rings as f64);
            m.strip(&last, &ring, straight);
            last = ring;
        }
        (last, straight, true)
    }

    /// A bend (radius, angle, direction): circle rings at θ_i = iα/N, straddled about
    /// the torus axis.
    fn bend(
        &self,
        m: &mut Builder,
        f: &SegmentFrame,
        segment: u16,
        (radius, angle, direction): (f64, f64, f64),
        prev: Joint,
    ) -> (Vec<u32>, Part, bool) {
        let (r, st) = (self.r, self.st);
        let label = Part {
            segment,
            kind: PartKind::Bend,
        };
        let (c, _) = f.bend_centre_and_turn(radius, angle, direction);
        let nb = f.rotation * Vector3::new(0.0, direction.cos(), direction.sin());
        let axis = Unit::new_normalize(f.axis().cross(&nb));
        let steps = (angle / self.res.bend_step).ceil().max(1.0) as usize;
        let dtheta = angle / steps as f64;
        let ka = straddle_factor_for(dtheta);
        // Ring 0 in the start plane, straddled about the torus axis.
        let base: Vec<Vector3<f64>> = self
            .angles
            .iter()
            .map(|&(cs, sn)| {
                let p = f.to_pcs(&Vector3::new(0.0, r * cs * st, r * sn * st));
                let v = p - c;
                let h = v.dot(&axis);
                let radial = v - axis.into_inner() * h;
                radial * ka + axis.into_inner() * h
            })
            .collect();
        let ring_at = |m: &mut Builder, i: usize| -> Vec<u32> {
            let turn = Rotation3::from_axis_angle(&axis, dtheta * i as f64);
            base.iter().map(|v| m.vertex(&(c + turn * v))).collect()
        };
        let first = ring_at(m, 0);
        if let Some((ring, plabel, _)) = prev {
            // The step belongs to the straight (or the earlier bend) before.
            m.strip(&ring, &first, plabel);
        }
        let mut last = first;
        for i in 1..=steps {
            let ring = ring_at(m, i);
            m.strip(&last, &ring, label);
            last = ring;
        }
        (last, label, false)
    }

    /// A tee (length, branch diameter, direction): the main run with its opening, then
    /// the branch tube from the intersection curve to its open end.
    fn tee(
        &self,
        m: &mut Builder,
        f: &SegmentFrame,
        segment: u16,
        (length, branch_diameter, direction): (f64, f64, f64),
        prev: Joint,
    ) -> (Vec<u32>, Part, bool) {
        let (a, b, n, res) = (self.a, self.b, self.angles.len(), self.res);
        let straight = Part {
            segment,
            kind: PartKind::Straight,
        };
        let rb = branch_diameter / 2.0;
        let xc = 0.5 * length;
        let nvec = Vector3::new(0.0, direction.cos(), direction.sin());
        let u2 = Vector3::x().cross(&nvec);
        let first = self.first_ellipse_ring(m, f, straight, prev);
        // Ring positions: coarse, then fine over the opening, then coarse.
        let margin = 2.0 * res.tee_ring_spacing;
        let (w0, w1) = ((xc - rb - margin).max(0.0), (xc + rb + margin).min(length));
        let mut xs = Vec::new();
        push_range(&mut xs, 0.0, w0, res.straight_ring_spacing);
        push_range(&mut xs, w0, w1, res.tee_ring_spacing);
        push_range(&mut xs, w1, length, res.straight_ring_spacing);
        // Whether the exact wall point of ring vertex (x, j) is in the footprint.
        let inside = |x: f64, j: usize| {
            let (cs, sn) = self.angles[j];
            let p = Vector3::new(x - xc, a * cs, b * sn);
            p.dot(&nvec) > 0.0 && p.x * p.x + p.dot(&u2).powi(2) < rb * rb
        };
        let mut last = first;
        let mut last_x = 0.0;
        for &x in &xs[1..] {
            let ring = self.ellipse_ring(m, f, x);
            for s in 0..n {
                let s1 = (s + 1) % n;
                let (i0, i1, j0, j1) = (last[s], last[s1], ring[s], ring[s1]);
                let (a0, a1) = (inside(last_x, s), inside(last_x, s1));
                let (b0, b1) = (inside(x, s), inside(x, s1));
                if !(a0 && a1 && b1) {
                    m.triangle([i0, i1, j1], straight);
                }
                if !(a0 && b1 && b0) {
                    m.triangle([i0, j1, j0], straight);
                }
            }
            last = ring;
            last_x = x;
        }
        self.branch(m, f, segment, (xc, rb, nvec, u2));
        (last, straight, true)
    }

    /// A tee's branch tube: generators from the exact intersection curve of the two
    /// cylinders (centre at local x = `xc`, radius `rb`, outward normal `nvec`, `u2` =
    /// X × `nvec`) to the open end `BRANCH_LENGTH` beyond the main wall.
    fn branch(
        &self,
        m: &mut Builder,
        f: &SegmentFrame,
        segment: u16,
        (xc, rb, nvec, u2): (f64, f64, Vector3<f64>, Vector3<f64>),
    ) {
        let (a, b, st) = (self.a, self.b, self.st);
        let branch = Part {
            segment,
            kind: PartKind::Branch,
        };
        let reach = 1.0 / ((nvec.y / a).powi(2) + (nvec.z / b).powi(2)).sqrt();
        let w_end = reach + BRANCH_LENGTH;
        let qa = (nvec.y / a).powi(2) + (nvec.z / b).powi(2);
        let bottom: Vec<f64> = self
            .angles
            .iter()
            .map(|&(_, sn)| {
                // |w·n + ρ·u2| on the ellipse, ρ = r_b·st·sin ψ: the larger root.
                let rho = rb * st * sn;
                let qb = rho * (nvec.y * u2.y / (a * a) + nvec.z * u2.z / (b * b));
                let qc = rho * rho * ((u2.y / a).powi(2) + (u2.z / b).powi(2)) - 1.0;
                (-qb + (qb * qb - qa * qc).max(0.0).sqrt()) / qa
            })
            .collect();
        let min_bottom = bottom.iter().copied().fold(f64::INFINITY, f64::min);
        let rings = ((w_end - min_bottom) / self.res.straight_ring_spacing)
            .ceil()
            .max(1.0) as usize;
        let mut below: Option<Vec<u32>> = None;
        for i in 0..=rings {
            let t = i as f64 / rings as f64;
            let ring: Vec<u32> = self
                .angles
                .iter()
                .zip(&bottom)
                .map(|(&(cs, sn), &w0)| {
                    let w = w0 + (w_end - w0) * t;
                    let local = Vector3::new(xc, 0.0, 0.0)
                        + nvec * w
                        + (Vector3::x() * cs + u2 * sn) * (rb * st);
                    m.vertex(&f.to_pcs(&local))
                })
                .collect();
            if let Some(l) = &below {
                m.strip(l, &ring, branch);
            }
            below = Some(ring);
        }
    }
}

/// The straddle factor (1 + 1/cos(Δ/2))/2 for chords spanning the angle Δ.
fn straddle_factor_for(delta: f64) -> f64 {
    0.5 * (1.0 + 1.0 / (delta / 2.0).cos())
}

/// Append to `xs` the points of [from, to] spaced at most `step` apart, without `from`
/// if `xs` already ends there; `from` itself if `xs` is empty.
fn push_range(xs: &mut Vec<f64>, from: f64, to: f64, step: f64) {
    if xs.last() != Some(&from) {
        xs.push(from);
    }
    if to > from {
        let k = ((to - from) / step).ceil().max(1.0) as usize;
        for i in 1..=k {
            xs.push(if i == k {
                to
            } else {
                from + (to - from) * i as f64 / k as f64
            });
        }
    }
}

/// Vertices, triangles and their labels, collected segment by segment.
#[derive(Default)]
struct Builder {
    vertices: Vec<Vector>,
    indices: Vec<[u32; 3]>,
    labels: Vec<Part>,
}

impl Builder {
    fn vertex(&mut self, p: &Vector3<f64>) -> u32 {
        self.vertices.push(Vector::new(p.x, p.y, p.z));
        (self.vertices.len() - 1) as u32
    }

    fn triangle(&mut self, t: [u32; 3], label: Part) {
        self.indices.push(t);
        self.labels.push(label);
    }

    /// The band between two rings of the same vertex count, as tube_mesh orders it.
    fn strip(&mut self, a: &[u32], b: &[u32], label: Part) {
        let n = a.len();
        for s in 0..n {
            let s1 = (s + 1) % n;
            self.triangle([a[s], a[s1], b[s1]], label);
            self.triangle([a[s], b[s1], b[s]], label);
        }
    }

    fn build(self) -> Result<LabeledMesh, SimError> {
        if self.vertices.len() >= u32::MAX as usize {
            return Err(SimError::Mesh("more than 2³² vertices".into()));
        }
        let mesh = TriMesh::new(self.vertices, self.indices)
            .map_err(|e| SimError::Mesh(format!("{e:?}")))?;
        Ok(LabeledMesh {
            mesh,
            labels: self.labels,
        })
    }
}
