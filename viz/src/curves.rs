//! Learning curves from `metrics.jsonl`.
//!
//! - [`LearningCurves`]: success rate (the log's 100-episode window), return and TD loss
//!   (trailing moving averages) against RL episodes, and the imitation loss against epochs. One
//!   line per run.
//! - [`ValidationCurves`]: the validation lines' success rate, collision rate and Disc. against
//!   RL episodes or wall-clock minutes. The runs of one method ([`group_runs`]: the seeds of one
//!   configuration) share a colour: their mean as a line ([`spread`]), dashed where only some
//!   of them reach, and their min–max range as a band.

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::metrics::{Metrics, ValidationPoint};
use crate::style;
use crate::{DrawError, Figure};

/// One run's log and its legend label.
#[derive(Debug, Clone, PartialEq)]
pub struct CurveRun {
    pub label: String,
    pub metrics: Metrics,
}

/// The figure's data.
#[derive(Debug, Clone, PartialEq)]
pub struct LearningCurves {
    pub title: String,
    pub runs: Vec<CurveRun>,
    /// Moving-average window (episodes) for the return and the loss.
    pub window: usize,
}

const TITLE_H: u32 = 44;
const LEGEND_H: u32 = 34;

/// Trailing moving average of `(x, y)` over `window` points (fewer at the start).
pub fn moving_average(points: &[(f64, f64)], window: usize) -> Vec<(f64, f64)> {
    let window = window.max(1);
    let mut sum = 0.0;
    let mut out = Vec::with_capacity(points.len());
    for (i, &(x, y)) in points.iter().enumerate() {
        sum += y;
        if i >= window {
            sum -= points[i - window].1;
        }
        out.push((x, sum / (i + 1).min(window) as f64));
    }
    out
}

/// The finite points' `(x min, x max, y min, y max)`; `None` without one.
pub(crate) fn bounds(series: &[Vec<(f64, f64)>]) -> Option<(f64, f64, f64, f64)> {
    let mut it = series
        .iter()
        .flatten()
        .filter(|p| p.0.is_finite() && p.1.is_finite());
    let first = it.next()?;
    let mut b = (first.0, first.0, first.1, first.1);
    for p in it {
        b = (b.0.min(p.0), b.1.max(p.0), b.2.min(p.1), b.3.max(p.1));
    }
    Some(b)
}

fn pad(lo: f64, hi: f64) -> (f64, f64) {
    if hi - lo < 1e-9 {
        (lo - 0.5, hi + 0.5)
    } else {
        let m = 0.05 * (hi - lo);
        (lo - m, hi + m)
    }
}

struct Panel<'a> {
    caption: &'a str,
    x_desc: &'a str,
    y_desc: &'a str,
    /// Fixed y range (rates), else from the data.
    y_range: Option<(f64, f64)>,
    log_y: bool,
}

fn no_data<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    caption: &str,
) -> Result<(), DrawError> {
    let (w, h) = area.dim_in_pixel();
    area.draw(&Text::new(
        caption.to_string(),
        (w as i32 / 2, 18),
        style::bold(16.0).pos(Pos::new(HPos::Center, VPos::Center)),
    ))?;
    area.draw(&Text::new(
        "no data in the log".to_string(),
        (w as i32 / 2, h as i32 / 2),
        style::font(14.0).pos(Pos::new(HPos::Center, VPos::Center)),
    ))?;
    Ok(())
}

