//! Running a scenario: trials (in parallel, or one at a time for timings), rows streamed
//! to `trials.csv`, statistics to `summary.csv`, metadata, plots.
//!
//! Its folder is written through [`crate::output`]: every file into a staging folder,
//! which then takes the output folder's place as a whole.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use epd_core::ParamErrors;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use crate::output::{
    INTERRUPTED, Interrupted, StagedFiles, create_new, finish, write_new, write_run, wrote,
};
use crate::provenance::{cpu_model, git_provenance, profile};
use crate::scenario::Scenario;
use crate::stats::Stats;
use crate::trial::{FramePool, TrialRecord, TrialResult, run_trial};

/// A summarised quantity: its name in `summary.csv`, unit, the error it reads (in that
/// unit) and the index of its parameter in β for the Cramér–Rao bound.
pub struct Quantity {
    /// Name in the `quantity` column.
    pub name: &'static str,
    /// Unit in the `unit` column.
    pub unit: &'static str,
    /// The error in that unit.
    pub error: fn(&ParamErrors) -> f64,
    /// β index of the parameter (for the CRB), if it is one.
    pub param: Option<usize>,
    /// m or rad → the unit.
    pub scale: f64,
}

const MM: f64 = 1e3;
const DEG: f64 = 180.0 / std::f64::consts::PI;

/// The error quantities of `summary.csv` (time_ms is summarised apart).
pub const QUANTITIES: [Quantity; 8] = [
    Quantity {
        name: "dmax",
        unit: "mm",
        error: |e| e.d_max * MM,
        param: Some(0),
        scale: MM,
    },
    Quantity {
        name: "dmin",
        unit: "mm",
        error: |e| e.d_min * MM,
        param: Some(1),
        scale: MM,
    },
    Quantity {
        name: "dmean",
        unit: "mm",
        error: |e| e.d_mean * MM,
        param: None,
        scale: MM,
    },
    Quantity {
        name: "roll",
        unit: "deg",
        error: |e| e.roll * DEG,
        param: Some(2),
        scale: DEG,
    },
    Quantity {
        name: "pitch",
        unit: "deg",
        error: |e| e.pitch * DEG,
        param: Some(3),
        scale: DEG,
    },
    Quantity {
        name: "yaw",
        unit: "deg",
        error: |e| e.yaw * DEG,
        param: Some(4),
        scale: DEG,
    },
    Quantity {
        name: "dy",
        unit: "mm",
        error: |e| e.dy * MM,
        param: Some(5),
        scale: MM,
    },
    Quantity {
        name: "dz",
        unit: "mm",
        error: |e| e.dz * MM,
        param: Some(6),
        scale: MM,
    },
];

pub use crate::stats::SummaryRow;

/// Where and how to run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The output folder.
    pub out: PathBuf,
    /// Trials per setting, overriding the scenario's.
    pub trials: Option<usize>,
    /// Show a progress bar (it hides itself anyway when stderr is not a terminal).
    pub progress: bool,
}

impl RunOptions {
    /// The trials per setting: `--trials` when given, else the scenario's, checked
    /// against the scenario's size (the error names the key the count came from).
    pub fn checked_trials(&self, scenario: &Scenario) -> anyhow::Result<usize> {
        let trials = self.trials.unwrap_or(scenario.trials);
        let key = if self.trials.is_some() {
            "--trials"
        } else {
            "trials"
        };
        scenario.check_trials(key, trials)?;
        Ok(trials)
    }
}

/// What a run produced.
#[derive(Clone, Debug)]
pub struct RunReport {
    /// The summary rows, in file order.
    pub summary: Vec<SummaryRow>,
    /// Files written.
    pub files: Vec<PathBuf>,
    /// Wall time (s).
    pub wall_time_s: f64,
    /// Trials or estimates that could not be made at all (status `error`).
    pub trial_errors: usize,
}

