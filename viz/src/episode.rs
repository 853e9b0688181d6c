//! One episode: a trajectory picture with the attention weight of every human at chosen times
//! (paper Fig. 7) and the same scene animated as a GIF.
//!
//! A human's colour is its attention weight in the decision the robot took at that instant (the
//! SARL/FSRL attention over humans, the chosen action's row), on one colour scale for the whole
//! picture; the number beside it is the weight. Policies without attention (ORCA, LSTM-RL) show
//! humans in plain colours.
//!
//! Static obstacles ([`Obstacle`]) are drawn under everything else: solid ones filled grey, walls
//! as thick lines, a bounding wall as its outline; the view then holds every obstacle, path and
//! goal at one scale on both axes. Without obstacles the view is Env 1–3's fixed ±5.5 m square
//! and every picture is drawn exactly as before walls existed.

use std::path::{Path, PathBuf};

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::style::{self, DARK, OBSTACLE, ROBOT, STANDING, WALL};
use crate::{create_parent, fonts, DrawError, Figure, VizError};

/// What does not change over an episode about one human.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HumanInfo {
    pub radius_m: f64,
    pub standing: bool,
    pub goal: (f64, f64),
}

/// What a static obstacle's outline is (the simulator's map kinds).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObstacleKind {
    /// A solid obstacle, closed (furniture, a pillar): drawn filled.
    Solid,
    /// An open polyline with walls on both sides: drawn as a thick line.
    Wall,
    /// A closed bounding wall with the free space inside (a room's outer wall): drawn as a thick
    /// outline.
    Boundary,
}

/// One static obstacle in world coordinates (metres); a closed outline's first vertex is not
/// repeated.
#[derive(Debug, Clone, PartialEq)]
pub struct Obstacle {
    pub kind: ObstacleKind,
    pub vertices: Vec<(f64, f64)>,
}

/// Everyone's position at one instant, and the attention of the decision taken then.
#[derive(Debug, Clone, PartialEq)]
pub struct TraceFrame {
    pub time_s: f64,
    pub robot: (f64, f64),
    pub heading_rad: f64,
    pub humans: Vec<(f64, f64)>,
    /// One weight per human (summing to 1), or `None` (no decision at this instant, or a
    /// policy without attention).
    pub attention: Option<Vec<f64>>,
}

/// A recorded episode, ready to draw.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeTrace {
    pub title: String,
    pub robot_radius_m: f64,
    pub robot_goal: (f64, f64),
    pub humans: Vec<HumanInfo>,
    /// The static obstacles, the same all episode long (empty on an open floor).
    pub obstacles: Vec<Obstacle>,
    /// Frames at t = 0 and after every step.
    pub frames: Vec<TraceFrame>,
    /// How the episode ended, e.g. "success after 11.50 s".
    pub outcome: String,
}

impl EpisodeTrace {
    /// Index of the frame nearest to `t_s`.
    pub fn frame_at(&self, t_s: f64) -> usize {
        let mut best = 0;
        for (k, f) in self.frames.iter().enumerate() {
            if (f.time_s - t_s).abs() < (self.frames[best].time_s - t_s).abs() {
                best = k;
            }
        }
        best
    }

    /// The world box a walled scene shows, `((x_min, x_max), (y_min, y_max))` in metres: every
    /// obstacle, body, path and goal, with a margin; `None` on an open floor (the fixed square).
    fn extent(&self) -> Option<((f64, f64), (f64, f64))> {
        if self.obstacles.is_empty() {
            return None;
        }
        let mut lo = (f64::INFINITY, f64::INFINITY);
        let mut hi = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        let mut add = |p: (f64, f64), r: f64| {
            if p.0.is_finite() && p.1.is_finite() && r.is_finite() {
                lo = (lo.0.min(p.0 - r), lo.1.min(p.1 - r));
                hi = (hi.0.max(p.0 + r), hi.1.max(p.1 + r));
            }
        };
        for o in &self.obstacles {
            for &v in &o.vertices {
                add(v, 0.0);
            }
        }
        add(self.robot_goal, GOAL_STAR_M);
        for h in &self.humans {
            add(h.goal, 0.1);
        }
        for f in &self.frames {
            add(f.robot, self.robot_radius_m);
            for (p, h) in f.humans.iter().zip(&self.humans) {
                add(*p, h.radius_m);
            }
        }
        if !(lo.0 < hi.0 && lo.1 < hi.1) {
            return None;
        }
        Some((
            (lo.0 - WALLED_MARGIN_M, hi.0 + WALLED_MARGIN_M),
            (lo.1 - WALLED_MARGIN_M, hi.1 + WALLED_MARGIN_M),
        ))
    }

