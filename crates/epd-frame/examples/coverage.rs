//! How often `epd estimate`'s defaults cover the truth with the 1-σ they report, frame by
//! frame, under the camera errors and scene contamination of tof-sim (issue: uncertainty
//! that holds on real ToF frames).
//!
//! ```text
//! cargo run --release -p epd-frame --example coverage -- [FRAMES] [MODEL…]
//! ```
//! For each model: FRAMES full 640 × 480 frames (default 60) of a 20" pipe (12 mm wall,
//! 2 % ovality, σ = 0.02 m, the paper's random poses), each measured by
//! `epd_frame::measure_frame` with `epd estimate`'s defaults. Prints one line per model:
//! the statuses, the coverage of the ±1.96σ̂ interval for Dmax, Dmin and the mean diameter
//! over the converged frames (with its binomial standard error), the spread of err/σ̂, and
//! how many converged frames are more than max(5σ̂, 0.5 mm) off, the largest |error| of
//! Dmax and Dmin (mm). With `EPD_DUMP_DIR=DIR`
//! every frame is also written there (see `dump`); with `EPD_STRAIGHT_ONLY=1` the frames
//! are fitted as `--straight-only` does, with `EPD_MAX_POINTS=N` as `--max-points N`
//! does (the informed choice); `EPD_OD_IN` and `EPD_WALL_MM` change the pipe. The geometry
//! column counts the frames per `geometry`, `straight+dent` for a straight pipe with a
//! dent reported (`dent_at_m`).

use std::borrow::Cow;
use std::collections::BTreeMap;

use epd_core::{Params, errors_against};
use epd_frame::{EstimateConfig, EstimateSettings, FrameInput, measure_frame};
use tof_sim::camera::{CameraNoise, MultipathBand, Wiggle};
use tof_sim::contamination::{Contamination, Dent, FloorLayer, Obstacle, ViewSector};
use tof_sim::{FrameSeed, Noise, Pipe, PoseRanges, Scene, Sensor, Subsample, WallModel};

/// One named case: camera errors, contamination, far outliers.
struct Case {
    name: &'static str,
    camera: CameraNoise,
    contamination: Contamination,
    far_outliers: f64,
}

fn cases() -> Vec<Case> {
    let plain = |name, camera| Case {
        name,
        camera,
        contamination: Contamination::default(),
        far_outliers: 0.0,
    };
    let dirty = |name, contamination| Case {
        name,
        camera: CameraNoise::default(),
        contamination,
        far_outliers: 0.0,
    };
    let corr = |l: f64| CameraNoise {
        correlation_length_px: l,
        ..CameraNoise::default()
    };
    vec![
        plain("independent", CameraNoise::default()),
        plain("correlated_1px", corr(1.0)),
        plain("correlated_2px", corr(2.0)),
        plain("correlated_3px", corr(3.0)),
        plain(
            "range_dependent",
            CameraNoise {
                sigma_range_exponent: 2.0,
                ..CameraNoise::default()
            },
        ),
        plain(
            "wiggling",
            CameraNoise {
                wiggle: Some(Wiggle {
                    random_phase: true,
                    ..Wiggle::helios2()
                }),
                ..CameraNoise::default()
            },
        ),
        plain(
            "multipath",
            CameraNoise {
                multipath_bands: vec![MultipathBand {
                    near_m: 1.0,
                    far_m: 2.0,
                    extra_m: 0.05,
                }],
                ..CameraNoise::default()
            },
        ),
        Case {
            name: "far_outliers_5pct",
            camera: CameraNoise::default(),
            contamination: Contamination::default(),
            far_outliers: 0.05,
        },
        dirty(
            "sediment_10cm",
            Contamination {
                floor: Some(FloorLayer { depth_m: 0.10 }),
                ..Contamination::default()
            },
        ),
        dirty(
            "obstacle",
            Contamination {
                obstacle: Some(Obstacle::Box {
                    x_m: 1.2,
                    length_m: 0.3,
                    width_m: 0.2,
                    height_m: 0.07,
                    y_m: 0.0,
                }),
                ..Contamination::default()
            },
        ),
        dirty("dent_25mm", dent(0.025)),
        dirty("dent_10mm", dent(0.010)),
        dirty("dent_5mm", dent(0.005)),
        dirty("dent_2mm", dent(0.002)),
        dirty(
            "upper_half_view",
            Contamination {
                view: Some(ViewSector {
                    start_rad: -std::f64::consts::FRAC_PI_2,
                    width_rad: std::f64::consts::PI,
                }),
                ..Contamination::default()
            },
        ),
    ]
}

