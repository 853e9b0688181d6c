//! An episode as an SVG picture: the robot's and the humans' paths with time marks, standing
//! humans filled, start and goal. Hand-written SVG: no dependency, exact control of the layout.

use std::fmt::Write as _;

use sim::{Episode, HumanState, Outcome, Vec2};

/// What the picture is of, for its title.
pub struct PictureInfo<'a> {
    pub title: &'a str,
    pub policy: &'a str,
}

const PALETTE: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22",
    "#7f7f7f", "#d62728",
];
const ROBOT: &str = "#c0392b";
const SCALE: f64 = 60.0; // pixels per metre
const HALF_M: f64 = 5.5; // the world window is [−HALF, HALF]²
const MARGIN: f64 = 50.0;
const LEGEND_W: f64 = 230.0;
/// A time mark every this many seconds.
const MARK_EVERY_S: f64 = 2.0;

fn px(p: Vec2) -> (f64, f64) {
    (
        MARGIN + (p.x + HALF_M) * SCALE,
        MARGIN + (HALF_M - p.y) * SCALE,
    )
}

/// Renders `episode` (which must have frames) whose initial humans are `humans`.
pub fn render(episode: &Episode, humans: &[HumanState], dt_s: f64, info: &PictureInfo) -> String {
    let world = 2.0 * HALF_M * SCALE;
    let (w, h) = (world + 2.0 * MARGIN + LEGEND_W, world + 2.0 * MARGIN + 30.0);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="Helvetica, Arial, sans-serif">"#
    );
    let _ = writeln!(s, r#"<rect width="100%" height="100%" fill="white"/>"#);
    // Grid and axes.
    for k in -5..=5 {
        let (x, _) = px(Vec2::new(k as f64, 0.0));
        let (_, y) = px(Vec2::new(0.0, k as f64));
        let (top, bottom) = (MARGIN, MARGIN + world);
        let stroke = if k == 0 { "#bbb" } else { "#eee" };
        let _ = writeln!(
            s,
            r#"<line x1="{x}" y1="{top}" x2="{x}" y2="{bottom}" stroke="{stroke}"/>"#
        );
        let _ = writeln!(
            s,
            r#"<line x1="{top}" y1="{y}" x2="{bottom}" y2="{y}" stroke="{stroke}"/>"#
        );
        let _ = writeln!(
            s,
            r##"<text x="{x}" y="{}" font-size="11" text-anchor="middle" fill="#666">{k}</text>"##,
            bottom + 15.0
        );
        let _ = writeln!(
            s,
            r##"<text x="{}" y="{}" font-size="11" text-anchor="end" fill="#666">{k}</text>"##,
            top - 6.0,
            y + 4.0
        );
    }
    let _ = writeln!(
        s,
        r##"<text x="{}" y="{}" font-size="12" text-anchor="middle" fill="#444">x (m)</text>"##,
        MARGIN + world / 2.0,
        MARGIN + world + 32.0
    );
    let _ = writeln!(
        s,
        r##"<text x="14" y="{}" font-size="12" fill="#444" transform="rotate(-90 14 {})" text-anchor="middle">y (m)</text>"##,
        MARGIN + world / 2.0,
        MARGIN + world / 2.0
    );
    let _ = writeln!(
        s,
        r#"<text x="{MARGIN}" y="28" font-size="16" font-weight="bold">{}</text>"#,
        escape(info.title)
    );

    let frames = &episode.frames;
    let mark_every = ((MARK_EVERY_S / dt_s).round() as usize).max(1);
    let last = frames.len().saturating_sub(1);
    let marks: Vec<usize> = (0..frames.len())
        .filter(|k| k % mark_every == 0 || *k == last)
        .collect();
    let r_px = |r: f64| r * SCALE;

    // Humans: dynamic paths with time marks; standing humans filled.
    for (i, hum) in humans.iter().enumerate() {
        let r = r_px(hum.radius_m);
        if hum.standing {
            let (x, y) = px(hum.position);
            let _ = writeln!(
                s,
                r##"<circle cx="{x:.1}" cy="{y:.1}" r="{r:.1}" fill="#555" stroke="#222" stroke-width="1.5"/>"##
            );
            continue;
        }
        let color = PALETTE[i % PALETTE.len()];
        let pts: Vec<String> = frames
            .iter()
            .map(|f| {
                let (x, y) = px(f.humans[i]);
                format!("{x:.1},{y:.1}")
            })
            .collect();
        let _ = writeln!(
            s,
            r#"<polyline points="{}" fill="none" stroke="{color}" stroke-width="1.5" stroke-opacity="0.55"/>"#,
            pts.join(" ")
        );
        for &k in &marks {
            let (x, y) = px(frames[k].humans[i]);
            let opacity = 0.25 + 0.75 * k as f64 / last.max(1) as f64;
            let _ = writeln!(
                s,
                r#"<circle cx="{x:.1}" cy="{y:.1}" r="{r:.1}" fill="{color}" fill-opacity="0.08" stroke="{color}" stroke-opacity="{opacity:.2}" stroke-width="1.2"/>"#
            );
            let t = frames[k].time_s;
            let _ = writeln!(
                s,
                r#"<text x="{x:.1}" y="{:.1}" font-size="9" text-anchor="middle" fill="{color}">{}</text>"#,
                y + 3.0,
                secs(t)
            );
        }
        let (gx, gy) = px(hum.goal);
        let _ = writeln!(
            s,
            r#"<path d="M{:.1},{:.1} l8,8 m0,-8 l-8,8" stroke="{color}" stroke-width="1.2" stroke-opacity="0.6"/>"#,
            gx - 4.0,
            gy - 4.0
        );
    }

    // Robot: start, goal, path, time marks with headings.
    if let Some(first) = frames.first() {
        let robot = first.robot;
        let (sx, sy) = px(robot.position);
        let _ = writeln!(
            s,
            r##"<rect x="{:.1}" y="{:.1}" width="14" height="14" fill="none" stroke="#000" stroke-width="2"/>"##,
            sx - 7.0,
            sy - 7.0
        );
        let (gx, gy) = px(robot.goal);
        let _ = writeln!(
            s,
            r##"<polygon points="{}" fill="#f1c40f" stroke="#7d6608" stroke-width="1.2"/>"##,
            star(gx, gy, 12.0, 5.0)
        );
        let pts: Vec<String> = frames
            .iter()
            .map(|f| {
                let (x, y) = px(f.robot.position);
                format!("{x:.1},{y:.1}")
            })
            .collect();
        let _ = writeln!(
            s,
            r#"<polyline points="{}" fill="none" stroke="{ROBOT}" stroke-width="3"/>"#,
            pts.join(" ")
        );
        let r = r_px(robot.radius_m);
        for &k in &marks {
            let f = &frames[k];
            let (x, y) = px(f.robot.position);
            let _ = writeln!(
                s,
                r#"<circle cx="{x:.1}" cy="{y:.1}" r="{r:.1}" fill="{ROBOT}" fill-opacity="0.15" stroke="{ROBOT}" stroke-width="1.5"/>"#
            );
            let (hx, hy) = (f.robot.heading_rad.cos(), f.robot.heading_rad.sin());
            let _ = writeln!(
                s,
                r#"<line x1="{x:.1}" y1="{y:.1}" x2="{:.1}" y2="{:.1}" stroke="{ROBOT}" stroke-width="2"/>"#,
                x + hx * r,
                y - hy * r
            );
            let _ = writeln!(
                s,
                r#"<text x="{:.1}" y="{:.1}" font-size="11" font-weight="bold" fill="{ROBOT}">{}s</text>"#,
                x + r + 3.0,
                y + 4.0,
                secs(f.time_s)
            );
        }
        if episode.summary.outcome == Outcome::Collision {
            let (x, y) = px(frames[last].robot.position);
            let _ = writeln!(
                s,
                r#"<path d="M{:.1},{:.1} l16,16 m0,-16 l-16,16" stroke="black" stroke-width="3"/>"#,
                x - 8.0,
                y - 8.0
            );
        }
    }

    // Legend.
    let lx = MARGIN + world + 25.0;
    let mut ly = MARGIN + 10.0;
    let robot_label = format!("robot ({})", info.policy);
    let marks_label = format!("positions every {MARK_EVERY_S:.0} s");
    type Shape = Box<dyn Fn(f64, f64) -> String>;
    let rows: Vec<(Shape, &str)> = vec![
        (
            Box::new(|x, y| {
                format!(
                    r#"<line x1="{x}" y1="{y}" x2="{}" y2="{y}" stroke="{ROBOT}" stroke-width="3"/>"#,
                    x + 22.0
                )
            }),
            &robot_label,
        ),
        (
            Box::new(|x, y| {
                format!(
                    r#"<line x1="{x}" y1="{y}" x2="{}" y2="{y}" stroke="{}" stroke-width="1.5"/>"#,
                    x + 22.0,
                    PALETTE[0]
                )
            }),
            "dynamic human",
        ),
        (
            Box::new(|x, y| {
                format!(
                    r##"<circle cx="{}" cy="{y}" r="8" fill="#555" stroke="#222"/>"##,
                    x + 11.0
                )
            }),
            "standing human",
        ),
        (
            Box::new(|x, y| {
                format!(
                    r##"<rect x="{}" y="{}" width="14" height="14" fill="none" stroke="#000" stroke-width="2"/>"##,
                    x + 4.0,
                    y - 7.0
                )
            }),
            "robot start",
        ),
        (
            Box::new(|x, y| {
                format!(
                    r##"<polygon points="{}" fill="#f1c40f" stroke="#7d6608"/>"##,
                    star(x + 11.0, y, 10.0, 4.0)
                )
            }),
            "robot goal",
        ),
        (
            Box::new(|x, y| {
                format!(
                    r#"<path d="M{},{} l8,8 m0,-8 l-8,8" stroke="{}" stroke-width="1.2"/>"#,
                    x + 7.0,
                    y - 4.0,
                    PALETTE[0]
                )
            }),
            "human goal",
        ),
        (
            Box::new(|x, y| {
                format!(
                    r#"<circle cx="{}" cy="{y}" r="8" fill="none" stroke="{ROBOT}"/>"#,
                    x + 11.0
                )
            }),
            &marks_label,
        ),
    ];
    for (shape, text) in rows {
        let _ = writeln!(s, "{}", shape(lx, ly));
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{:.1}" font-size="13">{}</text>"#,
            lx + 30.0,
            ly + 4.0,
            escape(text)
        );
        ly += 26.0;
    }
    let _ = writeln!(
        s,
        r##"<text x="{lx}" y="{:.1}" font-size="12" fill="#444">numbers: time (s)</text>"##,
        ly + 4.0
    );
    ly += 40.0;
    let sum = &episode.summary;
    for text in [
        format!("outcome: {}", sum.outcome.name()),
        format!("time: {:.2} s ({} steps)", sum.time_s, sum.steps),
        format!("path: {:.2} m", sum.path_length_m),
        format!("danger steps: {}", sum.danger_steps),
        format!("min distance: {:.3} m", sum.min_closest_m),
    ] {
        let _ = writeln!(
            s,
            r#"<text x="{lx}" y="{ly:.1}" font-size="13">{}</text>"#,
            escape(&text)
        );
        ly += 20.0;
    }
    s.push_str("</svg>\n");
    s
}

fn star(cx: f64, cy: f64, outer: f64, inner: f64) -> String {
    (0..10)
        .map(|k| {
            let r = if k % 2 == 0 { outer } else { inner };
            let a = -std::f64::consts::FRAC_PI_2 + k as f64 * std::f64::consts::PI / 5.0;
            format!("{:.1},{:.1}", cx + r * a.cos(), cy + r * a.sin())
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// A time label: whole seconds without decimals, others with as few as needed.
fn secs(t: f64) -> String {
    let s = format!("{t:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

fn escape(t: &str) -> String {
    t.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
