//! Learning curves from `metrics.jsonl`: success rate (the log's 100-episode window), return and
//! TD loss (trailing moving averages) against RL episodes, and the imitation loss against epochs.
//! One line per run.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::metrics::Metrics;
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

fn bounds(series: &[Vec<(f64, f64)>]) -> Option<(f64, f64, f64, f64)> {
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
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(panel.caption, style::bold(16.0))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60);
    let label_style = style::font(13.0);
    let desc_style = style::font(14.0);
    if panel.log_y {
        let (lo, hi) = (y0 / 1.5, y1 * 1.5);
        let mut chart = builder.build_cartesian_2d(x0..x1, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .light_line_style(style::GRID)
            .max_light_lines(0)
            .bold_line_style(style::GRID)
            .x_desc(panel.x_desc)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_desc(panel.y_desc)
            .y_label_formatter(&|y| format!("{y:.0e}"))
            .label_style(label_style)
            .axis_desc_style(desc_style)
            .draw()?;
        for (i, s) in series.iter().enumerate() {
            chart.draw_series(LineSeries::new(
                s.iter().copied(),
                style::palette(i).stroke_width(2),
            ))?;
        }
    } else {
        let (lo, hi) = panel.y_range.unwrap_or_else(|| pad(y0, y1));
        let mut chart = builder.build_cartesian_2d(x0..x1, lo..hi)?;
        chart
            .configure_mesh()
            .light_line_style(style::GRID)
            .max_light_lines(0)
            .bold_line_style(style::GRID)
            .x_desc(panel.x_desc)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_desc(panel.y_desc)
            .label_style(label_style)
            .axis_desc_style(desc_style)
            .draw()?;
        for (i, s) in series.iter().enumerate() {
            chart.draw_series(LineSeries::new(
                s.iter().copied(),
                style::palette(i).stroke_width(2),
            ))?;
        }
    }
    Ok(())
}

impl Figure for LearningCurves {
    fn size(&self) -> (u32, u32) {
        (1120, TITLE_H + LEGEND_H + 2 * 360)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), DrawError> {
        let body = style::titled(root, &self.title, TITLE_H)?;
        let (legend, body) = body.split_vertically(LEGEND_H);
        let items: Vec<(String, RGBColor)> = self
            .runs
            .iter()
            .enumerate()
            .map(|(i, r)| (r.label.clone(), style::palette(i)))
            .collect();
        style::legend_row(&legend, &items)?;
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
}
