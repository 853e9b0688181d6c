//! Colours, fonts and small drawing helpers shared by the figures.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::DrawError;

pub const SUCCESS: RGBColor = RGBColor(0x2c, 0xa0, 0x2c);
pub const COLLISION: RGBColor = RGBColor(0xd6, 0x27, 0x28);
pub const TIMEOUT: RGBColor = RGBColor(0xff, 0x9f, 0x1c);
pub const ROBOT: RGBColor = RGBColor(0xe6, 0x7e, 0x22);
pub const STANDING: RGBColor = RGBColor(0x70, 0x70, 0x70);
pub const GRID: RGBColor = RGBColor(0xe4, 0xe4, 0xe4);
pub const DARK: RGBColor = RGBColor(0x33, 0x33, 0x33);
/// Fill of solid static obstacles (furniture, pillars).
pub const OBSTACLE: RGBColor = RGBColor(0xa8, 0xa8, 0xa8);
/// Walls, bounding walls and the outlines of solid obstacles.
pub const WALL: RGBColor = RGBColor(0x45, 0x45, 0x45);

/// Series colours (methods, runs, humans).
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0x94, 0x67, 0xbd),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0x17, 0xbe, 0xcf),
    RGBColor(0xe3, 0x77, 0xc2),
];

pub fn palette(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

pub fn font(size: f64) -> TextStyle<'static> {
    ("sans-serif", size).into_font().color(&DARK)
}

pub fn bold(size: f64) -> TextStyle<'static> {
    ("sans-serif", size)
        .into_font()
        .style(FontStyle::Bold)
        .color(&BLACK)
}

/// Viridis-like colour for `t` in [0, 1] (dark purple → blue → green → yellow).
pub fn sequential(t: f64) -> RGBColor {
    const STOPS: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |p: f64, q: f64| (p + (q - p) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Draws the title of a figure at the top of `root` and returns the area below it.
pub fn titled<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    height: u32,
) -> Result<DrawingArea<DB, Shift>, DrawError> {
    let (top, rest) = root.split_vertically(height);
    let (w, h) = top.dim_in_pixel();
    top.draw(&Text::new(
        title.to_string(),
        (w as i32 / 2, h as i32 / 2),
        bold(20.0).pos(Pos::new(HPos::Center, VPos::Center)),
    ))?;
    Ok(rest)
}

/// A row of legend entries (filled square + label), centred in `area`.
pub fn legend_row<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    items: &[(String, RGBColor)],
) -> Result<(), DrawError> {
    let (w, h) = area.dim_in_pixel();
    let style = font(15.0);
    let widths: Vec<i32> = items
        .iter()
        .map(|(label, _)| {
            let (tw, _) = area.estimate_text_size(label, &style).unwrap_or((80, 15));
            tw as i32 + 46
        })
        .collect();
    let total: i32 = widths.iter().sum();
    let mut x = (w as i32 - total).max(0) / 2;
    let y = h as i32 / 2;
    for ((label, color), width) in items.iter().zip(widths) {
        area.draw(&Rectangle::new(
            [(x, y - 7), (x + 14, y + 7)],
            color.filled(),
        ))?;
        area.draw(&Text::new(
            label.clone(),
            (x + 20, y),
            style.pos(Pos::new(HPos::Left, VPos::Center)),
        ))?;
        x += width;
    }
    Ok(())
}

/// A vertical error bar with caps, in the chart's coordinates.
pub fn error_bar(x: f64, lo: f64, hi: f64, half_cap: f64) -> [PathElement<(f64, f64)>; 3] {
    let s = BLACK.stroke_width(1);
    [
        PathElement::new(vec![(x, lo), (x, hi)], s),
        PathElement::new(vec![(x - half_cap, lo), (x + half_cap, lo)], s),
        PathElement::new(vec![(x - half_cap, hi), (x + half_cap, hi)], s),
    ]
}

/// Category labels under a chart's x axis at the given x positions (bar charts: plotters' own
/// tick labels cannot be pinned to group centres).
pub fn category_labels<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    to_pixel: impl Fn(f64) -> (i32, i32),
    labels: &[String],
) -> Result<(), DrawError> {
    let (bx, by) = area.get_base_pixel();
    // Room per label: the distance between neighbouring category centres, less a margin.
    let slot = (to_pixel(1.5).0 - to_pixel(0.5).0).abs().max(1) as u32;
    let room = slot.saturating_sub(6).max(1);
    let width = |text: &str, size: f64| {
        area.estimate_text_size(text, &font(size))
            .map_or(u32::MAX, |(w, _)| w)
    };
    for (j, label) in labels.iter().enumerate() {
        let (x, y) = to_pixel(j as f64 + 0.5);
        // The largest size (13 → 10 px) at which the label fits on one line; otherwise two
        // lines split at the '+' or space nearest the middle, at the size where both fit.
        let one_line = [13.0, 12.0, 11.0, 10.0]
            .into_iter()
            .find(|&size| width(label, size) <= room);
        let lines: Vec<String> = match one_line {
            Some(_) => vec![label.clone()],
            None => split_near_middle(label),
        };
        let size = [13.0, 12.0, 11.0, 10.0, 9.0]
            .into_iter()
            .find(|&size| lines.iter().all(|l| width(l, size) <= room))
            .unwrap_or(9.0);
        for (k, line) in lines.iter().enumerate() {
            area.draw(&Text::new(
                line.clone(),
                (x - bx, y - by + 6 + k as i32 * (size as i32 + 2)),
                font(size).pos(Pos::new(HPos::Center, VPos::Top)),
            ))?;
        }
    }
    Ok(())
}

/// `label` in two lines, split before the '+' or at the space nearest its middle; one line if
/// it has neither.
fn split_near_middle(label: &str) -> Vec<String> {
    let mid = label.chars().count() / 2;
    let best = label
        .char_indices()
        .filter(|(_, c)| *c == '+' || *c == ' ')
        .min_by_key(|(i, _)| i.abs_diff(mid));
    match best {
        Some((i, ' ')) => vec![label[..i].to_string(), label[i + 1..].to_string()],
        Some((i, _)) if i > 0 => vec![label[..i].to_string(), label[i..].to_string()],
        _ => vec![label.to_string()],
    }
}

#[cfg(test)]
mod tests {
    use super::split_near_middle;

    #[test]
    fn long_labels_split_at_the_plus_or_space_nearest_the_middle() {
        assert_eq!(
            split_near_middle("sarl+efficiency (1)"),
            ["sarl", "+efficiency (1)"]
        );
        assert_eq!(
            split_near_middle("sarl+foresight (1)"),
            ["sarl", "+foresight (1)"]
        );
        assert_eq!(split_near_middle("success rate"), ["success", "rate"]);
        assert_eq!(split_near_middle("+R_f"), ["+R_f"]);
        assert_eq!(split_near_middle("orca"), ["orca"]);
    }
}
