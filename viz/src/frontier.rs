//! [`Frontier`]: the policies a run passed through, as points of Nav. Time against Disc. (one
//! point per validated snapshot), one panel per setting and one colour per method, with the
//! snapshot the run shipped ringed and the paper's row of each method as a cross. A point below
//! and left of its method's cross is at least as fast and as gentle as the paper reports
//! (`docs/REPRODUCTION.md`, Experiment 13).

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::style;
use crate::{DrawError, Figure};

/// One method's snapshots in one setting (all its seeds).
#[derive(Debug, Clone, PartialEq)]
pub struct FrontierGroup {
    /// The method, as in the legend (e.g. `fsrl`). Groups of the same label share a colour
    /// across panels.
    pub label: String,
    /// `(Nav. Time s, Disc.)` of each validated snapshot.
    pub points: Vec<(f64, f64)>,
    /// `(Nav. Time s, Disc.)` of the snapshots the runs chose (their shipped policies).
    pub chosen: Vec<(f64, f64)>,
    /// The paper's `(Nav. Time s, Disc.)` for this method and setting.
    pub paper: Option<(f64, f64)>,
}

/// One setting's panel.
#[derive(Debug, Clone, PartialEq)]
pub struct FrontierPanel {
    pub caption: String,
    pub groups: Vec<FrontierGroup>,
}

/// The figure's data.
#[derive(Debug, Clone, PartialEq)]
pub struct Frontier {
    pub title: String,
    pub panels: Vec<FrontierPanel>,
    /// A line under the title saying what the points are.
    pub note: String,
}

const TITLE_H: u32 = 44;
const NOTE_H: u32 = 22;
const LEGEND_H: u32 = 34;
const PANEL_W: u32 = 460;
const PANEL_H: u32 = 400;
const COLUMNS: usize = 3;
/// Room for the title and the note line, whatever the number of panels.
const MIN_W: u32 = 940;

impl Frontier {
    /// The distinct group labels in order of first appearance: one colour each.
    pub fn labels(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for g in self.panels.iter().flat_map(|p| &p.groups) {
            if !out.contains(&g.label) {
                out.push(g.label.clone());
            }
        }
        out
    }

    fn grid(&self) -> (usize, usize) {
        let n = self.panels.len().max(1);
        let cols = n.min(COLUMNS);
        (n.div_ceil(cols), cols)
    }
}

fn finite(p: &(f64, f64)) -> bool {
    p.0.is_finite() && p.1.is_finite()
}

/// The panel's axis ranges: every point and cross, padded.
fn ranges(panel: &FrontierPanel) -> Option<((f64, f64), (f64, f64))> {
    let all: Vec<(f64, f64)> = panel
        .groups
        .iter()
        .flat_map(|g| g.points.iter().chain(&g.chosen).chain(g.paper.iter()))
        .copied()
        .collect();
    let (x0, x1, y0, y1) = crate::curves::bounds(&[all])?;
    let pad = |lo: f64, hi: f64| {
        let m = if hi - lo < 1e-9 {
            0.5
        } else {
            0.08 * (hi - lo)
        };
        (lo - m, hi + m)
    };
    let (y0, y1) = pad(y0, y1);
    Some((pad(x0, x1), (y0.max(0.0), y1)))
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &FrontierPanel,
    labels: &[String],
) -> Result<(), DrawError> {
    let Some(((x0, x1), (y0, y1))) = ranges(panel) else {
        let (w, h) = area.dim_in_pixel();
        area.draw(&Text::new(
            format!("{}: no snapshots", panel.caption),
            (w as i32 / 2, h as i32 / 2),
            style::font(14.0).pos(Pos::new(HPos::Center, VPos::Center)),
        ))?;
        return Ok(());
    };
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.caption, style::bold(16.0))
        .margin(10)
        .margin_right(20)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .light_line_style(style::GRID)
        .max_light_lines(0)
        .bold_line_style(style::GRID)
        .x_desc("Nav. Time (s)")
        .x_label_formatter(&|v| format!("{v:.1}"))
        .y_desc("Disc.")
        .y_label_formatter(&|v| format!("{v:.2}"))
        .label_style(style::font(13.0))
        .axis_desc_style(style::font(14.0))
        .draw()?;
    for g in &panel.groups {
        let i = labels.iter().position(|l| *l == g.label).unwrap_or(0);
        let colour = style::palette(i);
        chart.draw_series(
            g.points
                .iter()
                .filter(|p| finite(p))
                .map(|&p| Circle::new(p, 3, colour.mix(0.55).filled())),
        )?;
        chart.draw_series(
            g.chosen
                .iter()
                .filter(|p| finite(p))
                .map(|&p| Circle::new(p, 7, colour.stroke_width(2))),
        )?;
        if let Some(p) = g.paper.filter(finite) {
            chart.draw_series(std::iter::once(Cross::new(p, 8, colour.stroke_width(3))))?;
            // The paper's quadrant: as fast and as gentle lies below and left of the cross.
            let dashed = colour.mix(0.6).stroke_width(1);
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(x0, p.1), p, (p.0, y0)],
                dashed,
            )))?;
        }
    }
    Ok(())
}