/// `trials.csv` columns: the error columns README lists first, then the truth and
/// estimate in full, the reported 1-σ, the Cramér–Rao 1-σ and the solver's message.
pub const TRIAL_COLUMNS: &[&str] = &[
    "sweep_variable",
    "sweep_value",
    "trial",
    "method",
    "n_points",
    "status",
    "iterations",
    "time_ms",
    "dmax_true_mm",
    "dmin_true_mm",
    "dmax_est_mm",
    "dmin_est_mm",
    "err_dmax_mm",
    "err_dmin_mm",
    "err_dmean_mm",
    "err_roll_deg",
    "err_pitch_deg",
    "err_yaw_deg",
    "err_dy_mm",
    "err_dz_mm",
    "roll_true_deg",
    "pitch_true_deg",
    "yaw_true_deg",
    "dy_true_mm",
    "dz_true_mm",
    "roll_est_deg",
    "pitch_est_deg",
    "yaw_est_deg",
    "dy_est_mm",
    "dz_est_mm",
    "sigma_dmax_mm",
    "sigma_dmin_mm",
    "sigma_roll_deg",
    "sigma_pitch_deg",
    "sigma_yaw_deg",
    "sigma_dy_mm",
    "sigma_dz_mm",
    "crb_dmax_mm",
    "crb_dmin_mm",
    "crb_roll_deg",
    "crb_pitch_deg",
    "crb_yaw_deg",
    "crb_dy_mm",
    "crb_dz_mm",
    "message",
];

/// `summary.csv` columns.
pub const SUMMARY_COLUMNS: &[&str] = &[
    "sweep_variable",
    "sweep_value",
    "method",
    "quantity",
    "unit",
    "n",
    "n_failed",
    "mean",
    "std",
    "rmse",
    "median",
    "min",
    "max",
    "range",
    "sem",
    "crb_std",
    "coverage95",
];

/// A number for CSV: shortest round-trip text, empty for NaN/None (epd-io's rule).
pub use epd_io::csv::num;

fn opt(v: Option<f64>, scale: f64) -> String {
    v.map_or(String::new(), |x| num(x * scale))
}

pub(crate) fn trial_rows(
    w: &mut impl Write,
    variable: &str,
    value: &str,
    t: &TrialRecord,
) -> std::io::Result<()> {
    let tr = &t.truth;
    for m in &t.methods {
        let e = m.errors.as_ref();
        let est = m.estimate.as_ref();
        let mut f: Vec<String> = vec![
            variable.to_string(),
            value.to_string(),
            t.trial.to_string(),
            m.method.name().into(),
            t.n_points.to_string(),
            m.status_name().to_string(),
            m.iterations.to_string(),
            num(m.time_ms),
            num(tr.d_max * MM),
            num(tr.d_min * MM),
            est.map_or(String::new(), |p| num(p.d_max * MM)),
            est.map_or(String::new(), |p| num(p.d_min * MM)),
        ];
        for q in &QUANTITIES {
            f.push(e.map_or(String::new(), |e| num((q.error)(e))));
        }
        for v in [
            tr.roll * DEG,
            tr.pitch * DEG,
            tr.yaw * DEG,
            tr.dy * MM,
            tr.dz * MM,
        ] {
            f.push(num(v));
        }
        for (i, s) in [(2, DEG), (3, DEG), (4, DEG), (5, MM), (6, MM)] {
            f.push(est.map_or(String::new(), |p| num(p.to_array()[i] * s)));
        }
        let scales = [MM, MM, DEG, DEG, DEG, MM, MM];
        for i in 0..7 {
            f.push(opt(m.sigma[i], scales[i]));
        }
        for i in 0..7 {
            f.push(opt(t.crb[i], scales[i]));
        }
        f.push(m.message.clone());
        writeln!(w, "{}", epd_io::csv::line(&f))?;
    }
    Ok(())
}

/// Summarise the trials of one setting (every one of them, in trial order).
pub(crate) fn summarise(
    value: &str,
    methods: &[epd_core::Method],
    trials: &[TrialRecord],
) -> Vec<SummaryRow> {
    let mut rows = Vec::new();
    for (mi, m) in methods.iter().enumerate() {
        let results: Vec<_> = trials.iter().map(|t| (&t.methods[mi], t)).collect();
        let ok: Vec<_> = results.iter().filter(|(r, _)| r.ok()).collect();
        let n_failed = results.len() - ok.len();
        for q in &QUANTITIES {
            let v: Vec<f64> = ok
                .iter()
                .filter_map(|(r, _)| r.errors.as_ref().map(q.error))
                .collect();
            let crb_std = q.param.and_then(|i| {
                let vars: Vec<f64> = trials
                    .iter()
                    .filter_map(|t| t.crb[i])
                    .map(|s| (s * q.scale).powi(2))
                    .collect();
                (!vars.is_empty()).then(|| (vars.iter().sum::<f64>() / vars.len() as f64).sqrt())
            });
            let coverage95 = q.param.filter(|_| !ok.is_empty()).map(|i| {
                let covered = ok
                    .iter()
                    .filter(|(r, _)| {
                        let (Some(e), Some(s)) = (r.errors.as_ref(), r.sigma[i]) else {
                            return false;
                        };
                        ((q.error)(e)).abs() <= 1.96 * s * q.scale
                    })
                    .count();
                covered as f64 / ok.len() as f64
            });
            rows.push(SummaryRow {
                sweep_value: value.into(),
                method: m.name().into(),
                quantity: q.name.into(),
                unit: q.unit.into(),
                stats: Stats::of(&v),
                n_failed,
                crb_std,
                coverage95,
            });
        }
        let times: Vec<f64> = results
            .iter()
            .filter(|(r, _)| r.estimate.is_some())
            .map(|(r, _)| r.time_ms)
            .collect();
        rows.push(SummaryRow {
            sweep_value: value.into(),
            method: m.name().into(),
            quantity: "time_ms".into(),
            unit: "ms".into(),
            stats: Stats::of(&times),
            n_failed,
            crb_std: None,
            coverage95: None,
        });
    }
    rows
}

