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

/// What a valid value of a checked field is (a sensor model's, a pipeline's).
#[derive(Clone, Copy)]
pub(crate) enum Rule {
    /// A finite number > 0.
    Positive,
    /// A finite number ≥ 0.
    NonNegative,
    /// A finite number.
    Finite,
    /// Valid when the condition holds; else the reason.
    Holds(bool, &'static str),
}

impl Rule {
    pub(crate) fn holds(self, v: f64) -> bool {
        match self {
            Rule::Positive => v.is_finite() && v > 0.0,
            Rule::NonNegative => v.is_finite() && v >= 0.0,
            Rule::Finite => v.is_finite(),
            Rule::Holds(ok, _) => ok,
        }
    }

    pub(crate) fn reason(self) -> &'static str {
        match self {
            Rule::Positive => "must be a finite number > 0",
            Rule::NonNegative => "must be a finite number ≥ 0",
            Rule::Finite => "must be finite",
            Rule::Holds(_, reason) => reason,
        }
    }
}

/// The first (field, value, rule) of `checks` whose value breaks its rule, in checking
/// order.
pub(crate) fn first_broken<K>(
    checks: impl IntoIterator<Item = (K, f64, Rule)>,
) -> Option<(K, f64, Rule)> {
    checks.into_iter().find(|(_, v, rule)| !rule.holds(*v))
}
