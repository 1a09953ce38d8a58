//! The contaminated scene ([`tof_sim::Contamination`]) against analytic intersections
//! written here anew in the PCS: a floor layer, a box and a half-cylinder on it, a dent,
//! a partial view.

use std::f64::consts::{PI, TAU};

use epd_core::Params;
use nalgebra::{Point3, Vector3};
use tof_sim::{
    Contamination, Dent, FloorLayer, Frame, FrameSeed, Noise, Obstacle, Pipe, PoseRanges, Scene,
    Sensor, SimError, Subsample, ToFPhysics, ViewSector, WallModel, simulate,
};

/// Two poses of the paper's ranges, pitch and yaw within ±3°.
fn truths() -> Vec<Params> {
    let r = PoseRanges {
        pitch: (-0.05, 0.05),
        yaw: (-0.05, 0.05),
        ..PoseRanges::default()
    };
    (0..2)
        .map(|k| r.sample(&Pipe::paper_20in(), 17, k).unwrap())
        .collect()
}

fn sensor() -> Sensor {
    Sensor {
        max_range: 50.0,
        ..Sensor::helios2()
    }
}

fn frame(scene: &Scene, noise: &Noise) -> Frame {
    simulate(
        &sensor(),
        scene,
        noise,
        Subsample::All,
        FrameSeed::default(),
    )
    .unwrap()
}

/// The sensor origin and a unit SCS direction in the PCS (eq. 3).
fn pcs_ray(t: &Params, d: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    (t.scs_to_pcs(&Point3::origin()).coords, t.dir_scs_to_pcs(d))
}

/// The wall's exit root of y²/a² + z²/b² = 1 along o + t·d (PCS), by the textbook formula.
fn wall_t(t: &Params, o: &Vector3<f64>, d: &Vector3<f64>) -> f64 {
    let (a2, b2) = ((t.d_max / 2.0).powi(2), (t.d_min / 2.0).powi(2));
    let qa = d.y * d.y / a2 + d.z * d.z / b2;
    let qb = 2.0 * (o.y * d.y / a2 + o.z * d.z / b2);
    let qc = o.y * o.y / a2 + o.z * o.z / b2 - 1.0;
    (-qb + (qb * qb - 4.0 * qa * qc).sqrt()) / (2.0 * qa)
}

/// The nearest of a set of PCS planes p·n = c met at a point inside their face's bounds.
fn box_t(o: &Vector3<f64>, d: &Vector3<f64>, lo: [f64; 3], hi: [f64; 3]) -> Option<f64> {
    let mut best: Option<f64> = None;
    for k in 0..3 {
        for c in [lo[k], hi[k]] {
            if d[k] == 0.0 {
                continue;
            }
            let t = (c - o[k]) / d[k];
            let p = o + d * t;
            let inside = (0..3)
                .filter(|&j| j != k)
                .all(|j| p[j] >= lo[j] - 1e-12 && p[j] <= hi[j] + 1e-12);
            if t > 0.0 && inside && best.is_none_or(|b| t < b) {
                best = Some(t);
            }
        }
    }
    best
}

/// The floor layer: every point is the nearer of the wall and the plane z = −b + depth
/// (analytic, to 1e-9 m), floor points lie on the plane to 1e-9 m, none below it.
#[test]
fn floor_layer_points_lie_on_its_plane() {
    for t in truths() {
        let depth = 0.09;
        let zf = -t.d_min / 2.0 + depth;
        let scene = Scene::new(&t, WallModel::Exact, 8.0)
            .unwrap()
            .with_contamination(Contamination {
                floor: Some(FloorLayer { depth_m: depth }),
                ..Contamination::default()
            })
            .unwrap();
        let f = frame(&scene, &Noise::none());
        let mut on_floor = 0;
        for (i, x) in f.exact.iter().enumerate() {
            let d = Vector3::from(f.directions[i]);
            let (o, dp) = pcs_ray(&t, &d);
            let tw = wall_t(&t, &o, &dp);
            let tf = if dp.z < 0.0 {
                (zf - o.z) / dp.z
            } else {
                f64::INFINITY
            };
            let r = Vector3::from(*x).norm();
            assert!((r - tw.min(tf)).abs() < 1e-9, "pixel {:?}", f.pixels[i]);
            let p = t.scs_to_pcs(&Point3::from(*x));
            assert!(p.z > zf - 1e-9, "below the floor: {}", p.z - zf);
            if tf < tw {
                assert!((p.z - zf).abs() < 1e-9);
                on_floor += 1;
            }
        }
        eprintln!("floor points: {on_floor} of {}", f.len());
        assert!(on_floor > 10_000);
        // On a meshed wall too: floor points on the plane to 1e-9 m and before the wall,
        // the others within the 2048-segment mesh's 10 µm of it (tests/frames.rs).
        let meshed = Scene::new(&t, WallModel::Mesh { segments: 2048 }, 8.0)
            .unwrap()
            .with_contamination(Contamination {
                floor: Some(FloorLayer { depth_m: depth }),
                ..Contamination::default()
            })
            .unwrap();
        let g = frame(&meshed, &Noise::none());
        for (i, x) in g.exact.iter().enumerate() {
            let (o, dp) = pcs_ray(&t, &Vector3::from(g.directions[i]));
            let p = t.scs_to_pcs(&Point3::from(*x));
            let tw = wall_t(&t, &o, &dp);
            let r = Vector3::from(*x).norm();
            if (p.z - zf).abs() < 1e-9 {
                // (Past the mesh's end at x = 8 m a ray meets the endless floor.)
                assert!(r <= tw + 10e-6 || p.x > 8.0, "{p:?}");
            } else {
                assert!(p.z > zf && (r - tw).abs() < 10e-6, "{}", r - tw);
            }
        }
    }
}

