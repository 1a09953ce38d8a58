//! One trial: a simulated frame, every method on the same cloud, errors against the truth
//! under the symmetries, and the Cramér–Rao bound of the frame.

use std::sync::Mutex;
use std::time::Instant;

use epd_core::{
    EstimateOptions, FitOutcome, FitStatus, LossScale, Method, N_PARAMS, ParamErrors, Params,
    Sigmas, cramer_rao_bound, errors_against, estimate,
};
use tof_sim::{Frame, FrameSeed, Scene, WallModel, simulate_into};

use super::scenario::Setting;

/// The outcome of one method on one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodResult {
    /// The method.
    pub method: Method,
    /// The estimate's status; `None` when no estimate could be made (written `error`).
    pub status: Option<FitStatus>,
    /// The reason or error message.
    pub message: String,
    /// Solver iterations.
    pub iterations: usize,
    /// Wall time of the estimate call alone (ms).
    pub time_ms: f64,
    /// The canonical estimate, when one was made.
    pub estimate: Option<Params>,
    /// Its reported 1-σ.
    pub sigma: Sigmas,
    /// Estimate − truth under the symmetries.
    pub errors: Option<ParamErrors>,
}

impl MethodResult {
    /// Whether the fit converged (the trial counts in the statistics).
    pub fn ok(&self) -> bool {
        self.status.is_some_and(|s| s.is_converged()) && self.errors.is_some()
    }

    /// The status as written in `trials.csv`: the estimate's, or `error`.
    pub fn status_name(&self) -> &'static str {
        self.status.map_or("error", |s| s.outcome().name())
    }
}

/// The outcome of one trial.
#[derive(Clone, Debug, PartialEq)]
pub struct TrialResult {
    /// Trial index.
    pub trial: usize,
    /// Points in the cloud the methods saw.
    pub n_points: usize,
    /// The true β (canonical form).
    pub truth: Params,
    /// Cramér–Rao 1-σ per parameter for range noise of the setting's σ.
    pub crb: Sigmas,
    /// One result per method, in the scenario's order.
    pub methods: Vec<MethodResult>,
    /// Why the frame could not be made, if it could not.
    pub error: Option<String>,
}

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
) -> TrialResult {
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
) -> TrialResult {
    let fail = |truth: Params, e: String| TrialResult::failed(setting, trial, truth, e);
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
    let scene = match Scene::new(&truth, WallModel::Exact, setting.sensor.max_range) {
        Ok(s) => s,
        Err(e) => return fail(truth, e.to_string()),
    };
    let seeds = FrameSeed {
        seed,
        trial: trial as u64,
        sweep_index: sweep_index as u64,
    };
    if let Err(e) = simulate_into(
        &setting.sensor,
        &scene,
        &setting.noise,
        setting.subsample(),
        seeds,
        frame,
    ) {
        return fail(truth, e.to_string());
    }
    let crb =
        cramer_rao_bound(&frame.exact, &truth, setting.noise.sigma).unwrap_or([None; N_PARAMS]);
    let opts = estimate_options(setting);
    let methods = setting
        .methods
        .iter()
        .map(|&m| {
            let t0 = Instant::now();
            let est = estimate(&frame.measured, m, &opts);
            let time_ms = t0.elapsed().as_secs_f64() * 1e3;
            MethodResult::of(m, est, &truth, time_ms)
        })
        .collect();
    TrialResult {
        trial,
        n_points: frame.len(),
        truth: epd_core::canonicalize(&truth),
        crb,
        methods,
        error: None,
    }
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

impl MethodResult {
    /// Method `method`'s result: its estimate `est` against `truth` (under the
    /// symmetries), or the error; `time_ms` the estimate call's wall time.
    fn of(
        method: Method,
        est: Result<epd_core::Estimate, epd_core::EpdError>,
        truth: &Params,
        time_ms: f64,
    ) -> Self {
        match est {
            Ok(e) => MethodResult {
                method,
                status: Some(e.status),
                message: e.status.reason(),
                iterations: e.iterations,
                time_ms,
                estimate: Some(e.params),
                sigma: e.sigma,
                errors: Some(errors_against(&e.params, truth)),
            },
            Err(err) => MethodResult::error(method, err.to_string(), time_ms),
        }
    }

    /// No estimate: status `error` with `message`.
    fn error(method: Method, message: String, time_ms: f64) -> Self {
        MethodResult {
            method,
            status: None,
            message,
            iterations: 0,
            time_ms,
            estimate: None,
            sigma: [None; N_PARAMS],
            errors: None,
        }
    }
}

impl TrialResult {
    /// A trial whose frame could not be made (why: `e`): every method an error.
    fn failed(setting: &Setting, trial: usize, truth: Params, e: String) -> Self {
        TrialResult {
            trial,
            n_points: 0,
            truth,
            crb: [None; N_PARAMS],
            methods: setting
                .methods
                .iter()
                .map(|&m| MethodResult::error(m, e.clone(), 0.0))
                .collect(),
            error: Some(e),
        }
    }
}

/// What the output files need of one method's result on one frame: a
/// [`MethodResult`] with its status reduced to its [`FitOutcome`], so that it can be
/// written to a shard's records file ([`crate::output::RECORDS_FILE`]) and read back
/// exactly.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodRecord {
    /// The method.
    pub method: Method,
    /// [`FitStatus::outcome`] of the estimate; `None` when no estimate could be made
    /// (written `error`).
    pub status: Option<FitOutcome>,
    /// The reason or error message.
    pub message: String,
    /// Solver iterations.
    pub iterations: usize,
    /// Wall time of the estimate call alone (ms).
    pub time_ms: f64,
    /// The canonical estimate, when one was made.
    pub estimate: Option<Params>,
    /// Its reported 1-σ.
    pub sigma: Sigmas,
    /// Estimate − truth under the symmetries.
    pub errors: Option<ParamErrors>,
}

