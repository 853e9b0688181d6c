//! Emulated hosts with their own CPU budget (issue 34, item 3): the router on a hub, the
//! learner on its own host, N = 1, 2, 4 actor hosts, each host a network namespace joined to the
//! hub by a veth pair and each host's processes in its own CPU cgroup with a quota (learner host
//! 1 core and 1 update thread, each actor host 0.25 core, the hub 0.5 core), every process the
//! real `fsrl` binary with the `deploy/` configs (TLS, per-role users, access control). SARL on
//! env1-invisible. For each N, two schedules, each a fresh cluster, measured in one run:
//!
//! - learner updates off (`batches_per_episode = 0`): what the actor hosts deliver;
//! - the fast schedule's fixed 20 batches per episode: what a run gets, and where the learner's
//!   ceiling is;
//! - the adaptive mode (`replay_ratio = { min = 2, max = 20 }`, rounds of 20 updates): the
//!   learner trains flat out and more actor hosts lower the updates per episode, so episodes/s
//!   grow with N until the learner's ceiling at 2 updates per episode.
//!
//! Per cluster: episodes/s, updates/s, realised updates per episode (replay ratio), the
//! learner's policy lag (mean, p95), bytes/s into and out of the router (the hub's ends of the
//! veths), and every process's CPU use against its host's quota (and how often the host was
//! throttled). Then a cost model from the measured actor CPU per episode and the stated learner
//! update cost, against the measured rates.
//!
//! Needs root, `ip netns` and a CPU cgroup controller (v1 or v2); skips with a message
//! otherwise. About 3 minutes once built. `cargo bench --workspace --bench hosts`

#[path = "../tests/multihost_support/mod.rs"]
mod multihost_support;

use std::time::Duration;

use mh::budget::{self, Measured, Spec};
use multihost_support as mh;

const ACTOR_CORES: f64 = 0.25;
const LEARNER_CORES: f64 = 1.0;
const HUB_CORES: f64 = 0.5;
/// µs per SARL update on one thread and the intake per episode (BENCHMARKS.md, "The learner's
/// ceiling").
const UPDATE_1T_S: f64 = 9345e-6;
const INTAKE_S: f64 = 34e-6;

fn main() {
    if mh::helper_main() {
        return;
    }
    if let Some(why) = mh::netns_unavailable().or_else(mh::cgroup::cgroups_unavailable) {
        println!("hosts benchmark skipped: {why}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (hosts, actor_hosts) =
        budget::make_hosts("h", 4, dir.path()).expect("making the emulated hosts");
    println!(
        "emulated hosts: learner {LEARNER_CORES} core (1 update thread), actor hosts {ACTOR_CORES} core each, hub (router + observer) {HUB_CORES} core; cgroup {:?}",
        mh::cgroup::flavour().unwrap()
    );
    let mut results: Vec<(Schedule, Vec<Measured>)> = Vec::new();
    for (schedule, measure) in [
        (Schedule::Off, 20u64),
        (Schedule::Fixed, 30),
        (Schedule::Adaptive, 30),
    ] {
        let (batches, replay_ratio) = match schedule {
            Schedule::Off => (0, None),
            Schedule::Fixed => (20, None),
            Schedule::Adaptive => (20, Some(ADAPTIVE)),
        };
        let mut row = Vec::new();
        for n in [1usize, 2, 4] {
            let spec = Spec {
                actors: n,
                actor_cores: ACTOR_CORES,
                learner_cores: LEARNER_CORES,
                learner_threads: 1,
                hub_cores: HUB_CORES,
                batches_per_episode: batches,
                replay_ratio,
                warm_episodes: 10.0,
                measure: Duration::from_secs(measure),
                patience: Duration::from_secs(120),
                log: "warn".into(),
            };
            let run_id = format!("hosts-{}-n{n}-{}", schedule.tag(), std::process::id());
            let m = budget::run(&hosts, &actor_hosts, dir.path(), &run_id, &spec, &[])
                .unwrap_or_else(|e| panic!("{run_id}: {e}"));
            eprintln!(
                "  measured {run_id}: {:.2} episodes/s, {:.1} updates/s",
                m.episodes_per_s, m.updates_per_s
            );
            row.push(m);
        }
        results.push((schedule, row));
    }
    for (schedule, row) in &results {
        print_table(*schedule, row);
    }
    cost_model(&results);
    drop(hosts);
}

/// The learner's schedule of one set of clusters.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Schedule {
    /// `batches_per_episode = 0`.
    Off,
    /// 20 batches per episode.
    Fixed,
    /// `replay_ratio` = [`ADAPTIVE`].
    Adaptive,
}

impl Schedule {
    fn tag(self) -> &'static str {
        match self {
            Schedule::Off => "off",
            Schedule::Fixed => "b20",
            Schedule::Adaptive => "adaptive",
        }
    }
}

/// The adaptive mode's bounds, updates per episode (docs/REPRODUCTION.md, Experiment 17).
const ADAPTIVE: (f64, f64) = (2.0, 20.0);

