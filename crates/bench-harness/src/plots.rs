//! PNG plots in the paper's style: bias as line + markers, the error range (min…max) as
//! error bars, one series per method. Text is drawn with DejaVu Sans embedded in the
//! binary (no system fonts needed).

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use epd_io::font::FONT;
use plotters::prelude::*;

use crate::run::{SummaryRow, write_new};
use crate::scenario::Scenario;

fn register_font() -> anyhow::Result<()> {
    epd_io::font::register_font().map_err(|e| anyhow!(e))
}

fn colour(method: &str) -> RGBColor {
    match method {
        "c-epd" => RGBColor(214, 39, 40),
        "ru-epd" => RGBColor(31, 119, 180),
        "ml-epd" => RGBColor(44, 160, 44),
        "ml-epd-w" => RGBColor(148, 103, 189),
        _ => RGBColor(80, 80, 80),
    }
}

/// One series on a panel: name, colour, (x, centre, low, high) points.
struct Series {
    name: String,
    colour: RGBColor,
    points: Vec<(f64, f64, f64, f64)>,
    bars: bool,
    marker_triangle: bool,
    /// A reference line (the Cramér–Rao bound): dashed, no markers, drawn first.
    dashed: bool,
}

struct Panel<'a> {
    title: String,
    y_label: String,
    series: &'a [Series],
}

/// Axis transform: the data are drawn on a linear axis, as log10 when `log`.
#[derive(Clone, Copy)]
struct Axis {
    log: bool,
}

impl Axis {
    fn f(&self, v: f64) -> f64 {
        // Not drawn: a missing value, or a non-positive one on a log axis.
        if !self.log {
            v
        } else if v > 0.0 {
            v.log10()
        } else {
            f64::NAN
        }
    }
    fn label(&self, v: f64) -> String {
        if self.log {
            // Label the decades only, in plain numbers.
            if (v - v.round()).abs() > 1e-9 {
                return String::new();
            }
            let k = v.round() as i32;
            if (-4..=6).contains(&k) {
                format!("{}", 10f64.powi(k))
            } else {
                format!("1e{k}")
            }
        } else {
            let s = format!("{v:.4}");
            let s = s.trim_end_matches('0').trim_end_matches('.');
            if s == "-0" { "0".into() } else { s.into() }
        }
    }
}

