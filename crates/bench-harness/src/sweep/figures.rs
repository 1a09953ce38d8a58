//! The figures of a sweep, drawn with the primitives of [`crate::plots`] from its summary
//! rows: the errors against the swept value (Figs. 4–6, 8), the time of an estimate
//! (Fig. 7) and the spread against the Cramér–Rao bound.

use std::collections::HashMap;

use super::scenario::Scenario;
use super::summary::SummaryRow;
use crate::plots::{
    Axis, BLUE, Figure, GREEN, Legend, Panel, Png, RED, REFERENCE, Series, colour, render,
};
use epd_frame::sampling::SamplingMethod;

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

/// Picks (centre, low, high) from a summary row.
type Pick = fn(&SummaryRow) -> Option<(f64, f64, f64)>;

/// The bias and the error range: (mean, min, max).
const BIAS_AND_RANGE: Pick = |r| Some((r.stats.mean, r.stats.min, r.stats.max));

/// What every figure of a sweep shares: its summary rows, the x of each swept value and
/// the methods, in the scenario's order.
struct Sweep<'a> {
    name: &'a str,
    summary: &'a [SummaryRow],
    /// The x of each swept value, looked up in constant time (10 000 values × every row
    /// of the summary would otherwise be quadratic); a repeated value keeps its first x.
    x_of: HashMap<&'a str, f64>,
    methods: Vec<String>,
    x_label: String,
    xa: Axis,
    /// The swept values' names when they are not numbers (drawn at x = 0, 1, …).
    x_names: Vec<String>,
    /// Trials were run one at a time (`time_ms` not contended).
    timing: bool,
}

impl<'a> Sweep<'a> {
    fn new(scenario: &'a Scenario, summary: &'a [SummaryRow]) -> Self {
        let values: Vec<&str> = scenario.sweeps.iter().map(|(v, _)| v.as_str()).collect();
        let owned: Vec<String> = values.iter().map(|v| (*v).to_string()).collect();
        let x = xs(&owned);
        let numeric = owned.iter().all(|v| v.parse::<f64>().is_ok());
        let x_names = if numeric { Vec::new() } else { owned.clone() };
        let mut x_of = HashMap::new();
        for (v, &xi) in values.iter().zip(&x) {
            x_of.entry(*v).or_insert(xi);
        }
        let methods = scenario
            .sweeps
            .first()
            .map(|(_, s)| s.methods.iter().map(|m| m.name().to_string()).collect())
            .unwrap_or_default();
        let log_x =
            scenario.sweep_variable == "points" && x.iter().all(|&v| v > 0.0) && values.len() > 1;
        Sweep {
            name: &scenario.name,
            summary,
            x_of,
            methods,
            x_label: axis_label(&scenario.sweep_variable),
            xa: Axis { log: log_x },
            x_names,
            timing: scenario.timing,
        }
    }

    /// One series per method of quantity `q`, (centre, low, high) from `pick`.
    fn series(&self, q: &str, bars: bool, pick: Pick) -> Vec<Series> {
        self.methods
            .iter()
            .map(|m| Series {
                name: m.to_uppercase(),
                colour: colour(m),
                points: self.points(q, m, pick),
                bars,
                marker_triangle: false,
                dashed: false,
                band: false,
                markers_only: false,
            })
            .collect()
    }

    /// (x, centre, low, high) of quantity `q` and method `m`, one per swept value.
    fn points(&self, q: &str, m: &str, pick: Pick) -> Vec<(f64, f64, f64, f64)> {
        self.summary
            .iter()
            .filter(|r| r.quantity == q && r.method == m)
            .filter_map(|r| {
                let (c, lo, hi) = pick(r)?;
                Some((*self.x_of.get(r.sweep_value.as_str())?, c, lo, hi))
            })
            .collect()
    }

    /// Whether C-EPD is one of several methods (its bias then sets an error plot's
    /// scale, and a second row without it shows the others').
    fn has_c(&self) -> bool {
        self.methods.iter().any(|m| m == "c-epd") && self.methods.len() > 1
    }

    fn figure(&self, name: &str, title: String, grid: (usize, usize), ya: Axis) -> Figure<'_> {
        // Panels 500 px high and 700 px wide (460 beyond three columns; a lone column
        // 1000, so the figure's title fits), plus the title and the legend strip.
        let width = match grid.1 {
            1 => 1000,
            2 | 3 => 700,
            _ => 460,
        };
        Figure {
            name: name.into(),
            title,
            grid,
            size: (width * grid.1 as u32 + 40, 500 * grid.0 as u32 + 74),
            x_label: &self.x_label,
            xa: self.xa,
            ya,
            legend: Legend::Shared,
            x_names: &self.x_names,
        }
    }
}

