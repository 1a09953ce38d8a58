//! Tests of the scene contamination: floor layers, obstacles, dents, partial views.

use super::*;

/// A circular pipe of radius 0.25 m, the sensor on its axis, the PCS = the SCS.
fn placed(c: Contamination) -> Result<Placed, SimError> {
    Placed::new(c, 0.25, 0.25, Matrix3::identity(), Vector3::zeros(), true)
}

/// The undented circular wall's hit, for `Placed::cast`.
fn circle(d: &Vector3<f64>) -> Option<Hit> {
    let s = d.y.hypot(d.z);
    (s > 0.0).then(|| Hit {
        range: 0.25 / s,
        normal: Vector3::new(0.0, d.y, d.z) / s,
    })
}

#[test]
fn root_and_maximum_finders_reach_adjacent_floats() {
    let f = |x: f64| x * x * x - 2.0;
    let r = bisect(&f, 0.0, 5.0);
    assert!((r - 2f64.cbrt()).abs() <= 4.0 * f64::EPSILON, "{r}");
    assert!(f(r) >= 0.0);
    // A root where f is flat on one side.
    let g = |x: f64| if x < 1.0 { -1.0 } else { (x - 1.0) * 1e-3 };
    assert!((bisect(&g, 0.0, 3.0) - 1.0).abs() <= 4.0 * f64::EPSILON);
    // A hump peaking at 0.3 just below zero, and one just above.
    let h = |c: f64| move |x: f64| c - (x - 0.3) * (x - 0.3);
    let (x, y) = golden_max(&h(-1e-12), 0.0, 1.0, 2.0);
    assert!(y < 0.0 && (x - 0.3).abs() < 1e-5, "{x} {y}");
    let (x, y) = golden_max(&h(1e-12), 0.0, 1.0, 2.0);
    assert!(y >= 0.0 && (x - 0.3).abs() < 2e-6, "{x} {y}");
    // Certainly below zero: stops at once.
    let (_, y) = golden_max(&h(-1.0), 0.0, 1.0, 2.0);
    assert!(y < -1.0);
}

#[test]
fn clock_angles() {
    let c = |y: f64, z: f64| clock_angle(&Vector3::new(0.0, y, z));
    assert!(c(0.0, 1.0).abs() < 1e-15);
    assert!((c(1.0, 0.0) - 0.5 * PI).abs() < 1e-15);
    assert!((c(0.0, -1.0) - PI).abs() < 1e-15);
    assert!((c(-1.0, 0.0) - 1.5 * PI).abs() < 1e-15);
    let lower = ViewSector::upper_half_blocked();
    assert!(lower.contains(PI) && lower.contains(0.5 * PI) && !lower.contains(0.1));
    // Wrapping through 12 o'clock.
    let top = ViewSector {
        start_rad: -0.5,
        width_rad: 1.0,
    };
    assert!(top.contains(0.0) && top.contains(TAU - 0.4) && !top.contains(0.6));
}

#[test]
fn floor_hits_lie_on_the_plane() {
    let p = placed(Contamination {
        floor: Some(FloorLayer { depth_m: 0.05 }),
        ..Contamination::default()
    })
    .unwrap();
    let d = Vector3::new(1.0, 0.1, -0.3).normalize();
    let h = p.cast(&d, 10.0, true, |_| circle(&d)).unwrap();
    assert!((d.z * h.range - (-0.2)).abs() < 1e-15);
    assert_eq!(h.normal, Vector3::z());
    // Upwards: the wall.
    let d = Vector3::new(1.0, 0.1, 0.3).normalize();
    let h = p.cast(&d, 10.0, true, |_| circle(&d)).unwrap();
    assert!((h.range - circle(&d).unwrap().range).abs() < 1e-15);
}

#[test]
fn box_and_half_cylinder_entry_points() {
    let ob = Obstacle::Box {
        x_m: 1.0,
        length_m: 0.2,
        width_m: 0.2,
        height_m: 0.1,
        y_m: 0.0,
    };
    let p = placed(Contamination {
        obstacle: Some(ob),
        ..Contamination::default()
    })
    .unwrap();
    // Towards the near face's centre (x = 1, y = 0, z = −0.2): hits it at x = 1.
    let d = Vector3::new(1.0, 0.0, -0.2).normalize();
    let h = p.cast(&d, 10.0, true, |_| circle(&d)).unwrap();
    assert!((h.range - 1.04f64.sqrt()).abs() < 1e-15);
    assert_eq!(h.normal, Vector3::new(-1.0, 0.0, 0.0));
    // Over the top (z = −0.15 at x = 1.1): the top face.
    let d = Vector3::new(1.1, 0.0, -0.15).normalize();
    let h = p.cast(&d, 10.0, true, |_| circle(&d)).unwrap();
    assert!((h.range - (1.1f64 * 1.1 + 0.15 * 0.15).sqrt()).abs() < 1e-14);
    assert_eq!(h.normal, Vector3::z());
    let hc = Obstacle::HalfCylinder {
        x_m: 1.0,
        radius_m: 0.1,
    };
    let p = placed(Contamination {
        obstacle: Some(hc),
        ..Contamination::default()
    })
    .unwrap();
    // Towards its top (x = 1, z = −0.15).
    let d = Vector3::new(1.0, 0.0, -0.15).normalize();
    let h = p.cast(&d, 10.0, true, |_| circle(&d)).unwrap();
    assert!((h.range - (1.0f64 + 0.0225).sqrt()).abs() < 1e-14);
    assert!((h.normal - Vector3::z()).norm() < 1e-12);
    // The sensor inside the obstacle is refused.
    let inside = Obstacle::HalfCylinder {
        x_m: 0.0,
        radius_m: 0.3,
    };
    let e = placed(Contamination {
        obstacle: Some(inside),
        ..Contamination::default()
    })
    .unwrap_err();
    assert!(e.to_string().contains("contamination.obstacle.x_m"), "{e}");
}

