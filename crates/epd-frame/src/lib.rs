//! One measurement of a frame, shared by every front end: the `epd` tool, the Python
//! package and the bench harness call this library, so a frame gives the same keys and
//! values whichever way it comes in.
//!
//! A frame flows through it in this order ([`measure::measure_file`] →
//! [`measure::measure_frame`]):
//! 1. [`input`]: read the file ([`input::read_input`], through `epd-io`'s readers) and
//!    convert its points to metres in the sensor frame, checking the unit is plausible;
//! 2. [`table`]: the depth-calibration table's correction
//!    ([`table::CalibrationTable::correct_points`]) — and the table's file format;
//! 3. [`scene`]: what lies ahead ([`scene::FrameScene::survey`]: straight, bend or tee ahead,
//!    in a bend) and which points belong to the straight section;
//! 4. the fit of the straight section with its checks and 1-σ (`epd_core`), in
//!    [`measure`];
//! 5. [`report`]: the report's keys and values ([`report::FileReport::fields`]), as JSON,
//!    CSV or text.
//!
//! A ROS 2 bag's PointCloud2 messages go the same way, one report per message ([`bag`]).
//! With `--max-points N`, [`sampling`] chooses the N points that carry the information
//! before step 2 (a pilot fit, then the rays of most influence on the mean diameter).
//!
//! [`export`] puts the fit where people can see it (the points' residuals, the wall as a
//! mesh). [`config`] holds the settings as given and checked; [`shard`] the `--shard K/N` split
//! of a batch. Arrows: epd-core ← epd-io ← epd-frame ← epd-cli, epd-py, bench-harness.
#![deny(missing_docs)]

pub mod bag;
pub mod config;
pub mod export;
pub mod input;
pub mod measure;
/// The point-cloud readers, which live in `epd-io` (re-exported for the front ends).
pub mod read {
    pub use epd_io::read::*;
    pub use epd_io::{pcd, ply, text};
}
pub mod report;
pub mod rig;
pub mod sampling;
pub mod scene;
pub mod shard;
pub mod table;

pub use config::{ConfigError, EstimateConfig, EstimateSettings, InputConfig, InputFrame, Units};
pub use measure::{FrameInput, measure_cloud, measure_file, measure_frame};
pub use report::{FileEstimate, FileReport};
pub use scene::{FrameScene, GeometryReport};
pub use table::CalibrationTable;

/// Keep freed memory in the process for the next frame instead of returning it to the
/// system: glibc hands large buffers (a frame's points, ~10 MB) back to the kernel on
/// `free` and the next frame pays a page fault per 4 KiB to get them again
/// (`cargo bench -p epd-frame --bench frame` measures a frame with it). Call once at
/// start-up; a no-op elsewhere than Linux with glibc.
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