fn draw_panel(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    p: &Panel<'_>,
    x_label: &str,
    xa: Axis,
    ya: Axis,
) -> anyhow::Result<()> {
    let err = |e: String| anyhow!("plot `{}`: {e}", p.title);
    let pts: Vec<(f64, f64)> = p
        .series
        .iter()
        .flat_map(|s| {
            s.points
                .iter()
                .flat_map(|&(x, c, lo, hi)| [(x, c), (x, lo), (x, hi)])
        })
        .collect();
    let finite: Vec<(f64, f64)> = pts
        .iter()
        .map(|&(x, y)| (xa.f(x), ya.f(y)))
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    if finite.is_empty() {
        return Ok(());
    }
    let (mut x0, mut x1) = finite
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &(x, _)| (a.min(x), b.max(x)));
    let (mut y0, mut y1) = finite
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &(_, y)| (a.min(y), b.max(y)));
    let dx = if x1 > x0 { 0.08 * (x1 - x0) } else { 0.5 };
    let dy = if y1 > y0 {
        0.08 * (y1 - y0)
    } else {
        0.5 * y0.abs().max(1e-3)
    };
    x0 -= dx;
    x1 += dx;
    y0 -= dy;
    // Headroom above the data for the legend (upper left), one line per series.
    y1 += dy + (y1 - y0) * (0.09 * p.series.len() as f64 + 0.04);
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, (FONT, 20))
        .margin(8)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(&p.y_label)
        .x_label_formatter(&|v| xa.label(*v))
        .y_label_formatter(&|v| ya.label(*v))
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 15))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    // Spread the methods' error bars a little along x so they do not hide each other.
    let n = p.series.iter().filter(|s| s.bars).count().max(1) as f64;
    let step = 0.012 * (x1 - x0);
    let mut bar_i = 0.0;
    // Reference lines first, beneath the methods.
    let ordered = p
        .series
        .iter()
        .filter(|s| s.dashed)
        .chain(p.series.iter().filter(|s| !s.dashed));
    for s in ordered {
        let shift = if s.bars {
            let v = (bar_i - (n - 1.0) / 2.0) * step;
            bar_i += 1.0;
            v
        } else {
            0.0
        };
        let c = s.colour;
        let line: Vec<(f64, f64)> = s
            .points
            .iter()
            .map(|&(x, m, _, _)| (xa.f(x) + shift, ya.f(m)))
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect();
        if s.dashed {
            chart
                .draw_series(DashedLineSeries::new(line.clone(), 7, 5, c.stroke_width(2)))
                .map_err(|e| err(e.to_string()))?
                .label(s.name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 8, y)], c.stroke_width(2))
                });
            continue;
        }
        // A missing value (NaN) breaks the line: no segment is drawn across a gap.
        let mut segments: Vec<Vec<(f64, f64)>> = vec![vec![]];
        for &(x, m, _, _) in &s.points {
            let (px, py) = (xa.f(x) + shift, ya.f(m));
            if px.is_finite() && py.is_finite() {
                if let Some(v) = segments.last_mut() {
                    v.push((px, py));
                }
            } else if segments.last().is_some_and(|v| !v.is_empty()) {
                segments.push(vec![]);
            }
        }
        for (k, seg) in segments.into_iter().enumerate() {
            let drawn = chart
                .draw_series(LineSeries::new(seg, c.stroke_width(2)))
                .map_err(|e| err(e.to_string()))?;
            if k == 0 {
                drawn.label(s.name.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                });
            }
        }
        if s.marker_triangle {
            chart
                .draw_series(line.iter().map(|&p| TriangleMarker::new(p, 5, c.filled())))
                .map_err(|e| err(e.to_string()))?;
        } else {
            chart
                .draw_series(line.iter().map(|&p| Circle::new(p, 4, c.filled())))
                .map_err(|e| err(e.to_string()))?;
        }
        if s.bars {
            chart
                .draw_series(
                    s.points
                        .iter()
                        .filter(|q| q.2.is_finite() && q.3.is_finite())
                        .map(|&(x, m, lo, hi)| {
                            ErrorBar::new_vertical(
                                xa.f(x) + shift,
                                ya.f(lo),
                                ya.f(m),
                                ya.f(hi),
                                c.stroke_width(1),
                                8,
                            )
                        }),
                )
                .map_err(|e| err(e.to_string()))?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, 13))
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    if 0.0 > y0 && 0.0 < y1 && !ya.log {
        chart
            .draw_series(LineSeries::new(vec![(x0, 0.0), (x1, 0.0)], BLACK.mix(0.4)))
            .map_err(|e| err(e.to_string()))?;
    }
    Ok(())
}

/// A figure: panels in a grid, one x axis description shared by all.
struct Figure<'a> {
    path: PathBuf,
    title: String,
    grid: (usize, usize),
    size: (u32, u32),
    x_label: &'a str,
    xa: Axis,
    ya: Axis,
}

/// Render panels in a grid to a PNG file (written whole).
fn render(fig: Figure<'_>, panels: &[Panel<'_>]) -> anyhow::Result<PathBuf> {
    let Figure {
        path,
        title,
        grid,
        size,
        x_label,
        xa,
        ya,
    } = fig;
    register_font()?;
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        let root = root
            .titled(&title, (FONT, 22))
            .map_err(|e| anyhow!("{e}"))?;
        let areas = root.split_evenly(grid);
        for (a, p) in areas.iter().zip(panels) {
            draw_panel(a, p, x_label, xa, ya)?;
        }
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    let mut png_bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_bytes, size.0, size.1);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().context("PNG header")?;
        w.write_image_data(&buf).context("PNG data")?;
    }
    write_new(&path, &png_bytes)
}

/// Numeric x of each swept value (its index when not a number).
fn xs(values: &[String]) -> Vec<f64> {
    let parsed: Vec<Option<f64>> = values.iter().map(|v| v.parse().ok()).collect();
    if parsed.iter().all(Option::is_some) {
        parsed.into_iter().flatten().collect()
    } else {
        (0..values.len()).map(|i| i as f64).collect()
    }
}