/// An error figure (Figs. 4–6, 8): one panel per (quantity, title, unit), the bias as
/// line and the error range as bars per method; when C-EPD is among several methods a
/// second row repeats the panels without it, whose bias sets the first row's scale.
fn error_figure(
    sw: &Sweep<'_>,
    qs: &[(&str, &str, &str)],
    name: &str,
    what: &str,
) -> anyhow::Result<Png> {
    let all: Vec<Vec<Series>> = qs
        .iter()
        .map(|(q, _, _)| sw.series(q, true, BIAS_AND_RANGE))
        .collect();
    let without_c: Vec<Vec<Series>> = all
        .iter()
        .map(|v| {
            v.iter()
                .filter(|s| s.name != "C-EPD")
                .map(Series::clone_line)
                .collect()
        })
        .collect();
    let mut panels: Vec<Panel<'_>> = qs
        .iter()
        .zip(&all)
        .map(|((_, t, u), s)| Panel {
            title: (*t).into(),
            y_label: format!("error ({u})"),
            series: s,
        })
        .collect();
    let rows = if sw.has_c() {
        panels.extend(qs.iter().zip(&without_c).map(|((_, t, u), s)| Panel {
            title: format!("{t}, without C-EPD"),
            y_label: format!("error ({u})"),
            series: s,
        }));
        2
    } else {
        1
    };
    render(
        sw.figure(
            name,
            format!(
                "{}: {what} (line: bias, bars: min…max over the trials)",
                sw.name
            ),
            (rows, qs.len()),
            Axis { log: false },
        ),
        &panels,
    )
}

/// `diameter_error.png` (Figs. 4, 5, 8): errors of Dmax and Dmin.
fn diameter_figure(sw: &Sweep<'_>) -> anyhow::Result<Png> {
    error_figure(
        sw,
        &[
            ("dmax", "major axis Dmax", "mm"),
            ("dmin", "minor axis Dmin", "mm"),
        ],
        "diameter_error.png",
        "diameter estimation error",
    )
}

/// `dmean_error.png`: error of the mean diameter (Dmax + Dmin)/2.
fn dmean_figure(sw: &Sweep<'_>) -> anyhow::Result<Png> {
    error_figure(
        sw,
        &[("dmean", "mean diameter (Dmax + Dmin)/2", "mm")],
        "dmean_error.png",
        "mean-diameter error",
    )
}

/// `pose_error.png` (Fig. 6): errors of roll, pitch, yaw, δy and δz.
fn pose_figure(sw: &Sweep<'_>) -> anyhow::Result<Png> {
    error_figure(
        sw,
        &[
            ("roll", "roll θx", "deg"),
            ("pitch", "pitch θy", "deg"),
            ("yaw", "yaw θz", "deg"),
            ("dy", "Y displacement δy", "mm"),
            ("dz", "Z displacement δz", "mm"),
        ],
        "pose_error.png",
        "pose estimation error",
    )
}

/// `time.png` (Fig. 7): time of one estimate call, mean and min…max; log–log over
/// `points`.
fn time_figure(sw: &Sweep<'_>) -> anyhow::Result<Png> {
    let time = sw.series("time_ms", true, BIAS_AND_RANGE);
    let how = if sw.timing {
        "trials one at a time"
    } else {
        "trials in parallel: contended"
    };
    let mut fig = sw.figure(
        "time.png",
        format!("{}: processing time of one estimate ({how})", sw.name),
        (1, 1),
        Axis { log: sw.xa.log },
    );
    fig.size = (900, 640);
    render(
        fig,
        &[Panel {
            title: "estimate call (line: mean, bars: min…max)".into(),
            y_label: "time (ms)".into(),
            series: &time,
        }],
    )
}