fn line_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    series: &[Vec<(f64, f64)>],
) -> Result<(), DrawError> {
    let series: Vec<Vec<(f64, f64)>> = series
        .iter()
        .map(|s| {
            s.iter()
                .copied()
                .filter(|p| p.0.is_finite() && p.1.is_finite() && (!panel.log_y || p.1 > 0.0))
                .collect()
        })
        .collect();
    let Some((x0, x1, y0, y1)) = bounds(&series) else {
        return no_data(area, panel.caption);
    };
    let x1 = if x1 > x0 { x1 } else { x0 + 1.0 };
    if panel.log_y {
        let (lo, hi) = (y0 / 1.5, y1 * 1.5);
        let mut chart =
            chart_builder(area, panel.caption).build_cartesian_2d(x0..x1, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .light_line_style(style::GRID)
            .max_light_lines(0)
            .bold_line_style(style::GRID)
            .x_desc(panel.x_desc)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_desc(panel.y_desc)
            .y_label_formatter(&|y| format!("{y:.0e}"))
            .label_style(style::font(13.0))
            .axis_desc_style(style::font(14.0))
            .draw()?;
        for (i, s) in series.iter().enumerate() {
            chart.draw_series(LineSeries::new(
                s.iter().copied(),
                style::palette(i).stroke_width(2),
            ))?;
        }
    } else {
        let y = panel.y_range.unwrap_or_else(|| pad(y0, y1));
        let mut chart = linear_chart(area, panel, (x0, x1), y)?;
        for (i, s) in series.iter().enumerate() {
            chart.draw_series(LineSeries::new(
                s.iter().copied(),
                style::palette(i).stroke_width(2),
            ))?;
        }
    }
    Ok(())
}

fn chart_builder<'a, 'b, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    caption: &str,
) -> ChartBuilder<'a, 'b, DB> {
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(caption, style::bold(16.0))
        .margin(10)
        .margin_right(24)
        .x_label_area_size(40)
        .y_label_area_size(60);
    builder
}

/// A tick label on an axis spanning `span`: to the precision its ticks need, without trailing
/// zeros (`2`, `2.5`, `0.15`).
fn tick_label(v: f64, span: f64) -> String {
    let decimals = if span >= 20.0 {
        0
    } else if span >= 2.0 {
        1
    } else {
        2
    };
    let s = format!("{v:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        &s
    };
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

type LinearChart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A panel's chart with linear axes over `x` and `y`, mesh and axis descriptions drawn.
fn linear_chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    panel: &Panel,
    x: (f64, f64),
    y: (f64, f64),
) -> Result<LinearChart<'a, DB>, DrawError> {
    let mut chart = chart_builder(area, panel.caption).build_cartesian_2d(x.0..x.1, y.0..y.1)?;
    let (x_span, y_span) = (x.1 - x.0, y.1 - y.0);
    chart
        .configure_mesh()
        .light_line_style(style::GRID)
        .max_light_lines(0)
        .bold_line_style(style::GRID)
        .x_desc(panel.x_desc)
        .x_label_formatter(&|v| tick_label(*v, x_span))
        .y_desc(panel.y_desc)
        .y_label_formatter(&|v| tick_label(*v, y_span))
        .label_style(style::font(13.0))
        .axis_desc_style(style::font(14.0))
        .draw()?;
    Ok(chart)
}

/// Draws the title and a legend row (one palette colour per label, in order); returns the area
/// below them.
fn title_and_legend<'a, DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    labels: impl Iterator<Item = &'a String>,
) -> Result<DrawingArea<DB, Shift>, DrawError> {
    let body = style::titled(root, title, TITLE_H)?;
    let (legend, body) = body.split_vertically(LEGEND_H);
    let items: Vec<(String, RGBColor)> = labels
        .enumerate()
        .map(|(i, label)| (label.clone(), style::palette(i)))
        .collect();
    style::legend_row(&legend, &items)?;
    Ok(body)
}

