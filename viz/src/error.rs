//! [`VizError`]: why a picture could not be made. Below every other module (the crate root's
//! `save` asks `fonts`, which fails with it).

use std::path::PathBuf;

/// Why a picture could not be made.
#[derive(Debug, thiserror::Error)]
pub enum VizError {
    #[error("no font to draw text with: {0}")]
    Font(String),
    #[error("cannot draw {path}: {reason}")]
    Draw { path: PathBuf, reason: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}:{line}: {reason}")]
    Metrics {
        path: PathBuf,
        line: usize,
        reason: String,
    },
    #[error("nothing to draw: {0}")]
    Empty(String),
}
