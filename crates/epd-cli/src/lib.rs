//! The library behind the `epd` tool: the estimate of a file, its report and the
//! calibration table. The binary is a thin layer of argument parsing over it; the file
//! formats (readers, JSON, CSV, atomic writes) are the `epd-io` crate's.
#![deny(missing_docs)]

pub mod estimate;
/// The point-cloud readers, which live in `epd-io` (re-exported here for the tool's
/// users: the binary, the Python package, the benchmarks).
pub mod read {
    pub use epd_io::read::*;
    pub use epd_io::{pcd, ply, text};
}
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
