//! Running a scenario: trials (in parallel, or one at a time for timings), rows streamed
//! to `trials.csv`, statistics to `summary.csv`, metadata, plots.
//!
//! A run's files land as one set. They are written into a fresh staging folder
//! (`.run-XXXXXX`, created exclusively with an unpredictable name beside the output
//! folder, mode 0700, so no link can be planted in it); when every file is written the
//! previous output folder, if any, is renamed to a fresh `.old-XXXXXX/previous`, the
//! staging folder is renamed to the output folder, and the old one is removed. A reader
//! sees the whole previous run or the whole new one (or, for the instant between the two
//! renames, no folder), never a mix. The output folder must be empty, absent, or hold a
//! previous run (its `metadata.json`): `--out ~` is refused. An interrupted run (SIGINT,
//! SIGTERM: [`INTERRUPTED`]) or a failed one removes its staging folder and leaves the
//! previous run untouched; after SIGKILL a `.run-*` folder remains beside the output.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::Context;
use epd_core::ParamErrors;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use crate::scenario::Scenario;
use crate::stats::Stats;
use crate::trial::{FramePool, TrialResult, run_trial};

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

/// The error quantities of SPEC §6 (time_ms is summarised apart).
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

/// One row of `summary.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct SummaryRow {
    /// The swept value as written in the scenario.
    pub sweep_value: String,
    /// Method name.
    pub method: String,
    /// Quantity name (dmax, …, time_ms).
    pub quantity: String,
    /// Its unit.
    pub unit: String,
    /// Statistics over the converged trials.
    pub stats: Stats,
    /// Trials that did not converge (or failed).
    pub n_failed: usize,
    /// √(mean over trials of the CRB variance): the physical limit of `stats.std`.
    pub crb_std: Option<f64>,
    /// Fraction of the converged trials whose |error| ≤ 1.96·(reported 1-σ): the
    /// coverage of the nominal 95 % interval (parameters only; trials without a
    /// reported 1-σ, e.g. an undetermined roll, count as not covered).
    pub coverage95: Option<f64>,
}

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

/// `trials.csv` columns: SPEC §6's, then the truth and estimate in full, the reported
/// 1-σ, the Cramér–Rao 1-σ and the solver's message.
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

/// A number for CSV: shortest round-trip text, empty for NaN/None.
pub fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        String::new()
    }
}

fn opt(v: Option<f64>, scale: f64) -> String {
    v.map_or(String::new(), |x| num(x * scale))
}

/// Quote a CSV field when needed.
pub fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Set (by a signal handler) to stop a run at the next batch of trials.
pub static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// The run was interrupted: nothing was written.
#[derive(Debug, thiserror::Error)]
#[error("interrupted: the previous results, if any, are untouched")]
pub struct Interrupted;

/// Create `path` (which must not exist) for writing; the error names the file.
fn create_new(path: &Path) -> anyhow::Result<BufWriter<File>> {
    let f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    Ok(BufWriter::new(f))
}

/// Flush and sync a file written with [`create_new`]; the error names the file.
fn finish(w: BufWriter<File>, path: &Path) -> anyhow::Result<PathBuf> {
    let f = w
        .into_inner()
        .map_err(|e| e.into_error())
        .with_context(|| format!("cannot write {}", path.display()))?;
    f.sync_all()
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path.to_path_buf())
}

/// Write `bytes` to the new file `path` (in a run's staging folder).
pub fn write_new(path: &Path, bytes: &[u8]) -> anyhow::Result<PathBuf> {
    let mut w = create_new(path)?;
    w.write_all(bytes)
        .with_context(|| format!("cannot write {}", path.display()))?;
    finish(w, path)
}

/// An I/O error writing `p`, naming it.
fn wrote(p: &Path) -> impl Fn(std::io::Error) -> anyhow::Error + '_ {
    move |e| anyhow::Error::new(e).context(format!("cannot write {}", p.display()))
}

/// The output folder may not be used (a usage error: nothing was written).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct OutputRefused(String);

