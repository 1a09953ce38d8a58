//! PNG plots in the paper's style: bias as line + markers, the error range (min…max) as
//! error bars or a shaded band, one series per method. Text is drawn with DejaVu Sans
//! embedded in the binary (no system fonts needed, [`crate::font`]).
//!
//! This module only draws: it takes the data and returns encoded PNGs ([`Png`]); the run
//! that made the data writes them. It holds the drawing primitives ([`Series`], [`Panel`],
//! [`render`]) shared by the bench harness's figures (`sweep/figures.rs`,
//! `pipeline/figures.rs`, `approach/figures.rs`) and `epd profile`'s `profile.png`.

use crate::WriteError;
use crate::font::FONT;
use plotters::prelude::*;
pub use plotters::style::RGBColor;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// One encoded figure: its file name in the output folder and its PNG bytes.
#[derive(Clone, Debug)]
pub struct Png {
    /// File name (`diameter_error.png`, …).
    pub name: String,
    /// The encoded image.
    pub bytes: Vec<u8>,
}

/// A drawing error of `what` (a figure, a panel, a series).
fn draw_error(what: impl Into<String>) -> impl Fn(String) -> WriteError {
    let what = what.into();
    move |message| WriteError::Draw {
        what: what.clone(),
        message,
    }
}

fn register_font() -> Result<(), WriteError> {
    crate::font::register_font().map_err(|e| draw_error("a figure")(e.to_string()))
}

/// The palette's red, blue and green (matplotlib's tab10).
pub const RED: RGBColor = RGBColor(214, 39, 40);
/// The palette's blue.
pub const BLUE: RGBColor = RGBColor(31, 119, 180);
/// The palette's green.
pub const GREEN: RGBColor = RGBColor(44, 160, 44);

/// A method's colour (by its name in the CSV files), grey for any other.
pub fn colour(method: &str) -> RGBColor {
    match method {
        "c-epd" => RED,
        "ru-epd" => BLUE,
        "ml-epd" => GREEN,
        "ml-epd-w" => RGBColor(148, 103, 189),
        _ => RGBColor(80, 80, 80),
    }
}

/// The colour of a reference line (a Cramér–Rao bound, a nominal or true value): grey,
/// dashed and wider than the methods' lines, drawn beneath them so a method that sits on
/// it stays visible.
pub const REFERENCE: RGBColor = RGBColor(110, 110, 110);

/// A point of a series: (x, y, bar low, bar high).
pub type Point = (f64, f64, f64, f64);

/// A break in a line.
pub const GAP: Point = (f64::NAN, f64::NAN, f64::NAN, f64::NAN);

/// One series on a panel: name, colour, (x, centre, low, high) points.
pub struct Series {
    /// Its name in the legend.
    pub name: String,
    /// Its colour.
    pub colour: RGBColor,
    /// Its points: (x, centre, low, high); a NaN centre breaks the line.
    pub points: Vec<Point>,
    /// Error bars from low to high at each point.
    pub bars: bool,
    /// Triangle markers instead of circles.
    pub marker_triangle: bool,
    /// A reference line (the Cramér–Rao bound): dashed, no markers, drawn first.
    pub dashed: bool,
    /// A shaded band from low to high under the line (a 1-σ band), broken where the centre
    /// is missing.
    pub band: bool,
    /// Markers only, no line between them (frames flagged along a run).
    pub markers_only: bool,
}

/// One panel of a figure: its title, its y axis description and its series.
pub struct Panel<'a> {
    /// Its title.
    pub title: String,
    /// The description of its y axis.
    pub y_label: String,
    /// What it shows.
    pub series: &'a [Series],
}

impl<'a> Panel<'a> {
    /// One panel per list of `series` and title of `titles` (in order, as many as the
    /// shorter has), all with the y axis description `y_label`.
    pub fn each(series: &'a [Vec<Series>], titles: &[String], y_label: &str) -> Vec<Self> {
        series
            .iter()
            .zip(titles)
            .map(|(v, t)| Panel {
                title: t.clone(),
                y_label: y_label.into(),
                series: v,
            })
            .collect()
    }
}

