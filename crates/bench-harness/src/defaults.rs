//! Default values of scenario keys that more than one scenario kind has, one copy each
//! (the serde `default = "…"` functions of `sweep/scenario/keys.rs`,
//! `pipeline/scenario/keys.rs` and `approach/scenario.rs`). A default that only one kind
//! has stays beside its key.

/// `seed`: 1.
pub(crate) fn seed() -> u64 {
    1
}

/// `nominal_od_in`: the paper's 20" pipe (`tof_sim::Pipe::paper_20in`, §4.1).
pub(crate) fn nominal_od_in() -> f64 {
    20.0
}

/// Wall thickness (mm) of the paper's pipe: 12 mm.
pub(crate) fn wall_mm() -> f64 {
    12.0
}

/// `ovality` of the paper's pipe, (D_max − D_min) / ID: 2 %.
pub(crate) fn ovality() -> f64 {
    0.02
}

/// An elbow's centreline radius in pipe diameters: 1.5 (long radius).
pub(crate) fn bend_radius_d() -> f64 {
    1.5
}

/// An elbow's angle (degrees): 90.
pub(crate) fn bend_angle_deg() -> f64 {
    90.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pipe_defaults_are_the_papers_pipe() {
        let p = tof_sim::Pipe::paper_20in();
        assert_eq!(nominal_od_in(), p.nominal_od_in);
        assert_eq!(wall_mm() / 1e3, p.wall_thickness);
        assert_eq!(ovality(), p.ovality);
    }
}
