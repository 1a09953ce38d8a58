//! The solver, which knows nothing of pipes: a least-squares problem behind a small trait,
//! the Levenberg–Marquardt loop, and the robust losses with their tuning constants.

pub mod cells;
pub mod lm;
pub mod loss;
pub mod points;
pub mod problem;
