//! Inputs measured in parallel and their results handed on in the inputs' order, a new
//! input started as soon as any other finishes.
//!
//! At most `in_flight` inputs are being measured (each holds its points: memory stays
//! bounded by a few frames, whatever the length of a bag), the next is read as soon as
//! one finishes, and results that finish before an earlier one wait, small, in a reorder
//! buffer. Before, inputs were measured in batches of 2 × threads, the next batch read
//! meanwhile: up to twice as many frames in memory. On a 300-message bag of Helios2-model
//! frames (docs/benchmarks.md, "A ROS 2 bag") the peak memory fell from 224–266 to
//! 147–161 MiB; the time did not (the batches had kept both cores busy).

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;

/// Results finished ahead of the one awaited that are held, per input in flight, before
/// no further input is started: a bound on the reorder buffer (a report is a few hundred
/// bytes, its frame's points are freed when it finishes) for an input that takes far
/// longer than the rest.
const HELD_PER_IN_FLIGHT: usize = 16;

/// Inputs being measured at once per worker thread: two, so that when one finishes the
/// next is already waiting in the pool while the calling thread reads the one after (a
/// bag's message is decoded there), and memory holds about two frames per thread.
const IN_FLIGHT_PER_THREAD: usize = 2;

/// Measures each item of `items` with `measure` on the global rayon pool, at most
/// [`IN_FLIGHT_PER_THREAD`] per worker at a time, and hands each result to `take` in the items' order. The items
/// are read on the calling thread (none of the pool's: waiting there keeps no worker from
/// the measurements) as room frees, a bag's next message decoded only then. `take`
/// returning `Ok(false)` (the output closed) or an error stops: no further item is read,
/// and those being measured are stopped at their next checkpoint
/// ([`epd_core::cancel`]: each solver step and survey stage) and dropped — before, they
/// ran to their end, and a closed output ended the run 0.2–2.3 s later on the
/// Helios2-model bag's frames (docs/epd.md). A panic in `measure` is raised again on the
/// calling thread once the items in flight have stopped.
pub(crate) fn in_order<T, R, I, F, G>(items: I, measure: F, take: G) -> anyhow::Result<()>
where
    I: Iterator<Item = T>,
    T: Send,
    R: Send,
    F: Fn(T) -> R + Sync,
    G: FnMut(R) -> anyhow::Result<bool>,
{
    let in_flight = IN_FLIGHT_PER_THREAD * rayon::current_num_threads();
    rayon::in_place_scope(|scope| run(scope, items, in_flight, &measure, take))
}

/// [`in_order`]'s loop, at most `in_flight` items being measured at once, its tasks spawned in `scope`.
fn run<'scope, T, R, I, F, G>(
    scope: &rayon::Scope<'scope>,
    items: I,
    in_flight: usize,
    measure: &'scope F,
    mut take: G,
) -> anyhow::Result<()>
where
    I: Iterator<Item = T>,
    T: Send + 'scope,
    R: Send + 'scope,
    F: Fn(T) -> R + Sync,
    G: FnMut(R) -> anyhow::Result<bool>,
{
    let in_flight = in_flight.max(1);
    // Set however this returns, so that the measurements still running stop (the scope
    // waits for them).
    let stop = StopOnDrop(Arc::new(AtomicBool::new(false)));
    let (tx, rx) = mpsc::channel();
    let mut items = items.fuse();
    let (mut started, mut handed, mut running) = (0usize, 0usize, 0usize);
    let mut exhausted = false;
    let mut done: BTreeMap<usize, R> = BTreeMap::new();
    loop {
        while running < in_flight && done.len() < HELD_PER_IN_FLIGHT * in_flight {
            let Some(item) = items.next() else {
                exhausted = true;
                break;
            };
            let (tx, i, flag) = (tx.clone(), started, stop.0.clone());
            scope.spawn(move |_| {
                let r = catch_unwind(AssertUnwindSafe(|| {
                    epd_core::cancel::run_cancellable(&flag, || measure(item))
                }));
                // The receiver outlives the scope: a send cannot fail. A stopped
                // measurement's result is no longer awaited: nothing to send.
                match r {
                    Ok(Ok(r)) => drop(tx.send((i, Ok(r)))),
                    Ok(Err(epd_core::cancel::Cancelled)) => {}
                    Err(panic) => drop(tx.send((i, Err(panic)))),
                }
            });
            started += 1;
            running += 1;
        }
        while let Some(r) = done.remove(&handed) {
            handed += 1;
            if !take(r)? {
                return Ok(());
            }
        }
        if running == 0 {
            // Everything started is handed on: done when nothing is left to read, else
            // room for more (the reorder buffer had been full).
            if exhausted {
                return Ok(());
            }
            continue;
        }
        // Every task sends before it ends, and this thread holds a sender: the channel
        // cannot close while one runs.
        let (i, r) = rx
            .recv()
            .map_err(|_| anyhow::anyhow!("a measurement ended without its result"))?;
        running -= 1;
        match r {
            Ok(r) => {
                done.insert(i, r);
            }
            Err(panic) => resume_unwind(panic),
        }
    }
}

