//! Pipelines (straights, bends, tees) against independent oracles: segment frames by
//! hand, the meshed scene against the exact surfaces of `common/oracle.rs` (elliptic
//! cylinders, `epd_core::Torus::ray_crossings`, the branch cylinder) pixel by pixel, the
//! faceting error against its sagitta bound, the labels against the surface each point
//! lies on, and the labels' alignment through `retain_valid` and subsampling.

mod common;

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use common::oracle::Exact;
use epd_core::Params;
use nalgebra::{Matrix3, Point3, Vector3};
use tof_sim::{
    FrameSeed, MeshResolution, Noise, Part, PartKind, Pipeline, Scene, Segment, Sensor, SimError,
    Subsample, ToFPhysics, WallModel, simulate,
};

/// A 20" standard-wall pipe: OD 508 mm, wall 9.53 mm, ID 488.94 mm.
const ID_20IN: f64 = 0.508 - 2.0 * 0.00953;
/// A long-radius elbow's centreline radius: 1.5 × the nominal size (ASME B16.9), 762 mm.
const R_LONG: f64 = 1.5 * 0.508;

fn elbow(d_max: f64, d_min: f64, bend_x: f64, direction: f64) -> Pipeline {
    Pipeline::with_one_bend(
        d_max,
        d_min,
        -1.0,
        bend_x,
        Segment::Bend {
            radius: R_LONG,
            angle: FRAC_PI_2,
            direction,
        },
        6.0,
    )
}

fn pose(p: &Pipeline, roll: f64, pitch: f64, yaw: f64, dy: f64, dz: f64) -> Params {
    Params {
        d_max: p.d_max,
        d_min: p.d_min,
        roll,
        pitch,
        yaw,
        dy,
        dz,
    }
}

fn close(a: &Vector3<f64>, b: &Vector3<f64>) -> bool {
    (a - b).norm() < 1e-12
}

