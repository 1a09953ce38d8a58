//! The library behind the `epd` tool: readers for real point-cloud files and the report
//! formats. The binary is a thin layer of argument parsing over it.
#![deny(missing_docs)]

pub mod read;
pub mod report;
pub mod table;

pub use read::{Format, PointCloud, ReadError, read_bytes};
