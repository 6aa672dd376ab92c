//! The one font every picture draws with: DejaVu Sans, embedded so that plots and
//! videos render the same on machines without system fonts.

use std::sync::Once;

use plotters::style::FontStyle;

static FONT: Once = Once::new();

/// Registers the embedded font as plotters' "sans-serif", once per process.
pub(crate) fn register() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../../assets/DejaVuSans.ttf");
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .unwrap_or_else(|_| panic!("embedded DejaVuSans.ttf is a valid font"));
    });
}