/// Where a figure's legend goes; either way it never covers data.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Legend {
    /// One legend per panel, in headroom added above the data (panels whose series
    /// differ, as a pipeline's sections).
    PerPanel,
    /// One strip under the figure's title for all panels (the same methods on each).
    Shared,
}

/// Axis transform: the data are drawn on a linear axis, as log10 when `log`.
#[derive(Clone, Copy)]
pub struct Axis {
    /// Logarithmic.
    pub log: bool,
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
}

/// A linear axis's tick label: at most four decimals, no trailing zeros, no "-0".
fn linear_label(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

/// m·10^k in plain digits (`0.02`, `500`), or `me k` beyond six decades.
fn plain(m: u32, k: i32) -> String {
    match k {
        0..=6 => format!("{m}{}", "0".repeat(k as usize)),
        -6..=-1 => format!("0.{}{m}", "0".repeat((-k - 1) as usize)),
        _ => format!("{m}e{k}"),
    }
}

/// The ticks of a log axis spanning [lo, hi] in log10 units: every m·10^k (m = 1…9)
/// inside, as (position, label). Labelled: the decades when the axis spans more than
/// three of them, the 1-2-5 sequence down to one decade, 1-2-3-5 down to half a decade,
/// every m below that (and every m whenever fewer than two ticks would be labelled).
fn log_ticks(lo: f64, hi: f64) -> Vec<(f64, Option<String>)> {
    let span = hi - lo;
    let ticks: Vec<(f64, u32, i32)> = ((lo.floor() as i32)..=(hi.ceil() as i32))
        .flat_map(|k| (1..=9u32).map(move |m| (k as f64 + f64::from(m).log10(), m, k)))
        .filter(|&(t, _, _)| t >= lo && t <= hi)
        .collect();
    let labelled = |set: &[u32]| ticks.iter().filter(|t| set.contains(&t.1)).count();
    let all = [1, 2, 3, 4, 5, 6, 7, 8, 9];
    let mut set: &[u32] = if span > 3.0 {
        &[1]
    } else if span > 1.0 {
        &[1, 2, 5]
    } else if span > 0.5 {
        &[1, 2, 3, 5]
    } else {
        &all
    };
    if labelled(set) < 2 {
        set = if set == [1] { &[1, 2, 5] } else { &all };
        if labelled(set) < 2 {
            set = &all;
        }
    }
    ticks
        .into_iter()
        .map(|(t, m, k)| (t, set.contains(&m).then(|| plain(m, k))))
        .collect()
}

type Chart<'a, 'b> = ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// Grid lines, tick marks and labels of the log axes of a panel, drawn by hand (the mesh
/// is built without labels on a log axis: plotters would put them at round log10 values).
fn draw_log_ticks(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    chart: &mut Chart<'_, '_>,
    (xa, ya): (Axis, Axis),
    (x0, x1, y0, y1): (f64, f64, f64, f64),
) -> Result<(), WriteError> {
    let e = draw_error("a log axis");
    let base = area.get_base_pixel();
    let label_style = TextStyle::from((FONT, 13).into_font());
    let grid = |labelled: bool| {
        if labelled {
            RGBColor(205, 205, 205)
        } else {
            RGBColor(238, 238, 238)
        }
    };
    if ya.log {
        for (t, label) in log_ticks(y0, y1) {
            chart
                .draw_series(LineSeries::new([(x0, t), (x1, t)], grid(label.is_some())))
                .map_err(|x| e(x.to_string()))?;
            if let Some(l) = label {
                let (px, py) = chart.backend_coord(&(x0, t));
                let (px, py) = (px - base.0, py - base.1);
                area.draw(&PathElement::new([(px - 5, py), (px, py)], BLACK))
                    .map_err(|x| e(x.to_string()))?;
                let style = label_style.clone().pos(Pos::new(HPos::Right, VPos::Center));
                area.draw(&Text::new(l, (px - 8, py), style))
                    .map_err(|x| e(x.to_string()))?;
            }
        }
    }
    if xa.log {
        for (t, label) in log_ticks(x0, x1) {
            chart
                .draw_series(LineSeries::new([(t, y0), (t, y1)], grid(label.is_some())))
                .map_err(|x| e(x.to_string()))?;
            if let Some(l) = label {
                let (px, py) = chart.backend_coord(&(t, y0));
                let (px, py) = (px - base.0, py - base.1);
                area.draw(&PathElement::new([(px, py), (px, py + 5)], BLACK))
                    .map_err(|x| e(x.to_string()))?;
                let style = label_style.clone().pos(Pos::new(HPos::Center, VPos::Top));
                area.draw(&Text::new(l, (px, py + 8), style))
                    .map_err(|x| e(x.to_string()))?;
            }
        }
    }
    Ok(())
}

/// The data's extent in drawn units, padded by 8 % (`None`: nothing to draw).
fn extent(p: &Panel<'_>, xa: Axis, ya: Axis) -> Option<(f64, f64, f64, f64)> {
    let finite: Vec<(f64, f64)> = p
        .series
        .iter()
        .flat_map(|s| {
            s.points
                .iter()
                .flat_map(|&(x, c, lo, hi)| [(x, c), (x, lo), (x, hi)])
        })
        .map(|(x, y)| (xa.f(x), ya.f(y)))
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    if finite.is_empty() {
        return None;
    }
    let (x0, x1) = finite
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &(x, _)| (a.min(x), b.max(x)));
    let (y0, y1) = finite
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &(_, y)| (a.min(y), b.max(y)));
    let dx = if x1 > x0 { 0.08 * (x1 - x0) } else { 0.5 };
    let dy = if y1 > y0 {
        0.08 * (y1 - y0)
    } else {
        0.5 * y0.abs().max(1e-3)
    };
    Some((x0 - dx, x1 + dx, y0 - dy, y1 + dy))
}