/// A box and a half-cylinder on the floor: every point is the nearest of the wall, the
/// floor and the obstacle (faces intersected one by one here; the cylinder by the
/// textbook quadratic), to 1e-9 m, and the physical model's incidence sees the faces.
#[test]
fn obstacles_are_hit_where_the_analytic_intersections_say() {
    let depth = 0.05;
    for t in truths() {
        let zb = -t.d_min / 2.0 + depth;
        let boxed = Obstacle::Box {
            x_m: 1.0,
            length_m: 0.4,
            width_m: 0.15,
            height_m: 0.1,
            y_m: -0.04,
        };
        let half = Obstacle::HalfCylinder {
            x_m: 1.5,
            radius_m: 0.08,
        };
        for ob in [boxed, half] {
            let scene = Scene::new(&t, WallModel::Exact, 8.0)
                .unwrap()
                .with_contamination(Contamination {
                    floor: Some(FloorLayer { depth_m: depth }),
                    obstacle: Some(ob),
                    ..Contamination::default()
                })
                .unwrap();
            let f = frame(&scene, &Noise::none());
            let mut on_obstacle = Vec::new();
            for (i, x) in f.exact.iter().enumerate() {
                let d = Vector3::from(f.directions[i]);
                let (o, dp) = pcs_ray(&t, &d);
                let mut want = wall_t(&t, &o, &dp);
                if dp.z < 0.0 {
                    want = want.min((zb - o.z) / dp.z);
                }
                let t_ob = match ob {
                    Obstacle::Box { .. } => {
                        box_t(&o, &dp, [1.0, -0.115, zb], [1.4, 0.035, zb + 0.1])
                    }
                    Obstacle::HalfCylinder { .. } => {
                        let (px, pz) = (o.x - 1.5, o.z - zb);
                        let qa = dp.x * dp.x + dp.z * dp.z;
                        let qb = 2.0 * (px * dp.x + pz * dp.z);
                        let qc = px * px + pz * pz - 0.08 * 0.08;
                        let disc = qb * qb - 4.0 * qa * qc;
                        let t0 = (-qb - disc.sqrt()) / (2.0 * qa);
                        (disc >= 0.0 && t0 > 0.0 && pz + t0 * dp.z >= 0.0).then_some(t0)
                    }
                };
                if let Some(t_ob) = t_ob
                    && t_ob < want
                {
                    want = t_ob;
                    on_obstacle.push(f.pixels[i]);
                }
                let r = Vector3::from(*x).norm();
                assert!((r - want).abs() < 1e-9, "{ob:?}: {r} vs {want}");
            }
            eprintln!("{ob:?}: {} points on the obstacle", on_obstacle.len());
            assert!(on_obstacle.len() > 2000);
            // The physical model casts with normals: the obstacle's pixels (near, mostly
            // head-on) are valid, with the amplitude of their own incidence.
            let physical = Noise {
                physics: Some(ToFPhysics::helios2()),
                ..Noise::none()
            };
            let g = frame(&scene, &physical);
            assert_eq!(g.len(), sensor().pixel_count());
            let valid = on_obstacle
                .iter()
                .filter(|[u, v]| g.is_valid((v * 640 + u) as usize))
                .count();
            assert!(valid as f64 > 0.99 * on_obstacle.len() as f64, "{valid}");
        }
    }
}

