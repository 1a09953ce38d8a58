//! Running a sweep's trials in batches: in parallel, or one at a time when the scenario
//! takes timings; a progress bar over them; stopped between batches when interrupted.

use std::sync::atomic::Ordering;

use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use super::record::TrialRecord;
use super::scenario::Scenario;
use super::trial::{FramePool, run_trial};
use crate::output::{INTERRUPTED, Interrupted};

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
            let done: Vec<TrialRecord> = if self.scenario.timing {
                ks.iter().map(run_one).collect()
            } else {
                ks.par_iter().map(run_one).collect()
            };
            self.bar.inc(done.len() as u64);
            for t in done {
                each(t)?;
            }
        }
        Ok(())
    }
}
