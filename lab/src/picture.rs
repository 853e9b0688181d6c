//! A simulated episode as `viz`'s plain data: the one conversion behind the episode pictures of
//! `fsrl plot episode` and `fsrl sim --svg` (viz draws; it knows nothing of the simulator).
//! A walled setting's static map goes with it, so every picture and GIF draws the walls.

use anyhow::Context;
use learner::model::Model;
use policy::method::Method;
use sim::map::{ShapeKind, StaticMap};
use sim::{run_episode, Env, Episode, EpisodeSummary, HumanState, Outcome, SimConfig};

/// How the episode ended, e.g. "success after 11.50 s"; a collision with a wall is "wall
/// collision at 4.25 s", with a person "collision at 4.25 s".
pub fn outcome(summary: &EpisodeSummary) -> String {
    let t = summary.time_s;
    match summary.outcome {
        Outcome::ReachGoal => format!("success after {t:.2} s"),
        Outcome::Collision if summary.wall_collision => format!("wall collision at {t:.2} s"),
        Outcome::Collision => format!("collision at {t:.2} s"),
        Outcome::Timeout => format!("timeout at {t:.2} s"),
        Outcome::Running => "unfinished".into(),
    }
}

/// The static obstacles of `map` as the picture's plain data (none without a map).
pub fn obstacles(map: Option<&StaticMap>) -> Vec<viz::Obstacle> {
    map.map_or(&[][..], StaticMap::shapes)
        .iter()
        .map(|shape| viz::Obstacle {
            kind: match shape.kind {
                ShapeKind::Polygon => viz::ObstacleKind::Solid,
                ShapeKind::Wall => viz::ObstacleKind::Wall,
                ShapeKind::Boundary => viz::ObstacleKind::Boundary,
            },
            vertices: shape.vertices.iter().map(|v| (v.x, v.y)).collect(),
        })
        .collect()
}

/// `episode` (recorded with frames) ready to draw; `humans` are the humans at the start,
/// `attention[k]` the weights of the decision taken at frame `k` (empty for a policy without
/// attention), `map` the episode's static obstacles (`env.walls()`'s map; `None` on an open
/// floor).
pub fn trace(
    title: String,
    episode: &Episode,
    humans: &[HumanState],
    attention: &[Option<Vec<f64>>],
    map: Option<&StaticMap>,
) -> viz::EpisodeTrace {
    let robot = episode.frames.first().map(|f| f.robot);
    viz::EpisodeTrace {
        title,
        robot_radius_m: robot.map_or(0.3, |r| r.radius_m),
        robot_goal: robot.map_or((0.0, 4.0), |r| (r.goal.x, r.goal.y)),
        humans: humans
            .iter()
            .map(|h| viz::HumanInfo {
                radius_m: h.radius_m,
                standing: h.standing,
                goal: (h.goal.x, h.goal.y),
            })
            .collect(),
        obstacles: obstacles(map),
        frames: episode
            .frames
            .iter()
            .enumerate()
            .map(|(k, f)| viz::TraceFrame {
                time_s: f.time_s,
                robot: (f.robot.position.x, f.robot.position.y),
                heading_rad: f.robot.heading_rad,
                humans: f.humans.iter().map(|p| (p.x, p.y)).collect(),
                attention: attention.get(k).cloned().flatten(),
            })
            .collect(),
        outcome: outcome(&episode.summary),
    }
}

/// The panels' times when none are asked for: a third, two thirds and the end of the episode.
pub fn default_times(trace: &viz::EpisodeTrace) -> Vec<f64> {
    let end = trace.frames.last().map_or(0.0, |f| f.time_s);
    vec![end / 3.0, 2.0 * end / 3.0, end]
}