#[test]
fn frames_of_elbows_by_hand() {
    let r = R_LONG;
    // Right (toward +Y): the centre of curvature at (1, R, 0), the end at (1 + R, R, 0)
    // heading +Y; the frame turned 90° about +Z.
    let p = elbow(0.49, 0.48, 1.0, 0.0);
    p.validate().unwrap();
    let f = p.frames();
    assert_eq!(f.len(), 4);
    assert!(close(&f[0].origin, &Vector3::new(-1.0, 0.0, 0.0)));
    assert!(close(&f[1].origin, &Vector3::new(1.0, 0.0, 0.0)));
    assert!(close(&f[2].origin, &Vector3::new(1.0 + r, r, 0.0)));
    let want = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    assert!((f[2].rotation.matrix() - want).norm() < 1e-12);
    assert!(close(&f[3].origin, &Vector3::new(1.0 + r, r + 6.0, 0.0)));
    assert_eq!(p.straight_until(), Some(1.0));
    let b = p.first_bend().unwrap();
    assert_eq!((b.segment, b.radius, b.angle), (1, r, FRAC_PI_2));
    assert!(close(&b.torus.centre, &Vector3::new(1.0, r, 0.0)));
    assert!(close(&b.torus.axis, &Vector3::z()));
    assert_eq!(b.torus.minor_radius, 0.2425);
    // The end of the bend is at angle α about the axis, the start at 0.
    assert!((b.angle_of(&f[2].origin) - FRAC_PI_2).abs() < 1e-12);
    assert!(b.angle_of(&f[1].origin).abs() < 1e-12);

    // Up (toward +Z): the frame turns about −Y, the axis ends along +Z.
    let p = elbow(0.49, 0.48, 2.0, FRAC_PI_2);
    let f = p.frames();
    assert!(close(&f[2].origin, &Vector3::new(2.0 + r, 0.0, r)));
    assert!(close(&f[2].axis(), &Vector3::z()));
    // Local Z (the minor axis) now points back along −X; local Y stays +Y.
    assert!(close(&(f[2].rotation * Vector3::z()), &-Vector3::x()));
    assert!(close(&(f[2].rotation * Vector3::y()), &Vector3::y()));
    assert!(close(&p.first_bend().unwrap().torus.axis, &-Vector3::y()));

    // A 45° bend toward (0, cos 45°, sin 45°): axis cos α·X + sin α·n,
    // origin o + R(1 − cos α)·n + R sin α·X.
    let mut p = elbow(0.49, 0.48, 1.0, FRAC_PI_4);
    p.segments[1] = Segment::Bend {
        radius: r,
        angle: FRAC_PI_4,
        direction: FRAC_PI_4,
    };
    let f = p.frames();
    let n = Vector3::new(0.0, 1.0, 1.0).normalize();
    let c = FRAC_PI_4.cos();
    assert!(close(&f[2].axis(), &(Vector3::x() * c + n * c)));
    let o = Vector3::new(1.0, 0.0, 0.0) + n * (r * (1.0 - c)) + Vector3::x() * (r * c);
    assert!(close(&f[2].origin, &o));
    let b = p.first_bend().unwrap();
    assert!((b.angle_of(&o) - FRAC_PI_4).abs() < 1e-12);
    let out = (f[1].origin - b.torus.centre) / r;
    let mid = b.torus.centre + (out * (PI / 8.0).cos() + Vector3::x() * (PI / 8.0).sin()) * r;
    assert!((b.angle_of(&mid) - PI / 8.0).abs() < 1e-12);
    assert!(b.contains_angle(&mid) && !b.contains_angle(&f[3].origin));
    // Frames stay orthonormal and right-handed.
    let m = f[3].rotation.matrix();
    assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-12);
    assert!((m.determinant() - 1.0).abs() < 1e-12);

    // A tee first: the straight ends at the branch opening's near edge.
    let p = Pipeline {
        d_max: 0.49,
        d_min: 0.48,
        bend_diameter: None,
        start_x: -1.0,
        segments: vec![
            Segment::Straight { length: 1.5 },
            Segment::Tee {
                length: 1.2,
                branch_diameter: 0.3,
                direction: PI,
            },
            Segment::Bend {
                radius: r,
                angle: PI,
                direction: 0.0,
            },
        ],
    };
    p.validate().unwrap();
    assert_eq!(p.straight_until(), Some(0.5 + 0.6 - 0.15));
    assert_eq!(p.first_run_end(), 1.7);
    let br = p.branches()[0];
    assert!(close(&br.origin, &Vector3::new(1.1, 0.0, 0.0)));
    assert!(close(&br.axis, &-Vector3::y()));
    assert!((br.length - (0.245 + tof_sim::pipeline::BRANCH_LENGTH)).abs() < 1e-12);
    // No bend, no tee: the straight runs to the open end.
    let p = Pipeline {
        segments: vec![Segment::Straight { length: 3.0 }],
        ..p
    };
    assert_eq!(p.straight_until(), None);
}

fn field(e: SimError) -> String {
    e.to_string()
}

/// The whole message: the field, the refused value and the rule it breaks; a segment's
/// fields in checking order (a tee's direction before its branch and length).
#[test]
fn validation_says_the_value_and_the_rule() {
    let good = elbow(0.49, 0.48, 1.0, 0.0);
    let with = |f: &dyn Fn(&mut Pipeline)| {
        let mut p = good.clone();
        f(&mut p);
        field(p.validate().unwrap_err())
    };
    let seg = |s: Segment| with(&|p: &mut Pipeline| p.segments[1] = s);
    let tee = |length, branch_diameter, direction| Segment::Tee {
        length,
        branch_diameter,
        direction,
    };
    let bend = |radius, angle| Segment::Bend {
        radius,
        angle,
        direction: 0.0,
    };
    let invalid = "invalid `pipeline.";
    for (message, want) in [
        (
            with(&|p| p.d_min = 0.0),
            "d_min` = 0: must be a finite number > 0",
        ),
        (
            with(&|p| p.start_x = f64::INFINITY),
            "start_x` = inf: must be finite",
        ),
        (
            with(&|p| p.segments.clear()),
            "segments` = 0: must hold 1 to 65536 segments",
        ),
        (
            seg(bend(0.2, 1.0)),
            "segments[1].radius` = 0.2: must be finite and exceed every tube radius (bend and straight)",
        ),
        (
            seg(bend(1.0, 3.2)),
            "segments[1].angle` = 3.2: must lie in (0, π]",
        ),
        (
            seg(tee(1.0, 0.5, 0.0)),
            "segments[1].branch_diameter` = 0.5: must not exceed the main pipe's inner width across the branch",
        ),
        (
            seg(tee(1.0, 0.0, 0.0)),
            "segments[1].branch_diameter` = 0: must be a finite number > 0",
        ),
        (
            seg(tee(0.3, 0.4, 0.0)),
            "segments[1].length` = 0.3: must be finite and exceed the branch diameter",
        ),
        (
            seg(tee(0.3, 0.0, f64::NAN)),
            "segments[1].direction` = NaN: must be finite",
        ),
    ] {
        assert_eq!(message, format!("{invalid}{want}"));
    }
}

