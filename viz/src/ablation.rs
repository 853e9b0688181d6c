//! The reward ablation (paper Fig. 8–9): success / collision / timeout rates, navigation time and
//! discomfort of R_c, R_c + R_f, R_c + R_t and the full FSRL reward, averaged over environments.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::bars::{outcome_panel, OutcomeCell};
use crate::style::{self, COLLISION, SUCCESS, TIMEOUT};
use crate::{DrawError, Figure, Interval};

/// The figure's data, one entry per reward variant.
#[derive(Debug, Clone, PartialEq)]
pub struct Ablation {
    pub title: String,
    /// Variant labels, e.g. "R_c", "+R_f", "+R_t", "all".
    pub variants: Vec<String>,
    pub outcomes: Vec<Option<OutcomeCell>>,
    pub nav_time_s: Vec<Option<Interval>>,
    /// Discomfort: danger steps / all steps.
    pub disc: Vec<Option<Interval>>,
    /// What the error bars mean (shown under the legend).
    pub interval_note: String,
}

const PANEL_W: u32 = 420;
const PANEL_H: u32 = 360;
const TITLE_H: u32 = 44;
const LEGEND_H: u32 = 46;

/// One bar per label with optional error bars.
fn metric_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    caption: &str,
    y_desc: &str,
    labels: &[String],
    values: &[Option<Interval>],
    color: RGBColor,
) -> Result<(), DrawError> {
    let m = labels.len().max(1);
    let top = values
        .iter()
        .flatten()
        .map(|v| v.hi.max(v.mean))
        .filter(|v| v.is_finite())
        .fold(0.0_f64, f64::max);
    let top = if top > 0.0 { top * 1.15 } else { 1.0 };
    let mut chart = ChartBuilder::on(area)
        .caption(caption, style::bold(16.0))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(52)
        .build_cartesian_2d(0.0..m as f64, 0.0..top)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .light_line_style(style::GRID)
        .max_light_lines(0)
        .bold_line_style(style::GRID)
        .x_labels(0)
        .y_labels(6)
        .y_desc(y_desc)
        .label_style(style::font(13.0))
        .axis_desc_style(style::font(14.0))
        .draw()?;
    style::category_labels(area, |x| chart.backend_coord(&(x, 0.0)), labels)?;
    for (j, v) in values.iter().enumerate().take(m) {
        let Some(v) = v else { continue };
        let (x0, x1) = (j as f64 + 0.25, j as f64 + 0.75);
        let mean = if v.mean.is_finite() { v.mean } else { 0.0 };
        chart.draw_series(std::iter::once(Rectangle::new(
            [(x0, 0.0), (x1, mean.max(top * 0.012))],
            color.filled(),
        )))?;
        if v.hi > v.lo {
            chart.draw_series(style::error_bar(0.5 + j as f64, v.lo, v.hi, 0.06))?;
        }
        chart.draw_series(std::iter::once(Text::new(
            format!("{mean:.3}"),
            (j as f64 + 0.5, v.hi.max(mean)),
            style::font(12.0).pos(Pos::new(HPos::Center, VPos::Bottom)),
        )))?;
    }
    Ok(())
}

impl Figure for Ablation {
    fn size(&self) -> (u32, u32) {
        (3 * PANEL_W, TITLE_H + LEGEND_H + PANEL_H)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), DrawError> {
        let body = style::titled(root, &self.title, TITLE_H)?;
        let (legend, body) = body.split_vertically(LEGEND_H);
        let (row, note) = legend.split_vertically(LEGEND_H - 16);
        style::legend_row(
            &row,
            &[
                ("success".into(), SUCCESS),
                ("collision".into(), COLLISION),
                ("timeout".into(), TIMEOUT),
                ("Nav. Time".into(), style::palette(0)),
                ("Disc.".into(), style::palette(3)),
            ],
        )?;
        let (w, _) = note.dim_in_pixel();
        note.draw(&Text::new(
            self.interval_note.clone(),
            (w as i32 / 2, 0),
            style::font(12.0).pos(Pos::new(HPos::Center, VPos::Top)),
        ))?;
        let panels = body.split_evenly((1, 3));
        outcome_panel(&panels[0], "outcome rates", &self.variants, &self.outcomes)?;
        metric_panel(
            &panels[1],
            "Nav. Time (successful episodes)",
            "time (s)",
            &self.variants,
            &self.nav_time_s,
            style::palette(0),
        )?;
        metric_panel(
            &panels[2],
            "Disc. (danger steps / steps)",
            "fraction of steps",
            &self.variants,
            &self.disc,
            style::palette(3),
        )?;
        Ok(())
    }
}
