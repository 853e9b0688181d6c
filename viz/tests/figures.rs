//! Every figure renders from synthetic data into valid, non-trivial SVG, PNG and GIF files with
//! the expected number of bars, series and frames. Set `VIZ_KEEP=dir` to keep the pictures.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use viz::metrics::{ImitationPoint, Metrics, RlPoint, ValidationPoint};
use viz::{
    group_runs, save, save_gif, Ablation, CurveRun, EpisodeTrace, HumanInfo, Interval,
    LearningCurves, OutcomeBars, OutcomeCell, TraceFrame, Trajectory, ValidationAxis,
    ValidationCurves,
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
