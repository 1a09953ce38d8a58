//! The drawing primitives of the harness's figures, which live in `epd_io::plot` (shared
//! with `epd profile`): each experiment's figures (`sweep/figures.rs`,
//! `pipeline/figures.rs`, `approach/figures.rs`) import them from here, never the other
//! way round.

pub(crate) use epd_io::plot::{
    Axis, BLUE, Figure, GAP, GREEN, Legend, Panel, Png, Point, RED, REFERENCE, Series, colour,
};

/// Render panels in a grid to an encoded PNG (`epd_io::plot::render`).
pub(crate) fn render(fig: Figure<'_>, panels: &[Panel<'_>]) -> anyhow::Result<Png> {
    Ok(epd_io::plot::render(fig, panels)?)
}