    /// Width over height of [`Self::extent`], `None` on an open floor.
    fn aspect(&self) -> Option<f64> {
        self.extent().map(|(x, y)| (x.1 - x.0) / (y.1 - y.0))
    }

    fn has_attention(&self) -> bool {
        self.frames.iter().any(|f| f.attention.is_some())
    }

    /// The attention shown at frame `k`: that frame's decision, or the last one before it (the
    /// final frame has no decision of its own).
    fn attention_at(&self, k: usize) -> Option<&[f64]> {
        self.frames[..=k.min(self.frames.len().saturating_sub(1))]
            .iter()
            .rev()
            .find_map(|f| f.attention.as_deref())
    }

    /// The colour scale of the attention shown at `frames`: from the smallest to the largest
    /// weight (from 0 when they are all equal).
    fn attention_range(&self, frames: &[usize]) -> (f64, f64) {
        let ws: Vec<f64> = frames
            .iter()
            .filter_map(|&k| self.attention_at(k))
            .flatten()
            .copied()
            .filter(|w| w.is_finite())
            .collect();
        let hi = ws.iter().copied().fold(0.0, f64::max);
        let lo = ws.iter().copied().fold(hi, f64::min);
        if hi - lo > 1e-3 {
            (lo, hi)
        } else {
            (0.0, hi.max(1e-9))
        }
    }
}

/// The trajectory picture: one panel per chosen time.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pub trace: EpisodeTrace,
    /// Times (s) of the panels; each picks the nearest frame.
    pub times_s: Vec<f64>,
}

const HALF_M: f64 = 5.5;
/// Outer radius of the robot goal's star (m).
const GOAL_STAR_M: f64 = 0.32;
/// Floor shown around everything in a walled scene (m).
const WALLED_MARGIN_M: f64 = 0.4;
const PANEL: u32 = 470;
/// Narrowest and widest panel of a walled scene (its width follows the scene's shape).
const WALLED_PANEL_W: (u32, u32) = (280, 760);
/// Narrowest picture: today's, and wider with walls (the legend holds one more entry).
const MIN_WIDTH: u32 = 760;
const MIN_WIDTH_WALLED: u32 = 1040;
/// Height of the panels of a walled scene at least twice as tall as it is wide (a corridor).
const PANEL_TALL: u32 = 620;
/// A chart's margin and label areas (px): (margin, x label area, y label area), large and small.
const CHART_MARGIN: u32 = 8;
const LABELS: (u32, u32) = (36, 40);
const LABELS_SMALL: (u32, u32) = (22, 28);
const CAPTION_PX: (f64, f64) = (17.0, 15.0);
const TITLE_H: u32 = 44;
const LEGEND_H: u32 = 34;
const FOOT_H: u32 = 28;
const BAR_W: u32 = 110;
/// Frames the GIF holds the last picture for.
pub const GIF_HOLD_FRAMES: usize = 8;

fn circle(c: (f64, f64), r: f64) -> Vec<(f64, f64)> {
    (0..32)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / 32.0;
            (c.0 + r * a.cos(), c.1 + r * a.sin())
        })
        .collect()
}

fn star(c: (f64, f64), outer: f64) -> Vec<(f64, f64)> {
    (0..10)
        .map(|k| {
            let r = if k % 2 == 0 { outer } else { outer * 0.42 };
            let a = std::f64::consts::FRAC_PI_2 + k as f64 * std::f64::consts::PI / 5.0;
            (c.0 + r * a.cos(), c.1 + r * a.sin())
        })
        .collect()
}