#[test]
fn validation_names_the_field() {
    let good = elbow(0.49, 0.48, 1.0, 0.0);
    let with = |f: &dyn Fn(&mut Pipeline)| {
        let mut p = good.clone();
        f(&mut p);
        field(p.validate().unwrap_err())
    };
    assert!(with(&|p| p.d_max = f64::NAN).contains("`pipeline.d_max`"));
    assert!(with(&|p| p.d_min = 0.0).contains("`pipeline.d_min`"));
    assert!(with(&|p| p.bend_diameter = Some(-1.0)).contains("`pipeline.bend_diameter`"));
    assert!(with(&|p| p.start_x = f64::INFINITY).contains("`pipeline.start_x`"));
    assert!(with(&|p| p.segments.clear()).contains("`pipeline.segments`"));
    let seg = |s: Segment| with(&|p: &mut Pipeline| p.segments[1] = s);
    let bend = |radius, angle, direction| Segment::Bend {
        radius,
        angle,
        direction,
    };
    assert!(seg(bend(0.2, 1.0, 0.0)).contains("`pipeline.segments[1].radius`"));
    assert!(seg(bend(f64::NAN, 1.0, 0.0)).contains("`pipeline.segments[1].radius`"));
    assert!(seg(bend(1.0, 0.0, 0.0)).contains("`pipeline.segments[1].angle`"));
    assert!(seg(bend(1.0, 3.2, 0.0)).contains("`pipeline.segments[1].angle`"));
    assert!(seg(bend(1.0, 1.0, f64::NAN)).contains("`pipeline.segments[1].direction`"));
    assert!(seg(Segment::Straight { length: -1.0 }).contains("`pipeline.segments[1].length`"));
    let tee = |length, branch_diameter, direction| Segment::Tee {
        length,
        branch_diameter,
        direction,
    };
    assert!(seg(tee(1.0, 0.5, 0.0)).contains("`pipeline.segments[1].branch_diameter`"));
    assert!(seg(tee(1.0, 0.0, 0.0)).contains("`pipeline.segments[1].branch_diameter`"));
    assert!(seg(tee(0.3, 0.4, 0.0)).contains("`pipeline.segments[1].length`"));
    assert!(seg(tee(1.0, 0.4, f64::NAN)).contains("`pipeline.segments[1].direction`"));
    // An equal tee of a round pipe is allowed; wider is not.
    let mut round = good.clone();
    round.d_min = round.d_max;
    round.segments[1] = tee(1.0, round.d_max, 0.3);
    round.validate().unwrap();

    let res = MeshResolution::default();
    let bad_res = |f: &dyn Fn(&mut MeshResolution)| {
        let mut r = res;
        f(&mut r);
        field(r.validate().unwrap_err())
    };
    assert!(bad_res(&|r| r.segments = 4).contains("`mesh.segments`"));
    assert!(bad_res(&|r| r.bend_step = 0.0).contains("`mesh.bend_step`"));
    assert!(bad_res(&|r| r.straight_ring_spacing = f64::NAN).contains("straight_ring_spacing"));
    assert!(bad_res(&|r| r.tee_ring_spacing = -1.0).contains("tee_ring_spacing"));
    let huge = MeshResolution {
        segments: 65536,
        bend_step: 1e-5,
        ..res
    };
    assert!(matches!(good.mesh(&huge), Err(SimError::Mesh(_))));

    // The scene: diameters must match, the sensor must be in the first straight.
    let t = pose(&good, 0.0, 0.0, 0.0, 0.0, 0.0);
    let e = Scene::pipeline(&Params { d_max: 0.5, ..t }, &good, &res);
    assert!(field(e.err().unwrap()).contains("pipeline.d_max/d_min"));
    let mut behind = good.clone();
    behind.start_x = 0.5;
    behind.segments[0] = Segment::Straight { length: 0.5 };
    assert!(field(Scene::pipeline(&t, &behind, &res).err().unwrap()).contains("pipeline.start_x"));
    let mut bend_first = good.clone();
    bend_first.segments.remove(0);
    assert!(
        field(Scene::pipeline(&t, &bend_first, &res).err().unwrap()).contains("pipeline.start_x")
    );
    let outside = Params { dy: 0.3, ..t };
    assert!(Scene::pipeline(&outside, &good, &res).is_err());
}

