//! The learner's ceiling, measured in one run: µs per V-learning update (a batch of 100 from a
//! full-size replay: target lookup, forward, backward, Adam) for each network with 1 and 2
//! rayon threads, the cost of taking in one episode (checks, featurisation, value targets), one
//! actor core's episodes per second, and from these the episodes per second one learner can
//! absorb at 20 and 100 batches per episode: how many actor cores one learner can keep busy.
//!
//! `cargo bench -p learner --bench ceiling` (FSRL_CEILING_UPDATES overrides the 300 timed
//! updates per case; each case keeps the best of 3 rounds).

use std::time::Instant;

use learner::LearnerCore;
use policy::lookahead::Lookahead;
use policy::method::{Method, RunSpec, TrainConfig};
use policy::rollout::{episode_seed, rollout, Behaviour, EpisodeData};
use sim::{Env, SimConfig};

fn spec(method: Method) -> RunSpec {
    RunSpec {
        method,
        setting: "env1-invisible".parse().unwrap(),
        sim: SimConfig::default(),
        train: TrainConfig::default(),
        seed: 0,
    }
}

/// ORCA demonstrations of `spec`'s setting (the replay's content does not change the cost).
fn demos(spec: &RunSpec, n: u64) -> Vec<EpisodeData> {
    let mut env = Env::new(spec.method_sim(), spec.setting, 0).unwrap();
    (0..n)
        .map(|k| {
            rollout(
                &mut env,
                episode_seed(0, 0, k),
                Behaviour::Orca {
                    safety_space_m: 0.15,
                },
            )
            .unwrap()
        })
        .collect()
}

/// A core with `episodes` in replay, in its RL phase, targets computed.
fn core(spec: &RunSpec, episodes: &[EpisodeData]) -> LearnerCore {
    let mut core = LearnerCore::new(spec.method, spec.train.clone(), 10, 0.25, 0).unwrap();
    for ep in episodes {
        core.add_episode(ep, true).unwrap();
    }
    core.start_rl().unwrap();
    core.train_rl(1).unwrap();
    core
}

/// Best-of-3 µs per update with `threads` rayon threads.
fn update_us(core: &mut LearnerCore, threads: usize, updates: u32) -> f64 {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        core.train_rl(20).unwrap();
        (0..3)
            .map(|_| {
                let t = Instant::now();
                // One round of `updates` (bumps the version once; the target-network refresh
                // every 50 RL episodes is not triggered: the episode count does not move).
                core.train_rl(updates).unwrap();
                t.elapsed().as_secs_f64() * 1e6 / updates as f64
            })
            .fold(f64::INFINITY, f64::min)
    })
}

/// Best-of-3 µs to take in one RL episode (checks, features, value targets; no update).
fn intake_us(core: &mut LearnerCore, episodes: &[EpisodeData]) -> f64 {
    (0..3)
        .map(|_| {
            let t = Instant::now();
            for ep in episodes {
                core.add_episode(ep, false).unwrap();
            }
            t.elapsed().as_secs_f64() * 1e6 / episodes.len() as f64
        })
        .fold(f64::INFINITY, f64::min)
}

/// One actor core's RL episodes per second (greedy with a fresh network; 20 episodes).
fn actor_episodes_per_s(spec: &RunSpec, core: &LearnerCore) -> f64 {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(|| {
        let mut env = Env::new(spec.method_sim(), spec.setting, 0).unwrap();
        let mut la = Lookahead::new(0.9, Default::default(), spec.method.human_order());
        let t = Instant::now();
        let n = 20;
        for k in 0..n {
            rollout(
                &mut env,
                episode_seed(0, 100, k),
                Behaviour::Net {
                    net: core.online(),
                    lookahead: &mut la,
                    epsilon: 0.1,
                    policy_version: 0,
                },
            )
            .unwrap();
        }
        n as f64 / t.elapsed().as_secs_f64()
    })
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let updates: u32 = std::env::var("FSRL_CEILING_UPDATES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(300);
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "learner ceiling: batch 100, replay of 1000 ORCA episodes, {updates} updates per round, best of 3; load average {}",
        load.split_whitespace().take(3).collect::<Vec<_>>().join(" ")
    );
    println!("| network | update, 1 thread | update, 2 threads | 2 threads / 1 | intake per episode | absorbs at 20 batches/ep (2 threads) | at 100 | actor core ep/s | actor cores at 20 | at 100 |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for method in [Method::Sarl, Method::LstmRl] {
        let spec = spec(method);
        let eps = demos(&spec, 1000);
        let mut core = core(&spec, &eps);
        let one = update_us(&mut core, 1, updates);
        let two = update_us(&mut core, 2, updates);
        let intake = intake_us(&mut core, &eps[..50]);
        let actor = actor_episodes_per_s(&spec, &core);
        let absorb = |batches: f64| 1e6 / (batches * two + intake);
        println!(
            "| {} | {one:.0} µs | {two:.0} µs | {:.2}× | {intake:.0} µs | {:.2} ep/s | {:.2} ep/s | {actor:.2} | {:.1} | {:.1} |",
            method.net().unwrap().kind().name(),
            one / two,
            absorb(20.0),
            absorb(100.0),
            absorb(20.0) / actor,
            absorb(100.0) / actor,
        );
    }
}