type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;
type Ranges = ((f64, f64), (f64, f64));

/// `extent` widened about its centre along one axis so that a metre has as many pixels across
/// as up on a plot of `plot_px` (width, height) pixels.
fn equal_scale(extent: Ranges, plot_px: (u32, u32)) -> Ranges {
    let ((x0, x1), (y0, y1)) = extent;
    let (w, h) = (plot_px.0.max(1) as f64, plot_px.1.max(1) as f64);
    let m_per_px = ((x1 - x0) / w).max((y1 - y0) / h);
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let (hx, hy) = (m_per_px * w / 2.0, m_per_px * h / 2.0);
    ((cx - hx, cx + hx), (cy - hy, cy + hy))
}

/// Draws the static obstacles: solid ones filled with an outline, walls as thick lines, bounding
/// walls as thick closed outlines.
fn obstacles<DB: DrawingBackend>(
    chart: &mut Chart<DB>,
    trace: &EpisodeTrace,
    small: bool,
) -> Result<(), DrawError> {
    let thick = if small { 3 } else { 4 };
    for o in &trace.obstacles {
        // From the middle of the first edge round to it again, so that every corner is joined
        // (a thick line's ends are cut square) and the ends meet in a straight line.
        let closed = || match o.vertices.as_slice() {
            [a, b, ..] => {
                let mid = ((a.0 + b.0) / 2.0, (a.1 + b.1) / 2.0);
                let mut v = vec![mid];
                v.extend(&o.vertices[1..]);
                v.extend([*a, mid]);
                v
            }
            _ => o.vertices.clone(),
        };
        match o.kind {
            ObstacleKind::Solid => {
                chart.draw_series(std::iter::once(Polygon::new(
                    o.vertices.clone(),
                    OBSTACLE.filled(),
                )))?;
                chart.draw_series(std::iter::once(PathElement::new(
                    closed(),
                    WALL.stroke_width(1),
                )))?;
            }
            ObstacleKind::Wall => {
                chart.draw_series(std::iter::once(PathElement::new(
                    o.vertices.clone(),
                    WALL.stroke_width(thick),
                )))?;
            }
            ObstacleKind::Boundary => {
                chart.draw_series(std::iter::once(PathElement::new(
                    closed(),
                    WALL.stroke_width(thick),
                )))?;
            }
        }
    }
    Ok(())
}