/// Sets its flag when dropped: [`run`]'s stop request to the measurements in flight.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;
    use std::time::Duration;

    /// [`in_order`] on a pool of `threads` workers, called from this thread (none of
    /// them), as `epd` calls it on the global pool from its main thread.
    fn in_order_on<T: Send, R: Send>(
        threads: usize,
        items: impl Iterator<Item = T>,
        in_flight: usize,
        measure: impl Fn(T) -> R + Sync,
        take: impl FnMut(R) -> anyhow::Result<bool>,
    ) -> anyhow::Result<()> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.in_place_scope(|scope| run(scope, items, in_flight, &measure, take))
    }

    /// Items whose measurement takes a time that falls with the index, so that later
    /// ones finish first: handed on in order all the same, never more than the window at
    /// once.
    #[test]
    fn results_come_in_the_items_order_and_the_window_holds() {
        let (now, most) = (AtomicUsize::new(0), AtomicUsize::new(0));
        let mut seen = Vec::new();
        in_order_on(
            3,
            0..24usize,
            4,
            |i| {
                let n = now.fetch_add(1, Ordering::SeqCst) + 1;
                most.fetch_max(n, Ordering::SeqCst);
                std::thread::sleep(Duration::from_millis(((24 - i) % 5) as u64 * 3));
                now.fetch_sub(1, Ordering::SeqCst);
                i * i
            },
            |r| {
                seen.push(r);
                Ok(true)
            },
        )
        .expect("run");
        assert_eq!(seen, (0..24).map(|i| i * i).collect::<Vec<_>>());
        let most = most.load(Ordering::SeqCst);
        assert!((1..=4).contains(&most), "{most} measured at once");
    }

    /// The output closes at the first result: the measurements then in flight, each
    /// waiting at checkpoints for up to 20 s, stop at their next one instead of running
    /// to their end (none of them finishes), and nothing is started after the close. On
    /// the previous loop every one of them ran its 20 s to the end.
    #[test]
    fn a_closed_output_stops_the_measurements_in_flight() {
        let (started, finished) = (AtomicUsize::new(0), AtomicUsize::new(0));
        let mut seen = Vec::new();
        in_order_on(
            2,
            0..40usize,
            4,
            |i| {
                started.fetch_add(1, Ordering::SeqCst);
                if i > 0 {
                    for _ in 0..2000 {
                        std::thread::sleep(Duration::from_millis(10));
                        epd_core::cancel::checkpoint();
                    }
                }
                finished.fetch_add(1, Ordering::SeqCst);
                i
            },
            |r| {
                seen.push(r);
                Ok(false)
            },
        )
        .expect("run");
        assert_eq!(seen, vec![0]);
        assert_eq!(
            finished.load(Ordering::SeqCst),
            1,
            "only the first ran to its end"
        );
        // The window (4), and the one started when the first finished, before its result
        // was handed on.
        assert!(
            started.load(Ordering::SeqCst) <= 5,
            "no item started after the close"
        );
    }

    /// One item far slower than the rest: the others finish meanwhile until the reorder
    /// buffer is full, the slow one finishes, and the rest are still read and handed on
    /// (a version that returned once nothing was running lost every item after the full
    /// buffer: 91 of a 300-message bag's results, with exit status 0).
    #[test]
    fn a_slow_item_holding_a_full_reorder_buffer_loses_nothing() {
        let n = 4 * HELD_PER_IN_FLIGHT * 2;
        let mut seen = Vec::new();
        in_order_on(
            2,
            0..n,
            2,
            |i| {
                if i == 0 {
                    std::thread::sleep(Duration::from_millis(300));
                }
                i
            },
            |r| {
                seen.push(r);
                Ok(true)
            },
        )
        .expect("run");
        assert_eq!(seen, (0..n).collect::<Vec<_>>());
    }

    /// `take` saying stop: nothing more is read than the window beyond what was taken.
    #[test]
    fn a_closed_output_stops_the_reading() {
        let read = AtomicUsize::new(0);
        let items = (0..1000usize).inspect(|_| {
            read.fetch_add(1, Ordering::SeqCst);
        });
        let mut taken = 0;
        in_order_on(
            2,
            items,
            2,
            |i| i,
            |_| {
                taken += 1;
                Ok(taken < 3)
            },
        )
        .expect("run");
        assert_eq!(taken, 3);
        // Three taken, at most two in flight and the held results beside them.
        let read = read.load(Ordering::SeqCst);
        assert!(read <= 3 + 2 + HELD_PER_IN_FLIGHT * 2, "{read} read");
    }

    /// An error from `take` is returned, and a panic in `measure` is raised again here.
    #[test]
    fn errors_and_panics_reach_the_caller() {
        let e = in_order(
            0..10usize,
            |i| i,
            |i| {
                anyhow::ensure!(i < 4, "stop at {i}");
                Ok(true)
            },
        );
        assert_eq!(e.expect_err("error").to_string(), "stop at 4");
        let caught = catch_unwind(|| {
            in_order_on(
                2,
                0..10usize,
                2,
                |i| {
                    assert!(i != 5, "item five");
                    i
                },
                |_| Ok(true),
            )
        });
        assert!(caught.is_err());
    }
}
