//! A whole sweep: its trials, setting by setting, streamed to `trials.csv`, their
//! statistics to `summary.csv`, then `scenario.toml`, the figures and `metadata.json`, all
//! into a staging folder that takes the output folder's place ([`crate::output`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use super::figures;
use super::record::TrialRecord;
use super::rows::{SUMMARY_COLUMNS, TRIAL_COLUMNS, summary_row, write_trial_rows};
use super::runner::{TrialRunner, progress_bar};
use super::scenario::Scenario;
use super::summary::{SummaryRow, summarise};
use crate::output::{CsvFile, INTERRUPTED, Interrupted, StagedFiles, write_new, write_run};
use crate::provenance::{Metadata, unix_now_s};

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

/// What `bench-harness` says when trials or estimates of a run or merge could not be made
/// at all (`n` of them; none: nothing to say).
pub fn trial_errors_note(n: usize) -> Option<String> {
    (n > 0).then(|| {
        format!("{n} trials or estimates could not be made (status `error` in trials.csv)")
    })
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

/// A sweep's `metadata.json`: what every run records ([`Metadata::new`]), the machine,
/// the scenario's file, swept key and trials, when the run finished, and what `time_ms`
/// and the `crb_*` columns mean.
pub(crate) fn metadata(scenario: &Scenario, trials: usize, wall_time_s: f64) -> Metadata {
    let timing = if scenario.timing {
        "trials one at a time: time_ms is the uncontended estimate call alone (each estimate \
         may still use all threads internally)"
    } else {
        "trials in parallel: time_ms is the estimate call alone, contended by concurrent trials"
    };
    Metadata::new(&scenario.name, scenario.seed, wall_time_s)
        .with_cpu()
        .with("scenario_file", scenario.path.display().to_string())
        .with("sweep_variable", scenario.sweep_variable.as_str())
        .with("trials_per_setting", trials)
        .with("finished_unix_s", unix_now_s())
        .with("timing", timing)
        .with(
            "crb",
            "crb_* and crb_std: Cramér–Rao 1-σ for range noise of the setting's σ (exact for \
             noise.model = range)",
        )
}

/// Write `summary.csv`, `scenario.toml`, the plots and `metadata.json` of a whole run
/// into `dir` (after `trials.csv`); `extra` adds to the metadata. Returns the files and
/// the wall time written in the metadata.
pub(crate) fn finish_run(
    scenario: &Scenario,
    summary: &[SummaryRow],
    trials: usize,
    dir: &Path,
    start: Instant,
    extra: impl FnOnce(Metadata) -> Metadata,
) -> anyhow::Result<(Vec<PathBuf>, f64)> {
    let mut files = vec![CsvFile::write_all(
        &dir.join("summary.csv"),
        SUMMARY_COLUMNS,
        summary
            .iter()
            .map(|r| summary_row(&scenario.sweep_variable, r)),
    )?];
    files.push(write_new(
        &dir.join("scenario.toml"),
        scenario.source.as_bytes(),
    )?);
    for png in figures::plot_all(scenario, summary)? {
        files.push(write_new(&dir.join(&png.name), &png.bytes)?);
    }
    let wall_time_s = start.elapsed().as_secs_f64();
    files.push(extra(metadata(scenario, trials, wall_time_s)).write(dir)?);
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
    let mut trials_csv = CsvFile::create(&dir.join("trials.csv"), TRIAL_COLUMNS)?;
    let bar = progress_bar(progress, (trials * scenario.sweeps.len()) as u64);
    let runner = TrialRunner::new(scenario, &bar);
    let all: Vec<usize> = (0..trials).collect();
    let mut summary = Vec::new();
    let mut trial_errors = 0;
    for (si, (value, setting)) in scenario.sweeps.iter().enumerate() {
        let mut results: Vec<TrialRecord> = Vec::with_capacity(trials);
        runner.run_setting(si, &all, |t| {
            write_trial_rows(&mut trials_csv, &scenario.sweep_variable, value, &t)?;
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
    let mut files = vec![trials_csv.finish()?];
    let (rest, wall_time_s) = finish_run(scenario, &summary, trials, dir, start, |meta| meta)?;
    files.extend(rest);
    Ok(Staged {
        summary,
        files,
        wall_time_s,
        trial_errors,
    })
}
