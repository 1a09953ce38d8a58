//! A global allocator that counts, per thread, the bytes in use and their peak, so a test
//! can bound the memory a reader takes for a given input, and a helper that runs a call on
//! its own thread with a time limit (a reader that hangs fails the test instead of hanging
//! it) and reports its time and peak memory.
#![allow(dead_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::{Duration, Instant};

/// The counting allocator; install it with `#[global_allocator]`.
pub struct PeakAlloc;

thread_local! {
    static IN_USE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn add(delta: isize) {
    let _ = IN_USE.try_with(|u| {
        let now = u.get() + delta;
        u.set(now);
        let _ = PEAK.try_with(|p| {
            if now > p.get() {
                p.set(now);
            }
        });
    });
}

// SAFETY: every call is forwarded to `System` unchanged; the counters are thread-local
// cells that never allocate.
unsafe impl GlobalAlloc for PeakAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's layout.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            add(layout.size() as isize);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's layout.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            add(layout.size() as isize);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by `System` with this layout.
        unsafe { System.dealloc(ptr, layout) };
        add(-(layout.size() as isize));
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded unchanged.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            add(new_size as isize - layout.size() as isize);
        }
        p
    }
}

/// What a bounded call took.
pub struct Cost {
    /// Wall time.
    pub time: Duration,
    /// The most heap bytes the call had in use at once, beyond what its thread started with.
    pub peak_bytes: usize,
}

/// Run `f` on a new thread; fail if it panics or does not return within `limit`.
pub fn bounded<T: Send + 'static>(
    limit: Duration,
    f: impl FnOnce() -> T + Send + 'static,
) -> (T, Cost) {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let base = IN_USE.with(|u| u.get());
        PEAK.with(|p| p.set(base));
        let t0 = Instant::now();
        let v = f();
        let time = t0.elapsed();
        let peak = PEAK.with(|p| p.get()) - base;
        let _ = tx.send((
            v,
            Cost {
                time,
                peak_bytes: peak.max(0) as usize,
            },
        ));
    });
    match rx.recv_timeout(limit) {
        Ok(v) => v,
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
            panic!("the call did not return within {limit:?} (a hang?)")
        }
        Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => panic!("the call panicked"),
    }
}