/// Draws the scene at frame `k` on `area`; `range` is the attention colour scale.
fn scene<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    trace: &EpisodeTrace,
    k: usize,
    range: (f64, f64),
    caption: &str,
    small: bool,
) -> Result<(), DrawError> {
    let caption_style = style::bold(if small { CAPTION_PX.1 } else { CAPTION_PX.0 });
    let (x_labels, y_labels) = if small { LABELS_SMALL } else { LABELS };
    let (x_range, y_range) = match trace.extent() {
        None => ((-HALF_M, HALF_M), (-HALF_M, HALF_M)),
        Some(extent) => {
            // The plot's pixels: the area less the margins, the label areas and the caption
            // (as plotters' `titled` takes it: the text and up to 5 px above and below).
            let caption_h = if caption.is_empty() {
                0
            } else {
                let (_, h) = area.estimate_text_size(caption, &caption_style)?;
                h + 2 * (h / 2).min(5)
            };
            let (w, h) = area.dim_in_pixel();
            let plot = (
                w.saturating_sub(2 * CHART_MARGIN + y_labels),
                h.saturating_sub(2 * CHART_MARGIN + x_labels + caption_h),
            );
            equal_scale(extent, plot)
        }
    };
    let mut builder = ChartBuilder::on(area);
    if !caption.is_empty() {
        builder.caption(caption, caption_style);
    }
    let mut chart: Chart<DB> = builder
        .margin(CHART_MARGIN)
        .x_label_area_size(x_labels)
        .y_label_area_size(y_labels)
        .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)?;
    let mut mesh = chart.configure_mesh();
    mesh.light_line_style(style::GRID)
        .max_light_lines(1)
        .bold_line_style(style::GRID)
        .x_labels(12)
        .y_labels(12)
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format!("{y:.0}"))
        .label_style(style::font(11.0))
        .axis_desc_style(style::font(13.0));
    if !small {
        mesh.x_desc("x (m)").y_desc("y (m)");
    }
    mesh.draw()?;
    let frames = &trace.frames;
    let k = k.min(frames.len().saturating_sub(1));
    let Some(now) = frames.get(k) else {
        return Ok(());
    };

    obstacles(&mut chart, trace, small)?;

    // Goals and paths so far.
    chart.draw_series(std::iter::once(Polygon::new(
        star(trace.robot_goal, GOAL_STAR_M),
        RGBColor(0xf1, 0xc4, 0x0f).filled(),
    )))?;
    for (i, h) in trace.humans.iter().enumerate() {
        if h.standing {
            continue;
        }
        let c = style::palette(i);
        let path: Vec<(f64, f64)> = frames[..=k].iter().map(|f| f.humans[i]).collect();
        chart.draw_series(std::iter::once(PathElement::new(
            path,
            c.mix(0.45).stroke_width(1),
        )))?;
        let g = h.goal;
        chart.draw_series(std::iter::once(Cross::new(
            g,
            4,
            c.mix(0.6).stroke_width(1),
        )))?;
    }
    let robot_path: Vec<(f64, f64)> = frames.iter().map(|f| f.robot).collect();
    chart.draw_series(std::iter::once(PathElement::new(
        robot_path.clone(),
        ROBOT.mix(0.25).stroke_width(2),
    )))?;
    chart.draw_series(std::iter::once(PathElement::new(
        robot_path[..=k].to_vec(),
        ROBOT.stroke_width(3),
    )))?;

    // Humans now, coloured by attention.
    let attention = trace.attention_at(k);
    for (i, h) in trace.humans.iter().enumerate() {
        let p = now.humans[i];
        let weight = attention.and_then(|a| a.get(i).copied());
        let fill = match weight {
            Some(w) => style::sequential((w - range.0) / (range.1 - range.0)),
            None if h.standing => STANDING,
            None => style::palette(i),
        };
        let body = circle(p, h.radius_m);
        chart.draw_series(std::iter::once(Polygon::new(
            body.clone(),
            fill.mix(if weight.is_some() { 0.95 } else { 0.55 })
                .filled(),
        )))?;
        let mut outline = body;
        outline.push(outline[0]);
        let edge = if h.standing {
            BLACK.stroke_width(3)
        } else {
            DARK.stroke_width(1)
        };
        chart.draw_series(std::iter::once(PathElement::new(outline, edge)))?;
        if let Some(w) = weight {
            chart.draw_series(std::iter::once(Text::new(
                format!("{w:.2}"),
                (p.0 + h.radius_m * 0.8, p.1 + h.radius_m * 0.9),
                style::font(if small { 11.0 } else { 13.0 })
                    .pos(Pos::new(HPos::Left, VPos::Bottom)),
            )))?;
        }
    }

    // The robot now, with its heading.
    let r = trace.robot_radius_m;
    let mut body = circle(now.robot, r);
    chart.draw_series(std::iter::once(Polygon::new(
        body.clone(),
        ROBOT.mix(0.9).filled(),
    )))?;
    body.push(body[0]);
    chart.draw_series(std::iter::once(PathElement::new(
        body,
        BLACK.stroke_width(1),
    )))?;
    let tip = (
        now.robot.0 + 1.6 * r * now.heading_rad.cos(),
        now.robot.1 + 1.6 * r * now.heading_rad.sin(),
    );
    chart.draw_series(std::iter::once(PathElement::new(
        vec![now.robot, tip],
        BLACK.stroke_width(2),
    )))?;
    Ok(())
}