/// Mesh against exact surfaces over every pixel of the Helios2 frame, ranges ≤ 6 m.
struct Comparison {
    /// Largest |Δt|·cos θ (m): the error along the wall normal.
    worst_normal: f64,
    /// Largest |Δt| (m).
    worst_range: f64,
    /// Largest |Δt| (m) over rays with cos θ ≥ 0.018 (incidence ≤ 89°).
    worst_range_below_89deg: f64,
    /// Pixels where exactly one of the two finds a wall within 6 m.
    one_sided: usize,
    /// Pixels where both hit but on differently labelled parts.
    label_differs: usize,
    /// Pixels compared.
    compared: usize,
    /// Pixels with |Δt| > 0.1 mm.
    above_100um: usize,
    /// Pixels with |Δt| > 1 mm.
    above_1mm: usize,
    /// Per-pixel |Δt|·cos θ ≤ bound(part) × 1.05 + 1 nm failures.
    over_bound: usize,
}

fn compare(scene: &Scene, truth: &Params, p: &Pipeline, bound: &dyn Fn(Part) -> f64) -> Comparison {
    let ex = Exact::new(p);
    let s = Sensor::helios2();
    let o = truth.scs_to_pcs(&Point3::origin()).coords;
    let mut c = Comparison {
        worst_normal: 0.0,
        worst_range: 0.0,
        worst_range_below_89deg: 0.0,
        one_sided: 0,
        label_differs: 0,
        compared: 0,
        above_100um: 0,
        above_1mm: 0,
        over_bound: 0,
    };
    for v in 0..s.height {
        for u in 0..s.width {
            let d = s.ray_direction(u, v);
            let dp = truth.dir_scs_to_pcs(&d);
            match (scene.cast_labeled(&d, 8.0), ex.first_hit(&o, &dp, 8.0)) {
                (Some((tm, _, part)), Some(h)) => {
                    if h.t > 6.0 && tm > 6.0 {
                        continue;
                    }
                    c.compared += 1;
                    let dt = (tm - h.t).abs();
                    let cos = h.normal.dot(&dp).abs();
                    c.worst_range = c.worst_range.max(dt);
                    c.worst_normal = c.worst_normal.max(dt * cos);
                    if cos >= 0.018 {
                        c.worst_range_below_89deg = c.worst_range_below_89deg.max(dt);
                    }
                    c.above_100um += usize::from(dt > 1e-4);
                    c.above_1mm += usize::from(dt > 1e-3);
                    c.over_bound += usize::from(dt * cos > bound(h.part) * 1.05 + 1e-9);
                    c.label_differs += usize::from(part != h.part);
                }
                (None, None) => {}
                (m, e) => {
                    let near = m.map_or(f64::INFINITY, |x| x.0);
                    let exact = e.map_or(f64::INFINITY, |x| x.t);
                    if near.min(exact) <= 6.0 {
                        c.one_sided += 1;
                    }
                }
            }
        }
    }
    c
}

