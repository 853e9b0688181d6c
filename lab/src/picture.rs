//! A simulated episode as `viz`'s plain data: the one conversion behind the episode pictures of
//! `fsrl plot episode` and `fsrl sim --svg` (viz draws; it knows nothing of the simulator).

use anyhow::Context;
use learner::model::Model;
use policy::method::Method;
use sim::{run_episode, Env, Episode, EpisodeSummary, HumanState, Outcome, SimConfig};

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
    Ok(trace(title, &episode, &humans0, &attention))
}
