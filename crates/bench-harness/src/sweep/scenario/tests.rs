//! The sweep scenario's keys, limits and messages.

use super::*;

fn parse(s: &str) -> Result<Scenario, ScenarioError> {
    Scenario::parse(Path::new("test.toml"), s)
}

#[test]
fn full_example_parses() {
    let s = parse(
        r#"
name = "sigma_sweep"
seed = 1
trials = 100
methods = ["c-epd", "ru-epd"]
points = "all"
[sensor]
width = 640
[pipe]
nominal_od_in = 20.0
[noise]
model = "range"
sigma_m = 0.03
[poses]
roll_deg = [-180.0, 180.0]
[sweep]
variable = "noise.sigma_m"
values = [0.01, 0.02, 0.03]
"#,
    )
    .unwrap();
    assert_eq!(s.sweeps.len(), 3);
    assert_eq!(s.sweeps[1].0, "0.02");
    assert_eq!(s.sweeps[1].1.noise.sigma, 0.02);
    assert_eq!(s.sweeps[1].1.methods, vec![Method::CEpd, Method::RuEpd]);
    assert!(!s.timing);
}

#[test]
fn sweeps_over_points_and_integers() {
    let s = parse("name = \"n\"\n[sweep]\nvariable = \"points\"\nvalues = [100, 1000, \"all\"]\n")
        .unwrap();
    assert_eq!(s.sweeps[0].1.points, Points::N(100));
    assert_eq!(s.sweeps[2].1.points, Points::All);
    assert!(s.timing);
    let s =
        parse("name = \"n\"\n[sweep]\nvariable = \"pipe.nominal_od_in\"\nvalues = [16, 18.0]\n")
            .unwrap();
    assert_eq!(s.sweeps[0].1.pipe.nominal_od_in, 16.0);
}

