//! Long calls under the caller's control: the work on a thread of its own while the
//! calling thread waits without the GIL and polls for signals, the process's thread pool
//! (rebuilt after `os.fork`), and the working memory reserved before the fit so that
//! running out raises `MemoryError`.

use super::*;

/// How often a waiting call checks for signals (Ctrl-C): a tenth of the 0.5 s a user
/// waits for at most, so the estimator's step, not the poll, sets the delay.
pub const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// The thread pool of the process that made it: `(pid, pool)`.
pub(crate) static POOL: Mutex<Option<(u32, Arc<rayon::ThreadPool>)>> = Mutex::new(None);

/// This process's thread pool (threads: `RAYON_NUM_THREADS`, else one per core). A
/// process forked after a call inherits the parent's pool without its threads (work
/// sent to it would wait forever): a pool made in another process is left alone and a
/// new one built.
pub(crate) fn pool() -> PyResult<Arc<rayon::ThreadPool>> {
    let pid = std::process::id();
    let mut slot = POOL.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((owner, p)) = slot.as_ref()
        && *owner == pid
    {
        return Ok(p.clone());
    }
    let p = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .thread_name(|i| format!("epd-{i}"))
            .build()
            .map_err(|e| PyRuntimeError::new_err(format!("cannot start epd's threads: {e}")))?,
    );
    // The parent's pool has no threads here: dropping it would wait on none, but its
    // memory is the parent's bookkeeping; it is kept (leaked once per fork).
    if let Some(old) = slot.replace((pid, p.clone())) {
        std::mem::forget(old);
    }
    Ok(p)
}

/// Why a call stopped without a result.
pub(crate) enum Stop<E> {
    /// The work's own error.
    Failed(E),
    /// A signal handler raised (Ctrl-C: `KeyboardInterrupt`).
    Signal(PyErr),
}

/// Run `work` in this process's pool ([`pool`]) on a thread of its own, the GIL
/// released, while this thread checks for signals every [`SIGNAL_POLL`]: when a Python
/// signal handler raises (Ctrl-C), the work is told to stop (`epd_core::cancel`), waited
/// for (it stops at the estimator's next step), and the exception returned. A panic of
/// the work goes on unwinding here.
pub(crate) fn run_interruptible<R: Send, E: Send>(
    py: Python<'_>,
    work: impl FnOnce() -> Result<R, E> + Send,
) -> Result<R, Stop<E>> {
    let pool = pool().map_err(Stop::Signal)?;
    let flag = Arc::new(AtomicBool::new(false));
    std::thread::scope(|scope| {
        let (tx, rx) = std::sync::mpsc::channel();
        let stop = flag.clone();
        let worker = scope.spawn(move || {
            let r = pool.install(|| epd_core::cancel::run_cancellable(&stop, work));
            let _ = tx.send(());
            r
        });
        let mut rx = rx;
        loop {
            // The receiver moves into the GIL-free wait and back (it is Send, not Sync).
            let (back, done) = py.detach(move || {
                let done = rx.recv_timeout(SIGNAL_POLL).is_ok();
                (rx, done)
            });
            rx = back;
            if done || worker.is_finished() {
                break;
            }
            if let Err(e) = py.check_signals() {
                flag.store(true, Ordering::Relaxed);
                py.detach(|| {
                    let _ = worker.join();
                });
                return Err(Stop::Signal(e));
            }
        }
        match worker.join() {
            Ok(Ok(Ok(r))) => Ok(r),
            Ok(Ok(Err(e))) => Err(Stop::Failed(e)),
            // The flag is set only above; a stop without it cannot happen.
            Ok(Err(epd_core::cancel::Cancelled)) => Err(Stop::Signal(
                PyKeyboardInterrupt::new_err("epd: the estimate was cancelled"),
            )),
            Err(panic) => std::panic::resume_unwind(panic),
        }
    })
}

/// Working memory of an estimate beyond its input, per point (bytes): the geometry
/// survey's per-point arrays (the fit itself adds none: the input is read in place, and
/// the survey's refits read their part of it through a mask of one bit a point), and a
/// weighted fit's (`sigma=`) clean copy of the points with their σᵢ and scales, 24 + 8 + 8 = 40 bytes.
/// Measured as the growth of the peak RSS of `epd.estimate` over the input's points, the
/// process's first call: 6.4–6.5 bytes on 2·10⁶ points of a simulated frame repeated, 5.8–6.1
/// on 4·10⁶ of the numpy caster's multipath and range² frames, whose survey refits (30.7
/// before the refits read in place), 5.1 on 10⁷. Reserved as the weighted fit's 40 and a
/// fifth more. tests/test_resources.py checks the measurement stays below.
pub const WORKING_BYTES_PER_POINT: usize = 48;

/// Reserve (and give back) the working memory an estimate of `n` points will need, so
/// that running out of memory raises `MemoryError` before the fit instead of aborting
/// the interpreter in the middle of it. Later allocations reuse the freed memory (the
/// allocator keeps it: `epd_frame::keep_freed_memory` where set, the address space
/// otherwise).
pub(crate) fn reserve_working_memory(n: usize) -> PyResult<()> {
    let bytes = n.saturating_mul(WORKING_BYTES_PER_POINT);
    let mut probe: Vec<u8> = Vec::new();
    probe.try_reserve_exact(bytes).map_err(|_| {
        PyMemoryError::new_err(format!(
            "epd.estimate: cannot allocate the {:.1} GB of working memory that {n} points \
             need ({WORKING_BYTES_PER_POINT} bytes per point beyond the input)",
            bytes as f64 / 1e9
        ))
    })?;
    Ok(())
}
