//! Success / collision / timeout rates per setting and method (paper Fig. 5): one panel per
//! setting, a group of three bars per method, 95% intervals as error bars.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::style::{self, COLLISION, SUCCESS, TIMEOUT};
use crate::{DrawError, Figure, Interval};

/// One method on one setting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutcomeCell {
    pub success: Interval,
    pub collision: Interval,
    pub timeout: Interval,
}

/// The whole figure's data.
#[derive(Debug, Clone, PartialEq)]
pub struct OutcomeBars {
    pub title: String,
    /// Panel titles, one per setting.
    pub settings: Vec<String>,
    /// Bar-group labels, one per method.
    pub methods: Vec<String>,
    /// `cells[setting][method]`; `None` where that method has no result on that setting.
    pub cells: Vec<Vec<Option<OutcomeCell>>>,
    /// What the error bars mean (shown under the legend).
    pub interval_note: String,
}

const PANEL_W: u32 = 420;
const PANEL_H: u32 = 340;
const TITLE_H: u32 = 44;
const LEGEND_H: u32 = 46;

impl OutcomeBars {
    fn grid(&self) -> (usize, usize) {
        let n = self.settings.len().max(1);
        let cols = n.min(3);
        (cols, n.div_ceil(cols))
    }
}

/// Draws grouped outcome bars for `methods` on one panel.
pub(crate) fn outcome_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    caption: &str,
    methods: &[String],
    cells: &[Option<OutcomeCell>],
) -> Result<(), DrawError> {
    let m = methods.len().max(1);
    let mut chart = ChartBuilder::on(area)
        .caption(caption, style::bold(16.0))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(48)
        .build_cartesian_2d(0.0..m as f64, 0.0..1.05)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .light_line_style(style::GRID)
        .max_light_lines(0)
        .bold_line_style(style::GRID)
        .x_labels(0)
        .y_labels(6)
        .y_label_formatter(&|y| format!("{y:.1}"))
        .y_desc("rate")
        .label_style(style::font(13.0))
        .axis_desc_style(style::font(14.0))
        .draw()?;
    style::category_labels(area, |x| chart.backend_coord(&(x, 0.0)), methods)?;
    for (j, cell) in cells.iter().enumerate().take(m) {
        let Some(cell) = cell else {
            chart.draw_series(std::iter::once(Text::new(
                "no result",
                (j as f64 + 0.5, 0.05),
                style::font(12.0).pos(Pos::new(HPos::Center, VPos::Bottom)),
            )))?;
            continue;
        };
        for (k, (iv, color)) in [
            (cell.success, SUCCESS),
            (cell.collision, COLLISION),
            (cell.timeout, TIMEOUT),
        ]
        .into_iter()
        .enumerate()
        {
            let x0 = j as f64 + 0.11 + k as f64 * 0.26;
            let x1 = x0 + 0.26;
            let v = if iv.mean.is_finite() { iv.mean } else { 0.0 };
            // A zero rate still shows as a hairline bar, so "0" never looks like "missing".
            chart.draw_series(std::iter::once(Rectangle::new(
                [(x0, 0.0), (x1, v.max(0.012))],
                color.filled(),
            )))?;
            if iv.hi > iv.lo {
                chart.draw_series(style::error_bar((x0 + x1) / 2.0, iv.lo, iv.hi, 0.05))?;
            }
        }
    }
    Ok(())
}

impl Figure for OutcomeBars {
    fn size(&self) -> (u32, u32) {
        let (cols, rows) = self.grid();
        (
            cols as u32 * PANEL_W,
            TITLE_H + LEGEND_H + rows as u32 * PANEL_H,
        )
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
            ],
        )?;
        let (w, _) = note.dim_in_pixel();
        note.draw(&Text::new(
            self.interval_note.clone(),
            (w as i32 / 2, 0),
            style::font(12.0).pos(Pos::new(HPos::Center, VPos::Top)),
        ))?;
        let (cols, rows) = self.grid();
        let panels = body.split_evenly((rows, cols));
        for (s, name) in self.settings.iter().enumerate() {
            let empty = vec![None; self.methods.len()];
            let cells = self.cells.get(s).unwrap_or(&empty);
            outcome_panel(&panels[s], name, &self.methods, cells)?;
        }
        Ok(())
    }
}
