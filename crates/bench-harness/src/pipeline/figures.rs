//! The figures of a pipeline run, drawn with the primitives of [`crate::plots`].

use plotters::style::RGBColor;

use super::rows::ProfileRow;
use super::{METHODS, PipelineScenario, SectionRow};
use crate::plots::{
    Axis, BLUE, Figure, GAP, GREEN, Panel, Png, Point, RED, REFERENCE, Series, colour, render,
};
use crate::stats::Stats;

/// The figures of a pipeline run: `diameters.png` (Fig. 11:
/// per-frame Dmax and Dmin against the nominal and the truth, with the depth table),
/// `section_errors.png` (Fig. 12: bias and error range per section, method and
/// calibration), `profile.png` (mean diameter and ovality along the distance) and
/// `weights.png` (spread of each method against the heteroscedastic Cramér–Rao bound).
pub(crate) fn plot_pipeline(
    s: &PipelineScenario,
    points: &[ProfileRow],
    sections: &[SectionRow],
) -> anyhow::Result<Vec<Png>> {
    Ok(vec![
        pipeline_diameters(s, points)?,
        pipeline_section_errors(s, sections)?,
        pipeline_profile(s, points)?,
        pipeline_weights(s, sections)?,
    ])
}

/// The grey of the nominal values' reference lines in a pipeline's figures.
const NOMINAL: RGBColor = RGBColor(90, 90, 90);

/// `diameters.png` (Fig. 11): per-frame Dmax and Dmin of each section, calibrated,
/// against the nominal ID and the truth.
fn pipeline_diameters(s: &PipelineScenario, points: &[ProfileRow]) -> anyhow::Result<Png> {
    let name = &s.name;
    let grey = NOMINAL;
    let pick = |si: usize, m: &'static str, cal: bool| {
        points
            .iter()
            .filter(move |p| p.section == si && p.method == m && p.calibrated == cal)
    };
    // Fig. 11: rows = sections, columns = Dmax, Dmin; calibrated estimates.
    let mut fig11: Vec<Vec<Series>> = Vec::new();
    let mut titles = Vec::new();
    for (si, sec) in s.sections.iter().enumerate() {
        let n = s.frames_per_section as f64 - 1.0;
        for (which, label) in [(0usize, "Dmax"), (1, "Dmin")] {
            let truth = 1e3
                * if which == 0 {
                    sec.pipe.d_max()
                } else {
                    sec.pipe.d_min()
                };
            let mut v = vec![
                Series::reference(
                    "nominal ID",
                    (0.0, n),
                    sec.pipe.inner_diameter() * 1e3,
                    grey,
                ),
                Series::reference(&format!("true {label}"), (0.0, n), truth, RGBColor(0, 0, 0)),
            ];
            for m in METHODS {
                v.push(Series {
                    name: m.to_uppercase(),
                    colour: colour(m),
                    points: pick(si, m, true)
                        .filter_map(|p| {
                            let d = p.d_mm()?;
                            let y = if which == 0 { d.0 } else { d.1 };
                            Some((p.frame as f64, y, y, y))
                        })
                        .collect(),
                    bars: false,
                    marker_triangle: m == "ml-epd-w",
                    dashed: false,
                    band: false,
                    markers_only: false,
                });
            }
            fig11.push(v);
            titles.push(format!("{}: {label} (with the depth table)", sec.name));
        }
    }
    let panels = Panel::each(&fig11, &titles, "diameter (mm)");
    render(
        Figure::linear(
            "diameters.png",
            format!("{name}: per-frame diameters (Fig. 11)"),
            (s.sections.len(), 2),
            (1440, 480 * s.sections.len() as u32 + 40),
            "frame",
        ),
        &panels,
    )
}