pub(crate) fn summary_line(variable: &str, r: &SummaryRow) -> String {
    let s = &r.stats;
    epd_io::csv::line([
        variable.to_string(),
        r.sweep_value.clone(),
        r.method.clone(),
        r.quantity.clone(),
        r.unit.clone(),
        s.n.to_string(),
        r.n_failed.to_string(),
        num(s.mean),
        num(s.std),
        num(s.rmse),
        num(s.median),
        num(s.min),
        num(s.max),
        num(s.range),
        num(s.sem()),
        r.crb_std.map_or(String::new(), num),
        r.coverage95.map_or(String::new(), num),
    ])
}

/// Run `scenario` into `options.out`.
pub fn run(scenario: &Scenario, options: &RunOptions) -> anyhow::Result<RunReport> {
    let start = Instant::now();
    let trials = options.checked_trials(scenario)?;
    let staged = write_run(&options.out, |dir| {
        stage(scenario, options.progress, trials, dir, start)
    })?;
    Ok(RunReport {
        summary: staged.summary,
        files: staged.files,
        wall_time_s: staged.wall_time_s,
        trial_errors: staged.trial_errors,
    })
}

impl StagedFiles for Staged {
    fn files_mut(&mut self) -> &mut Vec<PathBuf> {
        &mut self.files
    }
}

/// A run written into its staging folder, not yet in place.
struct Staged {
    summary: Vec<SummaryRow>,
    files: Vec<PathBuf>,
    wall_time_s: f64,
    trial_errors: usize,
}

/// A progress bar over `total` trials (hidden unless `progress`).
pub(crate) fn progress_bar(progress: bool, total: u64) -> ProgressBar {
    let bar = if progress {
        ProgressBar::new(total)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} trials, {elapsed} elapsed, eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar
}

/// Runs the trials of a scenario in batches: in parallel, or one at a time when the
/// scenario takes timings.
pub(crate) struct TrialRunner<'a> {
    scenario: &'a Scenario,
    pool: FramePool,
    batch: usize,
    bar: &'a ProgressBar,
}

impl<'a> TrialRunner<'a> {
    pub(crate) fn new(scenario: &'a Scenario, bar: &'a ProgressBar) -> Self {
        let batch = if scenario.timing {
            1
        } else {
            4 * rayon::current_num_threads().max(1)
        };
        Self {
            scenario,
            pool: FramePool::default(),
            batch,
            bar,
        }
    }

    /// Run trials `ts` (in that order) of setting `si`, handing each one's record to
    /// `each` in order; stops at the next batch when interrupted.
    pub(crate) fn run_setting(
        &self,
        si: usize,
        ts: &[usize],
        mut each: impl FnMut(TrialRecord) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        let (value, setting) = &self.scenario.sweeps[si];
        self.bar
            .set_message(format!("{} = {value}", self.scenario.sweep_variable));
        for ks in ts.chunks(self.batch) {
            if INTERRUPTED.load(Ordering::SeqCst) {
                self.bar.finish_and_clear();
                return Err(Interrupted.into());
            }
            let run_one = |&t: &usize| run_trial(setting, self.scenario.seed, t, si, &self.pool);
            let done: Vec<TrialResult> = if self.scenario.timing {
                ks.iter().map(run_one).collect()
            } else {
                ks.par_iter().map(run_one).collect()
            };
            self.bar.inc(done.len() as u64);
            for t in &done {
                each(TrialRecord::new(si, t))?;
            }
        }
        Ok(())
    }
}