fn draw_panel(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    p: &Panel<'_>,
    (x_label, x_names): (&str, &[String]),
    (xa, ya): (Axis, Axis),
    legend: Legend,
) -> Result<(), WriteError> {
    let err = draw_error(format!("plot `{}`", p.title));
    let Some((x0, x1, y0, mut y1)) = extent(p, xa, ya) else {
        return Ok(());
    };
    if legend == Legend::PerPanel {
        // Headroom above the data for the legend (upper left), one line per series.
        y1 += (y1 - y0) * (0.09 * p.series.len() as f64 + 0.04);
    }
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
        // Fewer x labels on a narrow panel, so they do not run into each other.
        .x_labels(match (xa.log, area.dim_in_pixel().0 < 600) {
            _ if !x_names.is_empty() => x_names.len(),
            (true, _) => 0,
            (false, true) => 6,
            (false, false) => 10,
        })
        .y_labels(if ya.log { 0 } else { 10 })
        .x_label_formatter(&|v| {
            if x_names.is_empty() {
                return linear_label(*v);
            }
            // A category's name at its integer x; nothing between them.
            let i = v.round();
            match x_names.get(i as usize) {
                Some(n) if (v - i).abs() < 1e-9 && i >= 0.0 => n.clone(),
                _ => String::new(),
            }
        })
        .y_label_formatter(&|v| linear_label(*v))
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 15))
        .light_line_style(RGBColor(238, 238, 238))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    draw_log_ticks(area, &mut chart, (xa, ya), (x0, x1, y0, y1))?;
    if 0.0 > y0 && 0.0 < y1 && !ya.log {
        chart
            .draw_series(LineSeries::new(vec![(x0, 0.0), (x1, 0.0)], BLACK.mix(0.5)))
            .map_err(|e| err(e.to_string()))?;
    }
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
        draw_series(&mut chart, s, (xa, ya), shift).map_err(|e| err(e.to_string()))?;
    }
    if legend == Legend::PerPanel {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((FONT, 13))
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(|e| err(e.to_string()))?;
    }
    Ok(())
}

