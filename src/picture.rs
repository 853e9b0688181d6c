//! A simulated episode as `viz`'s plain data: the one conversion behind the episode pictures of
//! `fsrl plot episode` and `fsrl sim --svg` (viz draws; it knows nothing of the simulator).

use sim::{Episode, EpisodeSummary, HumanState, Outcome};

/// How the episode ended, e.g. "success after 11.50 s".
pub fn outcome(summary: &EpisodeSummary) -> String {
    let t = summary.time_s;
    match summary.outcome {
        Outcome::ReachGoal => format!("success after {t:.2} s"),
        Outcome::Collision => format!("collision at {t:.2} s"),
        Outcome::Timeout => format!("timeout at {t:.2} s"),
        Outcome::Running => "unfinished".into(),
    }
}

/// `episode` (recorded with frames) ready to draw; `humans` are the humans at the start,
/// `attention[k]` the weights of the decision taken at frame `k` (empty for a policy without
/// attention).
pub fn trace(
    title: String,
    episode: &Episode,
    humans: &[HumanState],
    attention: &[Option<Vec<f64>>],
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
