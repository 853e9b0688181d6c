//! How much of the crowd a SARL-network policy attends to: for each model file, greedy test
//! episodes of its trained setting, and per decision the share of humans whose attention weight
//! (of the chosen candidate) is below 0.01, the largest weight, and, in a collision, the weight
//! the policy gave the human it hit at its last decision (`docs/REPRODUCTION.md`, Experiment 5);
//! for timeouts, how close the robot came to its goal and how many ended farther from it than they
//! started (a robot that retreats from the crowd); and Disc. with the share of its danger steps
//! whose nearest human (at the end of the step) stands (Experiment 14: where the foresight terms'
//! discomfort comes from in Env 2).
//!
//! ```sh
//! cargo run --release --example attention -- [--episodes 100] MODEL.fsrlm...
//! ```

use anyhow::{bail, Context};
use learner::model::load_policy;
use sim::{run_episode, Env, Outcome};

/// Below this weight a human counts as ignored.
const IGNORED: f32 = 0.01;

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut episodes = 100u64;
    if let Some(k) = args.iter().position(|a| a == "--episodes") {
        let n = args.get(k + 1).context("--episodes needs a number")?;
        episodes = n.parse().with_context(|| format!("--episodes: `{n}`"))?;
        args.drain(k..k + 2);
    }
    if args.is_empty() {
        bail!("usage: attention [--episodes N] MODEL.fsrlm...");
    }
    println!("| model | episodes | Succ. | Coll. | Timeout | humans ignored per decision | max weight | hit human's weight (mean) | hit human ignored | hits on standing | timeouts: closest to goal (m, mean) | timeouts ending farther than start | Disc. | danger steps at standing humans |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for path in &args {
        let (model, _) =
            load_policy(path.as_ref()).with_context(|| format!("cannot load {path}"))?;
        let n = model.sim.humans.count;
        let (mut outcomes, mut ignored, mut maxw, mut decisions) = ([0u32; 3], 0.0, 0.0, 0u64);
        let (mut hit_w, mut hit_ignored, mut hit_standing) = (Vec::new(), 0u32, 0u32);
        let (mut closest, mut retreats) = (Vec::new(), 0u32);
        let (mut steps, mut danger, mut danger_standing) = (0u64, 0u64, 0u64);
        for seed in model.train.test_seed_start..model.train.test_seed_start + episodes {
            let mut env = Env::new(model.sim.clone(), model.setting, seed)?;
            let standing: Vec<bool> = env.humans().iter().map(|h| h.standing).collect();
            let mut la = model.train.lookahead(model.method.human_order());
            let mut last: Vec<f32> = Vec::new();
            let mut failure = None;
            let ep = run_episode(
                &mut env,
                |env| match la.decide(env, &model.net) {
                    Ok(d) => {
                        if let Some(row) = la
                            .attention(&model.net)
                            .and_then(|a| a.get(d.action * n..(d.action + 1) * n))
                        {
                            ignored +=
                                row.iter().filter(|&&w| w < IGNORED).count() as f64 / n as f64;
                            maxw += row.iter().copied().fold(0.0, f32::max) as f64;
                            decisions += 1;
                            last = row.to_vec();
                        }
                        d.action
                    }
                    Err(e) => {
                        failure.get_or_insert(e);
                        0
                    }
                },
                true,
            )?;
            if let Some(e) = failure {
                bail!("{path}: the policy failed: {e}");
            }
            let k = match ep.summary.outcome {
                Outcome::ReachGoal => 0,
                Outcome::Collision => 1,
                _ => 2,
            };
            outcomes[k] += 1;
            // frames[i + 1] is the state after step i.
            for (step, f) in ep.steps.iter().zip(ep.frames.iter().skip(1)) {
                steps += 1;
                if step.eval.danger {
                    danger += 1;
                    danger_standing += u64::from(nearest(f).is_some_and(|i| standing[i]));
                }
            }
            if k == 1 && !last.is_empty() {
                // The human hit: the nearest one in the last frame (centre distance; the
                // humans share one radius, so the boundary distance orders them alike).
                let f = ep.frames.last().context("no frames")?;
                let hit = nearest(f).context("no humans")?;
                hit_w.push(last[hit] as f64);
                hit_ignored += u32::from(last[hit] < IGNORED);
                hit_standing += u32::from(standing[hit]);
            }
            if k == 2 {
                let to_goal = |f: &sim::Frame| f.robot.distance_to_goal();
                let (start, end) = ep
                    .frames
                    .first()
                    .zip(ep.frames.last())
                    .context("no frames")?;
                closest.push(ep.frames.iter().map(to_goal).fold(f64::INFINITY, f64::min));
                retreats += u32::from(to_goal(end) > to_goal(start));
            }
        }
        let e = episodes as f64;
        let d = decisions.max(1) as f64;
        let (hits, timeouts) = (hit_w.len(), closest.len());
        let (mean_hit, mean_closest) = (mean_cell(&hit_w, 3), mean_cell(&closest, 2));
        println!(
            "| {path} | {episodes} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {mean_hit} | {hit_ignored}/{hits} | {hit_standing}/{hits} | {mean_closest} | {retreats}/{timeouts} | {:.3} | {:.2} |",
            outcomes[0] as f64 / e,
            outcomes[1] as f64 / e,
            outcomes[2] as f64 / e,
            ignored / d,
            maxw / d,
            danger as f64 / steps.max(1) as f64,
            danger_standing as f64 / danger.max(1) as f64,
        );
    }
    Ok(())
}

/// The human nearest the robot (centre distance) in a frame.
fn nearest(f: &sim::Frame) -> Option<usize> {
    let d = |i: usize| (f.humans[i] - f.robot.position).norm();
    (0..f.humans.len()).min_by(|&a, &b| d(a).total_cmp(&d(b)))
}

/// A table cell: the mean of `values` with `decimals` digits, or a dash when there are none.
fn mean_cell(values: &[f64], decimals: usize) -> String {
    if values.is_empty() {
        return "–".to_string();
    }
    format!(
        "{:.decimals$}",
        values.iter().sum::<f64>() / values.len() as f64
    )
}