/// The faceting error of the default mesh in a 20" standard-wall pipe (ID 488.9 mm) with
/// a 90° long-radius elbow (R = 762 mm) 1 m ahead, for three sensor poses: against the
/// exact elliptic cylinder and `Torus::ray_crossings` pixel by pixel, every range
/// difference times cos θ stays within the sagitta bound e of
/// `MeshResolution::faceting_bound` (1.77 µm: 0.57 µm around, 1.20 µm along the bend),
/// hence |Δt| ≤ e/cos θ < 0.1 mm wherever cos θ ≥ 0.018; labels agree everywhere.
/// A sensor inside a bend: the mesh re-expressed in the centreline frame θ into the
/// bend (`LabeledMesh::express_in`), cast from there. Mapped back (x = o + R·x_local),
/// every bend hit lies on the exact torus within the faceting bound, and straight hits
/// on the straight after it or before it; the sensor's own frame sees the tube around it.
#[test]
fn a_sensor_inside_a_bend_sees_the_torus() {
    let p = elbow(ID_20IN, ID_20IN, 0.5, 0.4);
    let bend = p.first_bend().unwrap();
    let theta = 0.6;
    let mut partial = p.segments[1];
    if let Segment::Bend { angle, .. } = &mut partial {
        *angle = theta;
    }
    let at = bend.start.after(&partial);
    let mut mesh = p.mesh(&MeshResolution::default()).unwrap();
    mesh.express_in(&at);
    let truth = pose(&p, 0.3, 0.0, 0.0, 0.01, -0.02);
    let scene = Scene::with_labeled_mesh(&truth, mesh).unwrap();
    let seed = FrameSeed {
        seed: 1,
        trial: 0,
        sweep_index: 0,
    };
    let f = simulate(
        &Sensor::helios2(),
        &scene,
        &Noise::none(),
        Subsample::All,
        seed,
    )
    .unwrap();
    let tol =
        MeshResolution::default().faceting_bound(p.bend_tube_radius(), R_LONG, FRAC_PI_2) + 1e-9;
    let (mut n_bend, mut n_straight) = (0, 0);
    for (e, part) in f.exact.iter().zip(&f.part) {
        let Some(part) = part else { continue };
        let local = truth.scs_to_pcs(&Point3::new(e[0], e[1], e[2]));
        let q = at.to_pcs(&local.coords);
        match part.kind {
            PartKind::Bend => {
                let d = bend.torus.signed_distance(&q).abs();
                assert!(d <= tol, "bend hit {q:?} off the torus by {d}");
                n_bend += 1;
            }
            PartKind::Straight => {
                // After the bend: on its end frame's cylinder, beyond its end plane.
                let l = bend.end.to_local(&q);
                let r = (l.y * l.y + l.z * l.z).sqrt();
                assert!(l.x >= -1e-9, "straight hit behind the bend's end: {l:?}");
                assert!(
                    (r - ID_20IN / 2.0).abs() <= tol,
                    "straight hit at radius {r}"
                );
                n_straight += 1;
            }
            PartKind::Branch => panic!("no branch in an elbow"),
        }
    }
    assert!(
        n_bend > 50_000 && n_straight > 1_000,
        "{n_bend} bend, {n_straight} straight hits"
    );
}