/// tof-sim's Gaussian dent `depth_m` deep, 1.0 m ahead on top, extent σ 0.15 m along and
/// around.
fn dent(depth_m: f64) -> Contamination {
    Contamination {
        dent: Some(Dent {
            x_m: 1.0,
            clock_rad: 0.0,
            depth_m,
            axial_sigma_m: 0.15,
            circumferential_sigma_m: 0.15,
        }),
        ..Contamination::default()
    }
}

fn config() -> EstimateConfig {
    let settings = EstimateSettings {
        geometry: std::env::var_os("EPD_STRAIGHT_ONLY").is_none(),
        max_points: std::env::var("EPD_MAX_POINTS")
            .ok()
            .map(|v| v.parse().expect("EPD_MAX_POINTS: a number of points")),
        ..EstimateSettings::default()
    };
    EstimateConfig::new(&settings).expect("the defaults are valid")
}

/// Writes a frame's points as `NAME_KKK.xyz` (x y z per line, sensor frame, m) and its
/// true diameters as `NAME_KKK.truth` ("Dmax Dmin" in mm) into `dir`, for
/// `EPD_DUMP_DIR=DIR`: the frames can then be given to `epd estimate` or the
/// `survey_profile` example.
fn dump(
    dir: &std::path::Path,
    name: &str,
    k: u64,
    points: &[[f64; 3]],
    truth: &Params,
) -> std::io::Result<()> {
    use std::io::Write;
    let mut f = std::io::BufWriter::new(std::fs::File::create(
        dir.join(format!("{name}_{k:03}.xyz")),
    )?);
    for p in points {
        writeln!(f, "{} {} {}", p[0], p[1], p[2])?;
    }
    f.flush()?;
    std::fs::write(
        dir.join(format!("{name}_{k:03}.truth")),
        format!("{} {}\n", truth.d_max * 1e3, truth.d_min * 1e3),
    )
}

/// What one frame gave: status, and (err/σ̂, |err| in mm) for Dmax, Dmin, Dmean when
/// converged.
struct Outcome {
    status: String,
    geometry: &'static str,
    z: Option<[(f64, f64); 3]>,
}