/// Plays one episode of `setting` (a setting name; default: the model's trained setting, else
/// `env2-invisible`) and `seed` with a trained policy (`Some((model, label))`) or the ORCA robot
/// (`None`), recording the policy's attention over the humans at each step, as the picture's
/// trace. An error when the policy fails during the episode.
pub fn play(
    loaded: Option<(&Model, &str)>,
    setting: Option<&str>,
    seed: u64,
) -> anyhow::Result<viz::EpisodeTrace> {
    let (method, sim_cfg, trained) = match loaded {
        Some((l, _)) => (l.method, l.sim.clone(), Some(l.setting.name().to_string())),
        None => (Method::Orca, SimConfig::default(), None),
    };
    let setting_name = setting
        .map(str::to_string)
        .or(trained)
        .unwrap_or_else(|| "env2-invisible".into());
    let setting = sim_cfg.resolve_settings(&[setting_name.as_str()])?[0];
    let mut env = Env::new(method.sim_config(&sim_cfg), setting, seed)
        .with_context(|| format!("cannot build {setting} seed {seed}"))?;
    let humans0 = env.humans().to_vec();
    let n = humans0.len();
    let mut attention: Vec<Option<Vec<f64>>> = Vec::new();
    let mut failure = None;
    let episode = match loaded {
        None => run_episode(&mut env, |env| env.orca_robot_action(0.0), true)?,
        Some((l, _)) => {
            let train = &l.train;
            let mut la = train.lookahead(method.human_order());
            let net = &l.net;
            run_episode(
                &mut env,
                |env| match la.decide(env, net) {
                    Ok(d) => {
                        let row = la.attention(net).and_then(|att| {
                            att.get(d.action * n..(d.action + 1) * n)
                                .map(|r| r.iter().map(|&w| w as f64).collect())
                        });
                        attention.push(row);
                        d.action
                    }
                    Err(e) => {
                        failure.get_or_insert(e);
                        attention.push(None);
                        0
                    }
                },
                true,
            )?
        }
    };
    if let Some(e) = failure {
        return Err(anyhow::Error::new(e).context("the policy failed during the episode"));
    }
    let who = loaded.map_or_else(
        || "orca".to_string(),
        |(_, label)| format!("{method} ({label})"),
    );
    let title = format!("{who} on {setting}, seed {seed}");
    let map = env.walls().map(|w| w.map());
    Ok(trace(title, &episode, &humans0, &attention, map))
}

#[cfg(test)]
mod tests {
    use std::path::{Path, PathBuf};

    use sha2::{Digest, Sha256};

    use super::*;

