//! Training speed, measured in one run:
//! - one decision (10 humans × 51 actions through SARL, featurisation and lookahead included),
//!   next to CrowdNav's 136 ms;
//! - the paper schedule (3000 demonstrations, 50 imitation epochs, 10,000 RL episodes of 100
//!   batches) for one setting: demonstrations and one imitation epoch measured in full, a
//!   200-episode RL run measured, everything extrapolated; next to the 2-hour target and
//!   CrowdNav's ~20 hours.
//!
//! `cargo bench -p learner --bench schedule` (FSRL_SCHEDULE_RL_EPISODES overrides the 200)

use std::time::Instant;

use learner::LearnerCore;
use policy::lookahead::Lookahead;
use policy::method::{Method, RunSpec, TrainConfig};
use policy::rollout::{episode_seed, rollout, Behaviour};
use policy::{NetConfig, ValueNet};
use sim::{Env, SimConfig};

const CROWDNAV_DECISION_MS: f64 = 136.0;
const CROWDNAV_SCHEDULE_H: f64 = 20.0;

fn decision_ms() -> f64 {
    let net = ValueNet::new(NetConfig::sarl(), 1).unwrap();
    let mut env = Env::new(
        SimConfig::default(),
        "env1-invisible".parse().unwrap(),
        1000,
    )
    .unwrap();
    for _ in 0..8 {
        let a = env.orca_robot_action(0.0);
        env.step(a).unwrap();
    }
    let mut la = Lookahead::new(0.9, Default::default(), policy::joint::HumanOrder::AsGiven);
    for _ in 0..20 {
        la.decide(&mut env, &net).unwrap();
    }
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        let t = Instant::now();
        for _ in 0..100 {
            std::hint::black_box(la.decide(&mut env, &net).unwrap());
        }
        best = best.min(t.elapsed().as_secs_f64() * 1e3 / 100.0);
    }
    best
}

/// CPU time of this process so far (all threads, live or finished; `/proc/self/stat` utime +
/// stime, 10 ms resolution), to see through contention on a shared machine.
fn process_cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // Fields after the command name (which may contain spaces) start at field 3 (state).
    let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else {
        return f64::NAN;
    };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    // utime and stime are fields 14 and 15, i.e. 11 and 12 after the state field.
    (ticks(11) + ticks(12)) / 100.0
}

fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "all cores".into());
    let d = decision_ms();
    println!("one decision (SARL, 10 humans x 51 actions, lookahead incl.): {d:.3} ms = {:.0}x faster than CrowdNav (136 ms)", CROWDNAV_DECISION_MS / d);

    let rl_measured: u64 = std::env::var("FSRL_SCHEDULE_RL_EPISODES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    // The paper's schedule (configs/paper.toml), not the default short one.
    let mut train = TrainConfig::default();
    train.imitation.episodes = 3000;
    train.imitation.epochs = 50;
    train.rl.episodes = 10_000;
    train.rl.epsilon_decay_episodes = 4000;
    train.rl.batches_per_episode = 100;
    let spec = RunSpec {
        method: Method::Fsrl,
        setting: "env1-invisible".parse().unwrap(),
        sim: SimConfig::default(),
        train: train.clone(),
        seed: 0,
    };
    let mut core = LearnerCore::new(spec.method, train.clone(), 10, 0.25, 0).unwrap();
    // Demonstrations, in full.
    let t = Instant::now();
    let mut env = Env::new(spec.method_sim(), spec.setting, 0).unwrap();
    for k in 0..train.imitation.episodes {
        let ep = rollout(
            &mut env,
            episode_seed(0, 0, k),
            Behaviour::Orca {
                safety_space_m: 0.15,
            },
        )
        .unwrap();
        core.add_episode(&ep, true).unwrap();
    }
    let demos_s = t.elapsed().as_secs_f64();
    // One imitation epoch over everything, times 50.
    let t = Instant::now();
    core.imitation(1, |_, _| {}).unwrap();
    let epoch_s = t.elapsed().as_secs_f64();
    core.start_rl().unwrap();
    // RL episodes with 100 batches each.
    let mut la = Lookahead::new(
        train.gamma,
        train.human_model.into(),
        spec.method.human_order(),
    );
    let load_before = loadavg();
    let t = Instant::now();
    let cpu0 = process_cpu_s();
    let (mut sim_s, mut steps) = (0.0, 0u64);
    for k in 0..rl_measured {
        let eps = core.epsilon();
        let ts = Instant::now();
        let ep = rollout(
            &mut env,
            episode_seed(0, 1, k),
            Behaviour::Net {
                net: core.online(),
                lookahead: &mut la,
                epsilon: eps,
                policy_version: 0,
            },
        )
        .unwrap();
        sim_s += ts.elapsed().as_secs_f64();
        steps += ep.steps() as u64;
        core.add_episode(&ep, false).unwrap();
        core.train_rl(train.rl.batches_per_episode).unwrap();
    }
    let rl_s = t.elapsed().as_secs_f64();
    let rl_cpu_s = process_cpu_s() - cpu0;
    let per_ep = rl_s / rl_measured as f64;
    let il_total = demos_s + epoch_s * train.imitation.epochs as f64;
    let rl_total = per_ep * train.rl.episodes as f64;
    let total_h = (il_total + rl_total) / 3600.0;
    let updates = core.counters().updates as f64;
    println!(
        "\n== paper schedule, FSRL on env1-invisible, one process, rayon threads: {threads} =="
    );
    println!(
        "demonstrations: {} episodes in {demos_s:.1} s",
        train.imitation.episodes
    );
    println!(
        "imitation: 1 epoch over {} transitions in {epoch_s:.1} s -> 50 epochs {:.1} min",
        core.replay().len(),
        epoch_s * 50.0 / 60.0
    );
    println!(
        "RL: {rl_measured} episodes ({steps} steps, {} updates) in {rl_s:.1} s = {per_ep:.3} s/episode (simulation+decisions {:.0}%, learning {:.0}%)",
        updates as u64,
        100.0 * sim_s / rl_s,
        100.0 * (rl_s - sim_s) / rl_s
    );
    println!(
        "RL CPU time (all threads): {rl_cpu_s:.1} s = {:.3} s/episode, {:.2} cores busy on average | load average before {load_before}, after {}",
        rl_cpu_s / rl_measured as f64,
        rl_cpu_s / rl_s,
        loadavg()
    );
    println!("extrapolated: imitation {:.2} h + RL {:.2} h = {total_h:.2} h (target <= 2 h; CrowdNav ~{CROWDNAV_SCHEDULE_H} h here = {:.1}x)", il_total / 3600.0, rl_total / 3600.0, CROWDNAV_SCHEDULE_H / total_h);
}
