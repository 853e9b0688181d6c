//! Every figure renders from synthetic data into valid, non-trivial SVG, PNG and GIF files with
//! the expected number of bars, series and frames. Set `VIZ_KEEP=dir` to keep the pictures.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};
use viz::metrics::{ImitationPoint, Metrics, RlPoint, ValidationPoint};
use viz::{
    group_runs, save, save_gif, Ablation, CurveRun, EpisodeTrace, HumanInfo, Interval,
    LearningCurves, Obstacle, ObstacleKind, OutcomeBars, OutcomeCell, TraceFrame, Trajectory,
    ValidationAxis, ValidationCurves,
};

fn out_dir() -> (Option<tempfile::TempDir>, PathBuf) {
    match std::env::var_os("VIZ_KEEP") {
        Some(d) => {
            std::fs::create_dir_all(&d).unwrap();
            (None, PathBuf::from(d))
        }
        None => {
            let t = tempfile::tempdir().unwrap();
            let p = t.path().to_path_buf();
            (Some(t), p)
        }
    }
}

/// Parses the SVG and returns (width, height, fill colours of every `rect` and `polygon`,
/// number of 2-px `polyline`s, all text).
fn svg_facts(path: &Path) -> (f64, f64, Vec<String>, usize, String) {
    let text = std::fs::read_to_string(path).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "svg");
    let w: f64 = root.attribute("width").unwrap().parse().unwrap();
    let h: f64 = root.attribute("height").unwrap().parse().unwrap();
    let mut fills = Vec::new();
    let mut polylines = 0;
    let mut words = String::new();
    for n in doc.descendants() {
        match n.tag_name().name() {
            "rect" | "polygon" => fills.push(n.attribute("fill").unwrap_or("").to_uppercase()),
            // Data series are 2 px wide; mesh lines, axes and error bars 1 px.
            "polyline" if n.attribute("stroke-width") == Some("2") => polylines += 1,
            "text" => {
                words.push_str(n.text().unwrap_or(""));
                words.push('\n');
            }
            _ => {}
        }
    }
    (w, h, fills, polylines, words)
}

/// Decodes the PNG; checks its size and that it is not blank.
fn check_png(path: &Path, size: (u32, u32)) {
    let decoder = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), size, "{}", path.display());
    let px = info.color_type.samples();
    let colours: HashSet<&[u8]> = buf[..info.buffer_size()].chunks(px).collect();
    assert!(
        colours.len() > 20,
        "{}: only {} colours",
        path.display(),
        colours.len()
    );
}

fn count(fills: &[String], colour: &str) -> usize {
    fills.iter().filter(|f| f.as_str() == colour).count()
}

fn cell(s: f64, c: f64) -> OutcomeCell {
    let iv = |v: f64| Interval {
        mean: v,
        lo: (v - 0.05).max(0.0),
        hi: (v + 0.05).min(1.0),
    };
    OutcomeCell {
        success: iv(s),
        collision: iv(c),
        timeout: iv(1.0 - s - c),
    }
}