/// A reader's label for a swept scenario key.
fn axis_label(key: &str) -> String {
    match key {
        "noise.sigma_m" => "depth error σ (m)".into(),
        "noise.outlier_fraction" => "fraction of range outliers".into(),
        "noise.far_outlier_fraction" => "fraction of far outliers".into(),
        "noise.bias_b0_m" => "depth bias offset b0 (m)".into(),
        "noise.bias_b1" => "depth bias slope b1".into(),
        "pipe.nominal_od_in" => "nominal pipe diameter (inch)".into(),
        "pipe.ovality" => "ovality (Dmax − Dmin)/ID".into(),
        "pipe.wall_thickness_mm" => "wall thickness (mm)".into(),
        "poses.tilt_deg" => "tilt between pipe axis and optical axis (°)".into(),
        "points" => "input size N (points)".into(),
        "loss_scale_m" => "robust loss scale (m)".into(),
        "sensor.max_range_m" => "largest range kept (m)".into(),
        "sensor.min_range_m" => "smallest range kept (m)".into(),
        other => {
            // `section.some_key_unit` → "some key (unit)".
            let last = other.rsplit('.').next().unwrap_or(other);
            let mut words: Vec<&str> = last.split('_').collect();
            let unit = match words.last() {
                Some(&u) if ["m", "mm", "deg", "in"].contains(&u) => {
                    words.pop();
                    format!(" ({u})")
                }
                _ => String::new(),
            };
            format!("{}{unit}", words.join(" "))
        }
    }
}