#[test]
fn bend_faceting_error_within_the_sagitta_bound() {
    let p = elbow(ID_20IN, ID_20IN, 1.0, 0.0);
    let res = MeshResolution::default();
    let r = p.bend_tube_radius();
    let e_bend = res.faceting_bound(r, R_LONG, FRAC_PI_2);
    let e_straight = res.faceting_bound(r, f64::INFINITY, 0.0);
    assert!(
        (e_bend - 1.773e-6).abs() < 1e-9 && e_straight < 0.6e-6,
        "{e_bend}"
    );
    // One bound for every part: the joint slivers carry the bend's straddle offset.
    let bound = |_: Part| e_bend;
    for truth in [
        pose(&p, 0.0, 0.0, 0.0, 0.0, 0.0),
        pose(&p, 0.7, 0.03, -0.04, 0.03, -0.02),
        pose(&p, -2.0, -0.06, 0.05, -0.04, 0.05),
    ] {
        let t0 = std::time::Instant::now();
        let scene = Scene::pipeline(&truth, &p, &res).unwrap();
        let build = t0.elapsed();
        let c = compare(&scene, &truth, &p, &bound);
        eprintln!(
            "mesh built in {build:.2?}; {} pixels: max |Δt| {:.2} µm (at incidence ≤ 89°: {:.2} µm), \
             max |Δt|·cos θ {:.3} µm (bound {:.3} µm), > 0.1 mm: {}, one-sided {}, labels differ {}",
            c.compared,
            c.worst_range * 1e6,
            c.worst_range_below_89deg * 1e6,
            c.worst_normal * 1e6,
            e_bend * 1e6,
            c.above_100um,
            c.one_sided,
            c.label_differs
        );
        assert!(c.compared > 300_000);
        assert_eq!(c.over_bound, 0);
        assert!(c.worst_range_below_89deg < 1e-4);
        assert_eq!((c.one_sided, c.label_differs), (0, 0));
        // Only rays within a fraction of a degree of grazing exceed 0.1 mm.
        assert!(c.above_100um <= 10, "{}", c.above_100um);
    }
}

/// A coarse mesh must fail the same bound check: the comparison can fail.
#[test]
fn a_coarse_mesh_exceeds_the_fine_bound() {
    let p = elbow(ID_20IN, ID_20IN, 1.0, 0.0);
    let truth = pose(&p, 0.0, 0.0, 0.0, 0.0, 0.0);
    let fine = MeshResolution::default();
    let coarse = MeshResolution {
        segments: 64,
        bend_step: 0.05,
        ..fine
    };
    let scene = Scene::pipeline(&truth, &p, &coarse).unwrap();
    let e_fine = fine.faceting_bound(p.bend_tube_radius(), R_LONG, FRAC_PI_2);
    let c = compare(&scene, &truth, &p, &|_| e_fine);
    assert!(c.over_bound > 1000, "{}", c.over_bound);
    // …but keeps to its own bound (148 µm around, 157 µm along), except at a few
    // silhouette pixels where the ray grazes the wall and the polygon and the torus
    // occlude differently (16 of 307 200 here).
    let e = coarse.faceting_bound(p.bend_tube_radius(), R_LONG, FRAC_PI_2);
    let c = compare(&scene, &truth, &p, &|_| e);
    assert!(c.over_bound < 50, "{}", c.over_bound);
}