#[test]
fn dent_centre_is_depth_inwards_and_normal_is_the_gradient() {
    let dent = Dent {
        x_m: 1.0,
        clock_rad: 2.0,
        depth_m: 0.02,
        axial_sigma_m: 0.05,
        circumferential_sigma_m: 0.04,
    };
    let p = Placed::new(
        Contamination {
            dent: Some(dent),
            ..Contamination::default()
        },
        0.26,
        0.24,
        Matrix3::identity(),
        Vector3::new(0.0, 0.01, -0.02),
        true,
    )
    .unwrap();
    let (re, _) = ellipse_radius(0.26, 0.24, 2.0);
    let centre = Vector3::new(1.0, (re - 0.02) * 2f64.sin(), (re - 0.02) * 2f64.cos());
    assert!(p.dent_implicit(&centre).abs() < 1e-15);
    let d = (centre - p.origin).normalize();
    let wall = |_| {
        let c = crate::EllipticCylinder::new(0.26, 0.24);
        let ray = parry3d_f64::query::Ray::new(
            parry3d_f64::glamx::DVec3::new(0.0, 0.01, -0.02),
            parry3d_f64::glamx::DVec3::new(d.x, d.y, d.z),
        );
        c.time_of_impact(&ray, f64::INFINITY, false).map(|t| Hit {
            range: t,
            normal: Vector3::zeros(),
        })
    };
    let h = p.cast(&d, 10.0, true, wall).unwrap();
    let want = (centre - p.origin).norm();
    assert!((h.range - want).abs() < 1e-12, "{} vs {want}", h.range);
    // The normal against central differences of F.
    let q = Vector3::new(1.03, 0.1, -0.2);
    let q = q * (1.0 - p.dent_implicit(&q) / q.y.hypot(q.z));
    let eps = 1e-6;
    let mut g = Vector3::zeros();
    for k in 0..3 {
        let mut e = Vector3::zeros();
        e[k] = eps;
        g[k] = (p.dent_implicit(&(q + e)) - p.dent_implicit(&(q - e))) / (2.0 * eps);
    }
    let n = p.dent_normal(&dent, &q);
    assert!((n - g.normalize()).norm() < 1e-7, "{n} vs {g}");
}

#[test]
fn validation_names_the_field() {
    let field = |c: Contamination| match placed(c).unwrap_err() {
        SimError::Invalid { field, .. } => field,
        e => panic!("{e}"),
    };
    let floor = |depth_m| Contamination {
        floor: Some(FloorLayer { depth_m }),
        ..Contamination::default()
    };
    assert_eq!(field(floor(f64::NAN)), "contamination.floor.depth_m");
    assert_eq!(field(floor(-0.01)), "contamination.floor.depth_m");
    // Above the sensor on the axis.
    assert_eq!(field(floor(0.3)), "contamination.floor.depth_m");
    let boxed = |height_m| Contamination {
        obstacle: Some(Obstacle::Box {
            x_m: 1.0,
            length_m: 0.1,
            width_m: 0.1,
            height_m,
            y_m: 0.0,
        }),
        ..Contamination::default()
    };
    assert_eq!(field(boxed(-1.0)), "contamination.obstacle.height_m");
    assert_eq!(field(boxed(f64::NAN)), "contamination.obstacle.height_m");
    let dent = Dent {
        x_m: 1.0,
        clock_rad: 0.0,
        depth_m: 0.01,
        axial_sigma_m: 0.05,
        circumferential_sigma_m: 0.05,
    };
    let dented = |d: Dent| Contamination {
        dent: Some(d),
        ..Contamination::default()
    };
    assert_eq!(
        field(dented(Dent {
            depth_m: -0.01,
            ..dent
        })),
        "contamination.dent.depth_m"
    );
    assert_eq!(
        field(dented(Dent {
            axial_sigma_m: 0.0,
            ..dent
        })),
        "contamination.dent.axial_sigma_m"
    );
    assert_eq!(
        field(dented(Dent {
            circumferential_sigma_m: f64::INFINITY,
            ..dent
        })),
        "contamination.dent.circumferential_sigma_m"
    );
    assert_eq!(
        field(dented(Dent {
            clock_rad: f64::NAN,
            ..dent
        })),
        "contamination.dent.clock_rad"
    );
    let view = |width_rad| Contamination {
        view: Some(ViewSector {
            start_rad: 0.0,
            width_rad,
        }),
        ..Contamination::default()
    };
    assert_eq!(field(view(0.0)), "contamination.view.width_rad");
    assert_eq!(field(view(7.0)), "contamination.view.width_rad");
    // A dent on a meshed wall is refused.
    let e = Placed::new(
        dented(dent),
        0.25,
        0.25,
        Matrix3::identity(),
        Vector3::zeros(),
        false,
    )
    .unwrap_err();
    assert!(e.to_string().contains("contamination.dent"), "{e}");
}
