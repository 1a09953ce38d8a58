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
    /// Points farther from the sensor than any time-of-flight camera measures
    /// ([`crate::cloud::MAX_POINT_RANGE_M`]): a damaged file or a wrong unit.
    #[error(
        "{count} points lie farther than {limit_m} m from the sensor (the first, point \
         {index}, at {range_m:e} m): no time-of-flight camera measures so far; the file is \
         damaged or its unit is not metres"
    )]
    FarPoints {
        /// How many points.
        count: usize,
        /// The first one's index in the input.
        index: usize,
        /// Its distance from the sensor (m).
        range_m: f64,
        /// The limit (m).
        limit_m: f64,
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
