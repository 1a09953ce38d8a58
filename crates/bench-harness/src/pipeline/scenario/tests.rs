//! The pipeline scenario's checks: each key refused with its name and reason.

use std::path::Path;

use super::super::PipelineScenario;
use crate::scenario::ScenarioError;

/// A small valid pipeline scenario: two sections of two frames, a tee between them.
const OK: &str = "name = \"p\"\n[pipeline]\nframes_per_section = 2\n\
    [[pipeline.section]]\nname = \"a\"\nwall_mm = 10.0\nstart_m = 0.0\n\
    [[pipeline.fitting]]\nkind = \"tee\"\nat_m = 5.0\nbranch_diameter_mm = 100.0\n\
    [[pipeline.section]]\nname = \"b\"\nwall_mm = 10.0\nstart_m = 10.0\n\
    [pipeline.rig]\nnominal_od_in = 20\nwall_mm = 9.5\n[pipeline.drift]\n";

/// [`OK`] with `from` replaced by `to`.
fn set(from: &str, to: &str) -> String {
    assert!(OK.contains(from), "{from}");
    OK.replacen(from, to, 1)
}

/// [`OK`] with `line` added to the `[pipeline]` table.
fn pipeline(line: &str) -> String {
    set("[pipeline]\n", &format!("[pipeline]\n{line}\n"))
}

/// [`OK`] with `line` added to the `[pipeline.rig]` table.
fn rig(line: &str) -> String {
    set("wall_mm = 9.5\n", &format!("wall_mm = 9.5\n{line}\n"))
}

/// [`OK`] with `line` added to the `[pipeline.drift]` table (the last).
fn drift(line: &str) -> String {
    format!("{OK}{line}\n")
}

/// `source` is refused naming `key`, with a message that contains `reason`.
fn refused(source: &str, key: &str, reason: &str) {
    match PipelineScenario::parse(Path::new("p.toml"), source) {
        Err(ScenarioError::Invalid {
            key: k, message, ..
        }) => {
            assert_eq!(k, key, "{message}\n{source}");
            assert!(message.contains(reason), "{key}: {message}");
        }
        other => panic!("{key}: {other:?}\n{source}"),
    }
}

/// The run's own keys, checked first; with several errors, the first checked.
#[test]
fn parse_refuses_the_run_keys_naming_key_and_reason() {
    let s = PipelineScenario::parse(Path::new("p.toml"), OK).expect("a valid scenario");
    assert_eq!((s.sections.len(), s.route.fittings.len()), (2, 1));
    for (source, key, reason) in [
        (
            set("\"p\"", "\"a/b\""),
            "name",
            "= \"a/b\": must be a plain folder name (no path separator, no control character)",
        ),
        (
            set("frames_per_section = 2", "frames_per_section = 0"),
            "pipeline.frames_per_section",
            "= 0: must lie in [1, 10000]",
        ),
        (
            pipeline("frame_spacing_m = 0.0"),
            "pipeline.frame_spacing_m",
            "= 0: must be a finite number > 0",
        ),
        (
            pipeline("range_gate_m = [2.0, 1.0]"),
            "pipeline.range_gate_m",
            "= [2, 1]: need 0 ≤ min < max",
        ),
        (
            pipeline("sensor = \"x\""),
            "pipeline.sensor",
            "= \"x\": the one preset is \"helios2\"",
        ),
        (
            pipeline("sensor_model = { reflectivity = 2.0 }"),
            "pipeline.sensor_model",
            "reflectivity",
        ),
        (pipeline("mesh_segments = 0"), "pipeline.mesh_segments", ""),
        (
            set(
                "frames_per_section = 2",
                "frames_per_section = 0\nsensor = \"x\"",
            ),
            "pipeline.frames_per_section",
            "must lie in [1, 10000]",
        ),
    ] {
        refused(&source, key, reason);
    }
}

/// Sections (apart when fittings lie between them) and the rig: each key with its
/// range.
#[test]
fn parse_refuses_sections_and_rig_naming_key_and_reason() {
    for (source, key, reason) in [
        (
            set("\"a\"", "\"a\\nb\""),
            "pipeline.section[0].name",
            "a non-empty name without control characters",
        ),
        (
            set("= 10.0\nstart_m = 10.0", "= 10.0\nstart_m = nan"),
            "pipeline.section[1].start_m",
            "must be finite",
        ),
        (
            set("= 10.0\nstart_m = 10.0", "= -1.0\nstart_m = 10.0"),
            "pipeline.section[1]",
            "",
        ),
        (set("wall_mm = 9.5", "wall_mm = -1.0"), "pipeline.rig", ""),
        (
            rig("frames = 0"),
            "pipeline.rig.frames",
            "= 0: must lie in [1, 1000]",
        ),
        (
            rig("passes = 21"),
            "pipeline.rig.passes",
            "= 21: must lie in [1, 20]",
        ),
        (
            rig("intensity_bins = 0"),
            "pipeline.rig.range_bins",
            "and intensity_bins must lie in [1, 1000]",
        ),
        (
            rig("offset_mm = -1.0"),
            "pipeline.rig.offset_mm",
            "= -1: must lie in [0, 10000)",
        ),
        (
            rig("offset_mm = 400.0"),
            "pipeline.rig.offset_mm",
            "= 400: at 0.00 m the sensor leaves the pipe of the rig",
        ),
        (
            set("start_m = 10.0", "start_m = 0.1"),
            "pipeline.section",
            "with fittings, the sections must follow each other",
        ),
    ] {
        refused(&source, key, reason);
    }
}