/// The dented wall's radius ρ_w(x, φ) = ρ_E(φ) − h·G (the type's doc), written anew.
fn dented_radius(t: &Params, dent: &Dent, x: f64, phi: f64) -> f64 {
    let (a, b) = (t.d_max / 2.0, t.d_min / 2.0);
    let re = 1.0 / ((phi.sin() / a).powi(2) + (phi.cos() / b).powi(2)).sqrt();
    let mut dphi = (phi - dent.clock_rad).rem_euclid(TAU);
    if dphi > PI {
        dphi -= TAU;
    }
    let arc = 0.5 * (a + b) * dphi;
    let (sx, sc) = (dent.axial_sigma_m, dent.circumferential_sigma_m);
    let dx = x - dent.x_m;
    let g = if dx.abs() > 8.0 * sx || arc.abs() > 8.0 * sc {
        0.0
    } else {
        (-0.5 * (dx * dx / (sx * sx) + arc * arc / (sc * sc))).exp()
    };
    re - dent.depth_m * g
}

/// A dent: every point lies on the dented wall to 1e-9 m, reached from inside; a ray
/// aimed at the dent's
/// centre (x_d, ρ_E(φ_d) − h) meets it there, to 1e-12 m; and the deepest point of the
/// frame is h·G at its own offset from the centre, within [h·G(nearest pixel), h].
#[test]
fn dent_points_lie_on_the_dented_wall_and_its_depth_is_seen() {
    let gentle = Dent {
        x_m: 1.2,
        clock_rad: 2.4,
        depth_m: 0.025,
        axial_sigma_m: 0.1,
        circumferential_sigma_m: 0.06,
    };
    // Steep enough that its near flank hides part of its far one.
    let steep = Dent {
        x_m: 1.6,
        clock_rad: 5.0,
        depth_m: 0.06,
        axial_sigma_m: 0.02,
        circumferential_sigma_m: 0.03,
    };
    for (t, dent) in truths().into_iter().zip([gentle, steep]) {
        let scene = Scene::new(&t, WallModel::Exact, 8.0)
            .unwrap()
            .with_contamination(Contamination {
                dent: Some(dent),
                ..Contamination::default()
            })
            .unwrap();
        let f = frame(&scene, &Noise::none());
        let (mut deepest, mut nearest) = (0.0f64, (f64::INFINITY, 0.0));
        let mut in_dent = 0;
        for x in &f.exact {
            let p = t.scs_to_pcs(&Point3::from(*x));
            let phi = p.y.atan2(p.z).rem_euclid(TAU);
            let rho = p.y.hypot(p.z);
            let rw = dented_radius(&t, &dent, p.x, phi);
            assert!(
                (rho - rw).abs() < 1e-9,
                "off the dented wall by {}",
                rho - rw
            );
            let plain = dented_radius(
                &t,
                &Dent {
                    depth_m: 0.0,
                    ..dent
                },
                p.x,
                phi,
            );
            deepest = deepest.max(plain - rho);
            if plain - rho > 0.1 * dent.depth_m {
                in_dent += 1;
                // The first crossing: the segment from the sensor stays inside the wall
                // (checked at 400 points up to 99.9 % of the way).
                let o = t.sensor_origin_pcs();
                for k in 1..400 {
                    let q = o + (p - o) * (0.999 * k as f64 / 400.0);
                    let phi_q = q.y.atan2(q.z).rem_euclid(TAU);
                    assert!(q.y.hypot(q.z) < dented_radius(&t, &dent, q.x, phi_q));
                }
            }
            // The point nearest the centre in (axial, arc) standard units.
            let mut dphi = (phi - dent.clock_rad).rem_euclid(TAU);
            if dphi > PI {
                dphi -= TAU;
            }
            let arc = 0.5 * (t.d_max + t.d_min) / 2.0 * dphi;
            let q = ((p.x - dent.x_m) / dent.axial_sigma_m).powi(2)
                + (arc / dent.circumferential_sigma_m).powi(2);
            if q < nearest.0 {
                nearest = (q, plain - rho);
            }
        }
        let lower = dent.depth_m * (-0.5 * nearest.0).exp();
        eprintln!(
            "dent depth seen {:.4} mm (h {:.1} mm; nearest pixel's h·G {:.4} mm)",
            deepest * 1e3,
            dent.depth_m * 1e3,
            lower * 1e3
        );
        assert!(deepest >= lower - 1e-9 && deepest <= dent.depth_m + 1e-9);
        eprintln!("{in_dent} points deeper than h/10");
        assert!(in_dent > 100);
        // A ray aimed at the dent's centre.
        let (a, b) = (t.d_max / 2.0, t.d_min / 2.0);
        let phi = dent.clock_rad;
        let re = 1.0 / ((phi.sin() / a).powi(2) + (phi.cos() / b).powi(2)).sqrt();
        let c = Point3::new(
            dent.x_m,
            (re - dent.depth_m) * phi.sin(),
            (re - dent.depth_m) * phi.cos(),
        );
        let cs = t.pcs_to_scs(&c).coords;
        let r = scene.cast(&cs.normalize(), 10.0).unwrap();
        assert!((r - cs.norm()).abs() < 1e-12, "{r} vs {}", cs.norm());
    }
}