impl Figure for LearningCurves {
    fn size(&self) -> (u32, u32) {
        (1120, TITLE_H + LEGEND_H + 2 * 360)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), DrawError> {
        let body = title_and_legend(root, &self.title, self.runs.iter().map(|r| &r.label))?;
        let panels = body.split_evenly((2, 2));
        let rl = |f: &dyn Fn(&crate::metrics::RlPoint) -> Option<f64>| -> Vec<Vec<(f64, f64)>> {
            self.runs
                .iter()
                .map(|r| {
                    r.metrics
                        .rl
                        .iter()
                        .filter_map(|p| f(p).map(|y| (p.episode as f64, y)))
                        .collect()
                })
                .collect()
        };
        let w = self.window;
        let success = rl(&|p| Some(p.success_rate_window));
        let returns: Vec<_> = rl(&|p| Some(p.return_sum))
            .iter()
            .map(|s| moving_average(s, w))
            .collect();
        let losses: Vec<_> = rl(&|p| p.loss.filter(|l| l.is_finite()))
            .iter()
            .map(|s| moving_average(s, w))
            .collect();
        let imitation: Vec<Vec<(f64, f64)>> = self
            .runs
            .iter()
            .map(|r| {
                r.metrics
                    .imitation
                    .iter()
                    .filter_map(|p| p.loss.map(|l| (p.epoch as f64 + 1.0, l)))
                    .collect()
            })
            .collect();
        line_panel(
            &panels[0],
            &Panel {
                caption: "success rate (last 100 episodes)",
                x_desc: "RL episode",
                y_desc: "success rate",
                y_range: Some((0.0, 1.02)),
                log_y: false,
            },
            &success,
        )?;
        let ret_caption = format!("return (moving average of {w})");
        line_panel(
            &panels[1],
            &Panel {
                caption: &ret_caption,
                x_desc: "RL episode",
                y_desc: "episode return",
                y_range: None,
                log_y: false,
            },
            &returns,
        )?;
        let loss_caption = format!("TD loss (moving average of {w})");
        line_panel(
            &panels[2],
            &Panel {
                caption: &loss_caption,
                x_desc: "RL episode",
                y_desc: "loss (log scale)",
                y_range: None,
                log_y: true,
            },
            &losses,
        )?;
        line_panel(
            &panels[3],
            &Panel {
                caption: "imitation loss",
                x_desc: "epoch",
                y_desc: "loss (log scale)",
                y_range: None,
                log_y: true,
            },
            &imitation,
        )?;
        Ok(())
    }
}

/// The runs of one method: the seeds of one configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct CurveGroup {
    /// Legend label, e.g. `fsrl-env1-invisible (3 runs)`.
    pub label: String,
    pub runs: Vec<CurveRun>,
}

/// A run label without its seed: `fsrl-env1-invisible-s2` → `fsrl-env1-invisible` (the run
/// directories `fsrl train` names `<method>-<setting>-s<seed>`); other labels stay whole.
pub fn without_seed(label: &str) -> &str {
    match label.rsplit_once("-s") {
        Some((stem, seed))
            if !stem.is_empty() && !seed.is_empty() && seed.bytes().all(|b| b.is_ascii_digit()) =>
        {
            stem
        }
        _ => label,
    }
}

/// Groups runs whose labels differ only in the seed ([`without_seed`]), in order of first
/// appearance. A group of one run keeps the run's label.
pub fn group_runs(runs: Vec<CurveRun>) -> Vec<CurveGroup> {
    let mut keyed: Vec<(String, Vec<CurveRun>)> = Vec::new();
    for run in runs {
        let key = without_seed(&run.label).to_string();
        match keyed.iter_mut().find(|(k, _)| *k == key) {
            Some((_, members)) => members.push(run),
            None => keyed.push((key, vec![run])),
        }
    }
    keyed
        .into_iter()
        .map(|(key, runs)| CurveGroup {
            label: match runs.as_slice() {
                [one] => one.label.clone(),
                _ => format!("{key} ({} runs)", runs.len()),
            },
            runs,
        })
        .collect()
}

/// Several runs' curves at one x.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    pub x: f64,
    pub mean: f64,
    pub lo: f64,
    pub hi: f64,
    /// How many of the curves reach this x.
    pub n: usize,
}

/// `s` (sorted by x) at `x`, linearly interpolated; `None` outside its first and last x.
fn interpolate(s: &[(f64, f64)], x: f64) -> Option<f64> {
    let (first, last) = (s.first()?, s.last()?);
    if x < first.0 || x > last.0 {
        return None;
    }
    let i = s.partition_point(|p| p.0 < x);
    let b = s[i];
    if b.0 == x || i == 0 {
        return Some(b.1);
    }
    let a = s[i - 1];
    Some(a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0))
}

/// Mean, smallest and largest value of `series` (each sorted by x) at every x any of them has.
/// A curve counts at x when x lies between its first and last x, linearly interpolated between
/// its points; non-finite points are left out.
pub fn spread(series: &[Vec<(f64, f64)>]) -> Vec<Spread> {
    let clean: Vec<Vec<(f64, f64)>> = series
        .iter()
        .map(|s| {
            s.iter()
                .copied()
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .collect()
        })
        .collect();
    let mut xs: Vec<f64> = clean.iter().flatten().map(|p| p.0).collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    xs.into_iter()
        .filter_map(|x| {
            let ys: Vec<f64> = clean.iter().filter_map(|s| interpolate(s, x)).collect();
            let n = ys.len();
            (n > 0).then(|| Spread {
                x,
                mean: ys.iter().sum::<f64>() / n as f64,
                lo: ys.iter().copied().fold(f64::INFINITY, f64::min),
                hi: ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                n,
            })
        })
        .collect()
}