/// `std_vs_crb.png`: the standard deviation of every parameter's estimates (and of the
/// mean diameter) against the Cramér–Rao bound, dashed beneath (log scale).
fn crb_figure(sw: &Sweep<'_>) -> anyhow::Result<Png> {
    let quantities = [
        ("dmax", "Dmax", "mm"),
        ("dmin", "Dmin", "mm"),
        ("dmean", "mean diameter (no bound)", "mm"),
        ("roll", "roll θx", "deg"),
        ("pitch", "pitch θy", "deg"),
        ("yaw", "yaw θz", "deg"),
        ("dy", "Y displacement δy", "mm"),
        ("dz", "Z displacement δz", "mm"),
    ];
    let std: Pick = |r| Some((r.stats.std, f64::NAN, f64::NAN));
    let crb: Pick = |r| Some((r.crb_std?, f64::NAN, f64::NAN));
    let series: Vec<Vec<Series>> = quantities
        .iter()
        .map(|(q, _, _)| {
            let mut v = Vec::new();
            // The bound depends on the frame, not the method: the first method's rows.
            if let Some(m) = sw.methods.first().filter(|_| *q != "dmean") {
                v.push(Series {
                    // `crb_std` is the bound for range noise, whatever the scenario's model.
                    name: "Cramér–Rao bound for range noise".into(),
                    colour: REFERENCE,
                    points: sw.points(q, m, crb),
                    bars: false,
                    marker_triangle: false,
                    dashed: true,
                    band: false,
                    markers_only: false,
                });
            }
            v.extend(sw.series(q, false, std));
            v
        })
        .collect();
    let panels: Vec<Panel<'_>> = quantities
        .iter()
        .zip(&series)
        .map(|((_, t, u), s)| Panel {
            title: (*t).into(),
            y_label: format!("standard deviation ({u})"),
            series: s,
        })
        .collect();
    render(
        sw.figure(
            "std_vs_crb.png",
            format!(
                "{}: spread of the estimates over the trials against the Cramér–Rao bound (log scale)",
                sw.name
            ),
            (2, 4),
            Axis { log: true },
        ),
        &panels,
    )
}

/// `coverage.png`: how often the reported ±1.96σ̂ interval covered the true Dmax and Dmin
/// (and the mean diameter when the summary has its coverage), per swept value (the nominal 0.95 dashed): a 1-σ that holds gives
/// 0.95 within the binomial standard error √(0.95·0.05/trials) of the count.
fn coverage_figure(sw: &Sweep<'_>) -> anyhow::Result<Png> {
    // The quantities whose coverage the summary holds (the mean diameter's needs its own
    // 1-σ per trial).
    let quantities: Vec<(&str, &str)> = [
        ("dmax", "Dmax"),
        ("dmin", "Dmin"),
        ("dmean", "mean diameter"),
    ]
    .into_iter()
    .filter(|(q, _)| {
        sw.summary
            .iter()
            .any(|r| r.quantity == *q && r.coverage95.is_some())
    })
    .collect();
    let cov: Pick = |r| Some((r.coverage95?, f64::NAN, f64::NAN));
    let nominal: Pick = |r| r.coverage95.map(|_| (0.95, f64::NAN, f64::NAN));
    let series: Vec<Vec<Series>> = quantities
        .iter()
        .map(|(q, _)| {
            let mut v = Vec::new();
            if let Some(m) = sw.methods.first() {
                v.push(Series {
                    name: "nominal 0.95".into(),
                    colour: REFERENCE,
                    points: sw.points(q, m, nominal),
                    bars: false,
                    marker_triangle: false,
                    dashed: true,
                    band: false,
                    markers_only: false,
                });
            }
            v.extend(sw.series(q, false, cov));
            v
        })
        .collect();
    let panels: Vec<Panel<'_>> = quantities
        .iter()
        .zip(&series)
        .map(|((_, t), s)| Panel {
            title: (*t).into(),
            y_label: "coverage of ±1.96σ̂".into(),
            series: s,
        })
        .collect();
    // Named values (a swept table) need room for their names: one panel per row, about
    // 150 px per value.
    let rows = quantities.len().max(1);
    let (grid, size) = if sw.x_names.is_empty() {
        ((1, rows), None)
    } else {
        let width = (150 * sw.x_names.len() as u32 + 140).max(1040);
        ((rows, 1), Some((width, 500 * rows as u32 + 74)))
    };
    let mut fig = sw.figure(
        "coverage.png",
        format!(
            "{}: share of trials whose ±1.96σ̂ interval holds the truth",
            sw.name
        ),
        grid,
        Axis { log: false },
    );
    if let Some(size) = size {
        fig.size = size;
    }
    render(fig, &panels)
}

/// Every figure of a sweep, in [`crate::output::RUN_FILES`] order: `diameter_error.png`,
/// `dmean_error.png`, `pose_error.png`, `time.png`, `std_vs_crb.png`, `coverage.png`,
/// and `realtime.png` for a sweep over `sampling`.
pub fn plot_all(scenario: &Scenario, summary: &[SummaryRow]) -> anyhow::Result<Vec<Png>> {
    let sw = Sweep::new(scenario, summary);
    let mut pngs = vec![
        diameter_figure(&sw)?,
        dmean_figure(&sw)?,
        pose_figure(&sw)?,
        time_figure(&sw)?,
        crb_figure(&sw)?,
        coverage_figure(&sw)?,
    ];
    if scenario.sweep_variable == "sampling" {
        pngs.push(realtime_figure(scenario, summary)?);
    }
    Ok(pngs)
}

