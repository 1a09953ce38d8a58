//! The library behind the `epd` tool: readers for real point-cloud files and the report
//! formats. The binary is a thin layer of argument parsing over it.
#![deny(missing_docs)]

pub mod estimate;
pub mod read;
pub mod report;
pub mod shard;
pub mod simulate;
pub mod table;

/// Keep freed memory in the process for the next frame instead of returning it to the
/// system: glibc hands large buffers (a frame's points, ~10 MB) back to the kernel on
/// `free` and the next frame pays a page fault per 4 KiB to get them again — on this
/// project's 2-core VM about 34 ms per 640×480 frame, more than the estimate itself
/// (`cargo bench -p epd-cli --bench frame`). Call once at start-up; a no-op elsewhere
/// than Linux with glibc.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator thresholds; called before any thread
    // allocates concurrently.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
    }
}

pub use read::{Format, PointCloud, ReadError, read_bytes};