/// The upper half blocked: exactly the pixels whose hit has a clock angle in
/// [π/2, 3π/2] (PCS) are kept by the plain model; the physical one keeps the others as
/// invalid zeros with their wall point.
#[test]
fn partial_view_keeps_the_seen_sector() {
    for t in truths() {
        let open = Scene::new(&t, WallModel::Exact, 8.0).unwrap();
        let lower = Scene::new(&t, WallModel::Exact, 8.0)
            .unwrap()
            .with_contamination(Contamination {
                view: Some(ViewSector::upper_half_blocked()),
                ..Contamination::default()
            })
            .unwrap();
        let all = frame(&open, &Noise::none());
        let seen = frame(&lower, &Noise::none());
        let clock = |x: &[f64; 3]| {
            let p = t.scs_to_pcs(&Point3::from(*x));
            p.y.atan2(p.z).rem_euclid(TAU)
        };
        let want: Vec<[u32; 2]> = (0..all.len())
            .filter(|&i| (0.5 * PI..=1.5 * PI).contains(&clock(&all.exact[i])))
            .map(|i| all.pixels[i])
            .collect();
        eprintln!("seen {} of {} pixels", seen.len(), all.len());
        assert_eq!(seen.pixels, want);
        let physical = Noise {
            physics: Some(ToFPhysics::helios2()),
            ..Noise::none()
        };
        let g = frame(&lower, &physical);
        for i in 0..g.len() {
            if g.exact[i][0].is_nan() {
                continue;
            }
            let c = clock(&g.exact[i]);
            if !(0.5 * PI..=1.5 * PI).contains(&c) {
                assert!(!g.is_valid(i) && g.intensity[i] == 0.0 && g.sigma[i].is_nan());
            }
        }
    }
}

fn field_of(e: SimError) -> String {
    match e {
        SimError::Invalid { field, .. } => field.to_string(),
        other => panic!("not a field error: {other}"),
    }
}

/// Contamination that cannot be placed is refused, naming the field.
#[test]
fn bad_contamination_names_its_field() {
    let t = truths()[0];
    let place = |c: Contamination| {
        Scene::new(&t, WallModel::Exact, 8.0)
            .unwrap()
            .with_contamination(c)
            .map(|_| ())
    };
    let floor = |depth_m| Contamination {
        floor: Some(FloorLayer { depth_m }),
        ..Contamination::default()
    };
    assert_eq!(
        field_of(place(floor(f64::NAN)).unwrap_err()),
        "contamination.floor.depth_m"
    );
    // Up to the sensor.
    assert_eq!(
        field_of(place(floor(t.d_min / 2.0 + t.dz + 0.01)).unwrap_err()),
        "contamination.floor.depth_m"
    );
    let dent = Dent {
        x_m: 0.0,
        clock_rad: 0.0,
        depth_m: 0.1,
        axial_sigma_m: 0.1,
        circumferential_sigma_m: 0.5,
    };
    assert_eq!(
        field_of(
            place(Contamination {
                dent: Some(Dent {
                    depth_m: -0.1,
                    ..dent
                }),
                ..Contamination::default()
            })
            .unwrap_err()
        ),
        "contamination.dent.depth_m"
    );
    // A dent on a meshed wall.
    let meshed = Scene::new(&t, WallModel::Mesh { segments: 64 }, 8.0)
        .unwrap()
        .with_contamination(Contamination {
            dent: Some(dent),
            ..Contamination::default()
        });
    assert_eq!(field_of(meshed.err().unwrap()), "contamination.dent");
    // The default leaves the scene as it was.
    let s = Scene::new(&t, WallModel::Exact, 8.0)
        .unwrap()
        .with_contamination(Contamination::default())
        .unwrap();
    assert!(s.contamination().is_none());
}