/// Every point of a noise-free labelled frame lies on the surface its label names: bend
/// points on the torus, straight points on their elliptic cylinder (or on the joint
/// step of the oval pipe), branch points on the branch cylinder — within the faceting
/// bound along the normal.
#[test]
fn labels_name_the_surface_each_point_lies_on() {
    let id = 0.484;
    let (d_max, d_min) = (id * 1.01, id * 0.99);
    let res = MeshResolution::default();
    let tee_first = Pipeline {
        d_max,
        d_min,
        bend_diameter: None,
        start_x: -1.0,
        segments: vec![
            Segment::Straight { length: 1.8 },
            Segment::Tee {
                length: 1.2,
                branch_diameter: 0.3,
                direction: 1.2,
            },
            Segment::Straight { length: 0.5 },
            Segment::Bend {
                radius: R_LONG,
                angle: FRAC_PI_2,
                direction: -2.0,
            },
            Segment::Straight { length: 4.0 },
        ],
    };
    for (p, truth) in [
        (
            elbow(d_max, d_min, 1.0, 0.0),
            pose(&elbow(d_max, d_min, 1.0, 0.0), 0.4, 0.02, 0.03, 0.02, -0.03),
        ),
        (
            tee_first.clone(),
            pose(&tee_first, -0.3, -0.02, 0.04, -0.03, 0.01),
        ),
    ] {
        let scene = Scene::pipeline(&truth, &p, &res).unwrap();
        let f = simulate(
            &Sensor::helios2(),
            &scene,
            &Noise::none(),
            Subsample::All,
            FrameSeed::default(),
        )
        .unwrap();
        assert_eq!(f.part.len(), f.len());
        let frames = p.frames();
        let bends = p.bends();
        let branches = p.branches();
        let (a, b, r) = (d_max / 2.0, d_min / 2.0, p.bend_tube_radius());
        let e = 1.05 * res.faceting_bound(a.max(b), R_LONG, FRAC_PI_2) * (a / b).powi(2) + 1e-9;
        let mut counts = std::collections::BTreeMap::new();
        let mut steps = 0;
        for i in 0..f.len() {
            let part = f.part[i].unwrap();
            *counts.entry(part).or_insert(0usize) += 1;
            let x = truth
                .scs_to_pcs(&Point3::from(Vector3::from(f.exact[i])))
                .coords;
            let k = part.segment as usize;
            match part.kind {
                PartKind::Bend => {
                    let bt = bends.iter().find(|t| t.segment == part.segment).unwrap();
                    let sd = bt.torus.signed_distance(&x);
                    assert!(sd.abs() <= e, "bend point {x:?} off the torus by {sd}");
                    let th = bt.angle_of(&x);
                    assert!((-1e-6..=bt.angle + 1e-6).contains(&th), "{th}");
                }
                PartKind::Straight => {
                    let l = frames[k].to_local(&x);
                    let len = (frames[k + 1].origin - frames[k].origin).norm();
                    assert!(l.x > -1e-9 && l.x < len + 1e-9, "{l:?} outside [0, {len}]");
                    // Distance to the ellipse along its normal, to first order.
                    let g = (l.y / a).powi(2) + (l.z / b).powi(2) - 1.0;
                    let grad = 2.0 * ((l.y / (a * a)).powi(2) + (l.z / (b * b)).powi(2)).sqrt();
                    let off = g / grad;
                    if off.abs() > e {
                        // The joint step: in a joint plane, between ellipse and circle.
                        let at_end = l.x.abs() < 1e-6 || (l.x - len).abs() < 1e-6;
                        let rad = l.y.hypot(l.z);
                        let between = (g > 0.0) != (rad > r);
                        assert!(at_end && between, "straight point {l:?} off by {off}");
                        steps += 1;
                    }
                }
                PartKind::Branch => {
                    let br = branches.iter().find(|t| t.segment == part.segment).unwrap();
                    let rel = x - br.origin;
                    let w = rel.dot(&br.axis);
                    let off = (rel - br.axis.into_inner() * w).norm() - br.diameter / 2.0;
                    assert!(off.abs() <= e, "branch point off the cylinder by {off}");
                    assert!(w > 0.0 && w <= br.length + 1e-9);
                    let l = frames[k].to_local(&x);
                    assert!((l.y / a).powi(2) + (l.z / b).powi(2) > 1.0 - 1e-6);
                }
            }
        }
        eprintln!("points per part: {counts:?}; on joint steps: {steps}");
        // Every kind of wall of each pipeline is seen.
        let kinds: std::collections::BTreeSet<_> = counts.keys().map(|p| p.kind).collect();
        assert!(kinds.contains(&PartKind::Straight) && kinds.contains(&PartKind::Bend));
        if p.segments.len() > 3 {
            assert!(kinds.contains(&PartKind::Branch));
        }
    }
}