impl Figure for Frontier {
    fn size(&self) -> (u32, u32) {
        let (rows, cols) = self.grid();
        (
            (PANEL_W * cols as u32).max(MIN_W),
            TITLE_H + NOTE_H + LEGEND_H + PANEL_H * rows as u32,
        )
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), DrawError> {
        let body = style::titled(root, &self.title, TITLE_H)?;
        let (note, body) = body.split_vertically(NOTE_H);
        let (w, h) = note.dim_in_pixel();
        note.draw(&Text::new(
            self.note.clone(),
            (w as i32 / 2, h as i32 / 2),
            style::font(13.0).pos(Pos::new(HPos::Center, VPos::Center)),
        ))?;
        let (legend, body) = body.split_vertically(LEGEND_H);
        let labels = self.labels();
        let mut items: Vec<(String, RGBColor)> = labels
            .iter()
            .enumerate()
            .map(|(i, l)| (l.clone(), style::palette(i)))
            .collect();
        items.push(("ring: shipped, ×: paper".into(), style::DARK));
        style::legend_row(&legend, &items)?;
        let (rows, cols) = self.grid();
        for (area, panel) in body.split_evenly((rows, cols)).iter().zip(&self.panels) {
            draw_panel(area, panel, &labels)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn group(label: &str, points: Vec<(f64, f64)>, paper: Option<(f64, f64)>) -> FrontierGroup {
        FrontierGroup {
            label: label.into(),
            chosen: points.iter().take(1).copied().collect(),
            points,
            paper,
        }
    }

    #[test]
    fn ranges_cover_points_and_the_papers_cross() {
        let panel = FrontierPanel {
            caption: "Env 1".into(),
            groups: vec![group(
                "fsrl",
                vec![(12.0, 0.05), (13.0, 0.02)],
                Some((10.9, 0.01)),
            )],
        };
        let ((x0, x1), (y0, y1)) = ranges(&panel).unwrap();
        assert!(x0 < 10.9 && x1 > 13.0, "{x0} {x1}");
        assert!((0.0..=0.01).contains(&y0) && y1 > 0.05, "{y0} {y1}");
        let empty = FrontierPanel {
            caption: "Env 2".into(),
            groups: vec![group("sarl", vec![(f64::NAN, 0.1)], None)],
        };
        assert!(ranges(&empty).is_none());
    }

    #[test]
    fn a_method_keeps_its_colour_across_panels_and_the_svg_draws_every_point() {
        let fig = Frontier {
            title: "t".into(),
            note: "n".into(),
            panels: vec![
                FrontierPanel {
                    caption: "a".into(),
                    groups: vec![group("sarl", vec![(11.0, 0.1), (12.0, 0.05)], None)],
                },
                FrontierPanel {
                    caption: "b".into(),
                    groups: vec![
                        group("fsrl", vec![(11.5, 0.08)], Some((11.0, 0.07))),
                        group("sarl", vec![(10.5, 0.12)], Some((10.0, 0.1))),
                    ],
                },
            ],
        };
        assert_eq!(fig.labels(), ["sarl", "fsrl"]);
        assert_eq!(
            fig.size(),
            (
                (2 * PANEL_W).max(MIN_W),
                TITLE_H + NOTE_H + LEGEND_H + PANEL_H
            )
        );
        let svg = crate::to_svg_string(&fig).unwrap();
        // 4 snapshot dots and 3 rings (one chosen per group).
        assert_eq!(svg.matches("<circle").count(), 7, "{svg}");
    }
}
