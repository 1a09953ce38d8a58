//! Stopping a long estimate from outside (a Python caller's Ctrl-C): a flag that the
//! caller sets, polled at the solver's steps ([`checkpoint`]) and in the survey's serial loops over
//! points ([`tick`]).
//!
//! [`run_cancellable`] runs a computation with a flag for the current thread; a
//! [`checkpoint`] on that thread that finds the flag set unwinds to it (with
//! `resume_unwind`: no panic message, no panic hook), and `run_cancellable` returns
//! [`Cancelled`]. Checkpoints sit in sequential code only (each step of
//! [`crate::lm::minimize`], the stages of a frame), never inside parallel work, so an
//! unwind never crosses a parallel job. A parallel pass over points looks at the flag
//! through a [`Watch`] taken before it: once set, its remaining chunks are skipped (their
//! sums left zero) and the [`checkpoint`] right after the pass unwinds, so a stop takes
//! effect within one chunk, not one pass (a pass over 4·10⁶ points took 0.3–0.7 s on a
//! loaded 2-core machine). Without a flag (every caller but the Python package) a
//! checkpoint is one thread-local read, a watch one branch per chunk.

use std::cell::{Cell, RefCell};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

thread_local! {
    static FLAG: RefCell<Option<Arc<AtomicBool>>> = const { RefCell::new(None) };
    static TICKS: Cell<u32> = const { Cell::new(0) };
}

/// Per-point steps between two checkpoints of [`tick`]: 65 536 points of the survey's
/// per-point work take milliseconds, far under the 0.5 s a user waits for a Ctrl-C. With
/// it alone, SIGINT during `epd.estimate` of 4·10⁶ points (2 CPU hogs on a 2-core
/// machine, 20 random moments) took effect after 0.28 s (median), 0.72 s at most: one
/// solver pass over all points had no checkpoint; with the passes' [`Watch`], 0.05 s
/// (median), 0.36 s at most.
pub const TICKS_PER_CHECK: u32 = 1 << 16;

/// The computation was stopped by its flag.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

/// Run `f` with `flag` as the current thread's cancellation flag (the previous one is
/// restored afterwards, so runs may nest); `Err(Cancelled)` when a [`checkpoint`] found
/// it set. A panic of `f` for another reason goes on unwinding.
pub fn run_cancellable<R>(flag: &Arc<AtomicBool>, f: impl FnOnce() -> R) -> Result<R, Cancelled> {
    let previous = FLAG.with(|c| c.replace(Some(flag.clone())));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    FLAG.with(|c| *c.borrow_mut() = previous);
    match result {
        Ok(r) => Ok(r),
        Err(payload) if payload.is::<Cancelled>() => Err(Cancelled),
        Err(payload) => std::panic::resume_unwind(payload),
    }
}

/// Unwind to [`run_cancellable`] when the current thread's flag is set; nothing
/// otherwise (and nothing on a thread without a flag).
pub fn checkpoint() {
    let set = FLAG.with(|c| {
        c.borrow()
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
    });
    if set {
        std::panic::resume_unwind(Box::new(Cancelled));
    }
}

/// The current thread's stop flag, for the workers of a parallel pass to look at
/// ([`Watch::stopped`]); a pass that skips work on it must be followed by a
/// [`checkpoint`] on the thread that took the watch, before its result is used.
#[derive(Clone, Debug, Default)]
pub struct Watch(Option<Arc<AtomicBool>>);

impl Watch {
    /// Whether a stop was requested (never, on a thread without a flag).
    #[inline]
    pub fn stopped(&self) -> bool {
        self.0.as_ref().is_some_and(|f| f.load(Ordering::Relaxed))
    }
}

/// The current thread's flag, to look at from other threads (see [`Watch`]).
pub fn watch() -> Watch {
    FLAG.with(|c| Watch(c.borrow().clone()))
}

/// One step of a serial loop over points: a [`checkpoint`] every [`TICKS_PER_CHECK`]
/// calls on this thread.
#[inline]
pub fn tick() {
    let due = TICKS.with(|t| {
        let n = t.get().wrapping_add(1);
        t.set(n);
        n % TICKS_PER_CHECK == 0
    });
    if due {
        checkpoint();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_set_flag_stops_at_the_next_checkpoint() {
        let flag = Arc::new(AtomicBool::new(false));
        let mut steps = 0;
        let r = run_cancellable(&flag, || {
            for i in 0..10 {
                checkpoint();
                steps += 1;
                if i == 3 {
                    flag.store(true, Ordering::Relaxed);
                }
            }
        });
        assert_eq!(r, Err(Cancelled));
        assert_eq!(steps, 4);
        // No flag on this thread any more: a checkpoint does nothing.
        checkpoint();
        let unset = Arc::new(AtomicBool::new(false));
        assert_eq!(run_cancellable(&unset, || 7), Ok(7));
    }

    /// A watch sees its thread's flag from another thread; without a flag it never
    /// reports a stop.
    #[test]
    fn a_watch_sees_the_flag_from_another_thread() {
        assert!(!watch().stopped());
        let flag = Arc::new(AtomicBool::new(false));
        let r = run_cancellable(&flag, || {
            let w = watch();
            let before = std::thread::scope(|s| s.spawn(|| w.stopped()).join().unwrap());
            flag.store(true, Ordering::Relaxed);
            let after = std::thread::scope(|s| s.spawn(|| w.stopped()).join().unwrap());
            (before, after)
        });
        assert_eq!(r, Ok((false, true)));
    }
}