/// The tee against the exact union of the two cylinders: the mesh's opening is jagged by
/// at most one cell, so only rays through a rim of about `tee_ring_spacing` around the
/// opening see the main wall where the exact branch begins. Measured and bounded here.
#[test]
fn tee_seam_is_small() {
    let id = 0.484;
    let p = Pipeline {
        d_max: id,
        d_min: id,
        bend_diameter: None,
        start_x: -1.0,
        segments: vec![
            Segment::Straight { length: 1.5 },
            Segment::Tee {
                length: 1.0,
                branch_diameter: 0.3,
                direction: FRAC_PI_2,
            },
            Segment::Straight { length: 5.0 },
        ],
    };
    let truth = pose(&p, 0.0, 0.0, 0.0, 0.0, 0.0);
    let res = MeshResolution::default();
    let scene = Scene::pipeline(&truth, &p, &res).unwrap();
    let e = res.faceting_bound(id / 2.0, f64::INFINITY, 0.0);
    let c = compare(&scene, &truth, &p, &|_| e);
    eprintln!(
        "tee: {} pixels, > 1 mm: {}, labels differ: {}, one-sided {}, max |Δt|·cos θ {:.3} µm, \
         per-pixel bound failures {}",
        c.compared,
        c.above_1mm,
        c.label_differs,
        c.one_sided,
        c.worst_normal * 1e6,
        c.over_bound
    );
    assert!(c.compared > 300_000);
    assert_eq!(c.one_sided, 0);
    // The rim: a band ≲ 2 mm wide along the ≈ 1 m opening edge, seen from ≥ 1.3 m.
    assert!(
        c.label_differs < 400 && c.above_1mm < 400,
        "{}",
        c.label_differs
    );
}

/// Labels stay with their points through `retain_valid` and subsampling, with the
/// physical model (invalid pixels: `None` if no wall, else the wall's part), and frames
/// of scenes without labels carry none.
#[test]
fn frames_keep_parts_aligned() {
    // The bend 4 m ahead: the walls beyond ≈ 3.7 m are too dark (invalid pixels).
    let p = elbow(0.49, 0.48, 4.0, 0.3);
    let truth = pose(&p, 0.2, 0.01, -0.02, 0.01, 0.02);
    let scene = Scene::pipeline(&truth, &p, &MeshResolution::default()).unwrap();
    assert!(scene.is_labeled());
    let s = Sensor::helios2();
    let noise = Noise {
        physics: Some(ToFPhysics::helios2()),
        ..Noise::range(0.0)
    };
    let seeds = FrameSeed {
        seed: 3,
        trial: 1,
        sweep_index: 0,
    };
    let full = simulate(&s, &scene, &noise, Subsample::All, seeds).unwrap();
    assert_eq!(full.part.len(), full.len());
    let check = |f: &tof_sim::Frame| {
        for i in 0..f.len() {
            let d = Vector3::from(f.directions[i]);
            let want = scene.cast_labeled(&d, 100.0).map(|h| h.2);
            assert_eq!(f.part[i], want, "point {i}");
        }
    };
    check(&full);
    let invalid = (0..full.len()).filter(|&i| !full.is_valid(i)).count();
    assert!(invalid > 100, "{invalid}");
    let mut valid = full.clone();
    valid.retain_valid();
    assert_eq!(valid.part.len(), valid.len());
    assert_eq!(valid.len(), full.len() - invalid);
    check(&valid);
    let sub = simulate(&s, &scene, &noise, Subsample::Points(5000), seeds).unwrap();
    assert_eq!((sub.len(), sub.part.len()), (5000, 5000));
    check(&sub);
    // The physical model runs: valid points have intensities and σ.
    assert!((0..valid.len()).all(|i| valid.intensity[i] > 0.0 && valid.sigma[i] > 0.0));
    // Reusing a labelled frame's buffers for an unlabelled scene drops the labels.
    let plain = Scene::new(&truth, WallModel::Exact, 6.0).unwrap();
    assert!(!plain.is_labeled());
    let mut f = full;
    tof_sim::simulate_into(&s, &plain, &noise, Subsample::All, seeds, &mut f).unwrap();
    assert!(f.part.is_empty());
    assert_eq!(
        plain
            .cast_labeled(&Vector3::new(1.0, 0.3, 0.0).normalize(), 6.0)
            .map(|h| h.2),
        Some(Part {
            segment: 0,
            kind: PartKind::Straight
        })
    );
}