fn print_table(schedule: Schedule, row: &[Measured]) {
    let what = match schedule {
        Schedule::Off => "learner updates off".to_string(),
        Schedule::Fixed => "fixed 20 batches per episode".to_string(),
        Schedule::Adaptive => format!(
            "adaptive replay ratio, {} to {} updates per episode",
            ADAPTIVE.0, ADAPTIVE.1
        ),
    };
    println!(
        "\n{what} ({} s measured per N):",
        row[0].spec.measure.as_secs()
    );
    println!("| actor hosts | episodes/s | vs N=1 | updates/s | updates/episode | policy lag mean / p95 | router in / out (MB/s) | CPU per actor (quota {ACTOR_CORES}) | actor hosts throttled | actors waiting | learner CPU (quota {LEARNER_CORES}) | router CPU | steps/episode |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let e1 = row[0].episodes_per_s;
    for m in row {
        let actors: Vec<f64> = m.actors().map(|p| p.cores).collect();
        let thr: Vec<f64> = m.actors().map(|p| p.host_throttled).collect();
        let cpu = |name: &str| {
            m.procs
                .iter()
                .find(|p| p.name == name)
                .map_or(f64::NAN, |p| p.cores)
        };
        println!(
            "| {} | {:.2} | {:.2}× | {:.1} | {:.2} | {:.1} / {:.0} | {:.2} / {:.2} | {} | {:.0} % | {:.0} % | {:.2} | {:.2} | {:.0} |",
            m.spec.actors,
            m.episodes_per_s,
            m.episodes_per_s / e1,
            m.updates_per_s,
            m.updates_per_episode,
            m.lag_mean,
            m.lag_p95,
            m.router_in_bps / 1e6,
            m.router_out_bps / 1e6,
            range(&actors),
            100.0 * thr.iter().sum::<f64>() / thr.len() as f64,
            100.0 * m.actor_wait_frac,
            cpu("learner"),
            cpu("router"),
            m.steps_per_episode,
        );
    }
}

fn range(v: &[f64]) -> String {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if (hi - lo).abs() < 0.005 {
        format!("{lo:.2}")
    } else {
        format!("{lo:.2}–{hi:.2}")
    }
}

/// The cost model of BENCHMARKS.md ("Emulated hosts with their own CPU budget"), its
/// parameters from this run, against every measured rate:
///
/// `episodes/s = min(N·c / (s·L + w·N), c_l / (B·u))`
///
/// for N actor hosts of c cores (one actor process each), episodes of L steps, actor CPU s per
/// step and w per weights message received (the learner broadcasts weights after every episode
/// it takes in, so each actor receives N per episode of its own), and a learner of c_l ≤ 1 core
/// (one update thread) doing B updates of u CPU seconds per episode. s and w are fitted to the
/// updates-off runs with N = 1 and 4, u is the learner's CPU per update in the learner-bound
/// run (B = 20, N = 4); everything else is a prediction.
fn cost_model(results: &[(Schedule, Vec<Measured>)]) {
    let off = &results[0].1;
    let (a1, l1) = (off[0].actor_cpu_s_per_episode, off[0].steps_per_episode);
    let (a4, l4) = (off[2].actor_cpu_s_per_episode, off[2].steps_per_episode);
    let s = (4.0 * a1 - a4) / (4.0 * l1 - l4);
    let w = a1 - s * l1;
    let u = results[1].1[2].learner_cpu_s_per_update;
    println!(
        "\ncost model: actor CPU per step s = {:.3} ms, per weights message received w = {:.2} ms (fitted to updates off, N = 1 and 4); learner CPU per update u = {:.2} ms (intake included; B = 20, N = 4), stated {:.2} ms (1 thread)",
        s * 1e3,
        w * 1e3,
        u * 1e3,
        UPDATE_1T_S * 1e3
    );
    for (schedule, row) in results {
        for m in row {
            let n = m.spec.actors as f64;
            let learner_cores = m.spec.learner_cores.min(1.0);
            let (actors, learner, stated) = match schedule {
                // Weights after every episode: each actor receives N messages per episode.
                Schedule::Off | Schedule::Fixed => {
                    let batches = if *schedule == Schedule::Off {
                        0.0
                    } else {
                        20.0
                    };
                    let actors = n * m.spec.actor_cores / (s * m.steps_per_episode + w * n);
                    let learner = |u: f64| {
                        if batches == 0.0 {
                            f64::INFINITY
                        } else {
                            learner_cores / (batches * u)
                        }
                    };
                    (
                        actors,
                        learner(u),
                        actors.min(learner(UPDATE_1T_S + INTAKE_S / batches.max(1.0))),
                    )
                }
                // Weights after every round of 20 updates (a rate the learner sets, whatever
                // N); the learner takes episodes as long as it has done `min` updates for each.
                Schedule::Adaptive => {
                    let rounds_per_s = m.updates_per_s / 20.0;
                    let actors =
                        n * (m.spec.actor_cores - w * rounds_per_s) / (s * m.steps_per_episode);
                    let learner = learner_cores / (ADAPTIVE.0 * u);
                    (
                        actors,
                        learner,
                        actors.min(learner_cores / (ADAPTIVE.0 * UPDATE_1T_S + INTAKE_S)),
                    )
                }
            };
            let predicted = actors.min(learner);
            println!(
                "  {:>8} N={}: L = {:.0} steps; predicted min(actors {actors:.2}, learner {learner:.2}) = {predicted:.2} episodes/s, measured {:.2} ({:+.0} %); with the stated update cost {stated:.2} ({:+.0} %); learner CPU per update {:.2} ms, actor CPU per episode {:.1} ms",
                schedule.tag(),
                m.spec.actors,
                m.steps_per_episode,
                m.episodes_per_s,
                100.0 * (m.episodes_per_s / predicted - 1.0),
                100.0 * (m.episodes_per_s / stated - 1.0),
                m.learner_cpu_s_per_update * 1e3,
                m.actor_cpu_s_per_episode * 1e3,
            );
        }
    }
}