#[test]
fn outcome_bars_have_three_bars_per_method_and_setting() {
    let (_keep, dir) = out_dir();
    let settings: Vec<String> = ["env1", "env2", "env3", "env1 vis", "env2 vis", "env3 vis"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let methods: Vec<String> = ["orca", "sarl", "fsrl"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let mut cells = vec![vec![Some(cell(0.8, 0.1)); 3]; 6];
    cells[5][0] = None;
    let fig = OutcomeBars {
        title: "Outcomes".into(),
        settings,
        methods,
        cells,
        interval_note: "error bars: 95% Wilson intervals".into(),
    };
    let files = save(&fig, &dir.join("bars")).unwrap();
    let (w, h, fills, _, text) = svg_facts(&files[0]);
    assert_eq!((w as u32, h as u32), viz::Figure::size(&fig));
    // 17 cells × 1 bar + 1 legend square per outcome.
    assert_eq!(count(&fills, "#2CA02C"), 17 + 1);
    assert_eq!(count(&fills, "#D62728"), 17 + 1);
    assert_eq!(count(&fills, "#FF9F1C"), 17 + 1);
    for word in ["orca", "fsrl", "env3 vis", "rate", "success", "timeout"] {
        assert!(text.contains(word), "missing {word}");
    }
    check_png(&files[1], viz::Figure::size(&fig));
}

fn metrics(n: u64, offset: f64) -> Metrics {
    Metrics {
        imitation: (0..5)
            .map(|e| ImitationPoint {
                epoch: e,
                loss: Some(0.1 / (e + 1) as f64),
                wall_s: e as f64,
            })
            .collect(),
        rl: (0..n)
            .map(|k| RlPoint {
                episode: k,
                epsilon: 0.5,
                outcome: "success".into(),
                steps: 40,
                return_sum: 0.3 + offset + k as f64 * 0.001,
                loss: Some(0.01 + 0.001 * (k % 7) as f64),
                success_rate_window: (k as f64 / n as f64 + offset).min(1.0),
                collision_rate_window: 0.1,
                timeout_rate_window: 0.0,
                policy_version: k,
                env_steps: 40 * k,
                wall_s: k as f64,
            })
            .collect(),
        validation: (0..=n / 50)
            .map(|v| {
                let success = (v as f64 * 50.0 / n as f64 + offset).min(1.0);
                ValidationPoint {
                    episode: 50 * v,
                    success_rate: success,
                    collision_rate: 1.0 - success,
                    timeout_rate: 0.0,
                    discomfort: 0.2 - 0.1 * success,
                    nav_time_s: Some(12.0),
                    mean_return: Some(0.2),
                    episodes: 100,
                    seed_start: 0,
                    policy_version: 50 * v,
                    env_steps: 2000 * v,
                    wall_s: 30.0 + 50.0 * v as f64 * (1.0 + offset),
                }
            })
            .collect(),
        torn_last_line: false,
    }
}

#[test]
fn learning_curves_draw_one_line_per_run_and_panel() {
    let (_keep, dir) = out_dir();
    let fig = LearningCurves {
        title: "Learning curves".into(),
        runs: vec![
            CurveRun {
                label: "sarl s0".into(),
                metrics: metrics(300, 0.0),
            },
            CurveRun {
                label: "fsrl s0".into(),
                metrics: metrics(250, 0.1),
            },
        ],
        window: 20,
    };
    let files = save(&fig, &dir.join("curves")).unwrap();
    let (_, _, _, polylines, text) = svg_facts(&files[0]);
    assert_eq!(polylines, 4 * 2, "4 panels × 2 runs");
    for word in [
        "success rate",
        "RL episode",
        "sarl s0",
        "fsrl s0",
        "imitation loss",
    ] {
        assert!(text.contains(word), "missing {word}");
    }
    check_png(&files[1], viz::Figure::size(&fig));
}

#[test]
fn validation_curves_render_against_episodes_and_wall_clock() {
    let (_keep, dir) = out_dir();
    let run = |label: &str, n: u64, offset: f64| CurveRun {
        label: label.into(),
        metrics: metrics(n, offset),
    };
    let groups = group_runs(vec![
        run("fsrl-env1-invisible-s0", 300, 0.1),
        run("fsrl-env1-invisible-s1", 250, 0.05),
        run("sarl-env1-invisible-s0", 300, 0.0),
    ]);
    assert_eq!(groups.len(), 2);
    for (axis, stem, word) in [
        (
            ValidationAxis::Episodes,
            "validation-episodes",
            "RL episodes trained",
        ),
        (
            ValidationAxis::WallClock,
            "validation-time",
            "wall-clock time (min)",
        ),
    ] {
        let fig = ValidationCurves {
            title: "Validation".into(),
            groups: groups.clone(),
            axis,
        };
        let files = save(&fig, &dir.join(stem)).unwrap();
        let (w, h, _, polylines, text) = svg_facts(&files[0]);
        assert_eq!((w as u32, h as u32), viz::Figure::size(&fig));
        // At least one mean line per group and panel (the shorter seed adds dashes).
        assert!(polylines >= 2 * 3, "{polylines}");
        for word in [
            word,
            "fsrl-env1-invisible (2 runs)",
            "sarl-env1-invisible-s0",
            "validation success rate",
            "seeds 0–99",
        ] {
            assert!(text.contains(word), "missing {word}");
        }
        check_png(&files[1], viz::Figure::size(&fig));
    }
}

#[test]
fn ablation_has_a_bar_per_variant_and_metric() {
    let (_keep, dir) = out_dir();
    let variants: Vec<String> = ["R_c", "+R_f", "+R_t", "all"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let fig = Ablation {
        title: "Ablation".into(),
        variants,
        outcomes: vec![Some(cell(0.6, 0.3)); 4],
        nav_time_s: vec![
            Some(Interval {
                mean: 12.0,
                lo: 11.5,
                hi: 12.5
            });
            4
        ],
        disc: vec![Some(Interval::exact(0.05)); 4],
        interval_note: "error bars: ± std over seeds".into(),
    };
    let files = save(&fig, &dir.join("ablation")).unwrap();
    let (_, _, fills, _, text) = svg_facts(&files[0]);
    assert_eq!(count(&fills, "#2CA02C"), 4 + 1);
    // Nav. Time bars share the first palette colour with the legend square.
    assert_eq!(count(&fills, "#1F77B4"), 4 + 1);
    assert_eq!(count(&fills, "#9467BD"), 4 + 1);
    for word in ["R_c", "+R_f", "all", "Nav. Time", "Disc."] {
        assert!(text.contains(word), "missing {word}");
    }
    check_png(&files[1], viz::Figure::size(&fig));
}

fn trace(attention: bool) -> EpisodeTrace {
    let n = 6;
    let steps = 30;
    let humans: Vec<HumanInfo> = (0..n)
        .map(|i| HumanInfo {
            radius_m: 0.3,
            standing: i >= 4,
            goal: (-(i as f64) + 2.0, 4.0),
        })
        .collect();
    let frames = (0..=steps)
        .map(|k| {
            let t = k as f64 * 0.25;
            TraceFrame {
                time_s: t,
                robot: (0.1 * t.sin(), -4.0 + 8.0 * k as f64 / steps as f64),
                heading_rad: std::f64::consts::FRAC_PI_2,
                humans: (0..n)
                    .map(|i| {
                        if i >= 4 {
                            (i as f64 - 5.0, 1.0)
                        } else {
                            (-4.0 + 8.0 * k as f64 / steps as f64, i as f64 - 2.0)
                        }
                    })
                    .collect(),
                attention: (attention && k < steps)
                    .then(|| (0..n).map(|i| (i + 1) as f64 / 21.0).collect()),
            }
        })
        .collect();
    EpisodeTrace {
        title: "fsrl on env2-invisible, seed 1000".into(),
        robot_radius_m: 0.3,
        robot_goal: (0.0, 4.0),
        humans,
        obstacles: Vec::new(),
        frames,
        outcome: "success after 7.50 s".into(),
    }
}

#[test]
fn trajectory_shows_every_human_at_every_chosen_time() {
    let (_keep, dir) = out_dir();
    let fig = Trajectory {
        trace: trace(true),
        times_s: vec![2.0, 5.0, 7.5],
    };
    let files = save(&fig, &dir.join("trajectory")).unwrap();
    let (_, _, _, _, text) = svg_facts(&files[0]);
    for word in [
        "t = 2.00 s",
        "t = 5.00 s",
        "t = 7.50 s",
        "attention",
        "0.29",
    ] {
        assert!(text.contains(word), "missing {word}");
    }
    // Every human's weight is printed in every panel.
    let weights = text
        .lines()
        .filter(|l| l.starts_with("0.") && l.len() == 4)
        .count();
    assert!(weights >= 3 * 6, "{weights} weight labels");
    check_png(&files[1], viz::Figure::size(&fig));

    let plain = Trajectory {
        trace: trace(false),
        times_s: vec![3.0],
    };
    let files = save(&plain, &dir.join("trajectory-plain")).unwrap();
    let (_, _, _, _, text) = svg_facts(&files[0]);
    assert!(text.contains("no attention"));
}

#[test]
fn gif_has_a_frame_per_step_plus_the_hold() {
    let (_keep, dir) = out_dir();
    let t = trace(true);
    let path = save_gif(&t, &dir.join("episode.gif"), 300, 100, 1).unwrap();
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut d = opts.read_info(std::fs::File::open(&path).unwrap()).unwrap();
    assert_eq!(d.width(), 300 + 80);
    let mut frames = 0;
    while let Some(f) = d.read_next_frame().unwrap() {
        assert_eq!(f.delay, 10);
        frames += 1;
    }
    assert_eq!(frames, t.frames.len() + viz::GIF_HOLD_FRAMES);
    // Every third step: frames 0, 3, ..., 27 of 0..30, then the last one held.
    let path = save_gif(&t, &dir.join("episode-stride.gif"), 200, 100, 3).unwrap();
    let mut d = gif::DecodeOptions::new()
        .read_info(std::fs::File::open(&path).unwrap())
        .unwrap();
    let mut strided = 0;
    while d.read_next_frame().unwrap().is_some() {
        strided += 1;
    }
    assert_eq!(strided, 10 + 1 + viz::GIF_HOLD_FRAMES);
    let empty = EpisodeTrace {
        frames: Vec::new(),
        ..t
    };
    assert!(save_gif(&empty, &dir.join("empty.gif"), 300, 100, 1).is_err());
}

fn sha256(path: &Path) -> String {
    format!("{:x}", Sha256::digest(std::fs::read(path).unwrap()))
}

/// Without obstacles an episode is drawn byte for byte as before walls existed: the SHA-256s
/// of the SVG, PNG and GIF drawn then (with DejaVu Sans, whose text widths place the legend).
#[test]
fn an_open_floor_is_drawn_as_before_walls() {
    let font = viz::fonts::ensure().unwrap();
    assert!(
        font.ends_with("DejaVuSans.ttf"),
        "the reference pictures were drawn with DejaVu Sans, not {}: install fonts-dejavu-core",
        font.display()
    );
    let (_keep, dir) = out_dir();
    let fig = Trajectory {
        trace: trace(true),
        times_s: vec![2.0, 5.0, 7.5],
    };
    let files = save(&fig, &dir.join("open-floor")).unwrap();
    assert_eq!(
        sha256(&files[0]),
        "7ac228bb211a17faeb5a6aa4321cde076f763b78bcdba1ff7d96c74ce48d481f"
    );
    assert_eq!(
        sha256(&files[1]),
        "159c1f06238d47c74b2cf09fea0d9fc0eadc2bc570158d771616ed7905abeb02"
    );
    let plain = Trajectory {
        trace: trace(false),
        times_s: vec![3.0],
    };
    let files = save(&plain, &dir.join("open-floor-plain")).unwrap();
    assert_eq!(
        sha256(&files[0]),
        "ec1a30c79304571039b29df7c82eda0ed4c702752f9c3351a852deeb6cfc30a2"
    );
    let gif = save_gif(&trace(true), &dir.join("open-floor.gif"), 300, 100, 1).unwrap();
    assert_eq!(
        sha256(&gif),
        "b1b94b5ccd37cd26b703fdfbbc542e3003271b35379f55930ae8830373545d21"
    );
}

/// The synthetic episode in a corridor 2 m wide and 14 m long (walls at x = ±1 from y = −7 to
/// 7), with a box and a bounding wall around the far end.
fn walled_trace() -> EpisodeTrace {
    let mut t = trace(false);
    t.obstacles = vec![
        Obstacle {
            kind: ObstacleKind::Wall,
            vertices: vec![(-1.0, -7.0), (-1.0, 7.0)],
        },
        Obstacle {
            kind: ObstacleKind::Wall,
            vertices: vec![(1.0, 7.0), (1.0, -7.0)],
        },
        Obstacle {
            kind: ObstacleKind::Solid,
            vertices: vec![(0.5, 5.0), (0.9, 5.0), (0.9, 5.5), (0.5, 5.5)],
        },
        Obstacle {
            kind: ObstacleKind::Boundary,
            vertices: vec![(-1.0, 6.0), (-1.0, 7.0), (1.0, 7.0), (1.0, 6.0)],
        },
    ];
    t.outcome = "wall collision at 7.50 s".into();
    t
}

/// Points `x,y` of every polyline drawn in `stroke` at `width` px.
fn polylines(svg: &str, stroke: &str, width: &str) -> Vec<Vec<(f64, f64)>> {
    let doc = roxmltree::Document::parse(svg).unwrap();
    doc.descendants()
        .filter(|n| {
            n.tag_name().name() == "polyline"
                && n.attribute("stroke") == Some(stroke)
                && n.attribute("stroke-width") == Some(width)
        })
        .map(|n| {
            n.attribute("points")
                .unwrap()
                .split_whitespace()
                .map(|p| {
                    let (x, y) = p.split_once(',').unwrap();
                    (x.parse().unwrap(), y.parse().unwrap())
                })
                .collect()
        })
        .collect()
}

/// Walls are thick lines, a bounding wall a thick closed outline, a solid obstacle a grey
/// polygon with a thin outline, in every panel; the view holds them (a corridor 14 m long does
/// not fit Env 1–3's ±5.5 m square) at one scale on both axes, and the legend names them.
#[test]
fn walls_are_drawn_in_view_at_one_scale() {
    let (_keep, dir) = out_dir();
    let fig = Trajectory {
        trace: walled_trace(),
        times_s: vec![2.0, 5.0, 7.5],
    };
    let files = save(&fig, &dir.join("walled")).unwrap();
    let (w, h, fills, _, text) = svg_facts(&files[0]);
    let svg = std::fs::read_to_string(&files[0]).unwrap();
    assert!(text.contains("walls and obstacles"));
    assert!(text.contains("wall collision at 7.50 s"));
    assert_eq!(count(&fills, "#A8A8A8"), 3, "one box per panel");
    let thick = polylines(&svg, "#454545", "4");
    assert_eq!(thick.len(), 3 * 3, "two walls and a boundary per panel");
    // The boundary is closed: it starts and ends in the middle of its first edge.
    let closed: Vec<_> = thick.iter().filter(|p| p.len() > 2).collect();
    assert_eq!(closed.len(), 3);
    assert!(closed.iter().all(|p| p.first() == p.last() && p.len() == 6));
    let thin = polylines(&svg, "#454545", "1");
    assert_eq!(thin.len(), 3, "the box's outline per panel");
    // Every wall is inside the panels (below the title, legend and captions; above the
    // axis labels and the foot).
    let walls: Vec<_> = thick.iter().filter(|p| p.len() == 2).collect();
    for p in thick.iter().flatten() {
        assert!(p.0 > 0.0 && p.0 < w, "{p:?} outside 0..{w}");
        assert!(
            p.1 > 44.0 + 34.0 + 20.0 && p.1 < h - 28.0 - 30.0,
            "{p:?} outside"
        );
    }
    // One scale: the corridor's 2 m across take a seventh of the pixels its 14 m along do.
    let (left, right) = (walls[0], walls[1]);
    let across = (right[0].0 - left[0].0).abs();
    let along = (left[1].1 - left[0].1).abs();
    assert!(
        (across * 7.0 / along - 1.0).abs() < 0.03,
        "{across} px across, {along} px along"
    );
    // Room for the legend's extra entry.
    assert!(w >= 1040.0, "{w}");
    check_png(&files[1], viz::Figure::size(&fig));

    // The GIF of a tall scene is taller than wide, a frame per step plus the hold.
    let path = save_gif(&walled_trace(), &dir.join("walled.gif"), 300, 100, 1).unwrap();
    let mut d = gif::DecodeOptions::new()
        .read_info(std::fs::File::open(&path).unwrap())
        .unwrap();
    assert_eq!(d.width(), 300);
    assert!(d.height() > 400, "{}", d.height());
    let mut frames = 0;
    while d.read_next_frame().unwrap().is_some() {
        frames += 1;
    }
    assert_eq!(frames, 31 + viz::GIF_HOLD_FRAMES);
}
