//! `viz`: the pictures users judge a run by, drawn with plotters as SVG and PNG (and an animated
//! GIF of an episode):
//!
//! - [`OutcomeBars`]: success / collision / timeout rates per setting and method (paper Fig. 5);
//! - [`LearningCurves`]: success rate, return and loss against RL episodes (from `metrics.jsonl`,
//!   read by [`metrics::read_metrics`]);
//! - [`ValidationCurves`]: the validation success rate, collision rate and Disc. against RL
//!   episodes or wall-clock minutes, the seeds of one method as a mean line and a min–max band;
//! - [`Ablation`]: the reward ablation R_c, +R_f, +R_t, all (paper Fig. 8–9);
//! - [`Frontier`]: every validated snapshot of runs as Nav. Time against Disc., beside the
//!   paper's rows (is the paper's point among the policies a run passes through?);
//! - [`Trajectory`]: an episode with the attention weight of every human at chosen times (paper
//!   Fig. 7), and [`save_gif`], the same episode animated; static obstacles ([`Obstacle`]: solid
//!   polygons, walls, bounding walls) are drawn with it.
//!
//! Inputs are plain data ([`EpisodeTrace`], [`Interval`], ...), so this crate knows nothing of the
//! simulator, the networks or the file formats of reports. Text is drawn with a TrueType font found
//! at run time ([`fonts::ensure`]; Debian: `fonts-dejavu-core`), so nothing links a system font
//! library.

mod ablation;
mod bars;
mod curves;
mod episode;
mod error;
pub mod fonts;
mod frontier;
pub mod metrics;
mod style;

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

pub use ablation::Ablation;
pub use bars::{OutcomeBars, OutcomeCell};
pub use curves::{
    group_runs, spread, without_seed, CurveGroup, CurveRun, LearningCurves, Spread, ValidationAxis,
    ValidationCurves,
};
pub use episode::{
    save_gif, EpisodeTrace, HumanInfo, Obstacle, ObstacleKind, TraceFrame, Trajectory,
    GIF_HOLD_FRAMES,
};
pub use error::VizError;
pub use frontier::{Frontier, FrontierGroup, FrontierPanel};

/// A drawing failure inside a figure, before it is tied to a file.
#[derive(Debug)]
pub struct DrawError(pub String);

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for DrawError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        DrawError(e.to_string())
    }
}

/// A value with a 95% interval (for a single run: Wilson or t interval; over runs: mean ± std).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    pub mean: f64,
    pub lo: f64,
    pub hi: f64,
}

impl Interval {
    /// A value without uncertainty.
    pub fn exact(v: f64) -> Self {
        Self {
            mean: v,
            lo: v,
            hi: v,
        }
    }
}

/// A picture that can be drawn on any plotters back-end.
pub trait Figure {
    /// Width and height in pixels.
    fn size(&self) -> (u32, u32);
    /// Draws the whole picture on `root` (already filled white).
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), DrawError>;
}

/// `stem` with `.ext` appended (`docs/bars` → `docs/bars.svg`), keeping any dots in the stem.
pub fn with_ext(stem: &Path, ext: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push(".");
    s.push(ext);
    PathBuf::from(s)
}

fn create_parent(path: &Path) -> Result<(), VizError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| VizError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    Ok(())
}

fn draw_on<DB: DrawingBackend, F: Figure>(
    root: DrawingArea<DB, Shift>,
    fig: &F,
) -> Result<(), DrawError> {
    root.fill(&WHITE)?;
    fig.draw(&root)?;
    root.present()?;
    Ok(())
}

/// Writes `fig` as `<stem>.svg` and `<stem>.png`; returns both paths.
pub fn save<F: Figure>(fig: &F, stem: &Path) -> Result<Vec<PathBuf>, VizError> {
    fonts::ensure()?;
    create_parent(stem)?;
    let size = fig.size();
    let svg = with_ext(stem, "svg");
    draw_on(SVGBackend::new(&svg, size).into_drawing_area(), fig).map_err(|e| VizError::Draw {
        path: svg.clone(),
        reason: e.0,
    })?;
    let png = with_ext(stem, "png");
    draw_on(BitMapBackend::new(&png, size).into_drawing_area(), fig).map_err(|e| {
        VizError::Draw {
            path: png.clone(),
            reason: e.0,
        }
    })?;
    Ok(vec![svg, png])
}

/// Draws `fig` into an SVG string (for tests and embedding).
pub fn to_svg_string<F: Figure>(fig: &F) -> Result<String, VizError> {
    fonts::ensure()?;
    let mut s = String::new();
    draw_on(
        SVGBackend::with_string(&mut s, fig.size()).into_drawing_area(),
        fig,
    )
    .map_err(|e| VizError::Draw {
        path: PathBuf::from("<memory>"),
        reason: e.0,
    })?;
    Ok(s)
}