/// The attention colour scale, drawn vertically in `area`.
fn colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    range: (f64, f64),
) -> Result<(), DrawError> {
    let (_, h) = area.dim_in_pixel();
    let (top, bottom) = (60, h as i32 - 60);
    let x0 = 16;
    area.draw(&Text::new(
        "attention".to_string(),
        (x0 - 6, top - 30),
        style::bold(14.0).pos(Pos::new(HPos::Left, VPos::Center)),
    ))?;
    let steps = 64;
    for s in 0..steps {
        let t = s as f64 / (steps - 1) as f64;
        let y1 = bottom - ((bottom - top) as f64 * s as f64 / steps as f64) as i32;
        let y0 = bottom - ((bottom - top) as f64 * (s + 1) as f64 / steps as f64) as i32;
        area.draw(&Rectangle::new(
            [(x0, y0), (x0 + 22, y1)],
            style::sequential(t).filled(),
        ))?;
    }
    area.draw(&Rectangle::new([(x0, top), (x0 + 22, bottom)], BLACK))?;
    for (t, y) in [(0.0, bottom), (0.5, (top + bottom) / 2), (1.0, top)] {
        area.draw(&Text::new(
            format!("{:.3}", range.0 + t * (range.1 - range.0)),
            (x0 + 28, y),
            style::font(13.0).pos(Pos::new(HPos::Left, VPos::Center)),
        ))?;
    }
    Ok(())
}

fn legend_items(trace: &EpisodeTrace) -> Vec<(String, RGBColor)> {
    let mut items = vec![
        ("robot (path, heading)".to_string(), ROBOT),
        ("robot goal".to_string(), RGBColor(0xf1, 0xc4, 0x0f)),
        ("standing human (thick outline)".to_string(), STANDING),
    ];
    if trace.has_attention() {
        items.push((
            "human colour = attention weight".to_string(),
            style::sequential(0.7),
        ));
    } else {
        items.push((
            "dynamic human (no attention)".to_string(),
            style::palette(0),
        ));
    }
    if !trace.obstacles.is_empty() {
        items.push(("walls and obstacles".to_string(), WALL));
    }
    items
}

impl Trajectory {
    fn frames(&self) -> Vec<usize> {
        let mut ks: Vec<usize> = self
            .times_s
            .iter()
            .map(|&t| self.trace.frame_at(t))
            .collect();
        if ks.is_empty() {
            ks.push(self.trace.frames.len().saturating_sub(1));
        }
        ks
    }

    /// A panel's height: [`PANEL`], or [`PANEL_TALL`] for a walled scene at least twice as
    /// tall as wide.
    fn panel_height(&self) -> u32 {
        match self.trace.aspect() {
            Some(aspect) if aspect <= 0.5 => PANEL_TALL,
            _ => PANEL,
        }
    }

    /// A panel's width: [`PANEL`] on an open floor; with walls, as wide as the scene's shape
    /// asks at the panel's height, within [`WALLED_PANEL_W`].
    fn panel_width(&self) -> u32 {
        match self.trace.aspect() {
            None => PANEL,
            Some(aspect) => {
                let caption_h = CAPTION_PX.0 as u32 + 10;
                let plot_h = self.panel_height() - 2 * CHART_MARGIN - LABELS.0 - caption_h;
                let plot_w = (plot_h as f64 * aspect).round() as u32;
                (plot_w + 2 * CHART_MARGIN + LABELS.1).clamp(WALLED_PANEL_W.0, WALLED_PANEL_W.1)
            }
        }
    }
}

impl Figure for Trajectory {
    fn size(&self) -> (u32, u32) {
        let n = self.frames().len() as u32;
        let bar = if self.trace.has_attention() { BAR_W } else { 0 };
        let min_width = if self.trace.obstacles.is_empty() {
            MIN_WIDTH
        } else {
            MIN_WIDTH_WALLED
        };
        (
            (n * self.panel_width() + bar).max(min_width),
            TITLE_H + LEGEND_H + self.panel_height() + FOOT_H,
        )
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), DrawError> {
        let trace = &self.trace;
        let body = style::titled(root, &trace.title, TITLE_H)?;
        let (legend, body) = body.split_vertically(LEGEND_H);
        style::legend_row(&legend, &legend_items(trace))?;
        let (panels_area, foot) = body.split_vertically(self.panel_height());
        let ks = self.frames();
        let range = trace.attention_range(&ks);
        let bar = if trace.has_attention() { BAR_W } else { 0 };
        let (w, _) = panels_area.dim_in_pixel();
        let (panels_area, bar_area) = panels_area.split_horizontally(w - bar);
        let panels = panels_area.split_evenly((1, ks.len()));
        for (panel, &k) in panels.iter().zip(&ks) {
            let t = trace.frames.get(k).map_or(0.0, |f| f.time_s);
            scene(panel, trace, k, range, &format!("t = {t:.2} s"), false)?;
        }
        if bar > 0 {
            colour_bar(&bar_area, range)?;
        }
        let (fw, _) = foot.dim_in_pixel();
        foot.draw(&Text::new(
            format!(
                "{}; robot path: bold up to t, faint after; human paths up to t",
                trace.outcome
            ),
            (fw as i32 / 2, 4),
            style::font(13.0).pos(Pos::new(HPos::Center, VPos::Top)),
        ))?;
        Ok(())
    }
}