#[test]
fn errors_name_file_and_key() {
    let e = parse("name = \"x\"\n[noise]\nsigma = 0.1\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("test.toml") && e.contains("sigma") && e.contains("line 3"),
        "{e}"
    );
    let e = parse("name = \"x\"\nfoo = 1\n").unwrap_err().to_string();
    assert!(e.contains("foo"), "{e}");
    let e = parse("name = \"x\"\n[noise]\nsigma_m = -0.1\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("noise.sigma_m"), "{e}");
    let e = parse("name = \"x\"\n[sweep]\nvariable = \"noise.sigma\"\nvalues = [0.1]\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("noise.sigma") && e.contains("unknown field"),
        "{e}"
    );
    let e = parse("name = \"x\"\n[sweep]\nvariable = \"pipe.ovality\"\nvalues = [0.1, 1.5]\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("pipe.ovality") && e.contains("1.5"), "{e}");
    let e = parse("name = \"x\"\nmethods = [\"d-epd\"]\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("methods") && e.contains("d-epd"), "{e}");
    let e = parse("name = \"x\"\npoints = 0\n").unwrap_err().to_string();
    assert!(e.contains("points"), "{e}");
    let e = parse("name = \"x\"\n[poses]\ndy_mm = [-300.0, 300.0]\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("poses.dy_mm"), "{e}");
    let e = parse("name = \"x\"\ntrials = 0\n").unwrap_err().to_string();
    assert!(e.contains("trials"), "{e}");
    let e = parse("name = \"x\"\n[sensor]\nfov_h_deg = 180.0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("sensor.fov_h_deg"), "{e}");
    let e = parse("name = \"x\"\n[noise]\nmodel = \"gauss\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("noise.model"), "{e}");
}

#[test]
fn limits_name_the_key_the_value_and_the_limit() {
    for (src, needles) in [
        (
            "trials = 1e18",
            &["`trials` = 1e18 (a float)", "[1, 1000000]"][..],
        ),
        ("trials = 1000001", &["`trials` = 1000001", "[1, 1000000]"]),
        ("trials = \"10\"", &["`trials` = \"10\""]),
        ("trials = true", &["`trials` = true"]),
        (
            "[sensor]\nwidth = 4097",
            &["`sensor.width` = 4097", "[1, 4096]"],
        ),
        ("[sensor]\nheight = -1", &["`sensor.height` = -1"]),
        ("points = 6", &["`points` = 6", "[9, 10000000]"]),
        // Issue 27: 7 and 8 passed, and then every trial failed "at least 9 are needed".
        ("points = 7", &["`points` = 7", "[9, 10000000]"]),
        ("points = 8", &["`points` = 8", "[9, 10000000]"]),
        ("points = 1e7", &["`points` = 10000000.0 (a float)"]),
    ] {
        let e = parse(&format!("name = \"x\"\n{src}\n"))
            .unwrap_err()
            .to_string();
        for n in needles {
            assert!(e.contains(n), "{src}: `{n}` not in {e}");
        }
    }
    let s = parse("name = \"x\"\ntrials = 1000000\npoints = 9\n[sensor]\nwidth = 4096\n").unwrap();
    assert_eq!(s.trials, MAX_TRIALS);
    assert!(s.check_trials("--trials", 100).is_ok());
    let e = s
        .check_trials("--trials", MAX_TRIALS + 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("`--trials` = 1000001"), "{e}");
    // Three methods by default: 3 × 10^6 estimates is within 10^8, 40 values not.
    let values = vec!["0.01"; 40].join(", ");
    let e = parse(&format!(
        "name = \"x\"\ntrials = 1000000\n[sweep]\nvariable = \"noise.sigma_m\"\nvalues = [{values}]\n"
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("120000000 estimates") && e.contains("100000000"),
        "{e}"
    );
}

/// A tilt of 90° is named in degrees with the real reason (issue 27: radians, and "must be
/// a finite range [lo, hi] with lo ≤ hi").
#[test]
fn angles_are_refused_in_degrees_with_the_reason() {
    for (src, needles) in [
        (
            "[poses]\ntilt_deg = 90",
            &["poses.tilt_deg", "= 90:", "[0°, 90°)", "perpendicular"][..],
        ),
        ("[poses]\ntilt_deg = [10, 95]", &["[10, 95]", "[0°, 90°)"]),
        ("[poses]\ntilt_deg = -1", &["= -1:", "[0°, 90°)"]),
        (
            "[poses]\npitch_deg = [-5, 90]",
            &["poses.pitch_deg", "[-5, 90]", "(−90°, 90°)"],
        ),
        (
            "[poses]\nroll_deg = [0, 400]",
            &["poses.roll_deg", "[0, 400]", "[−360°, 360°]"],
        ),
    ] {
        let e = parse(&format!("name = \"x\"\n{src}\n"))
            .unwrap_err()
            .to_string();
        for n in needles {
            assert!(e.contains(n), "{src}: `{n}` not in {e}");
        }
        assert!(!e.contains("1.57"), "{src}: radians in {e}");
    }
}

/// A sweep over whole `noise` tables: each value named by its label, its camera keys in
/// the setting (degrees → radians), the keys it leaves out at their defaults.
#[test]
fn noise_tables_are_swept_by_label_with_their_camera_keys() {
    let s = parse(
        r#"
name = "n"
[sweep]
variable = "noise"
values = [
  { label = "plain", sigma_m = 0.02 },
  { label = "camera", sigma_m = 0.01, camera = { correlation_length_px = 2.0, wiggle_amplitude_m = 0.006, wiggle_phase_deg = 90.0, wiggle_random_phase = false, multipath_bands = [[1.0, 2.0, 0.05]], flying_pixel_probability = 0.25 } },
  { sigma_m = 0.03 },
]
"#,
    )
    .unwrap();
    assert_eq!(s.sweeps[0].0, "plain");
    assert_eq!(s.sweeps[1].0, "camera");
    assert_eq!(s.sweeps[2].0, "{ sigma_m = 0.03 }");
    assert_eq!(s.sweeps[0].1.camera, CameraNoise::default());
    let c = &s.sweeps[1].1.camera;
    assert_eq!(s.sweeps[1].1.noise.sigma, 0.01);
    assert_eq!(c.correlation_length_px, 2.0);
    let w = c.wiggle.expect("a wiggle");
    assert_eq!((w.amplitude_m, w.random_phase), (0.006, false));
    assert!((w.phase_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
    assert_eq!(c.multipath_bands.len(), 1);
    assert_eq!(c.multipath_bands[0].extra_m, 0.05);
    assert_eq!(c.flying_pixels.map(|f| f.probability), Some(0.25));
}

/// The camera's and the contamination's limits are checked before anything runs, and the
/// message names the file's key.
#[test]
fn camera_and_contamination_keys_are_checked_by_name() {
    let err = |body: &str| {
        parse(&format!("name = \"n\"\n{body}"))
            .unwrap_err()
            .to_string()
    };
    let e = err("[noise.camera]\ncorrelation_length_px = 100.0");
    assert!(e.contains("noise.camera.correlation_length_px"), "{e}");
    let e = err("[noise.camera]\nmultipath_bands = [[2.0, 1.0, 0.05]]");
    assert!(e.contains("noise.camera.multipath_bands"), "{e}");
    let e = err("[noise.camera]\ncorrelation = 1.0");
    assert!(e.contains("correlation"), "{e}");
    let e = err("[contamination]\nfloor_depth_mm = 400.0");
    assert!(e.contains("contamination.floor.depth_m"), "{e}");
    let e = err(
        "[contamination.dent]\nx_m = 1.0\nclock_deg = 0.0\ndepth_mm = -5.0\naxial_sigma_m = 0.1\ncircumferential_sigma_m = 0.1",
    );
    assert!(e.contains("contamination.dent.depth_m"), "{e}");
}

/// The contamination's keys in the file's units reach the simulator in metres and
/// radians.
#[test]
fn contamination_keys_reach_the_simulator_in_si_units() {
    let s = parse(
        r#"
name = "c"
[contamination]
floor_depth_mm = 100.0
obstacle = { x_m = 1.2, radius_mm = 50.0 }
dent = { x_m = 1.0, clock_deg = 180.0, depth_mm = 25.0, axial_sigma_m = 0.15, circumferential_sigma_m = 0.1 }
seen_sector = { start_deg = -90.0, width_deg = 180.0 }
"#,
    )
    .unwrap();
    let c = s.sweeps[0].1.contamination;
    assert_eq!(c.floor.map(|f| f.depth_m), Some(0.1));
    assert!(matches!(
        c.obstacle,
        Some(tof_sim::Obstacle::HalfCylinder { radius_m, .. }) if (radius_m - 0.05).abs() < 1e-15
    ));
    let d = c.dent.expect("a dent");
    assert!(
        (d.clock_rad - std::f64::consts::PI).abs() < 1e-15 && (d.depth_m - 0.025).abs() < 1e-15
    );
    let v = c.view.expect("a view");
    assert!((v.width_rad - std::f64::consts::PI).abs() < 1e-15);
}

/// `sampling`: swept by label (`scenarios/realtime.toml`), `"all"` for the full frame; a
/// count below the least or an unknown method names the key and the limit.
#[test]
fn sampling_is_swept_by_label_and_checked() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/realtime.toml");
    let s = Scenario::load(&path).unwrap();
    assert_eq!(s.sweep_variable, "sampling");
    assert_eq!(s.sweeps[0].0, "full frame");
    assert_eq!(s.sweeps[0].1.sampling, None);
    let informed = s
        .sweeps
        .iter()
        .find(|(v, _)| v == "informed 20000")
        .and_then(|(_, set)| set.sampling)
        .unwrap();
    assert_eq!(informed.max_points, 20_000);
    assert_eq!(
        informed.method,
        epd_frame::sampling::SamplingMethod::Informed
    );
    let base = "name = \"x\"\ntrials = 1\n";
    for (extra, key, needle) in [
        (
            "sampling = { max_points = 10 }",
            "sampling.max_points",
            "1000",
        ),
        (
            "sampling = { max_points = 5000, method = \"best\" }",
            "sampling.method",
            "informed",
        ),
    ] {
        let e = parse(&format!("{base}{extra}\n")).unwrap_err().to_string();
        assert!(e.contains(key) && e.contains(needle), "{extra}: {e}");
    }
}

#[test]
fn keys_swept_together() {
    let s = parse(
        r#"
name = "fa"
geometry = true
[pipe]
wall_thickness_mm = 8.0
[sweep]
variable = "pipe+noise"
values = [
  { label = "8 in / independent", pipe = { nominal_od_in = 8.0 }, noise = { sigma_m = 0.02 } },
  { pipe = { nominal_od_in = 42.0, ovality = 0.01 }, noise = { sigma_m = 0.01, camera = { correlation_length_px = 2.0 } } },
]
"#,
    )
    .unwrap();
    assert_eq!(s.sweep_variable, "pipe+noise");
    assert_eq!(s.sweeps[0].0, "8 in / independent");
    let (a, b) = (&s.sweeps[0].1, &s.sweeps[1].1);
    assert!(a.geometry && b.geometry);
    assert_eq!((a.pipe.nominal_od_in, a.noise.sigma), (8.0, 0.02));
    assert_eq!((b.pipe.nominal_od_in, b.pipe.ovality), (42.0, 0.01));
    assert_eq!(b.camera.correlation_length_px, 2.0);
    // A swept table replaces the file's table whole, as a single swept table does.
    assert_eq!(a.pipe.wall_thickness, crate::defaults::wall_mm() * 1e-3);
    // Unlabelled values are named by their TOML text.
    assert!(s.sweeps[1].0.contains("42"), "{}", s.sweeps[1].0);
    assert!(!parse("name = \"fa\"\n").unwrap().sweeps[0].1.geometry);

    let bad = |values: &str| {
        parse(&format!(
            "name = \"fa\"\n[sweep]\nvariable = \"pipe+noise\"\nvalues = [{values}]\n"
        ))
        .unwrap_err()
        .to_string()
    };
    let e = bad("{ pipe = { nominal_od_in = 8.0 } }");
    assert!(
        e.contains("sweep.values") && e.contains("lacks `noise`"),
        "{e}"
    );
    let e = bad("{ pipe = {}, noise = {}, sensor = { width = 8 } }");
    assert!(e.contains("has `sensor`, which is not swept"), "{e}");
    let e = bad("8.0");
    assert!(e.contains("is not a table"), "{e}");
    let e = bad("{ pipe = { nominal_od_in = -8.0 }, noise = {} }");
    assert!(e.contains("nominal_od_in"), "{e}");
    for v in ["pipe+trials", "pipe+", "noise+sweep.values"] {
        let e = parse(&format!(
            "name = \"fa\"\n[sweep]\nvariable = \"{v}\"\nvalues = [{{}}]\n"
        ))
        .unwrap_err()
        .to_string();
        assert!(e.contains("cannot be swept"), "{v}: {e}");
    }
}