/// One series: a dashed reference line, or the method's line (broken at missing values)
/// with markers and, when `bars`, its error bars; `shift` moves it along x (drawn units).
fn draw_series(
    chart: &mut Chart<'_, '_>,
    s: &Series,
    (xa, ya): (Axis, Axis),
    shift: f64,
) -> Result<(), WriteError> {
    let e = draw_error(format!("series `{}`", s.name));
    let c = s.colour;
    let line: Vec<(f64, f64)> = s
        .points
        .iter()
        .map(|&(x, m, _, _)| (xa.f(x) + shift, ya.f(m)))
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    if s.dashed {
        chart
            .draw_series(DashedLineSeries::new(line, 9, 6, c.stroke_width(3)))
            .map_err(|x| e(x.to_string()))?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 8, y)], c.stroke_width(3)));
        return Ok(());
    }
    if s.band {
        draw_band(chart, s, (xa, ya), shift).map_err(&e)?;
    }
    if s.markers_only {
        chart
            .draw_series(line.iter().map(|&p| Cross::new(p, 6, c.stroke_width(2))))
            .map_err(|x| e(x.to_string()))?
            .label(s.name.clone())
            .legend(move |(x, y)| Cross::new((x + 10, y), 6, c.stroke_width(2)));
        return Ok(());
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
            .map_err(|x| e(x.to_string()))?;
        if k == 0 {
            drawn.label(s.name.clone()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
            });
        }
    }
    if s.marker_triangle {
        chart
            .draw_series(line.iter().map(|&p| TriangleMarker::new(p, 5, c.filled())))
            .map_err(|x| e(x.to_string()))?;
    } else {
        chart
            .draw_series(line.iter().map(|&p| Circle::new(p, 4, c.filled())))
            .map_err(|x| e(x.to_string()))?;
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
            .map_err(|x| e(x.to_string()))?;
    }
    Ok(())
}

/// The shaded band of `s` from each point's low to its high, one polygon per stretch
/// without a missing value.
fn draw_band(
    chart: &mut Chart<'_, '_>,
    s: &Series,
    (xa, ya): (Axis, Axis),
    shift: f64,
) -> Result<(), String> {
    let mut stretches: Vec<Vec<(f64, f64, f64)>> = vec![vec![]];
    for &(x, _, lo, hi) in &s.points {
        let (px, l, h) = (xa.f(x) + shift, ya.f(lo), ya.f(hi));
        if px.is_finite() && l.is_finite() && h.is_finite() {
            if let Some(v) = stretches.last_mut() {
                v.push((px, l, h));
            }
        } else if stretches.last().is_some_and(|v| !v.is_empty()) {
            stretches.push(vec![]);
        }
    }
    let fill = s.colour.mix(0.25).filled();
    for st in stretches.into_iter().filter(|v| !v.is_empty()) {
        let mut outline: Vec<(f64, f64)> = st.iter().map(|&(x, _, h)| (x, h)).collect();
        outline.extend(st.iter().rev().map(|&(x, l, _)| (x, l)));
        if st.len() == 1 {
            // One point: a bar of the band's height.
            chart
                .draw_series(std::iter::once(PathElement::new(
                    outline,
                    s.colour.mix(0.4).stroke_width(3),
                )))
                .map_err(|x| x.to_string())?;
            continue;
        }
        chart
            .draw_series(std::iter::once(Polygon::new(outline, fill)))
            .map_err(|x| x.to_string())?;
    }
    Ok(())
}

