//! The survey's departure profile of one frame, slice by slice: what the scene step saw.
//!
//! `cargo run --release -p epd-frame --example survey_profile -- FRAME.ply`
//! (sensor frame, metres, as `epd estimate` reads it by default).

use std::path::PathBuf;

use epd_core::segment::{SegmentOptions, survey};
use epd_frame::config::{EstimateConfig, EstimateSettings};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path: PathBuf = std::env::args()
        .nth(1)
        .ok_or("usage: survey_profile FRAME")?
        .into();
    let cfg = EstimateConfig::new(&EstimateSettings::default())?;
    let cloud = epd_frame::input::read_input(&path, &cfg.input)?;
    let o = SegmentOptions::default();
    let s = survey(&cloud.points, cfg.method, &cfg.options, &o)?;
    let seg = &s.segmentation;
    let first = epd_core::estimate(&cloud.points, cfg.method, &cfg.options)?;
    let axis = epd_core::segment::axis_under_straight_pipe(
        &cloud.points,
        &first,
        cfg.method,
        &cfg.options.without_start(),
    );
    let first_profile = epd_core::segment::profile(&cloud.points, &axis.0, &axis.1, &o);
    let which = std::env::args().nth(2).unwrap_or_default();
    let shown = if which == "first" {
        &first_profile
    } else {
        &seg.profile
    };
    println!(
        "layout {} until {:?} rounds {} withheld {}",
        seg.layout.name(),
        seg.straight_until,
        seg.rounds,
        seg.straight_withheld
    );
    println!(
        "start_m n sectors widen_mm shift_mm se_mm bump_mm bump_se_mm ratio F Fcrit opening_p departs"
    );
    for sl in shown.iter().filter(|s| s.n_points > 0) {
        println!(
            "{:.3} {} {} {:.2} {:.2} {:.3} {:.2} {:.3} {:.1} {:.1} {:.1} {:.1e} {}",
            sl.start_m,
            sl.n_points,
            sl.n_sectors,
            sl.widening_m * 1e3,
            sl.shift() * 1e3,
            sl.shift_se_m * 1e3,
            sl.bump_m * 1e3,
            sl.bump_se_m * 1e3,
            sl.variance_ratio,
            sl.shift_f,
            sl.critical_f,
            sl.opening_p,
            if sl.shifts(&o) {
                "SHIFT"
            } else if sl.bumps(&o) {
                "BUMP"
            } else if sl.opens() {
                "OPENS"
            } else {
                ""
            }
        );
    }
    Ok(())
}