impl MethodRecord {
    /// Whether the fit converged (the trial counts in the statistics), as
    /// [`MethodResult::ok`].
    pub fn ok(&self) -> bool {
        self.status == Some(FitOutcome::Converged) && self.errors.is_some()
    }

    /// The status as written in `trials.csv`: the estimate's, or `error`.
    pub fn status_name(&self) -> &'static str {
        self.status.map_or("error", FitOutcome::name)
    }
}

impl From<&MethodResult> for MethodRecord {
    fn from(m: &MethodResult) -> Self {
        Self {
            method: m.method,
            status: m.status.map(|s| s.outcome()),
            message: m.message.clone(),
            iterations: m.iterations,
            time_ms: m.time_ms,
            estimate: m.estimate,
            sigma: m.sigma,
            errors: m.errors,
        }
    }
}

/// What the output files (`trials.csv`, `summary.csv`) need of one trial, with the
/// index of its setting: written by a run, or read back from shard files by a merge.
#[derive(Clone, Debug, PartialEq)]
pub struct TrialRecord {
    /// Index of the setting (swept value) in the scenario.
    pub setting: usize,
    /// Trial index within the setting.
    pub trial: usize,
    /// Points in the cloud the methods saw.
    pub n_points: usize,
    /// The true β (canonical form).
    pub truth: Params,
    /// Cramér–Rao 1-σ per parameter for range noise of the setting's σ.
    pub crb: Sigmas,
    /// One record per method, in the scenario's order.
    pub methods: Vec<MethodRecord>,
    /// Why the frame could not be made, if it could not.
    pub error: Option<String>,
}

impl TrialRecord {
    /// The record of `result`, a trial of setting `setting`.
    pub fn new(setting: usize, result: &TrialResult) -> Self {
        Self {
            setting,
            trial: result.trial,
            n_points: result.n_points,
            truth: result.truth,
            crb: result.crb,
            methods: result.methods.iter().map(MethodRecord::from).collect(),
            error: result.error.clone(),
        }
    }

    /// Trials or estimates of this trial that could not be made at all (status
    /// `error`): the frame, and each method without an estimate.
    pub fn errors(&self) -> usize {
        usize::from(self.error.is_some())
            + self.methods.iter().filter(|m| m.status.is_none()).count()
    }
}