/// The legend strip of a [`Legend::Shared`] figure: each series name once, in order of
/// appearance, centred on one line.
fn draw_shared_legend(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    panels: &[Panel<'_>],
) -> Result<(), WriteError> {
    let e = draw_error("the legend");
    let mut seen: Vec<&Series> = Vec::new();
    for s in panels.iter().flat_map(|p| p.series.iter()) {
        if !seen.iter().any(|t| t.name == s.name) {
            seen.push(s);
        }
    }
    let style = TextStyle::from((FONT, 16).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let (sample, gap) = (34i32, 28i32);
    let widths: Vec<i32> = seen
        .iter()
        .map(|s| {
            area.estimate_text_size(&s.name, &style)
                .map(|(w, _)| w as i32)
                .map_err(|x| e(x.to_string()))
        })
        .collect::<Result<_, WriteError>>()?;
    let total: i32 = widths.iter().map(|w| sample + 6 + w + gap).sum::<i32>() - gap;
    let (w, h) = area.dim_in_pixel();
    let y = h as i32 / 2;
    let mut x = (w as i32 - total).max(0) / 2;
    for (s, tw) in seen.iter().zip(widths) {
        let c = s.colour;
        if s.dashed {
            for k in 0..3 {
                let a = x + k * 13;
                area.draw(&PathElement::new([(a, y), (a + 8, y)], c.stroke_width(3)))
                    .map_err(|x| e(x.to_string()))?;
            }
        } else {
            area.draw(&PathElement::new(
                [(x, y), (x + sample, y)],
                c.stroke_width(2),
            ))
            .map_err(|x| e(x.to_string()))?;
            let mid = (x + sample / 2, y);
            if s.marker_triangle {
                area.draw(&TriangleMarker::new(mid, 5, c.filled()))
                    .map_err(|x| e(x.to_string()))?;
            } else {
                area.draw(&Circle::new(mid, 4, c.filled()))
                    .map_err(|x| e(x.to_string()))?;
            }
        }
        area.draw(&Text::new(
            s.name.clone(),
            (x + sample + 6, y),
            style.clone(),
        ))
        .map_err(|x| e(x.to_string()))?;
        x += sample + 6 + tw + gap;
    }
    Ok(())
}

/// A figure: panels in a grid, one x axis description shared by all.
pub struct Figure<'a> {
    /// The PNG's file name.
    pub name: String,
    /// The title over the panels.
    pub title: String,
    /// Rows and columns of panels.
    pub grid: (usize, usize),
    /// Width and height (px).
    pub size: (u32, u32),
    /// The description of the x axis, shared by all panels.
    pub x_label: &'a str,
    /// The x axis's transform.
    pub xa: Axis,
    /// The y axes' transform.
    pub ya: Axis,
    /// Where the legend goes.
    pub legend: Legend,
    /// Names of the x values 0, 1, 2, … when they are categories (a swept table), drawn
    /// as the x tick labels instead of the numbers; empty: numbers.
    pub x_names: &'a [String],
}

impl<'a> Figure<'a> {
    /// The figure `name` with `title` over a `grid` of panels, `size` px: linear axes,
    /// numbers on the x axis ([`x_label`](Self::x_label) describing it) and a legend in
    /// each panel; other axes or legends by struct update (`Figure { ya: Axis { log: true
    /// }, ..Figure::linear(…) }`).
    pub fn linear(
        name: &str,
        title: String,
        grid: (usize, usize),
        size: (u32, u32),
        x_label: &'a str,
    ) -> Self {
        Figure {
            name: name.into(),
            title,
            grid,
            size,
            x_label,
            xa: Axis { log: false },
            ya: Axis { log: false },
            legend: Legend::PerPanel,
            x_names: &[],
        }
    }
}

/// Render panels in a grid to an encoded PNG.
pub fn render(fig: Figure<'_>, panels: &[Panel<'_>]) -> Result<Png, WriteError> {
    let Figure {
        name,
        title,
        grid,
        size,
        x_label,
        xa,
        ya,
        legend,
        x_names,
    } = fig;
    register_font()?;
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&WHITE)
            .map_err(|e| draw_error(name.clone())(e.to_string()))?;
        let mut root = root
            .titled(&title, (FONT, 22))
            .map_err(|e| draw_error(name.clone())(e.to_string()))?;
        if legend == Legend::Shared {
            let (strip, rest) = root.split_vertically(34);
            draw_shared_legend(&strip, panels)?;
            root = rest;
        }
        let areas = root.split_evenly(grid);
        for (a, p) in areas.iter().zip(panels) {
            draw_panel(a, p, (x_label, x_names), (xa, ya), legend)?;
        }
        root.present()
            .map_err(|e| draw_error(name.clone())(e.to_string()))?;
    }
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, size.0, size.1);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let png = |e: png::EncodingError| WriteError::io(name.clone(), std::io::Error::other(e));
        let mut w = enc.write_header().map_err(png)?;
        w.write_image_data(&buf).map_err(png)?;
    }
    Ok(Png { name, bytes })
}