/// `section_errors.png` (Fig. 12): bias and error range of Dmax, Dmin and the mean
/// diameter per section, method and calibration.
fn pipeline_section_errors(s: &PipelineScenario, sections: &[SectionRow]) -> anyhow::Result<Png> {
    let name = &s.name;
    // Fig. 12: rows = Dmax, Dmin, mean diameter; columns = without / with the table;
    // x = the section's nominal wall (mm).
    let mut fig12: Vec<Vec<Series>> = Vec::new();
    let mut titles = Vec::new();
    type Q = fn(&SectionRow) -> &Stats;
    let qs: [(&str, Q); 3] = [
        ("Dmax error", |r| &r.dmax),
        ("Dmin error", |r| &r.dmin),
        ("mean-diameter error", |r| &r.dmean),
    ];
    for (label, q) in qs {
        for cal in [false, true] {
            fig12.push(
                METHODS
                    .iter()
                    .map(|m| Series {
                        name: format!("{} (bias, range)", m.to_uppercase()),
                        colour: colour(m),
                        points: sections
                            .iter()
                            .filter(|r| r.method == *m && r.calibrated == cal)
                            .map(|r| {
                                let st = q(r);
                                (r.wall_true_mm, st.mean, st.min, st.max)
                            })
                            .collect(),
                        bars: true,
                        marker_triangle: *m == "ml-epd-w",
                        dashed: false,
                        band: false,
                        markers_only: false,
                    })
                    .collect(),
            );
            titles.push(format!(
                "{label}, {}",
                if cal {
                    "with the depth table"
                } else {
                    "uncalibrated"
                }
            ));
        }
    }
    let panels = Panel::each(&fig12, &titles, "error (mm)");
    render(
        Figure::linear(
            "section_errors.png",
            format!("{name}: errors per section (Fig. 12; line: bias, bars: min…max)"),
            (3, 2),
            (1440, 1480),
            "nominal wall thickness of the section (mm)",
        ),
        &panels,
    )
}

/// A dashed grey line at `y(pipe)` over each section's stretch of the distance.
fn section_references(
    s: &PipelineScenario,
    label: &str,
    y: fn(&tof_sim::Pipe) -> f64,
) -> Vec<Series> {
    s.sections
        .iter()
        .map(|sec| {
            let x1 = sec.start_m + (s.frames_per_section as f64 - 1.0) * s.frame_spacing_m;
            Series::reference(
                &format!("{label} {}", sec.name),
                (sec.start_m, x1),
                y(&sec.pipe),
                NOMINAL,
            )
        })
        .collect()
}

/// `f` of the diameters (Dmax, Dmin) of method `m` along the distance (`driven`: sorted
/// by distance), broken where the place changes and where an estimate is withheld.
fn along_distance(driven: &[&ProfileRow], m: &str, f: fn((f64, f64)) -> f64) -> Vec<Point> {
    let mut v = Vec::new();
    let mut place = None;
    for p in driven.iter().filter(|p| p.method == m) {
        if place.is_some_and(|q| q != p.section) {
            v.push(GAP);
        }
        place = Some(p.section);
        v.push(p.d_mm().map_or(GAP, |d| {
            let y = f(d);
            (p.distance_m, y, y, y)
        }));
    }
    v
}

/// The geometry ahead, once per frame: the survey's distance to the straight section's
/// end by its verdict, a bend's frames at 0, and the route's truth.
fn geometry_ahead(frames: &[&ProfileRow]) -> Vec<Series> {
    let found = |layout: &str| -> Vec<Point> {
        frames
            .iter()
            .filter(|p| p.geometry.found == layout)
            .flat_map(|p| {
                let y = if layout == "in_bend" {
                    0.0
                } else {
                    p.geometry.straight_until.unwrap_or(f64::NAN)
                };
                [(p.distance_m, y, y, y), GAP]
            })
            .collect()
    };
    // Broken where the truth changes from one fitting to the next.
    let mut truth_line: Vec<Point> = Vec::new();
    for (k, p) in frames.iter().enumerate() {
        if k > 0 && frames[k - 1].geometry.truth.geometry != p.geometry.truth.geometry {
            truth_line.push(GAP);
        }
        let y = match (p.geometry.truth.geometry, p.geometry.truth.straight_until_m) {
            ("in_bend", _) => 0.0,
            (_, Some(u)) => u,
            _ => f64::NAN,
        };
        truth_line.push((p.distance_m, y, y, y));
    }
    vec![
        Series::line(
            "truth (0: in the bend)",
            RGBColor(150, 150, 150),
            truth_line,
            false,
        ),
        Series::line("found: bend ahead", BLUE, found("bend_ahead"), true),
        Series::line("found: tee ahead", RED, found("tee_ahead"), false),
        Series::line("found: in a bend (withheld)", GREEN, found("in_bend"), true),
    ]
}