/// The drift: each key with its range, and the sensor inside the pipe all along.
#[test]
fn parse_refuses_drift_naming_key_and_reason() {
    for (source, key, reason) in [
        (
            drift("roll_deg_per_m = inf"),
            "pipeline.drift.roll_deg_per_m",
            "= inf: out of range",
        ),
        (
            drift("tilt_deg = 30.0"),
            "pipeline.drift.tilt_deg",
            "= 30: out of range",
        ),
        (
            drift("tilt_period_m = 0.0"),
            "pipeline.drift.tilt_period_m",
            "= 0: out of range",
        ),
        (
            drift("offset_mm = 1e4"),
            "pipeline.drift.offset_mm",
            "= 10000: out of range",
        ),
        (
            drift("offset_period_m = -1.0"),
            "pipeline.drift.offset_period_m",
            "= -1: out of range",
        ),
        (
            drift("offset_mm = 400.0"),
            "pipeline.drift.offset_mm",
            "= 400: at 0.00 m the sensor leaves the pipe of section a",
        ),
    ] {
        refused(&source, key, reason);
    }
}

/// Fittings: kind and size, between two sections' frames, in driving order.
#[test]
fn parse_refuses_fittings_naming_key_and_reason() {
    let at = |v: &str| set("at_m = 5.0", &format!("at_m = {v}"));
    let elbow = |line: &str| {
        set(
            "\"tee\"\nat_m = 5.0\nbranch_diameter_mm = 100.0",
            &format!("\"elbow\"\nat_m = 5.0\n{line}"),
        )
    };
    let second_tee =
        "[[pipeline.fitting]]\nkind = \"tee\"\nat_m = 5.1\nbranch_diameter_mm = 100.0\n";
    for (source, field, reason) in [
        (at("inf"), "at_m", "= inf: must be finite"),
        (
            at("5.0\ndirection_deg = nan"),
            "direction_deg",
            "must be finite",
        ),
        (
            at("-1.0"),
            "at_m",
            "= -1: must lie after the first section's frames",
        ),
        (at("11.0"), "at_m", "= 11: must lie before the last section"),
        (
            at("0.1"),
            "at_m",
            "= 0.1: the fitting (0.20 m long) must lie between section a's last frame \
             (0.20 m) and section b's first (10.00 m)",
        ),
        (
            set(
                "[[pipeline.section]]\nname = \"b\"",
                &format!("{second_tee}[[pipeline.section]]\nname = \"b\""),
            ),
            "at_m",
            "= 5.1: overlaps the fitting before it (ends at 5.200 m); list them in driving order",
        ),
        (
            set("\"tee\"", "\"wye\""),
            "kind",
            "= \"wye\": must be \"tee\" or \"elbow\"",
        ),
        (
            at("5.0\nangle_deg = 90.0"),
            "kind",
            "= \"tee\" takes branch_diameter_mm, not bend_radius_d or angle_deg",
        ),
        (
            set("branch_diameter_mm = 100.0", ""),
            "branch_diameter_mm",
            "a tee needs its branch's inner diameter",
        ),
        (
            set("= 100.0", "= 1000.0"),
            "branch_diameter_mm",
            "= 1000: must lie in (0, ",
        ),
        (
            set("\"tee\"", "\"elbow\""),
            "kind",
            "= \"elbow\" takes bend_radius_d and angle_deg, not branch_diameter_mm",
        ),
        (
            elbow("bend_radius_d = 0.5"),
            "bend_radius_d",
            "= 0.5: must lie in [0.75, 50] pipe diameters",
        ),
        (
            elbow("angle_deg = 181.0"),
            "angle_deg",
            "= 181: must lie in (0, 180]",
        ),
    ] {
        let k = if reason.contains("overlaps") { 1 } else { 0 };
        refused(&source, &format!("pipeline.fitting[{k}].{field}"), reason);
    }
}

/// Sections far apart or frames spaced finely plan more frames between the sections than
/// a run can hold (found by the fuzz suite: 14.7 GB planned for one mutated scenario).
#[test]
fn frames_between_sections_are_counted_before_they_are_planned() {
    refused(
        &set("start_m = 10.0", "start_m = 1e300"),
        "pipeline.frame_spacing_m",
        "at most 100000",
    );
    refused(
        &pipeline("frame_spacing_m = 1e-300"),
        "pipeline.frame_spacing_m",
        "at most 100000",
    );
    // 10 m at the default 0.2 m: within the limit.
    assert!(PipelineScenario::parse(Path::new("p.toml"), OK).is_ok());
}

/// A section's name may hold what a CSV cell quotes (commas, quotes): `epd_io::csv`
/// writes it as one cell.
#[test]
fn a_section_name_with_commas_and_quotes_is_taken() {
    let source = set("\"a\"", "'a, \"b\"'");
    let s = PipelineScenario::parse(Path::new("s.toml"), &source).expect("parses");
    assert!(s.sections.iter().any(|x| x.name == "a, \"b\""));
}