/// Refuse an output folder that holds something other than a previous run.
fn check_output_folder(out: &Path) -> anyhow::Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(out) else {
        return Ok(());
    };
    if !meta.is_dir() {
        return Err(OutputRefused(format!(
            "{} exists and is not a folder (a link is not followed): choose another --out",
            out.display()
        ))
        .into());
    }
    let mut entries =
        std::fs::read_dir(out).with_context(|| format!("cannot read {}", out.display()))?;
    let empty = entries.next().is_none();
    let previous_run = out.join("metadata.json").is_file() && out.join("scenario.toml").is_file();
    if !(empty || previous_run) {
        return Err(OutputRefused(format!(
            "{} holds files that are not a bench-harness run; a run replaces its output \
             folder as a whole: choose an empty or new --out",
            out.display()
        ))
        .into());
    }
    Ok(())
}

/// Replace `out` by the finished staging folder (see the module doc).
fn swap_into_place(staging: tempfile::TempDir, out: &Path, parent: &Path) -> anyhow::Result<()> {
    let old = if out.exists() {
        let old = tempfile::Builder::new()
            .prefix(".old-")
            .tempdir_in(parent)
            .with_context(|| format!("cannot create a folder in {}", parent.display()))?;
        let previous = old.path().join("previous");
        std::fs::rename(out, &previous)
            .with_context(|| format!("cannot move the previous run {} aside", out.display()))?;
        Some((old, previous))
    } else {
        None
    };
    let staged = staging.keep();
    if let Err(e) = std::fs::rename(&staged, out) {
        // Put the previous run back; leave nothing behind.
        if let Some((_, previous)) = &old {
            let _ = std::fs::rename(previous, out);
        }
        let _ = std::fs::remove_dir_all(&staged);
        return Err(e).with_context(|| format!("cannot move the results into {}", out.display()));
    }
    drop(old);
    Ok(())
}

/// The workspace the binary was built from, when it is still there.
fn workspace_root() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let root = root.canonicalize().ok()?;
    root.join("Cargo.toml").is_file().then_some(root)
}

/// The default output folder of a scenario: `target/results/<name>/` of the workspace
/// (ignored by git, so the user's runs never touch the committed `results/`), or
/// `results/<name>/` in the current folder when the binary runs outside its workspace.
pub fn default_output(name: &str) -> PathBuf {
    match workspace_root() {
        Some(root) => root.join("target").join("results").join(name),
        None => PathBuf::from("results").join(name),
    }
}

