//! The exact first wall hit of a ray inside a pipeline, from the closed-form surfaces
//! (elliptic cylinders, `Torus::ray_crossings`, circular cylinders and joint planes)
//! clipped to their patches: an oracle for the mesh that shares nothing with it but the
//! segment frames (checked by hand in `frames_of_elbows_by_hand`).

#![allow(dead_code)]

use nalgebra::Vector3;
use tof_sim::{Part, PartKind, Pipeline, Segment, SegmentFrame};

/// The first hit: ray parameter (m, unit direction), the part, and the unit normal of the
/// exact surface there (PCS).
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f64,
    pub part: Part,
    pub normal: Vector3<f64>,
}

/// Both roots t of y²/a² + z²/b² = 1 along local o + t·d (none if parallel or missed).
fn ellipse_roots(a: f64, b: f64, o: &Vector3<f64>, d: &Vector3<f64>) -> [Option<f64>; 2] {
    let qa = (d.y / a).powi(2) + (d.z / b).powi(2);
    let qb = o.y * d.y / (a * a) + o.z * d.z / (b * b);
    let qc = (o.y / a).powi(2) + (o.z / b).powi(2) - 1.0;
    let disc = qb * qb - qa * qc;
    if qa <= 0.0 || disc < 0.0 {
        return [None, None];
    }
    let s = disc.sqrt();
    [Some((-qb - s) / qa), Some((-qb + s) / qa)]
}

/// The pipeline's exact wall, with its patches.
pub struct Exact {
    pub pipeline: Pipeline,
    pub frames: Vec<SegmentFrame>,
}

impl Exact {
    pub fn new(pipeline: &Pipeline) -> Self {
        Self {
            pipeline: pipeline.clone(),
            frames: pipeline.frames(),
        }
    }

    /// The first hit of the PCS ray o + t·d (d unit), t ∈ (0, t_max].
    pub fn first_hit(&self, o: &Vector3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        let p = &self.pipeline;
        let (a, b) = (p.d_max / 2.0, p.d_min / 2.0);
        let r = p.bend_tube_radius();
        let mut best: Option<Hit> = None;
        let mut offer = |t: f64, part: Part, normal: Vector3<f64>| {
            if t > 1e-12 && t <= t_max && best.is_none_or(|h| t < h.t) {
                best = Some(Hit { t, part, normal });
            }
        };
        let bends = p.bends();
        let branches = p.branches();
        for (k, seg) in p.segments.iter().enumerate() {
            let f = &self.frames[k];
            let ol = f.to_local(o);
            let dl = f.rotation.inverse() * d;
            let part = |kind| Part {
                segment: k as u16,
                kind,
            };
            match *seg {
                Segment::Straight { length } | Segment::Tee { length, .. } => {
                    for t in ellipse_roots(a, b, &ol, &dl).into_iter().flatten() {
                        let q = ol + dl * t;
                        if !(0.0..=length).contains(&q.x) {
                            continue;
                        }
                        if let Segment::Tee {
                            branch_diameter,
                            direction,
                            ..
                        } = *seg
                        {
                            // The opening: inside the branch cylinder, on its side.
                            let n = Vector3::new(0.0, direction.cos(), direction.sin());
                            let rel = q - Vector3::new(length / 2.0, 0.0, 0.0);
                            let off = rel - n * rel.dot(&n);
                            if rel.dot(&n) > 0.0 && off.norm() < branch_diameter / 2.0 {
                                continue;
                            }
                        }
                        let nl = Vector3::new(0.0, q.y / (a * a), q.z / (b * b)).normalize();
                        offer(t, part(PartKind::Straight), f.rotation * nl);
                    }
                }
                Segment::Bend { angle, .. } => {
                    let bt = bends.iter().find(|bt| bt.segment as usize == k).unwrap();
                    let c = bt.torus.ray_crossings(o, d, t_max);
                    for &t in c.as_slice() {
                        let q = o + d * t;
                        // The angle about the torus axis from the start radius.
                        let v = q - bt.torus.centre;
                        let out = (bt.start.origin - bt.torus.centre).normalize();
                        let th = v.dot(&bt.start.axis()).atan2(v.dot(&out));
                        if (0.0..=angle).contains(&th) {
                            let nrm = bt.torus.normal(&q).unwrap().into_inner();
                            offer(t, part(PartKind::Bend), nrm);
                            break;
                        }
                    }
                }
            }
            if let Segment::Tee { .. } = *seg {
                let br = branches.iter().find(|x| x.segment as usize == k).unwrap();
                let ax = br.axis.into_inner();
                let rb = br.diameter / 2.0;
                // |(o + t d − c) − ((o + t d − c)·ax) ax|² = rb².
                let oc = o - br.origin;
                let op = oc - ax * oc.dot(&ax);
                let dp = d - ax * d.dot(&ax);
                let qa = dp.norm_squared();
                let qb = op.dot(&dp);
                let qc = op.norm_squared() - rb * rb;
                let disc = qb * qb - qa * qc;
                if qa > 0.0 && disc >= 0.0 {
                    for t in [(-qb - disc.sqrt()) / qa, (-qb + disc.sqrt()) / qa] {
                        let q = o + d * t;
                        let w = (q - br.origin).dot(&ax);
                        let ql = f.to_local(&q);
                        let outside_main = (ql.y / a).powi(2) + (ql.z / b).powi(2) >= 1.0;
                        if w > 0.0 && w <= br.length && outside_main {
                            let rel = q - br.origin;
                            let nrm = (rel - ax * rel.dot(&ax)).normalize();
                            offer(t, part(PartKind::Branch), nrm);
                        }
                    }
                }
            }
        }
        // Joint steps of an oval pipe: the annulus between the ellipse and the circle in
        // the plane where a straight (or tee) meets a bend; labelled as the straight.
        if a != r || b != r {
            for k in 1..p.segments.len() {
                let (s0, s1) = (&p.segments[k - 1], &p.segments[k]);
                let bend0 = matches!(s0, Segment::Bend { .. });
                let bend1 = matches!(s1, Segment::Bend { .. });
                if bend0 == bend1 {
                    continue;
                }
                let straight = if bend0 { k } else { k - 1 };
                let f = &self.frames[k];
                let ol = f.to_local(o);
                let dl = f.rotation.inverse() * d;
                if dl.x == 0.0 {
                    continue;
                }
                let t = -ol.x / dl.x;
                let q = ol + dl * t;
                let in_ellipse = (q.y / a).powi(2) + (q.z / b).powi(2) < 1.0;
                let in_circle = q.y * q.y + q.z * q.z < r * r;
                if in_ellipse != in_circle {
                    offer(
                        t,
                        Part {
                            segment: straight as u16,
                            kind: PartKind::Straight,
                        },
                        f.axis(),
                    );
                }
            }
        }
        best
    }
}
