//! Errors of the estimators.

/// Why an estimate could not be made. Every variant says what is wrong with the input.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EpdError {
    /// Fewer usable points than parameters.
    #[error(
        "only {usable} usable points ({dropped} dropped as non-finite or at the origin); \
         at least {needed} are needed to estimate the 7 parameters"
    )]
    TooFewPoints {
        /// Points left after cleaning.
        usable: usize,
        /// Points dropped while cleaning.
        dropped: usize,
        /// Points needed.
        needed: usize,
    },
    /// The points do not span a cylinder (identical points, a line, a plane).
    #[error("degenerate point cloud: {0}")]
    Degenerate(String),
    /// The points are not the inside of a pipe seen from within.
    #[error("not a pipe: {0}")]
    NotAPipe(String),
    /// An option outside its range.
    #[error("invalid option: {0}")]
    InvalidOption(String),
    /// A geometric shape (a torus) with impossible dimensions.
    #[error("invalid geometry: {0}")]
    InvalidGeometry(String),
}