/// Every plot of a scenario: diameter errors (Figs. 4, 5, 8; a second row without
/// C-EPD, whose bias sets the scale), the mean-diameter error, pose errors (Fig. 6),
/// time (Fig. 7; log–log over `points`) and the standard deviation of every parameter
/// against the Cramér–Rao bound (dashed).
pub fn plot_all(
    scenario: &Scenario,
    summary: &[SummaryRow],
    out: &Path,
) -> anyhow::Result<Vec<PathBuf>> {
    let values: Vec<String> = scenario.sweeps.iter().map(|(v, _)| v.clone()).collect();
    let x = xs(&values);
    // The x of each swept value, looked up in constant time (10 000 values × every row
    // of the summary would otherwise be quadratic); a repeated value keeps its first x.
    let mut x_of = std::collections::HashMap::new();
    for (v, &xi) in values.iter().zip(&x) {
        x_of.entry(v.as_str()).or_insert(xi);
    }
    let xv = |v: &str| x_of.get(v).copied();
    let methods: Vec<String> = scenario.sweeps[0]
        .1
        .methods
        .iter()
        .map(|m| m.name().to_string())
        .collect();
    let log_x =
        scenario.sweep_variable == "points" && x.iter().all(|&v| v > 0.0) && values.len() > 1;
    let xa = Axis { log: log_x };
    let x_label = axis_label(&scenario.sweep_variable);
    let select = |q: &str, m: &str| -> Vec<&SummaryRow> {
        summary
            .iter()
            .filter(|r| r.quantity == q && r.method == m)
            .collect()
    };
    // One series per method of quantity `q`: (centre, low, high) picked from each row.
    type Pick = fn(&SummaryRow) -> Option<(f64, f64, f64)>;
    let method_series = |q: &str, label: &str, bars: bool, pick: Pick| -> Vec<Series> {
        methods
            .iter()
            .map(|m| Series {
                name: format!("{} {label}", m.to_uppercase()),
                colour: colour(m),
                points: select(q, m)
                    .iter()
                    .filter_map(|r| {
                        let (c, lo, hi) = pick(r)?;
                        Some((xv(&r.sweep_value)?, c, lo, hi))
                    })
                    .collect(),
                bars,
                marker_triangle: false,
                dashed: false,
            })
            .collect()
    };
    let bias_and_range: Pick = |r| Some((r.stats.mean, r.stats.min, r.stats.max));
    let error_series = |q: &str| method_series(q, "(bias, range)", true, bias_and_range);
    let mut files = Vec::new();
    let name = &scenario.name;
    // Without C-EPD, whose bias sets the scale: the small biases of RU-EPD and ML-EPD.
    let without_c = |v: Vec<Series>| -> Vec<Series> {
        v.into_iter()
            .filter(|s| !s.name.starts_with("C-EPD"))
            .collect()
    };
    let has_c = methods.iter().any(|m| m == "c-epd") && methods.len() > 1;
    let diameter_figure = |qs: &[(&str, &str)], file: &str, what: &str| {
        let all: Vec<Vec<Series>> = qs.iter().map(|(q, _)| error_series(q)).collect();
        let zoomed: Vec<Vec<Series>> = qs.iter().map(|(q, _)| without_c(error_series(q))).collect();
        let mut panels: Vec<Panel<'_>> = qs
            .iter()
            .zip(&all)
            .map(|((_, t), s)| Panel {
                title: (*t).into(),
                y_label: "error (mm)".into(),
                series: s,
            })
            .collect();
        if has_c {
            panels.extend(qs.iter().zip(&zoomed).map(|((_, t), s)| Panel {
                title: format!("{t}, without C-EPD"),
                y_label: "error (mm)".into(),
                series: s,
            }));
        }
        let rows = if has_c { 2 } else { 1 };
        render(
            Figure {
                path: out.join(file),
                title: format!("{name}: {what} (line: bias, bars: min…max)"),
                grid: (rows, qs.len()),
                size: (700 * qs.len() as u32 + 40, 520 * rows as u32 + 40),
                x_label: &x_label,
                xa,
                ya: Axis { log: false },
            },
            &panels,
        )
    };
    files.push(diameter_figure(
        &[("dmax", "major axis Dmax"), ("dmin", "minor axis Dmin")],
        "diameter_error.png",
        "diameter estimation error",
    )?);
    files.push(diameter_figure(
        &[("dmean", "mean diameter (Dmax + Dmin)/2")],
        "dmean_error.png",
        "mean-diameter error",
    )?);
    let pose = [
        error_series("roll"),
        error_series("pitch"),
        error_series("yaw"),
        error_series("dy"),
        error_series("dz"),
    ];
    let titles = [
        ("roll θx", "deg"),
        ("pitch θy", "deg"),
        ("yaw θz", "deg"),
        ("Y displacement δy", "mm"),
        ("Z displacement δz", "mm"),
    ];
    let panels: Vec<Panel<'_>> = titles
        .iter()
        .zip(&pose)
        .map(|((t, u), s)| Panel {
            title: (*t).into(),
            y_label: format!("error ({u})"),
            series: s,
        })
        .collect();
    files.push(render(
        Figure {
            path: out.join("pose_error.png"),
            title: format!("{name}: pose estimation error (line: bias, bars: min…max)"),
            grid: (1, 5),
            size: (2300, 520),
            x_label: &x_label,
            xa,
            ya: Axis { log: false },
        },
        &panels,
    )?);
    let time = method_series("time_ms", "(mean, min…max)", true, bias_and_range);
    files.push(render(
        Figure {
            path: out.join("time.png"),
            title: format!(
                "{name}: processing time of one estimate{}",
                if scenario.timing {
                    " (trials one at a time)"
                } else {
                    " (trials in parallel: contended)"
                }
            ),
            grid: (1, 1),
            size: (900, 600),
            x_label: &x_label,
            xa,
            ya: Axis { log: log_x },
        },
        &[Panel {
            title: "estimate call".into(),
            y_label: "time (ms)".into(),
            series: &time,
        }],
    )?);
    let crb_panels = [
        ("dmax", "Dmax", "mm"),
        ("dmin", "Dmin", "mm"),
        ("dmean", "mean diameter (no bound)", "mm"),
        ("roll", "roll θx", "deg"),
        ("pitch", "pitch θy", "deg"),
        ("yaw", "yaw θz", "deg"),
        ("dy", "δy", "mm"),
        ("dz", "δz", "mm"),
    ];
    let crb_series: Vec<Vec<Series>> = crb_panels
        .iter()
        .map(|(q, _, _)| {
            let mut v = method_series(q, "std", false, |r| Some((r.stats.std, f64::NAN, f64::NAN)));
            if let Some(m) = methods.first().filter(|_| *q != "dmean") {
                v.push(Series {
                    name: "Cramér–Rao bound".into(),
                    colour: RGBColor(0, 0, 0),
                    points: select(q, m)
                        .iter()
                        .filter_map(|r| Some((xv(&r.sweep_value)?, r.crb_std?, f64::NAN, f64::NAN)))
                        .collect(),
                    bars: false,
                    marker_triangle: false,
                    dashed: true,
                });
            }
            v
        })
        .collect();
    let panels: Vec<Panel<'_>> = crb_panels
        .iter()
        .zip(&crb_series)
        .map(|((_, t, u), s)| Panel {
            title: (*t).into(),
            y_label: format!("standard deviation ({u})"),
            series: s,
        })
        .collect();
    files.push(render(
        Figure {
            path: out.join("std_vs_crb.png"),
            title: format!(
                "{name}: spread of the estimates against the Cramér–Rao bound (log scale)"
            ),
            grid: (2, 4),
            size: (2200, 1000),
            x_label: &x_label,
            xa,
            ya: Axis { log: true },
        },
        &panels,
    )?);
    Ok(files)
}

