//! Simulator benchmarks: one ORCA step for 10 humans, and one full environment step (10 humans,
//! ORCA robot, reward with foresight terms). After criterion's statistics, a short report prints
//! steps per second and the ratios to RVO2 (C++) and CrowdNav (Python), measured in this run.
//!
//! `cargo bench -p sim`

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, Criterion, Throughput};
use sim::geom::Vec2f;
use sim::orca::{Orca, OrcaAgent, OrcaParams};
use sim::{run_episode, Env, Setting, SimConfig};

/// RVO2 C++ (-O3), 10 agents, on this kind of machine (issue 2).
const RVO2_STEPS_PER_S: f64 = 117_800.0;
/// CrowdNav's Python environment with 10 humans on this kind of machine (issue 2).
const CROWDNAV_ENV_STEPS_PER_S: f64 = 1_218.0;

/// States of a 10-human crossing, sampled along an episode, as ORCA agents.
fn orca_states() -> Vec<Vec<OrcaAgent>> {
    let mut env = Env::new(
        SimConfig::default(),
        "env1-invisible".parse().unwrap(),
        1000,
    )
    .unwrap();
    let mut states = Vec::new();
    for _ in 0..40 {
        states.push(
            env.humans()
                .iter()
                .map(|h| OrcaAgent {
                    position: Vec2f::new(h.position.x as f32, h.position.y as f32),
                    velocity: Vec2f::new(h.velocity.x as f32, h.velocity.y as f32),
                    pref_velocity: {
                        let d = h.goal - h.position;
                        let d = if d.norm() > 1.0 { d / d.norm() } else { d };
                        Vec2f::new(d.x as f32, d.y as f32)
                    },
                    radius_m: 0.31,
                    max_speed_mps: 1.0,
                    reciprocal: true,
                })
                .collect(),
        );
        env.step(0).unwrap();
    }
    states
}

fn orca_params() -> OrcaParams {
    OrcaParams {
        neighbor_dist_m: 10.0,
        max_neighbors: 10,
        time_horizon_s: 5.0,
        time_step_s: 0.25,
        time_horizon_obst_s: 5.0,
    }
}

/// One RVO2 `doStep` for every agent of `agents`: new velocities, then positions.
fn orca_step(orca: &mut Orca, agents: &mut [OrcaAgent], new_v: &mut [Vec2f]) {
    for (i, v) in new_v.iter_mut().enumerate() {
        *v = orca.new_velocity(i, agents);
    }
    for (a, v) in agents.iter_mut().zip(new_v.iter()) {
        a.velocity = *v;
        a.position += *v * 0.25;
    }
}

/// Runs full episodes with the ORCA robot until `steps` env steps were taken.
fn env_steps(env: &mut Env, seed: &mut u64, steps: u64) -> u64 {
    let mut done = 0;
    while done < steps {
        env.reset(*seed).unwrap();
        *seed += 1;
        let ep = run_episode(env, |env| env.orca_robot_action(0.0), false).unwrap();
        done += ep.summary.steps as u64;
    }
    done
}

fn bench(c: &mut Criterion) {
    let states = orca_states();
    let mut orca = Orca::new(orca_params());
    let mut new_v = vec![Vec2f::zeros(); 10];
    let mut g = c.benchmark_group("orca");
    g.throughput(Throughput::Elements(1));
    g.bench_function("step_10_agents", |b| {
        let mut k = 0;
        let mut agents = states[0].clone();
        b.iter(|| {
            agents.copy_from_slice(&states[k % states.len()]);
            k += 1;
            orca_step(&mut orca, black_box(&mut agents), &mut new_v);
        })
    });
    g.finish();

    let mut g = c.benchmark_group("env");
    for setting in ["env1-invisible", "env2-visible", "env3-visible"] {
        let s: Setting = setting.parse().unwrap();
        let mut env = Env::new(SimConfig::default(), s, 0).unwrap();
        let mut seed = 0;
        g.bench_function(format!("step_orca_robot_{setting}"), |b| {
            b.iter_custom(|iters| {
                let t = Instant::now();
                env_steps(&mut env, &mut seed, iters);
                t.elapsed()
            })
        });
    }
    g.finish();
}

/// Best of `rounds` timings of `f`, each running for about `each`; returns items per second.
fn rate(rounds: usize, each: Duration, mut f: impl FnMut() -> u64) -> f64 {
    let mut best = 0f64;
    for _ in 0..rounds {
        let t = Instant::now();
        let mut n = 0;
        while t.elapsed() < each {
            n += f();
        }
        best = best.max(n as f64 / t.elapsed().as_secs_f64());
    }
    best
}

fn report() {
    let states = orca_states();
    let mut orca = Orca::new(orca_params());
    let mut new_v = vec![Vec2f::zeros(); 10];
    let mut agents = states[0].clone();
    let mut k = 0;
    let orca_rate = rate(5, Duration::from_millis(400), || {
        for _ in 0..1000 {
            agents.copy_from_slice(&states[k % states.len()]);
            k += 1;
            orca_step(&mut orca, black_box(&mut agents), &mut new_v);
        }
        1000
    });
    println!("\n== sim report (one core, this run) ==");
    println!(
        "ORCA step, 10 agents:      {:>10.0} steps/s  ({:.2} µs/step)  = {:.2}x RVO2 C++ (117,800 steps/s)",
        orca_rate,
        1e6 / orca_rate,
        orca_rate / RVO2_STEPS_PER_S
    );
    for setting in ["env1-invisible", "env2-visible", "env3-visible"] {
        let mut env = Env::new(SimConfig::default(), setting.parse().unwrap(), 0).unwrap();
        let mut seed = 0;
        let env_rate = rate(5, Duration::from_millis(400), || {
            env_steps(&mut env, &mut seed, 2000)
        });
        println!(
            "env step {setting:<15}  {:>10.0} steps/s  ({:.2} µs/step)  = {:.0}x CrowdNav (1,218 steps/s)",
            env_rate,
            1e6 / env_rate,
            env_rate / CROWDNAV_ENV_STEPS_PER_S
        );
    }
}

criterion_group!(benches, bench);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    report();
}
