//! Frames and an independent XYZ writer for the tests of the `epd` tool: the reader
//! tests' helpers of epd-io, one copy for both crates.

#[path = "../../../epd-io/tests/common/mod.rs"]
mod shared;

// Each test file uses a part of them.
#[allow(unused_imports)]
pub use shared::{frame, temp_dir, xyz};