/// What the validation curves are drawn against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValidationAxis {
    /// RL episodes trained before the validation.
    Episodes,
    /// Wall-clock minutes since the run started (imitation included; resumptions add up).
    WallClock,
}

/// The validation curves: success rate, collision rate and Disc. of the greedy policy on the
/// runs' validation seeds, one colour per group of runs.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidationCurves {
    pub title: String,
    pub groups: Vec<CurveGroup>,
    pub axis: ValidationAxis,
}

const FOOT_H: u32 = 30;

impl ValidationCurves {
    /// Per group, per run: `(x, y)` of every validation line.
    fn series(&self, y: impl Fn(&ValidationPoint) -> f64) -> Vec<Vec<Vec<(f64, f64)>>> {
        let x = |p: &ValidationPoint| match self.axis {
            ValidationAxis::Episodes => p.episode as f64,
            ValidationAxis::WallClock => p.wall_s / 60.0,
        };
        self.groups
            .iter()
            .map(|g| {
                g.runs
                    .iter()
                    .map(|r| {
                        let mut s: Vec<(f64, f64)> =
                            r.metrics.validation.iter().map(|p| (x(p), y(p))).collect();
                        s.sort_by(|a, b| a.0.total_cmp(&b.0));
                        s
                    })
                    .collect()
            })
            .collect()
    }

    /// What the lines and bands are, and on what the validations ran when all runs agree.
    fn note(&self) -> String {
        let mut parts = Vec::new();
        if self.groups.iter().any(|g| g.runs.len() > 1) {
            parts.push(
                "line: mean over a group's runs (dashed where only some reach), band: min–max"
                    .to_string(),
            );
        }
        let points = || {
            self.groups
                .iter()
                .flat_map(|g| &g.runs)
                .flat_map(|r| &r.metrics.validation)
        };
        if let Some(first) = points().next() {
            let (n, s0) = (first.episodes, first.seed_start);
            if n > 0 && points().all(|p| p.episodes == n && p.seed_start == s0) {
                parts.push(format!(
                    "each point: {n} validation episodes, seeds {s0}–{}",
                    s0 + n as u64 - 1
                ));
            }
        }
        parts.join("; ")
    }
}

/// One panel of groups: per group its mean line (dashed where not every run reaches), markers,
/// and its min–max band when it has several runs.
fn spread_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    groups: &[Vec<Vec<(f64, f64)>>],
    marker_px: u32,
) -> Result<(), DrawError> {
    let spreads: Vec<Vec<Spread>> = groups.iter().map(|g| spread(g)).collect();
    let extent: Vec<Vec<(f64, f64)>> = spreads
        .iter()
        .map(|s| s.iter().flat_map(|p| [(p.x, p.lo), (p.x, p.hi)]).collect())
        .collect();
    let Some((x0, x1, y0, y1)) = bounds(&extent) else {
        return no_data(area, panel.caption);
    };
    // Both axes (episodes, minutes) start at the run's start.
    let x0 = x0.min(0.0);
    let x = if x1 > x0 { (x0, x1) } else { (x0, x0 + 1.0) };
    let y = panel
        .y_range
        .unwrap_or_else(|| (0.0_f64.min(y0), pad(y0, y1).1));
    let mut chart = linear_chart(area, panel, x, y)?;
    for (i, (s, runs)) in spreads.iter().zip(groups).enumerate() {
        let colour = style::palette(i);
        let all = runs.iter().filter(|r| !r.is_empty()).count();
        if all > 1 {
            let band: Vec<(f64, f64)> = s
                .iter()
                .map(|p| (p.x, p.hi))
                .chain(s.iter().rev().map(|p| (p.x, p.lo)))
                .collect();
            chart.draw_series(std::iter::once(Polygon::new(band, colour.mix(0.18))))?;
        }
        // The mean line in stretches: solid between points every run reaches, dashed elsewhere.
        let solid = |k: usize| s[k - 1].n == all && s[k].n == all;
        let mut k = 1;
        while k < s.len() {
            let (start, kind) = (k - 1, solid(k));
            while k < s.len() && solid(k) == kind {
                k += 1;
            }
            let pts: Vec<(f64, f64)> = s[start..k].iter().map(|p| (p.x, p.mean)).collect();
            if kind {
                chart.draw_series(LineSeries::new(pts, colour.stroke_width(2)))?;
            } else {
                chart.draw_series(DashedLineSeries::new(pts, 6, 4, colour.stroke_width(2)))?;
            }
        }
        chart.draw_series(
            s.iter()
                .map(|p| Circle::new((p.x, p.mean), marker_px, colour.filled())),
        )?;
    }
    Ok(())
}