/// The points of `realtime.png` of one sampling method `how` (`None`: the full frame):
/// (N, value) per swept value that samples that way, value = `of(dmean row, time row)`.
fn realtime_points(
    scenario: &Scenario,
    summary: &[SummaryRow],
    method: &str,
    how: Option<SamplingMethod>,
    of: impl Fn(&SummaryRow, &SummaryRow) -> f64,
) -> Vec<(f64, f64)> {
    let row = |value: &str, q: &str| {
        summary
            .iter()
            .find(|r| r.sweep_value == value && r.method == method && r.quantity == q)
    };
    let mut v: Vec<(f64, f64)> = scenario
        .sweeps
        .iter()
        .filter(|(_, s)| s.sampling.map(|s| s.method) == how)
        .filter_map(|(value, s)| {
            let n = s.sampling.map_or(f64::NAN, |s| s.max_points as f64);
            Some((n, of(row(value, "dmean")?, row(value, "time_ms")?)))
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}

/// `realtime.png` (issue 25), for a sweep over `sampling` with a full-frame value
/// (`max_points = "all"`): against the points fitted N, per sampling method, (left) the
/// mean diameter's RMS error over the full frame's RMS error on the same frames (the
/// full frame's *empirical* spread stands for its Cramér–Rao bound: under independent
/// range noise the full-frame ML-EPD estimate is efficient, its RMS error within a few
/// per cent of the bound, `std_vs_crb.png`), 1 dashed; (right) the mean time per frame of
/// the choice and the estimate, the full frame's dashed. The first method's rows.
fn realtime_figure(scenario: &Scenario, summary: &[SummaryRow]) -> anyhow::Result<Png> {
    let method = scenario
        .sweeps
        .first()
        .and_then(|(_, s)| s.methods.first())
        .map_or("ml-epd", |m| m.name());
    let full = realtime_points(scenario, summary, method, None, |d, _| d.stats.rmse);
    let full_time = realtime_points(scenario, summary, method, None, |_, t| t.stats.mean);
    let full_rmse = full.first().map_or(f64::NAN, |p| p.1);
    let full_ms = full_time.first().map_or(f64::NAN, |p| p.1);
    let all: Vec<f64> = scenario
        .sweeps
        .iter()
        .filter_map(|(_, s)| s.sampling.map(|s| s.max_points as f64))
        .collect();
    let (lo, hi) = all
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &n| (l.min(n), h.max(n)));
    let line = |y: f64| vec![(lo, y, f64::NAN, f64::NAN), (hi, y, f64::NAN, f64::NAN)];
    let colours = [RED, BLUE, GREEN];
    let mut ratio = vec![Series {
        name: "full frame".into(),
        colour: REFERENCE,
        points: line(1.0),
        bars: false,
        marker_triangle: false,
        dashed: true,
        band: false,
        markers_only: false,
    }];
    let mut time = vec![Series {
        name: "full frame".into(),
        colour: REFERENCE,
        points: line(full_ms),
        bars: false,
        marker_triangle: false,
        dashed: true,
        band: false,
        markers_only: false,
    }];
    for (how, colour) in SamplingMethod::ALL.into_iter().zip(colours) {
        let r = realtime_points(scenario, summary, method, Some(how), |d, _| {
            d.stats.rmse / full_rmse
        });
        let t = realtime_points(scenario, summary, method, Some(how), |_, t| t.stats.mean);
        for (dest, pts) in [(&mut ratio, r), (&mut time, t)] {
            dest.push(Series {
                name: how.name().into(),
                colour,
                points: pts
                    .into_iter()
                    .map(|(x, y)| (x, y, f64::NAN, f64::NAN))
                    .collect(),
                bars: false,
                marker_triangle: false,
                dashed: false,
                band: false,
                markers_only: false,
            });
        }
    }
    let x_label = "points fitted N".to_string();
    let fig = Figure {
        name: "realtime.png".into(),
        title: format!(
            "{}: {method} on N chosen points — mean-diameter RMS error over the full frame's \
             ({:.3} mm), and time per frame",
            scenario.name, full_rmse
        ),
        grid: (1, 2),
        size: (1440, 574),
        x_label: &x_label,
        xa: Axis { log: true },
        ya: Axis { log: true },
        legend: Legend::Shared,
        x_names: &[],
    };
    render(
        fig,
        &[
            Panel {
                title: "RMS error of (Dmax + Dmin)/2 ÷ full frame's".into(),
                y_label: "ratio".into(),
                series: &ratio,
            },
            Panel {
                title: "choice + estimate, mean over the trials".into(),
                y_label: "time per frame (ms)".into(),
                series: &time,
            },
        ],
    )
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
}