impl Series {
    /// A dashed horizontal reference line from x = xs.0 to xs.1 at height y.
    pub fn reference(label: &str, xs: (f64, f64), y: f64, colour: RGBColor) -> Series {
        Series {
            name: label.into(),
            colour,
            points: vec![(xs.0, y, y, y), (xs.1, y, y, y)],
            bars: false,
            marker_triangle: false,
            dashed: true,
            band: false,
            markers_only: false,
        }
    }

    /// A solid line through `points`, without bars; triangle markers if `triangles`.
    pub fn line(
        name: impl Into<String>,
        colour: RGBColor,
        points: Vec<Point>,
        triangles: bool,
    ) -> Series {
        Series {
            name: name.into(),
            colour,
            points,
            bars: false,
            marker_triangle: triangles,
            dashed: false,
            band: false,
            markers_only: false,
        }
    }

    /// Means through `points` with bars from their min to their max.
    pub fn bars(name: impl Into<String>, colour: RGBColor, points: Vec<Point>) -> Series {
        Series {
            name: name.into(),
            colour,
            points,
            bars: true,
            marker_triangle: false,
            dashed: false,
            band: false,
            markers_only: false,
        }
    }

    /// A copy of a reference line.
    pub fn clone_line(&self) -> Series {
        Series {
            name: self.name.clone(),
            colour: self.colour,
            points: self.points.clone(),
            bars: self.bars,
            marker_triangle: self.marker_triangle,
            dashed: self.dashed,
            band: self.band,
            markers_only: self.markers_only,
        }
    }
}

/// A diverging colour for `v` in [−1, 1]: blue (−1) through white (0) to red (+1).
pub fn diverging(v: f64) -> RGBColor {
    let v = if v.is_finite() {
        v.clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let mix = |a: RGBColor, t: f64| {
        let f = |c: u8| (255.0 + (f64::from(c) - 255.0) * t).round() as u8;
        RGBColor(f(a.0), f(a.1), f(a.2))
    };
    if v < 0.0 { mix(BLUE, -v) } else { mix(RED, v) }
}

/// A map of values at (x, y) points: each point a dot coloured by its value on
/// [`diverging`] from −`limit` (blue) to +`limit` (red), with a colour bar labelled
/// `value_label`; axes `x_label`, `y_label` over `y_range`.
pub struct ValueMap<'a> {
    /// The PNG's file name.
    pub name: String,
    /// The title.
    pub title: String,
    /// The points: (x, y, value).
    pub points: &'a [(f64, f64, f64)],
    /// The colour scale's limit (the value's unit).
    pub limit: f64,
    /// The x axis's description.
    pub x_label: &'a str,
    /// The y axis's description.
    pub y_label: &'a str,
    /// The y axis's range.
    pub y_range: (f64, f64),
    /// The colour bar's description.
    pub value_label: &'a str,
}

/// The largest colour-scale limit [`value_map`] draws: the scale spans 2·limit and its
/// ticks are cut from that span, which must stay finite with room (1.8e308 is f64's
/// largest; a limit of 1e308 overflowed the span and the tick search never ended).
pub const MAX_VALUE_LIMIT: f64 = 1e300;

