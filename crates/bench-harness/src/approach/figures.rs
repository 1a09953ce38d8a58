//! The figure of an approach run, drawn with the primitives of [`crate::plots`].

use plotters::style::RGBColor;

use super::{ApproachScenario, FrameRow};
use crate::plots::{BLUE, Figure, GREEN, Panel, Png, Point, RED, Series, render};

/// (distance, mean, min, max) of `f` over the frames of each distance with the survey
/// (`segmented`) or without, finite values only; distances without any left out.
fn spread_by_distance(
    s: &ApproachScenario,
    rows: &[FrameRow],
    segmented: bool,
    f: fn(&FrameRow) -> f64,
) -> Vec<Point> {
    s.distances_m
        .iter()
        .filter_map(|&d| {
            let v: Vec<f64> = rows
                .iter()
                .filter(|r| r.distance_m == d && r.segmented == segmented)
                .map(f)
                .filter(|v| v.is_finite())
                .collect();
            if v.is_empty() {
                return None;
            }
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            Some((d, mean, lo, hi))
        })
        .collect()
}

/// The direction's error where the survey reports one: in a bend the departure's
/// direction is no bend's, and is left out as its radius is.
fn reported_direction_err(r: &FrameRow) -> f64 {
    if r.geometry == "in_bend" {
        f64::NAN
    } else {
        r.direction_err_deg
    }
}

/// `approach.png` of an `[approach]` run: per distance, the mean-diameter error of the
/// plain fit and of the survey's straight estimate (mean, bars from min to max over the
/// frames), the error of `straight_until_m`, the bend radius's error and the direction's
/// (of the frames that report them: not `in_bend`).
pub(crate) fn plot_approach(s: &ApproachScenario, rows: &[FrameRow]) -> anyhow::Result<Png> {
    type Column = fn(&FrameRow) -> f64;
    /// A series: name, colour, with the survey, value.
    type Bars = (&'static str, RGBColor, bool, Column);
    // Per panel: title, y label, and its series.
    let layout: [(&str, &str, &[Bars]); 4] = [
        (
            "mean-diameter error",
            "error (mm)",
            &[
                ("one fit on every point", RED, false, |r| r.dmean_err_mm),
                ("straight section only", GREEN, true, |r| r.dmean_err_mm),
            ],
        ),
        (
            "mean-diameter error, segmented (zoom)",
            "error (mm)",
            &[("straight section only", GREEN, true, |r| r.dmean_err_mm)],
        ),
        (
            "end of the straight section",
            "error (mm)",
            &[("straight_until_m", GREEN, true, |r| r.straight_until_err_mm)],
        ),
        (
            "bend radius (%) and direction (deg) errors",
            "error (% / deg)",
            &[
                ("bend radius", GREEN, true, |r| r.bend_radius_err_pct),
                ("direction (deg)", BLUE, true, reported_direction_err),
            ],
        ),
    ];
    let lo = s.distances_m.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = s
        .distances_m
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    let series: Vec<Vec<Series>> = layout
        .iter()
        .map(|(_, _, list)| {
            let zero = Series::reference("0", (lo, hi), 0.0, RGBColor(90, 90, 90));
            let bars = list.iter().map(|&(name, c, segmented, f)| {
                Series::bars(name, c, spread_by_distance(s, rows, segmented, f))
            });
            std::iter::once(zero).chain(bars).collect()
        })
        .collect();
    let panels: Vec<Panel<'_>> = layout
        .iter()
        .zip(&series)
        .map(|((title, y_label, _), v)| Panel {
            title: (*title).into(),
            y_label: (*y_label).into(),
            series: v,
        })
        .collect();
    render(
        Figure::linear(
            "approach.png",
            format!(
                "{}: mean, min and max over the frames at each distance",
                s.name
            ),
            (2, 2),
            (1440, 1000),
            "distance to the end of the straight section (m)",
        ),
        &panels,
    )
}