    fn root() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
    }

    /// The pictures below were drawn with DejaVu Sans (text widths place the legend).
    fn dejavu() {
        let font = viz::fonts::ensure().unwrap();
        assert!(
            font.ends_with("DejaVuSans.ttf"),
            "these pictures were drawn with DejaVu Sans, not {}: install fonts-dejavu-core",
            font.display()
        );
    }

    /// `(polylines of `stroke` at `width` px, polygons filled with `fill`)` in an SVG.
    fn count_shapes(svg: &str, stroke: &str, width: u32, fill: &str) -> (usize, usize) {
        let lines = svg
            .lines()
            .filter(|l| {
                l.starts_with("<polyline")
                    && l.contains(&format!("stroke=\"{stroke}\""))
                    && l.contains(&format!("stroke-width=\"{width}\""))
            })
            .count();
        let polygons = svg
            .lines()
            .filter(|l| l.starts_with("<polygon") && l.contains(&format!("fill=\"{fill}\"")))
            .count();
        (lines, polygons)
    }

    /// A paper episode draws exactly as before walls existed: the shipped FSRL model's test
    /// episode is the README's picture byte for byte (SVG, PNG and the GIF, drawn as
    /// docs/make-pictures.sh draws them), and the ORCA robot's env2-invisible episode is the
    /// SVG drawn before walls came (its SHA-256).
    #[test]
    fn a_paper_episode_is_drawn_as_before_walls() {
        dejavu();
        let model = root().join("models/fsrl-env1-invisible-s0.fsrlm");
        let (model, _) = crate::policy_file::load_policy(&model).unwrap();
        let trace = play(Some((&model, "models/fsrl-env1-invisible-s0")), None, 1000).unwrap();
        assert!(trace.obstacles.is_empty());
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("episode");
        let times_s = default_times(&trace);
        viz::save(
            &viz::Trajectory {
                trace: trace.clone(),
                times_s,
            },
            &stem,
        )
        .unwrap();
        viz::save_gif(&trace, &viz::with_ext(&stem, "gif"), 300, 150, 2).unwrap();
        for ext in ["svg", "png", "gif"] {
            let ours = std::fs::read(viz::with_ext(&stem, ext)).unwrap();
            let shipped =
                std::fs::read(root().join(format!("docs/pictures/episode.{ext}"))).unwrap();
            assert!(ours == shipped, "episode.{ext} differs from docs/pictures'");
        }

        let trace = play(None, Some("env2-invisible"), 1000).unwrap();
        let times_s = default_times(&trace);
        let svg = viz::to_svg_string(&viz::Trajectory { trace, times_s }).unwrap();
        assert!(!svg.contains("walls and obstacles"));
        assert_eq!(
            format!("{:x}", Sha256::digest(svg.as_bytes())),
            "b4422dbc71a45e94d3a24243964adcd8a67be4fddd08753b11b81f59432f8642"
        );
    }

    /// Every walled setting's picture draws its map: a corridor's two walls and a doorway's
    /// four as thick lines in every panel, a room's bounding wall as a thick outline and its
    /// furniture filled, the pillars filled; the legend names them.
    #[test]
    fn a_walled_episode_draws_its_walls() {
        for setting in sim::Setting::WALLED {
            let name = setting.name();
            let trace = play(None, Some(name), 1000).unwrap();
            let env = Env::new(SimConfig::default(), setting, 1000).unwrap();
            let map = env.walls().expect("a walled setting has walls").map();
            let kinds = |k: ShapeKind| map.shapes().iter().filter(|s| s.kind == k).count();
            let (walls, solids, boundaries) = (
                kinds(ShapeKind::Wall),
                kinds(ShapeKind::Polygon),
                kinds(ShapeKind::Boundary),
            );
            assert_eq!(trace.obstacles, obstacles(Some(map)), "{name}");
            assert!(walls + solids + boundaries > 0, "{name}");
            let times_s = default_times(&trace);
            let panels = times_s.len();
            let svg = viz::to_svg_string(&viz::Trajectory { trace, times_s }).unwrap();
            assert!(svg.contains("walls and obstacles"), "{name}");
            // Thick walls (4 px) and bounding walls, and each solid's fill and 1-px outline.
            let (thick, filled) = count_shapes(&svg, "#454545", 4, "#A8A8A8");
            let (outlines, _) = count_shapes(&svg, "#454545", 1, "#A8A8A8");
            assert_eq!(thick, panels * (walls + boundaries), "{name}");
            assert_eq!(filled, panels * solids, "{name}");
            assert_eq!(outlines, panels * solids, "{name}");
        }
        let paper = play(None, Some("env1-visible"), 1000).unwrap();
        assert!(paper.obstacles.is_empty());
    }

    #[test]
    fn a_wall_collision_is_told_apart_from_a_collision_with_a_person() {
        let mut summary = EpisodeSummary {
            outcome: Outcome::Collision,
            steps: 17,
            time_s: 4.25,
            danger_steps: 0,
            path_length_m: 1.0,
            total_abs_rotation_rad: 0.0,
            return_sum: -0.25,
            min_closest_m: 0.0,
            min_danger_m: f64::INFINITY,
            wall_collision: true,
            frozen: false,
        };
        assert_eq!(outcome(&summary), "wall collision at 4.25 s");
        summary.wall_collision = false;
        assert_eq!(outcome(&summary), "collision at 4.25 s");
        summary.outcome = Outcome::ReachGoal;
        assert_eq!(outcome(&summary), "success after 4.25 s");
    }
}
