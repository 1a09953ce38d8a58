//! Fitting a frame: the cleaning of its points, the data-only initial guess, the staged
//! estimate with its covariance and Cramér–Rao bound, and the checks that the result
//! agrees with its points.

pub mod bound;
pub mod check;
pub mod cloud;
pub mod covariance;
pub mod estimate;
pub mod form;
pub mod init;
pub mod options;
pub mod student;
pub mod uncertainty;
