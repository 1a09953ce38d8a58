//! One trial: a simulated frame, every method on the same cloud, errors against the truth
//! under the symmetries, and the Cramér–Rao bound of the frame, as a [`TrialRecord`].

use std::borrow::Cow;
use std::sync::Mutex;
use std::time::Instant;

use epd_core::{
    EstimateOptions, Loss, LossScale, Method, N_PARAMS, Params, cramer_rao_bound, errors_against,
    estimate,
};
use epd_frame::{EstimateConfig, EstimateSettings, FrameInput, measure_frame};
use tof_sim::{Frame, FrameSeed, Scene, WallModel, simulate_into_with};

use super::record::{MethodRecord, TrialRecord};
use super::scenario::Setting;

/// Frames kept between trials so their buffers are reused.
#[derive(Default)]
pub struct FramePool(Mutex<Vec<Frame>>);

impl FramePool {
    fn take(&self) -> Frame {
        self.0
            .lock()
            .ok()
            .and_then(|mut v| v.pop())
            .unwrap_or_else(Frame::empty)
    }

    fn give(&self, f: Frame) {
        if let Ok(mut v) = self.0.lock() {
            v.push(f);
        }
    }
}

/// Run trial `trial` of `setting` (sweep index `sweep_index`, scenario seed `seed`).
pub fn run_trial(
    setting: &Setting,
    seed: u64,
    trial: usize,
    sweep_index: usize,
    pool: &FramePool,
) -> TrialRecord {
    let mut frame = pool.take();
    let r = run_with(setting, seed, trial, sweep_index, &mut frame);
    pool.give(frame);
    r
}

fn run_with(
    setting: &Setting,
    seed: u64,
    trial: usize,
    sweep_index: usize,
    frame: &mut Frame,
) -> TrialRecord {
    let fail =
        |truth: Params, e: String| TrialRecord::failed(setting, sweep_index, trial, truth, e);
    let nan = Params {
        d_max: f64::NAN,
        d_min: f64::NAN,
        roll: f64::NAN,
        pitch: f64::NAN,
        yaw: f64::NAN,
        dy: f64::NAN,
        dz: f64::NAN,
    };
    let truth = match setting.poses.sample(&setting.pipe, seed, trial as u64) {
        Ok(t) => t,
        Err(e) => return fail(nan, e.to_string()),
    };
    let scene = match Scene::new(&truth, WallModel::Exact, setting.sensor.max_range)
        .and_then(|s| s.with_contamination(setting.contamination))
    {
        Ok(s) => s,
        Err(e) => return fail(truth, e.to_string()),
    };
    let seeds = FrameSeed {
        seed,
        trial: trial as u64,
        sweep_index: sweep_index as u64,
    };
    if let Err(e) = simulate_into_with(
        &setting.sensor,
        &scene,
        &setting.noise,
        &setting.camera,
        setting.subsample(),
        seeds,
        frame,
    ) {
        return fail(truth, e.to_string());
    }
    let crb =
        cramer_rao_bound(&frame.exact, &truth, setting.noise.sigma).unwrap_or([None; N_PARAMS]);
    let opts = estimate_options(setting);
    let mut n_points = frame.len();
    let methods = setting
        .methods
        .iter()
        .map(|&m| {
            if setting.geometry {
                let (record, n) = measured(setting, m, &frame.measured, seeds, &truth);
                n_points = n.unwrap_or(n_points);
                return record;
            }
            let t0 = Instant::now();
            // With `sampling`, the choice is part of the estimate's time; it is seeded by
            // the frame's seeds, so every method of a trial fits its own choice
            // deterministically.
            let chosen = setting.sampling.and_then(|s| {
                let s = s.with_seed(sampling_seed(seeds));
                epd_frame::sampling::choose(&frame.measured, &s, m, &opts)
            });
            let est = match &chosen {
                None => estimate(&frame.measured, m, &opts),
                Some(c) => {
                    let pts: Vec<[f64; 3]> = c.indices.iter().map(|&i| frame.measured[i]).collect();
                    n_points = pts.len();
                    estimate(&pts, m, &opts)
                }
            };
            let time_ms = t0.elapsed().as_secs_f64() * 1e3;
            MethodRecord::of(m, est, &truth, time_ms)
        })
        .collect();
    TrialRecord {
        setting: sweep_index,
        trial,
        n_points,
        truth: epd_core::canonicalize(&truth),
        crb,
        methods,
        error: None,
    }
}

