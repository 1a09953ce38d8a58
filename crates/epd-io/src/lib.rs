//! The file formats of the EPD workspace, in one place: every encoding that the `epd`
//! tool, the Python package, the bench harness and the simulator read or write.
//!
//! - [`cloud`]: a frame as the writers take it ([`cloud::SensorCloud`]: points with their
//!   pixels and named per-point properties), whatever made it; this crate knows no
//!   simulator.
//! - [`read`]: format detection and the readers' common types ([`PointCloud`],
//!   [`ReadError`]); the readers themselves in [`ply`], [`pcd`] and [`text`].
//! - [`records`]: the fixed-size records of a binary PLY or PCD read by index, not the
//!   whole file decoded (`--max-points`).
//! - [`ply`]: PLY read and write (ASCII, binary; `intensity`, `segment`, `part`).
//! - [`bag`]: ROS 2 bags (MCAP): the `sensor_msgs/msg/PointCloud2` messages of a topic,
//!   streamed and decoded from CDR; the bag's topics.
//! - [`csv`]: CSV written through the `csv` crate, one quoting rule; numbers as
//!   shortest round-trip text; a frame's points as `x,y,z`.
//! - [`json`]: JSON through `serde_json`, numbers as shortest round-trip decimals; a
//!   report's fields ([`epd_core::report::Field`]) as one object.
//! - [`atomic`]: a file written whole (temporary file, fsync of the file and of its
//!   folder, rename; a device or pipe written through), its temporary files removed on
//!   a signal and after a kill.
//! - [`name`]: file names shown as data (control characters escaped, bytes that are not
//!   UTF-8 kept).
//! - [`diag`]: diagnostics on standard error that a closed pipe cannot turn into a
//!   panic.
//! - [`plot`]: figures of panels of series (lines, error bars, 1-σ bands), the bench
//!   harness's and `epd profile`'s.
//! - [`depth_png`]: a frame's depth image with its colour bar, drawn with plotters in
//!   the figures' [`font`].
//!
//! epd-core knows no encoding: it gives a report as (key, value) data, and this crate
//! encodes it. Arrows: epd-core ← epd-io ← tof-sim, epd-frame ← the front ends.
#![deny(missing_docs)]

pub mod atomic;
pub mod bag;
pub mod cloud;
pub mod csv;
pub mod depth_png;
pub mod diag;
pub mod font;
pub mod json;
pub mod name;
pub mod pcd;
pub mod plot;
pub mod ply;
pub mod read;
pub mod records;
pub mod text;

pub use read::{Format, MAX_INPUT_BYTES, PointCloud, ReadError, read_bytes, read_from, read_path};

/// Writing a file failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WriteError {
    /// An I/O error while writing `what` (a path, or a description).
    #[error("cannot write {what}: {source}")]
    Io {
        /// What was being written.
        what: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A figure could not be drawn.
    #[error("cannot draw {what}: {message}")]
    Draw {
        /// The figure.
        what: String,
        /// The drawing back end's message.
        message: String,
    },
}

impl WriteError {
    /// An I/O error while writing `what`.
    pub fn io(what: impl Into<String>, source: std::io::Error) -> Self {
        WriteError::Io {
            what: what.into(),
            source,
        }
    }
}
