//! Configuration errors of the simulator.

/// A configuration the simulator refuses, naming the field and what is wrong.
#[derive(Clone, Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// A field outside its valid range.
    #[error("invalid `{field}` = {value}: {reason}")]
    Invalid {
        /// The field, as named in a scenario file (`sensor.fov_h_deg`, …).
        field: &'static str,
        /// The refused value, as text.
        value: String,
        /// What the field must satisfy.
        reason: &'static str,
    },
    /// A field of one segment of a pipeline outside its valid range.
    #[error("invalid `pipeline.segments[{index}].{field}` = {value}: {reason}")]
    InvalidSegment {
        /// The segment's index in `Pipeline::segments`.
        index: usize,
        /// The field of the segment (`radius`, `angle`, …).
        field: &'static str,
        /// The refused value, as text.
        value: String,
        /// What the field must satisfy.
        reason: &'static str,
    },
    /// The pipe geometry could not be built.
    #[error("cannot build the pipe mesh: {0}")]
    Mesh(String),
}

impl SimError {
    pub(crate) fn invalid(
        field: &'static str,
        value: impl std::fmt::Display,
        reason: &'static str,
    ) -> Self {
        SimError::Invalid {
            field,
            value: value.to_string(),
            reason,
        }
    }
}