/// The height of a GIF's scene `side` pixels wide: `side` on an open floor; with walls, as tall
/// as the scene's shape asks, from 0.6 to 1.6 times `side`.
fn gif_scene_height(trace: &EpisodeTrace, side: u32) -> u32 {
    match trace.aspect() {
        None => side,
        Some(aspect) => {
            let plot_w = side.saturating_sub(2 * CHART_MARGIN + LABELS_SMALL.1) as f64;
            let plot_h = (plot_w / aspect).round() as u32;
            (plot_h + 2 * CHART_MARGIN + LABELS_SMALL.0).clamp(side * 3 / 5, side * 8 / 5)
        }
    }
}

/// Writes the episode as an animated GIF (one frame every `stride` steps and the final one, the
/// last held for [`GIF_HOLD_FRAMES`] frames), the scene `side` pixels wide (and as tall on an
/// open floor; with walls, as the scene's shape asks); returns the path.
pub fn save_gif(
    trace: &EpisodeTrace,
    path: &Path,
    side: u32,
    frame_delay_ms: u32,
    stride: usize,
) -> Result<PathBuf, VizError> {
    fonts::ensure()?;
    if trace.frames.is_empty() {
        return Err(VizError::Empty(format!(
            "{}: the episode has no frames",
            path.display()
        )));
    }
    create_parent(path)?;
    let draw_err = |reason: String| VizError::Draw {
        path: path.to_path_buf(),
        reason,
    };
    let bar = if trace.has_attention() { 80 } else { 0 };
    let size = (side + bar, gif_scene_height(trace, side) + 34);
    let all: Vec<usize> = (0..trace.frames.len()).collect();
    let range = trace.attention_range(&all);
    let root = BitMapBackend::gif(path, size, frame_delay_ms)
        .map_err(|e| draw_err(e.to_string()))?
        .into_drawing_area();
    let last = trace.frames.len() - 1;
    let frames = (0..last)
        .step_by(stride.max(1))
        .chain(std::iter::repeat_n(last, GIF_HOLD_FRAMES + 1));
    for k in frames {
        let draw = || -> Result<(), DrawError> {
            root.fill(&WHITE)?;
            let (top, rest) = root.split_vertically(34);
            let t = trace.frames[k].time_s;
            let text = if k == last {
                format!("{}: {}", trace.title, trace.outcome)
            } else {
                format!("{}: t = {t:.2} s", trace.title)
            };
            // With walls, the heading shrinks to fit the width (open-floor GIFs are drawn as
            // they always were).
            let mut font_px = 14.0;
            if !trace.obstacles.is_empty() {
                while font_px > 9.0
                    && top.estimate_text_size(&text, &style::bold(font_px))?.0 + 8 > size.0
                {
                    font_px -= 1.0;
                }
            }
            top.draw(&Text::new(
                text,
                (size.0 as i32 / 2, 17),
                style::bold(font_px).pos(Pos::new(HPos::Center, VPos::Center)),
            ))?;
            let (scene_area, bar_area) = rest.split_horizontally(side);
            scene(&scene_area, trace, k, range, "", true)?;
            if bar > 0 {
                colour_bar(&bar_area, range)?;
            }
            root.present()?;
            Ok(())
        };
        draw().map_err(|e| draw_err(e.0))?;
    }
    Ok(path.to_path_buf())
}