fn frame_outcome(case: &Case, k: u64, cfg: &EstimateConfig) -> Outcome {
    let env = |name: &str| {
        std::env::var(name).ok().map(|v| {
            v.parse::<f64>()
                .unwrap_or_else(|_| panic!("{name}: a number"))
        })
    };
    let paper = Pipe::paper_20in();
    let pipe = Pipe {
        ovality: 0.02,
        nominal_od_in: env("EPD_OD_IN").unwrap_or(paper.nominal_od_in),
        wall_thickness: env("EPD_WALL_MM").map_or(paper.wall_thickness, |w| w * 1e-3),
    };
    let truth: Params = PoseRanges::default()
        .sample(&pipe, 7, k)
        .expect("a pose of the paper's ranges");
    let scene = Scene::new(&truth, WallModel::Exact, 6.0)
        .and_then(|s| s.with_contamination(case.contamination))
        .expect("a valid scene");
    let noise = Noise {
        far_outlier_fraction: case.far_outliers,
        ..Noise::range(0.02)
    };
    let frame = tof_sim::simulate_with(
        &Sensor::helios2(),
        &scene,
        &noise,
        &case.camera,
        Subsample::All,
        FrameSeed {
            seed: 7,
            trial: k,
            sweep_index: 0,
        },
    )
    .expect("a frame");
    if let Some(dir) = std::env::var_os("EPD_DUMP_DIR")
        && let Err(e) = dump(
            std::path::Path::new(&dir),
            case.name,
            k,
            &frame.measured,
            &truth,
        )
    {
        eprintln!(
            "coverage: cannot write frame {k} of {} to {dir:?}: {e}",
            case.name
        );
    }
    let input = FrameInput {
        points: Cow::Borrowed(&frame.measured),
        intensity: None,
        sigma: None,
        read_ms: 0.0,
    };
    let e = match measure_frame(input, cfg) {
        Ok(e) => e,
        Err(_) => {
            return Outcome {
                status: "error".into(),
                geometry: "none",
                z: None,
            };
        }
    };
    let withheld = e.geometry.as_ref().and_then(|g| g.withheld()).is_some();
    let geometry = e.geometry.as_ref().map_or("not surveyed", |g| {
        if g.dent.is_some() {
            "straight+dent"
        } else {
            g.layout
        }
    });
    let est = &e.estimate;
    let status = if withheld {
        "withheld".to_string()
    } else {
        est.status.name().to_string()
    };
    if withheld || !est.status.is_converged() {
        if std::env::var_os("EPD_REASONS").is_some() {
            eprintln!("{} frame {k}: {status}: {}", case.name, est.status.reason());
        }
        return Outcome {
            status,
            geometry,
            z: None,
        };
    }
    let err = errors_against(&est.params, &truth);
    let (s_max, s_min) = (est.sigma[0], est.sigma[1]);
    let z = match (s_max, s_min) {
        (Some(a), Some(b)) => {
            let s_mean = est.sigma_d_mean().unwrap_or(f64::NAN);
            Some([
                (err.d_max / a, err.d_max.abs() * 1e3),
                (err.d_min / b, err.d_min.abs() * 1e3),
                (err.d_mean / s_mean, err.d_mean.abs() * 1e3),
            ])
        }
        _ => None,
    };
    Outcome {
        status,
        geometry,
        z,
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let frames: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(60);
    let wanted: Vec<String> = args.collect();
    let cfg = config();
    println!(
        "{:<20} {:>5} {:>28}  {:>16} {:>16} {:>16}  {:>14}  {:>9}  {:>13}  geometry",
        "model",
        "n",
        "statuses",
        "cov Dmax (±se)",
        "cov Dmin (±se)",
        "cov Dmean (±se)",
        "sd z max/min",
        "far_off",
        "max|err| mm",
    );
    for case in cases() {
        if !wanted.is_empty() && !wanted.iter().any(|w| w == case.name) {
            continue;
        }
        let outcomes: Vec<Outcome> = (0..frames).map(|k| frame_outcome(&case, k, &cfg)).collect();
        let mut statuses: BTreeMap<String, usize> = BTreeMap::new();
        for o in &outcomes {
            *statuses.entry(o.status.clone()).or_default() += 1;
        }
        let conv: Vec<&[(f64, f64); 3]> = outcomes.iter().filter_map(|o| o.z.as_ref()).collect();
        let n = conv.len() as f64;
        let cover = |q: usize| {
            let c = conv.iter().filter(|z| z[q].0.abs() <= 1.96).count() as f64 / n.max(1.0);
            format!("{c:.3} ± {:.3}", (c * (1.0 - c) / n.max(1.0)).sqrt())
        };
        let sd = |q: usize| (conv.iter().map(|z| z[q].0 * z[q].0).sum::<f64>() / n.max(1.0)).sqrt();
        // Converged more than max(5σ̂, 0.5 mm) off, on Dmax or Dmin.
        let far_off = conv
            .iter()
            .filter(|z| (0..2).any(|q| z[q].0.abs() > 5.0 && z[q].1 > 0.5))
            .count();
        let worst = |q: usize| conv.iter().map(|z| z[q].1).fold(0.0, f64::max);
        let st: Vec<String> = statuses.iter().map(|(k, v)| format!("{k}:{v}")).collect();
        let mut layouts: BTreeMap<&str, usize> = BTreeMap::new();
        for o in &outcomes {
            *layouts.entry(o.geometry).or_default() += 1;
        }
        let geometry: Vec<String> = layouts.iter().map(|(k, v)| format!("{k}:{v}")).collect();
        println!(
            "{:<20} {:>5} {:>28}  {:>16} {:>16} {:>16}  {:>6.2}/{:<6.2}  {:>9}  {:>6.3}/{:<6.3}  {}",
            case.name,
            frames,
            st.join(","),
            cover(0),
            cover(1),
            cover(2),
            sd(0),
            sd(1),
            far_off,
            worst(0),
            worst(1),
            geometry.join(",")
        );
    }
}
