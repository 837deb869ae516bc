//! The TrueType font the bench charts draw their text with (plotters needs one registered): the
//! first readable of $BIMTILES_FONT and the usual DejaVu / Liberation paths (Debian
//! `fonts-dejavu-core`). Shared by the bench examples through `#[path]`.

use plotters::style::FontStyle;
use std::path::PathBuf;

/// The family name charts ask for.
pub const FONT: &str = "bench-sans";

const FONT_PATHS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

/// Registers [`FONT`]; an error lists the paths tried.
pub fn load_font() -> Result<(), Box<dyn std::error::Error>> {
    let mut candidates: Vec<PathBuf> = std::env::var_os("BIMTILES_FONT")
        .map(PathBuf::from)
        .into_iter()
        .collect();
    candidates.extend(FONT_PATHS.iter().map(PathBuf::from));
    for p in &candidates {
        if let Ok(bytes) = std::fs::read(p) {
            // plotters keeps registered fonts for the process's lifetime.
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            if plotters::style::register_font(FONT, FontStyle::Normal, bytes).is_ok() {
                return Ok(());
            }
        }
    }
    Err(format!(
        "no usable TrueType font; tried {candidates:?} (set BIMTILES_FONT or install fonts-dejavu-core)"
    )
    .into())
}
