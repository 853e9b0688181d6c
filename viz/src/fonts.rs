//! The TrueType font the pictures' text is drawn with. plotters' `ab_glyph` back-end needs the
//! font bytes registered once; we read a file found at run time instead of linking fontconfig and
//! freetype. `FSRL_FONT` names a file explicitly; otherwise the first of [`CANDIDATES`] that exists
//! is used (on Debian and Ubuntu, `apt-get install fonts-dejavu-core` provides the first one).
//! A bold face beside it (`…-Bold.ttf`) is used for titles when present.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::style::{register_font, FontStyle};

use crate::VizError;

/// The environment variable naming a `.ttf` file to draw text with.
pub const FONT_ENV: &str = "FSRL_FONT";

/// Regular sans-serif fonts tried in order when `FSRL_FONT` is unset.
pub const CANDIDATES: [&str; 7] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu-sans-fonts/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
];

static FONT: OnceLock<Result<PathBuf, String>> = OnceLock::new();

fn leak(path: &Path) -> Result<&'static [u8], String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(Box::leak(bytes.into_boxed_slice()))
}

fn bold_beside(regular: &Path) -> Option<PathBuf> {
    let stem = regular.file_stem()?.to_str()?;
    let base = stem.strip_suffix("-Regular").unwrap_or(stem);
    let bold = regular.with_file_name(format!("{base}-Bold.ttf"));
    bold.exists().then_some(bold)
}

fn load() -> Result<PathBuf, String> {
    let path = match std::env::var_os(FONT_ENV) {
        Some(p) => PathBuf::from(p),
        None => CANDIDATES
            .iter()
            .map(PathBuf::from)
            .find(|p| p.exists())
            .ok_or_else(|| {
                format!(
                    "none of {} exists; install one (Debian/Ubuntu: `apt-get install fonts-dejavu-core`) or set {FONT_ENV} to a .ttf file",
                    CANDIDATES.join(", ")
                )
            })?,
    };
    let regular = leak(&path)?;
    for name in ["sans-serif", "serif", "monospace"] {
        register_font(name, FontStyle::Normal, regular)
            .map_err(|_| format!("{}: not a TrueType/OpenType font", path.display()))?;
    }
    if let Some(bold) = bold_beside(&path) {
        if let Ok(bytes) = leak(&bold) {
            // A broken bold face is not worth failing for: titles fall back to the regular one.
            let _ = register_font("sans-serif", FontStyle::Bold, bytes);
        }
    }
    Ok(path)
}

/// Registers the font once per process; returns the file used.
pub fn ensure() -> Result<PathBuf, VizError> {
    FONT.get_or_init(load).clone().map_err(VizError::Font)
}
