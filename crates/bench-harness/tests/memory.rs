//! Loading a scenario takes memory linear in its swept values: the peak heap use, counted
//! by a global allocator, for 1 000 and 10 000 values (the quadratic loader took 3.1 GB
//! for 10 000). One test in this binary, so no other test allocates meanwhile.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use bench_harness::Scenario;

/// The system allocator, counting the bytes in use and their peak.
struct Counting;

static IN_USE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is forwarded to `System` with the same arguments; the counters are
// only bookkeeping.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded as is.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = IN_USE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as is.
        unsafe { System.dealloc(ptr, layout) };
        IN_USE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Peak heap bytes above the baseline while parsing a sweep of `n` values.
fn peak_for(n: usize) -> usize {
    let values: Vec<String> = (0..n)
        .map(|i| format!("{}", 0.01 + i as f64 * 1e-6))
        .collect();
    let src = format!(
        "name = \"m\"\ntrials = 1\n[sweep]\nvariable = \"noise.sigma_m\"\nvalues = [{}]\n",
        values.join(",")
    );
    let base = IN_USE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let s = Scenario::parse(Path::new("many.toml"), &src).unwrap();
    assert_eq!(s.sweeps.len(), n);
    drop(s);
    PEAK.load(Ordering::Relaxed) - base
}

#[test]
fn sweep_memory_is_linear_in_the_number_of_values() {
    let small = peak_for(1_000);
    let large = peak_for(10_000);
    eprintln!(
        "peak heap while loading: 1 000 values {small} B, 10 000 values {large} B ({:.2}×)",
        large as f64 / small as f64
    );
    // Measured 5 250 003 B for 10 000 values, 10.0× the memory for 10× the values:
    // bounds at 2× the peak and 12× the ratio (the quadratic loader took 3.1 GB; a
    // loader quadratic in the values would take ~100× for 10× the values).
    assert!(large < 10_500_000, "10 000 values took {large} bytes");
    assert!(
        large < 12 * small,
        "10× the values took {:.1}× the memory",
        large as f64 / small as f64
    );
}