/// The run's `metadata.json` (keys sorted): the scenario, the code, the machine and the
/// wall time.
pub(crate) fn metadata(
    scenario: &Scenario,
    trials: usize,
    wall_time_s: f64,
) -> serde_json::Map<String, serde_json::Value> {
    let (git_commit, git_dirty) = git_provenance();
    let meta = serde_json::json!({
        "scenario": scenario.name,
        "scenario_file": scenario.path.display().to_string(),
        "sweep_variable": scenario.sweep_variable,
        "trials_per_setting": trials,
        "seed": scenario.seed,
        "crate_version": env!("CARGO_PKG_VERSION"),
        "git_commit": git_commit,
        "git_dirty": git_dirty,
        "threads": rayon::current_num_threads(),
        "cpu_model": cpu_model(),
        "wall_time_s": wall_time_s,
        "finished_unix_s": std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0),
        "timing": if scenario.timing {
            "trials one at a time: time_ms is the uncontended estimate call alone (each estimate may still use all threads internally)"
        } else {
            "trials in parallel: time_ms is the estimate call alone, contended by concurrent trials"
        },
        "crb": "crb_* and crb_std: Cramér–Rao 1-σ for range noise of the setting's σ (exact for noise.model = range)",
        "profile": profile(),
    });
    match meta {
        serde_json::Value::Object(m) => m,
        _ => serde_json::Map::new(),
    }
}

/// Write `summary.csv`, `scenario.toml`, the plots and `metadata.json` of a whole run
/// into `dir` (after `trials.csv`); `extra` keys go into the metadata. Returns the files
/// and the wall time written in the metadata.
pub(crate) fn finish_run(
    scenario: &Scenario,
    summary: &[SummaryRow],
    trials: usize,
    dir: &Path,
    start: Instant,
    extra: serde_json::Map<String, serde_json::Value>,
) -> anyhow::Result<(Vec<PathBuf>, f64)> {
    let summary_path = dir.join("summary.csv");
    let mut summary_csv = create_new(&summary_path)?;
    writeln!(summary_csv, "{}", epd_io::csv::line(SUMMARY_COLUMNS))
        .map_err(wrote(&summary_path))?;
    for row in summary {
        writeln!(
            summary_csv,
            "{}",
            summary_line(&scenario.sweep_variable, row)
        )
        .map_err(wrote(&summary_path))?;
    }
    let mut files = vec![finish(summary_csv, &summary_path)?];
    files.push(write_new(
        &dir.join("scenario.toml"),
        scenario.source.as_bytes(),
    )?);
    for png in crate::plots::plot_all(scenario, summary)? {
        files.push(write_new(&dir.join(&png.name), &png.bytes)?);
    }
    let wall_time_s = start.elapsed().as_secs_f64();
    let mut meta = metadata(scenario, trials, wall_time_s);
    meta.extend(extra);
    files.push(write_new(
        &dir.join("metadata.json"),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?);
    Ok((files, wall_time_s))
}

/// Run the trials and write every file of the run into `dir` (the staging folder).
fn stage(
    scenario: &Scenario,
    progress: bool,
    trials: usize,
    dir: &Path,
    start: Instant,
) -> anyhow::Result<Staged> {
    let trials_path = dir.join("trials.csv");
    let mut trials_csv = create_new(&trials_path)?;
    writeln!(trials_csv, "{}", epd_io::csv::line(TRIAL_COLUMNS)).map_err(wrote(&trials_path))?;
    let bar = progress_bar(progress, (trials * scenario.sweeps.len()) as u64);
    let runner = TrialRunner::new(scenario, &bar);
    let all: Vec<usize> = (0..trials).collect();
    let mut summary = Vec::new();
    let mut trial_errors = 0;
    for (si, (value, setting)) in scenario.sweeps.iter().enumerate() {
        let mut results: Vec<TrialRecord> = Vec::with_capacity(trials);
        runner.run_setting(si, &all, |t| {
            trial_rows(&mut trials_csv, &scenario.sweep_variable, value, &t)
                .map_err(wrote(&trials_path))?;
            trial_errors += t.errors();
            results.push(t);
            Ok(())
        })?;
        summary.extend(summarise(value, &setting.methods, &results));
    }
    bar.finish_and_clear();
    if INTERRUPTED.load(Ordering::SeqCst) {
        return Err(Interrupted.into());
    }
    let mut files = vec![finish(trials_csv, &trials_path)?];
    let (rest, wall_time_s) = finish_run(
        scenario,
        &summary,
        trials,
        dir,
        start,
        serde_json::Map::new(),
    )?;
    files.extend(rest);
    Ok(Staged {
        summary,
        files,
        wall_time_s,
        trial_errors,
    })
}
