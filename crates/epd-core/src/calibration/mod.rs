//! Depth calibration by lookup table (the paper's §4.2, its ref. 27).
//!
//! A ToF camera's systematic range error (wiggling, an amplitude-dependent offset,
//! multipath) depends mostly on the measured range r and the return's intensity I. In a
//! pipe of known diameter the pose of each frame is fitted with the diameters held at
//! their known values; every point then gives one observation of the error along its
//! sensing line,
//!
//!   δᵢ = ‖x̂ᵢ‖ − t(x̂ᵢ)·‖x̂ᵢ‖  (measured range − model range, m),
//!
//! with t the line parameter of eq. (21) at the fitted β ([`offsets`]). A [`DepthTable`]
//! stores, per (range × log-intensity) bin, the robust mean of δ over many frames (the
//! random error averages out) and its robust spread (the random error's σ there).
//! [`DepthTable::correct`] moves each measured point of a new frame along its own ray by
//! −T(r, I), interpolated between bin centres.
//!
//! Binning uses the *model* range of each observation: binned by measured range, a
//! bin would collect the points whose noise pushed them in, and store that noise's
//! conditional mean along with the systematic error. A new frame has no model: its
//! correction solves ρ + T(ρ, I) = r for the wall range ρ of each measured range r.

mod incidence;
mod joint;
mod propagate;
mod rig;
mod table;
#[cfg(test)]
mod tests;

pub use incidence::{
    Correction, IncidenceBins, IncidenceObservation, IncidenceTable, Lookup, Support,
};
pub use joint::{JOINT_MAX_STEPS, JOINT_STOP_CHI2, JointOutcome, LAMBDA_START};
pub use propagate::{shared_error_cov, shared_error_cov_terms};
pub use rig::{
    Calibration, CalibrationFrame, CalibrationSettings, Observation, RigFrames, calibrate,
    calibrate_rigs, incidences, offsets, offsets_with_incidence,
};
pub use table::{
    Axis, DepthTable, MAX_INVERSE_CELLS, MAX_INVERSE_COLUMNS, MAX_OFFSET_M, MAX_TABLE_BINS,
    MAX_TABLE_RANGE_M, MIN_AXIS_SPAN, TableBins,
};