/// `profile.png`: mean diameter and ovality along the distance, with the depth table.
fn pipeline_profile(s: &PipelineScenario, points: &[ProfileRow]) -> anyhow::Result<Png> {
    // Along the distance: the sections and the frames between them.
    let mut driven: Vec<&ProfileRow> = points.iter().filter(|p| p.calibrated).collect();
    driven.sort_by(|a, b| a.distance_m.total_cmp(&b.distance_m));
    let frames: Vec<&ProfileRow> = driven
        .iter()
        .copied()
        .filter(|p| p.method == "ml-epd")
        .collect();
    let geometry = geometry_ahead(&frames);
    let mut dmean = section_references(s, "nominal ID", |p| p.inner_diameter() * 1e3);
    let mut oval = section_references(s, "true ovality", |p| p.ovality * 100.0);
    for m in METHODS {
        let triangles = m == "ml-epd-w";
        let (name, c) = (m.to_uppercase(), colour(m));
        let mean = along_distance(&driven, m, |d| 0.5 * (d.0 + d.1));
        dmean.push(Series::line(name.clone(), c, mean, triangles));
        let ovality = along_distance(&driven, m, |d| 100.0 * (d.0 - d.1) / (0.5 * (d.0 + d.1)));
        oval.push(Series::line(name, c, ovality, triangles));
    }
    render(
        Figure::linear(
            "profile.png",
            format!(
                "{}: pipe tally along the run (with the depth table)",
                s.name
            ),
            (3, 1),
            (1440, 1400),
            "odometer distance (m)",
        ),
        &[
            Panel {
                title: "mean inner diameter".into(),
                y_label: "mm".into(),
                series: &dmean,
            },
            Panel {
                title: "ovality (Dmax − Dmin)/D, D the mean diameter".into(),
                y_label: "%".into(),
                series: &oval,
            },
            Panel {
                title: "geometry ahead: where the straight section ends (survey of every frame)"
                    .into(),
                y_label: "m ahead".into(),
                series: &geometry,
            },
        ],
    )
}

/// A section row's (std, Cramér–Rao bound) of one diameter (mm).
type Spread = fn(&SectionRow) -> (f64, f64);

/// One panel of `weights.png`: the bound (from the ML-EPD rows) and each method's std
/// of `rows`, against the section's wall thickness.
fn spread_series(rows: &[&SectionRow], f: Spread) -> Vec<Series> {
    let points = |m: &str, pick: fn((f64, f64)) -> f64| -> Vec<Point> {
        rows.iter()
            .filter(|r| r.method == m)
            .map(|r| {
                let c = pick(f(r));
                (r.wall_true_mm, c, c, c)
            })
            .collect()
    };
    let mut v = vec![Series {
        name: "Cramér–Rao bound".into(),
        colour: REFERENCE,
        points: points("ml-epd", |(_, crb)| crb),
        bars: false,
        marker_triangle: false,
        dashed: true,
        band: false,
        markers_only: false,
    }];
    for m in METHODS {
        let std = points(m, |(std, _)| std);
        v.push(Series::line(
            m.to_uppercase(),
            colour(m),
            std,
            m == "ml-epd-w",
        ));
    }
    v
}

/// `weights.png`: the spread of each method over a section's frames against the
/// heteroscedastic Cramér–Rao bound.
fn pipeline_weights(s: &PipelineScenario, sections: &[SectionRow]) -> anyhow::Result<Png> {
    let mut spread: Vec<Vec<Series>> = Vec::new();
    let mut titles = Vec::new();
    let ss: [(&str, Spread); 2] = [
        ("Dmax", |r| (r.dmax.std, r.crb.0)),
        ("Dmin", |r| (r.dmin.std, r.crb.1)),
    ];
    for (label, f) in ss {
        for cal in [false, true] {
            let rows: Vec<&SectionRow> = sections.iter().filter(|r| r.calibrated == cal).collect();
            spread.push(spread_series(&rows, f));
            titles.push(format!(
                "std of {label} over the frames, {}",
                if cal {
                    "with the depth table"
                } else {
                    "uncalibrated"
                }
            ));
        }
    }
    let panels = Panel::each(&spread, &titles, "std (mm, log)");
    render(
        Figure {
            ya: Axis { log: true },
            ..Figure::linear(
                "weights.png",
                format!(
                    "{}: spread per section against the Cramér–Rao bound",
                    s.name
                ),
                (2, 2),
                (1440, 1040),
                "nominal wall thickness of the section (mm)",
            )
        },
        &panels,
    )
}
