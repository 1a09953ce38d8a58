//! The one font of every figure: DejaVu Sans, embedded (no system fonts needed), as
//! plotters' `sans-serif`.

use std::sync::OnceLock;

use plotters::style::FontStyle;

/// The font family figures name in their text styles.
pub const FONT: &str = "sans-serif";

/// Register the embedded font with plotters, once per process; the error says it could
/// not be loaded.
pub fn register_font() -> Result<(), &'static str> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = DONE.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    if *ok {
        Ok(())
    } else {
        Err("cannot load the embedded DejaVu font")
    }
}