impl Figure for ValidationCurves {
    fn size(&self) -> (u32, u32) {
        (1500, TITLE_H + LEGEND_H + 420 + FOOT_H)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), DrawError> {
        let body = title_and_legend(root, &self.title, self.groups.iter().map(|g| &g.label))?;
        let (_, h) = body.dim_in_pixel();
        let (body, foot) = body.split_vertically(h.saturating_sub(FOOT_H));
        let panels = body.split_evenly((1, 3));
        // Several runs' validations fall at different times: smaller markers there.
        let (x_desc, marker_px) = match self.axis {
            ValidationAxis::Episodes => ("RL episodes trained", 3),
            ValidationAxis::WallClock => ("wall-clock time (min)", 2),
        };
        let rate = |caption, y_desc| Panel {
            caption,
            x_desc,
            y_desc,
            y_range: Some((0.0, 1.02)),
            log_y: false,
        };
        spread_panel(
            &panels[0],
            &rate("validation success rate", "success rate"),
            &self.series(|p| p.success_rate),
            marker_px,
        )?;
        spread_panel(
            &panels[1],
            &rate("validation collision rate", "collision rate"),
            &self.series(|p| p.collision_rate),
            marker_px,
        )?;
        spread_panel(
            &panels[2],
            &Panel {
                caption: "validation Disc. (danger steps / steps)",
                x_desc,
                y_desc: "Disc.",
                y_range: None,
                log_y: false,
            },
            &self.series(|p| p.discomfort),
            marker_px,
        )?;
        let (fw, _) = foot.dim_in_pixel();
        foot.draw(&Text::new(
            self.note(),
            (fw as i32 / 2, 6),
            style::font(13.0).pos(Pos::new(HPos::Center, VPos::Top)),
        ))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moving_average_is_trailing() {
        let p: Vec<(f64, f64)> = (0..5).map(|i| (i as f64, i as f64)).collect();
        let m = moving_average(&p, 2);
        assert_eq!(m[0], (0.0, 0.0));
        assert_eq!(m[1], (1.0, 0.5));
        assert_eq!(m[4], (4.0, 3.5));
    }

    fn run(label: &str, points: &[(u64, f64, f64)]) -> CurveRun {
        let text: String = points
            .iter()
            .map(|&(episode, success, wall_s)| {
                format!(
                    "{{\"phase\":\"validation\",\"episode\":{episode},\"env_steps\":0,\"policy_version\":0,\"episodes\":100,\"seed_start\":0,\"success_rate\":{success},\"collision_rate\":{},\"timeout_rate\":0.0,\"discomfort\":0.1,\"nav_time_s\":12.5,\"mean_return\":0.3,\"wall_s\":{wall_s}}}\n",
                    1.0 - success
                )
            })
            .collect();
        CurveRun {
            label: label.into(),
            metrics: crate::metrics::parse_metrics(&text, std::path::Path::new("m.jsonl")).unwrap(),
        }
    }

    #[test]
    fn tick_labels_drop_trailing_zeros() {
        assert_eq!(tick_label(2.0, 12.5), "2");
        assert_eq!(tick_label(2.5, 12.5), "2.5");
        assert_eq!(tick_label(0.2, 1.02), "0.2");
        assert_eq!(tick_label(0.15, 1.02), "0.15");
        assert_eq!(tick_label(1500.0, 5000.0), "1500");
        assert_eq!(tick_label(-0.001, 1.0), "0");
    }

    #[test]
    fn seeds_of_one_configuration_group_together() {
        assert_eq!(
            without_seed("fsrl-env1-invisible-s12"),
            "fsrl-env1-invisible"
        );
        assert_eq!(without_seed("sarl-s0"), "sarl");
        for whole in ["fsrl-env1-invisible", "-s1", "runs-s", "a-s1x", "sarl"] {
            assert_eq!(without_seed(whole), whole);
        }
        let groups = group_runs(vec![
            run("fsrl-env1-invisible-s0", &[]),
            run("sarl-env1-invisible-s0", &[]),
            run("fsrl-env1-invisible-s1", &[]),
            run("fsrl-env1-invisible-s2", &[]),
        ]);
        let labels: Vec<&str> = groups.iter().map(|g| g.label.as_str()).collect();
        assert_eq!(
            labels,
            ["fsrl-env1-invisible (3 runs)", "sarl-env1-invisible-s0"]
        );
        assert_eq!(groups[0].runs[2].label, "fsrl-env1-invisible-s2");
    }

    #[test]
    fn spread_interpolates_and_counts_the_runs_that_reach() {
        let a = vec![(0.0, 0.0), (10.0, 1.0)];
        let b = vec![(0.0, 0.5), (5.0, 0.5)];
        let s = spread(&[a, b]);
        let xs: Vec<f64> = s.iter().map(|p| p.x).collect();
        assert_eq!(xs, [0.0, 5.0, 10.0]);
        assert_eq!(
            s[0],
            Spread {
                x: 0.0,
                mean: 0.25,
                lo: 0.0,
                hi: 0.5,
                n: 2
            }
        );
        // a is interpolated to 0.5 at x = 5.
        assert_eq!((s[1].mean, s[1].lo, s[1].hi, s[1].n), (0.5, 0.5, 0.5, 2));
        // Only a reaches x = 10.
        assert_eq!((s[2].mean, s[2].n), (1.0, 1));
        assert!(spread(&[vec![], vec![(1.0, f64::NAN)]]).is_empty());
    }

    #[test]
    fn validation_curves_draw_a_mean_and_a_band_per_group() {
        // Two seeds of fsrl (one ahead of the other) and one sarl run.
        let groups = group_runs(vec![
            run(
                "fsrl-s0",
                &[(0, 0.1, 60.0), (500, 0.6, 600.0), (1000, 0.9, 1200.0)],
            ),
            run("fsrl-s1", &[(0, 0.2, 90.0), (500, 0.8, 660.0)]),
            run("sarl-s0", &[(0, 0.0, 30.0), (500, 0.4, 400.0)]),
        ]);
        let fig = ValidationCurves {
            title: "Validation".into(),
            groups,
            axis: ValidationAxis::Episodes,
        };
        assert_eq!(fig.note(), "line: mean over a group's runs (dashed where only some reach), band: min–max; each point: 100 validation episodes, seeds 0–99");
        let svg = crate::to_svg_string(&fig).unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let stroke = |colour: &str| {
            doc.descendants()
                .filter(|n| {
                    n.has_tag_name("polyline")
                        && n.attribute("stroke-width") == Some("2")
                        && n.attribute("stroke")
                            .is_some_and(|s| s.eq_ignore_ascii_case(colour))
                })
                .count()
        };
        // sarl (second colour): one solid line per panel.
        assert_eq!(stroke("#D62728"), 3);
        // fsrl (first colour): solid to episode 500, then dashes, in each panel.
        assert!(stroke("#1F77B4") > 3 * 2, "{}", stroke("#1F77B4"));
        // The band: only for the group of two runs, one per panel.
        let bands = doc
            .descendants()
            .filter(|n| {
                n.has_tag_name("polygon")
                    && n.attribute("fill")
                        .is_some_and(|f| f.eq_ignore_ascii_case("#1F77B4"))
            })
            .count();
        assert_eq!(bands, 3);
        for word in [
            "fsrl (2 runs)",
            "sarl-s0",
            "validation success rate",
            "validation collision rate",
            "Disc.",
            "RL episodes trained",
        ] {
            assert!(svg.contains(word), "missing {word}");
        }
        let timed = ValidationCurves {
            axis: ValidationAxis::WallClock,
            ..fig
        };
        let svg = crate::to_svg_string(&timed).unwrap();
        assert!(svg.contains("wall-clock time (min)"));
    }
}
