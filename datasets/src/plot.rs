//! What every picture of the project shares: the embedded font (so that text
//! renders on a machine without fonts) and writing a finished bitmap as a PNG
//! atomically.

use std::path::Path;
use std::sync::Once;

use image::RgbImage;

use crate::error::{DataError, Result};

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans-subset.ttf");

/// Registers the embedded font as plotters' "sans-serif"; call before drawing.
pub fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is compiled in; if it ever failed to parse, plots would
        // lose their text but still be drawn.
        let _ = plotters::style::register_font("sans-serif", plotters::style::FontStyle::Normal, FONT);
    });
}

/// An RGB pixel buffer for plotters' bitmap backend.
pub fn canvas(width: u32, height: u32) -> Vec<u8> {
    vec![255; (width * height * 3) as usize]
}

/// Writes a canvas filled by plotters as a PNG (atomically).
pub fn write_png(path: &Path, width: u32, height: u32, pixels: Vec<u8>) -> Result<()> {
    let image = RgbImage::from_raw(width, height, pixels)
        .ok_or_else(|| DataError::invalid(path, "canvas size does not match its pixels"))?;
    crate::atomic::write_image(path, &image.into())
}

/// A plotters error as a data error naming the picture.
pub fn plot_error(path: &Path, error: impl std::fmt::Display) -> DataError {
    DataError::invalid(path, format!("drawing failed: {error}"))
}