fn trial_rows(
    w: &mut impl Write,
    variable: &str,
    value: &str,
    t: &TrialResult,
) -> std::io::Result<()> {
    let tr = &t.truth;
    for m in &t.methods {
        let e = m.errors.as_ref();
        let est = m.estimate.as_ref();
        let mut f: Vec<String> = vec![
            field(variable),
            field(value),
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
        f.push(field(&m.message));
        writeln!(w, "{}", f.join(","))?;
    }
    Ok(())
}

/// Summarise the trials of one setting.
fn summarise(value: &str, methods: &[epd_core::Method], trials: &[TrialResult]) -> Vec<SummaryRow> {
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

fn summary_line(variable: &str, r: &SummaryRow) -> String {
    let s = &r.stats;
    [
        field(variable),
        field(&r.sweep_value),
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
    ]
    .join(",")
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}

/// The workspace's commit and whether tracked files differ from it (`None` outside a
/// git checkout).
fn git_provenance() -> (Option<String>, Option<bool>) {
    let Some(root) = workspace_root() else {
        return (None, None);
    };
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .arg("-C")
            .arg(&root)
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let commit = git(&["rev-parse", "HEAD"]);
    let dirty = git(&["status", "--porcelain", "--untracked-files=no"]).map(|s| !s.is_empty());
    (commit, dirty)
}

/// Run `scenario` into `options.out`.
pub fn run(scenario: &Scenario, options: &RunOptions) -> anyhow::Result<RunReport> {
    let start = Instant::now();
    let trials = options.trials.unwrap_or(scenario.trials);
    anyhow::ensure!(
        (1..=crate::scenario::MAX_TRIALS).contains(&trials),
        "--trials {trials}: must lie in [1, {}]",
        crate::scenario::MAX_TRIALS
    );
    let out = &options.out;
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    check_output_folder(out)?;
    std::fs::create_dir_all(&parent)
        .with_context(|| format!("cannot create {}", parent.display()))?;
    let staging = tempfile::Builder::new()
        .prefix(".run-")
        .tempdir_in(&parent)
        .with_context(|| format!("cannot create a staging folder in {}", parent.display()))?;
    let dir = staging.path().to_path_buf();
    let trials_path = dir.join("trials.csv");
    let summary_path = dir.join("summary.csv");
    let mut trials_csv = create_new(&trials_path)?;
    let mut summary_csv = create_new(&summary_path)?;
    writeln!(trials_csv, "{}", TRIAL_COLUMNS.join(",")).map_err(wrote(&trials_path))?;
    writeln!(summary_csv, "{}", SUMMARY_COLUMNS.join(",")).map_err(wrote(&summary_path))?;
    let total = (trials * scenario.sweeps.len()) as u64;
    let bar = if options.progress {
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
    let pool = FramePool::default();
    let batch = if scenario.timing {
        1
    } else {
        4 * rayon::current_num_threads().max(1)
    };
    let mut summary = Vec::new();
    let mut trial_errors = 0;
    for (si, (value, setting)) in scenario.sweeps.iter().enumerate() {
        bar.set_message(format!("{} = {value}", scenario.sweep_variable));
        let mut results: Vec<TrialResult> = Vec::with_capacity(trials);
        let mut k = 0;
        while k < trials {
            if INTERRUPTED.load(Ordering::SeqCst) {
                bar.finish_and_clear();
                return Err(Interrupted.into());
            }
            let ks: Vec<usize> = (k..(k + batch).min(trials)).collect();
            let run_one = |&t: &usize| run_trial(setting, scenario.seed, t, si, &pool);
            let done: Vec<TrialResult> = if scenario.timing {
                ks.iter().map(run_one).collect()
            } else {
                ks.par_iter().map(run_one).collect()
            };
            for t in &done {
                trial_rows(&mut trials_csv, &scenario.sweep_variable, value, t)
                    .map_err(wrote(&trials_path))?;
                trial_errors += usize::from(t.error.is_some())
                    + t.methods.iter().filter(|m| m.status.is_none()).count();
            }
            bar.inc(done.len() as u64);
            results.extend(done);
            k += ks.len();
        }
        for row in summarise(value, &setting.methods, &results) {
            writeln!(
                summary_csv,
                "{}",
                summary_line(&scenario.sweep_variable, &row)
            )
            .map_err(wrote(&summary_path))?;
            summary.push(row);
        }
    }
    bar.finish_and_clear();
    let mut files = vec![
        finish(trials_csv, &trials_path)?,
        finish(summary_csv, &summary_path)?,
    ];
    files.push(write_new(
        &dir.join("scenario.toml"),
        scenario.source.as_bytes(),
    )?);
    files.extend(crate::plots::plot_all(scenario, &summary, &dir)?);
    let (git_commit, git_dirty) = git_provenance();
    let wall_time_s = start.elapsed().as_secs_f64();
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
        "profile": if cfg!(debug_assertions) { "dev" } else { "release" },
    });
    files.push(write_new(
        &dir.join("metadata.json"),
        serde_json::to_string_pretty(&meta)?.as_bytes(),
    )?);
    if INTERRUPTED.load(Ordering::SeqCst) {
        return Err(Interrupted.into());
    }
    swap_into_place(staging, out, &parent)?;
    let files = files
        .iter()
        .filter_map(|f| f.file_name().map(|n| out.join(n)))
        .collect();
    Ok(RunReport {
        summary,
        files,
        wall_time_s,
        trial_errors,
    })
}