/// Method `m` on a frame's `points` through the frame library, as `epd estimate`
/// measures a file (`epd_frame::measure_frame`: the scene ahead surveyed, then the
/// straight section fitted), with the setting's loss, loss scale, range gate and
/// sampling as `epd estimate`'s flags would give them. The record carries the reported
/// geometry; with it the points fitted when the frame was sampled.
fn measured(
    setting: &Setting,
    m: Method,
    points: &[[f64; 3]],
    seeds: FrameSeed,
    truth: &Params,
) -> (MethodRecord, Option<usize>) {
    let settings = EstimateSettings {
        method: m,
        min_range: setting.range_gate.map(|g| g.0),
        max_range: setting.range_gate.map(|g| g.1),
        loss: setting.loss.name().into(),
        // `--loss-scale` fixes the scale; without it the scale follows the residuals.
        loss_scale: match setting.loss {
            Loss::Huber { scale } | Loss::Cauchy { scale } if !setting.loss_scale_auto => {
                Some(scale)
            }
            _ => None,
        },
        geometry: true,
        ..EstimateSettings::default()
    };
    let mut cfg = match EstimateConfig::new(&settings) {
        Ok(c) => c,
        Err(e) => return (MethodRecord::error(m, e.to_string(), 0.0), None),
    };
    cfg.sampling = setting.sampling.map(|s| s.with_seed(sampling_seed(seeds)));
    let input = FrameInput {
        points: Cow::Borrowed(points),
        intensity: None,
        sigma: None,
        read_ms: 0.0,
    };
    let t0 = Instant::now();
    let measured = measure_frame(input, &cfg);
    let time_ms = t0.elapsed().as_secs_f64() * 1e3;
    match measured {
        Ok(e) => {
            let n = e.sampled.map(|(n, _)| n);
            let mut record = MethodRecord::of(m, Ok(e.estimate), truth, time_ms);
            if let Some(g) = &e.geometry {
                record.geometry = Some(g.layout.to_string());
                record.straight_withheld = g.straight_withheld;
            }
            (record, n)
        }
        Err(message) => (MethodRecord::error(m, message, time_ms), None),
    }
}

/// The seed of a trial's choice of points: its frame's seeds mixed (the sweep index
/// left out, so that every swept sampling of a trial starts from the same seed).
fn sampling_seed(s: FrameSeed) -> u64 {
    s.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ s.trial.wrapping_mul(0xD1B5_4A32_D192_ED03)
}

/// The estimator's options of a setting: its loss, the loss's scale fixed or from the
/// residuals, its range gate.
fn estimate_options(setting: &Setting) -> EstimateOptions {
    let opts = EstimateOptions::default()
        .with_loss(setting.loss)
        .unwrap_or_default()
        .with_loss_scale(if setting.loss_scale_auto {
            LossScale::Auto
        } else {
            LossScale::Fixed
        });
    match setting.range_gate {
        Some((lo, hi)) => opts.with_range_gate(lo, hi).unwrap_or(opts),
        None => opts,
    }
}

impl MethodRecord {
    /// Method `method`'s result: its estimate `est` against `truth` (under the
    /// symmetries), or the error; `time_ms` the estimate call's wall time.
    fn of(
        method: Method,
        est: Result<epd_core::Estimate, epd_core::EpdError>,
        truth: &Params,
        time_ms: f64,
    ) -> Self {
        match est {
            Ok(e) => MethodRecord {
                method,
                status: Some(e.status.outcome()),
                message: e.status.reason(),
                iterations: e.iterations,
                time_ms,
                estimate: Some(e.params),
                sigma: e.sigma,
                errors: Some(errors_against(&e.params, truth)),
                geometry: None,
                straight_withheld: false,
            },
            Err(err) => MethodRecord::error(method, err.to_string(), time_ms),
        }
    }

    /// No estimate: status `error` with `message`.
    fn error(method: Method, message: String, time_ms: f64) -> Self {
        MethodRecord {
            method,
            status: None,
            message,
            iterations: 0,
            time_ms,
            estimate: None,
            sigma: [None; N_PARAMS],
            errors: None,
            geometry: None,
            straight_withheld: false,
        }
    }
}

impl TrialRecord {
    /// Trial `trial` of setting `sweep_index` whose frame could not be made (why: `e`):
    /// every method an error.
    fn failed(
        setting: &Setting,
        sweep_index: usize,
        trial: usize,
        truth: Params,
        e: String,
    ) -> Self {
        TrialRecord {
            setting: sweep_index,
            trial,
            n_points: 0,
            truth,
            crb: [None; N_PARAMS],
            methods: setting
                .methods
                .iter()
                .map(|&m| MethodRecord::error(m, e.clone(), 0.0))
                .collect(),
            error: Some(e),
        }
    }
}