/// The figures of a pipeline run (see [`crate::pipeline`]): `diameters.png` (Fig. 11:
/// per-frame Dmax and Dmin against the nominal and the truth, with the depth table),
/// `section_errors.png` (Fig. 12: bias and error range per section, method and
/// calibration), `profile.png` (mean diameter and ovality along the distance) and
/// `weights.png` (spread of each method against the heteroscedastic Cramér–Rao bound).
pub fn plot_pipeline(
    s: &crate::pipeline::PipelineScenario,
    points: &[crate::pipeline::ProfilePoint],
    sections: &[crate::pipeline::SectionRow],
    out: &Path,
) -> anyhow::Result<Vec<PathBuf>> {
    use crate::pipeline::METHODS;
    use tof_sim::Pipe;
    let name = &s.name;
    let mut files = Vec::new();
    let pick = |si: usize, m: &'static str, cal: bool| {
        points
            .iter()
            .filter(move |p| p.section == si && p.method == m && p.calibrated == cal)
    };
    let reference = |label: &str, xs: (f64, f64), y: f64, colour: RGBColor| Series {
        name: label.into(),
        colour,
        points: vec![(xs.0, y, y, y), (xs.1, y, y, y)],
        bars: false,
        marker_triangle: false,
        dashed: true,
    };
    let grey = RGBColor(90, 90, 90);
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
                reference(
                    "nominal ID",
                    (0.0, n),
                    sec.pipe.inner_diameter() * 1e3,
                    grey,
                ),
                reference(&format!("true {label}"), (0.0, n), truth, RGBColor(0, 0, 0)),
            ];
            for m in METHODS {
                v.push(Series {
                    name: m.to_uppercase(),
                    colour: colour(m),
                    points: pick(si, m, true)
                        .filter_map(|p| {
                            let d = p.d_mm?;
                            let y = if which == 0 { d.0 } else { d.1 };
                            Some((p.frame as f64, y, y, y))
                        })
                        .collect(),
                    bars: false,
                    marker_triangle: m == "ml-epd-w",
                    dashed: false,
                });
            }
            fig11.push(v);
            titles.push(format!("{}: {label} (with the depth table)", sec.name));
        }
    }
    let panels: Vec<Panel<'_>> = fig11
        .iter()
        .zip(&titles)
        .map(|(v, t)| Panel {
            title: t.clone(),
            y_label: "diameter (mm)".into(),
            series: v,
        })
        .collect();
    files.push(render(
        Figure {
            path: out.join("diameters.png"),
            title: format!("{name}: per-frame diameters (Fig. 11)"),
            grid: (s.sections.len(), 2),
            size: (1440, 480 * s.sections.len() as u32 + 40),
            x_label: "frame",
            xa: Axis { log: false },
            ya: Axis { log: false },
        },
        &panels,
    )?);
    // Fig. 12: rows = Dmax, Dmin, mean diameter; columns = without / with the table;
    // x = the section's nominal wall (mm).
    let mut fig12: Vec<Vec<Series>> = Vec::new();
    let mut titles = Vec::new();
    type Q = fn(&crate::pipeline::SectionRow) -> &crate::stats::Stats;
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
    let panels: Vec<Panel<'_>> = fig12
        .iter()
        .zip(&titles)
        .map(|(v, t)| Panel {
            title: t.clone(),
            y_label: "error (mm)".into(),
            series: v,
        })
        .collect();
    files.push(render(
        Figure {
            path: out.join("section_errors.png"),
            title: format!("{name}: errors per section (Fig. 12; line: bias, bars: min…max)"),
            grid: (3, 2),
            size: (1440, 1480),
            x_label: "nominal wall thickness of the section (mm)",
            xa: Axis { log: false },
            ya: Axis { log: false },
        },
        &panels,
    )?);
    // Profile along the distance: mean diameter and ovality, with the table.
    // A dashed line over each section's stretch of the distance.
    let per_section = |label: &str, y: fn(&Pipe) -> f64| -> Vec<Series> {
        s.sections
            .iter()
            .map(|sec| {
                let x1 = sec.start_m + (s.frames_per_section as f64 - 1.0) * s.frame_spacing_m;
                reference(
                    &format!("{label} {}", sec.name),
                    (sec.start_m, x1),
                    y(&sec.pipe),
                    grey,
                )
            })
            .collect()
    };
    let nominal = per_section("nominal ID", |p| p.inner_diameter() * 1e3);
    // Along the distance, with a break (NaN) between sections.
    let along = |m: &str, f: fn((f64, f64)) -> f64| -> Vec<(f64, f64, f64, f64)> {
        let mut v = Vec::new();
        for si in 0..s.sections.len() {
            if si > 0 {
                v.push((f64::NAN, f64::NAN, f64::NAN, f64::NAN));
            }
            v.extend(
                points
                    .iter()
                    .filter(|p| p.section == si && p.method == m && p.calibrated)
                    .filter_map(|p| {
                        let y = f(p.d_mm?);
                        Some((p.distance_m, y, y, y))
                    }),
            );
        }
        v
    };
    let mut dmean = nominal;
    let mut oval = per_section("true ovality", |p| p.ovality * 100.0);
    for m in METHODS {
        dmean.push(Series {
            name: m.to_uppercase(),
            colour: colour(m),
            points: along(m, |d| 0.5 * (d.0 + d.1)),
            bars: false,
            marker_triangle: m == "ml-epd-w",
            dashed: false,
        });
        oval.push(Series {
            name: m.to_uppercase(),
            colour: colour(m),
            points: along(m, |d| 100.0 * (d.0 - d.1) / (0.5 * (d.0 + d.1))),
            bars: false,
            marker_triangle: m == "ml-epd-w",
            dashed: false,
        });
    }
    files.push(render(
        Figure {
            path: out.join("profile.png"),
            title: format!("{name}: pipe tally along the run (with the depth table)"),
            grid: (2, 1),
            size: (1440, 1000),
            x_label: "odometer distance (m)",
            xa: Axis { log: false },
            ya: Axis { log: false },
        },
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
        ],
    )?);
    // Spread against the heteroscedastic Cramér–Rao bound.
    let mut spread: Vec<Vec<Series>> = Vec::new();
    let mut titles = Vec::new();
    type S = fn(&crate::pipeline::SectionRow) -> (f64, f64);
    let ss: [(&str, S); 2] = [
        ("Dmax", |r| (r.dmax.std, r.crb.0)),
        ("Dmin", |r| (r.dmin.std, r.crb.1)),
    ];
    for (label, f) in ss {
        for cal in [false, true] {
            let rows: Vec<&crate::pipeline::SectionRow> =
                sections.iter().filter(|r| r.calibrated == cal).collect();
            let mut v = vec![Series {
                name: "Cramér–Rao bound".into(),
                colour: RGBColor(0, 0, 0),
                points: rows
                    .iter()
                    .filter(|r| r.method == "ml-epd")
                    .map(|r| {
                        let c = f(r).1;
                        (r.wall_true_mm, c, c, c)
                    })
                    .collect(),
                bars: false,
                marker_triangle: false,
                dashed: true,
            }];
            for m in METHODS {
                v.push(Series {
                    name: m.to_uppercase(),
                    colour: colour(m),
                    points: rows
                        .iter()
                        .filter(|r| r.method == m)
                        .map(|r| {
                            let c = f(r).0;
                            (r.wall_true_mm, c, c, c)
                        })
                        .collect(),
                    bars: false,
                    marker_triangle: m == "ml-epd-w",
                    dashed: false,
                });
            }
            spread.push(v);
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
    let panels: Vec<Panel<'_>> = spread
        .iter()
        .zip(&titles)
        .map(|(v, t)| Panel {
            title: t.clone(),
            y_label: "std (mm, log)".into(),
            series: v,
        })
        .collect();
    files.push(render(
        Figure {
            path: out.join("weights.png"),
            title: format!("{name}: spread per section against the Cramér–Rao bound"),
            grid: (2, 2),
            size: (1440, 1040),
            x_label: "nominal wall thickness of the section (mm)",
            xa: Axis { log: false },
            ya: Axis { log: true },
        },
        &panels,
    )?);
    Ok(files)
}

/// `approach.png` of an `[approach]` run: per distance, the mean-diameter error of the
/// plain fit and of the survey's straight estimate (mean, bars from min to max over the
/// frames), the error of `straight_until_m`, the bend radius's error and the direction's.
pub fn plot_approach(
    s: &crate::approach::ApproachScenario,
    rows: &[crate::approach::FrameRow],
    out: &Path,
) -> anyhow::Result<PathBuf> {
    // (x, mean, min, max) of `f` over the frames of each distance, finite values only.
    let spread = |segmented: bool, f: fn(&crate::approach::FrameRow) -> f64| {
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
            .collect::<Vec<_>>()
    };
    let series = |name: &str, c: RGBColor, points| Series {
        name: name.into(),
        colour: c,
        points,
        bars: true,
        marker_triangle: false,
        dashed: false,
    };
    let zero = {
        let lo = s.distances_m.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = s
            .distances_m
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        Series {
            name: "0".into(),
            colour: RGBColor(90, 90, 90),
            points: vec![(lo, 0.0, 0.0, 0.0), (hi, 0.0, 0.0, 0.0)],
            bars: false,
            marker_triangle: false,
            dashed: true,
        }
    };
    let red = RGBColor(214, 39, 40);
    let green = RGBColor(44, 160, 44);
    let p0 = vec![
        zero.clone_line(),
        series(
            "one fit on every point",
            red,
            spread(false, |r| r.dmean_err_mm),
        ),
        series(
            "straight section only",
            green,
            spread(true, |r| r.dmean_err_mm),
        ),
    ];
    let p0b = vec![
        zero.clone_line(),
        series(
            "straight section only",
            green,
            spread(true, |r| r.dmean_err_mm),
        ),
    ];
    let p1 = vec![
        zero.clone_line(),
        series(
            "straight_until_m",
            green,
            spread(true, |r| r.straight_until_err_mm),
        ),
    ];
    let p2 = vec![
        zero.clone_line(),
        series(
            "bend radius",
            green,
            spread(true, |r| r.bend_radius_err_pct),
        ),
        series(
            "direction (deg)",
            RGBColor(31, 119, 180),
            spread(true, |r| r.direction_err_deg),
        ),
    ];
    let panels = [
        Panel {
            title: "mean-diameter error".into(),
            y_label: "error (mm)".into(),
            series: &p0,
        },
        Panel {
            title: "mean-diameter error, segmented (zoom)".into(),
            y_label: "error (mm)".into(),
            series: &p0b,
        },
        Panel {
            title: "end of the straight section".into(),
            y_label: "error (mm)".into(),
            series: &p1,
        },
        Panel {
            title: "bend radius (%) and direction (deg) errors".into(),
            y_label: "error (% / deg)".into(),
            series: &p2,
        },
    ];
    render(
        Figure {
            path: out.join("approach.png"),
            title: format!(
                "{}: mean, min and max over the frames at each distance",
                s.name
            ),
            grid: (2, 2),
            size: (1440, 1000),
            x_label: "distance to the end of the straight section (m)",
            xa: Axis { log: false },
            ya: Axis { log: false },
        },
        &panels,
    )
}

impl Series {
    /// A copy of a reference line.
    fn clone_line(&self) -> Series {
        Series {
            name: self.name.clone(),
            colour: self.colour,
            points: self.points.clone(),
            bars: self.bars,
            marker_triangle: self.marker_triangle,
            dashed: self.dashed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_labels_are_for_people() {
        assert_eq!(
            axis_label("noise.outlier_fraction"),
            "fraction of range outliers"
        );
        assert_eq!(axis_label("pipe.some_length_mm"), "some length (mm)");
        assert_eq!(axis_label("seed"), "seed");
        assert!(!axis_label("poses.tilt_deg").contains('.'));
    }

    #[test]
    fn missing_or_non_positive_values_are_not_drawn_on_a_log_axis() {
        let a = Axis { log: true };
        assert!(a.f(f64::NAN).is_nan() && a.f(0.0).is_nan() && a.f(-1.0).is_nan());
        assert_eq!(a.f(100.0), 2.0);
    }
}