/// Draw a [`ValueMap`] as a PNG (1400 × 800 px).
pub fn value_map(m: &ValueMap<'_>) -> Result<Png, WriteError> {
    register_font()?;
    let size = (1400u32, 800u32);
    let e = draw_error(m.name.clone());
    let (mut x0, mut x1) = m
        .points
        .iter()
        .filter(|p| p.0.is_finite())
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    if !(x1 > x0) {
        (x0, x1) = (0.0, 1.0);
    }
    if !(m.limit > 0.0 && m.limit <= MAX_VALUE_LIMIT) {
        return Err(e(format!(
            "the colour scale's limit {:e} must lie in (0, {MAX_VALUE_LIMIT:e}]",
            m.limit
        )));
    }
    let limit = m.limit;
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
        let root = root
            .titled(&m.title, (FONT, 22))
            .map_err(|x| e(x.to_string()))?;
        let (main, bar) = root.split_horizontally(size.0 - 150);
        let mut chart = ChartBuilder::on(&main)
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, m.y_range.0..m.y_range.1)
            .map_err(|x| e(x.to_string()))?;
        chart
            .configure_mesh()
            .x_desc(m.x_label)
            .y_desc(m.y_label)
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 16))
            .x_label_formatter(&|v| linear_label(*v))
            .y_label_formatter(&|v| linear_label(*v))
            .disable_mesh()
            .draw()
            .map_err(|x| e(x.to_string()))?;
        // A dark ground, so that the white of a zero residual shows.
        chart
            .plotting_area()
            .fill(&RGBColor(64, 64, 64))
            .map_err(|x| e(x.to_string()))?;
        chart
            .draw_series(
                m.points
                    .iter()
                    .filter(|p| p.0.is_finite() && p.1.is_finite() && p.2.is_finite())
                    .map(|&(x, y, v)| Circle::new((x, y), 1, diverging(v / limit).filled())),
            )
            .map_err(|x| e(x.to_string()))?;
        let mut scale = ChartBuilder::on(&bar)
            .margin(20)
            .margin_top(40)
            .set_label_area_size(LabelAreaPosition::Right, 60)
            .build_cartesian_2d(0.0..1.0, -limit..limit)
            .map_err(|x| e(x.to_string()))?;
        scale
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc(m.value_label)
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 16))
            .y_label_formatter(&|v| linear_label(*v))
            .draw()
            .map_err(|x| e(x.to_string()))?;
        let steps = 200;
        scale
            .draw_series((0..steps).map(|k| {
                let a = -limit + 2.0 * limit * k as f64 / steps as f64;
                let b = a + 2.0 * limit / steps as f64;
                Rectangle::new(
                    [(0.0, a), (1.0, b)],
                    diverging(0.5 * (a + b) / limit).filled(),
                )
            }))
            .map_err(|x| e(x.to_string()))?;
        root.present().map_err(|x| e(x.to_string()))?;
    }
    let mut bytes = Vec::new();
    crate::depth_png::encode_rgb(&mut bytes, &buf, size)?;
    Ok(Png {
        name: m.name.clone(),
        bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ticks_label_decades_or_the_1_2_5_sequence() {
        let labels = |lo: f64, hi: f64| -> Vec<String> {
            log_ticks(lo, hi).into_iter().filter_map(|t| t.1).collect()
        };
        // 0.01 … 100: four decades, decades only; 9 ticks per decade plus the last.
        assert_eq!(labels(-2.0, 2.0), ["0.01", "0.1", "1", "10", "100"]);
        assert_eq!(log_ticks(-2.0, 2.0).len(), 4 * 9 + 1);
        // 0.015 … 0.25: the 1-2-5 sequence.
        assert_eq!(
            labels(0.015f64.log10(), 0.25f64.log10()),
            ["0.02", "0.05", "0.1", "0.2"]
        );
        // 0.031 … 0.058: every m.
        assert_eq!(labels(0.031f64.log10(), 0.058f64.log10()), ["0.04", "0.05"]);
        // Ticks sit at log10(m·10^k).
        let t = log_ticks(0.0, 1.0);
        assert!((t[1].0 - 2f64.log10()).abs() < 1e-12 && t[1].1.as_deref() == Some("2"));
    }

    #[test]
    fn plain_numbers_have_no_float_noise() {
        assert_eq!(plain(3, -1), "0.3");
        assert_eq!(plain(7, -3), "0.007");
        assert_eq!(plain(5, 2), "500");
        assert_eq!(plain(2, -9), "2e-9");
    }

    #[test]
    fn missing_or_non_positive_values_are_not_drawn_on_a_log_axis() {
        let a = Axis { log: true };
        assert!(a.f(f64::NAN).is_nan() && a.f(0.0).is_nan() && a.f(-1.0).is_nan());
        assert_eq!(a.f(100.0), 2.0);
    }
}
