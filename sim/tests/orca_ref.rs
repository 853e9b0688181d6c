//! Replays RVO2 v2.0.3 reference scenes (format `orca_ref v1`, and `orca_ref v2` with static
//! obstacles) two ways:
//!
//! - whole runs through [`sim::rvo::Simulator`] (RVO2's simulator: agent and obstacle k-d trees):
//!   from the initial state, every position and velocity of every step must equal RVO2's bit for
//!   bit, symmetric scenes included;
//! - one step at a time through [`sim::orca::Orca`] (what the environment's humans use): from the
//!   reference state at every step, the velocities must equal RVO2's for every agent of every
//!   non-symmetric scene (symmetric scenes have exactly equal distances, whose order only RVO2's
//!   agent tree reproduces).
//!
//! The scenes default to the repository's `testdata/orca_ref` and `testdata/orca_ref_obstacles`
//! (where they come from: `testdata/README.md`); `FSRL_ORCA_REF_DIR` names another directory, of
//! v1 and v2 files alike. Every `*.csv` below it (subdirectories included) is replayed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

mod support;

use sim::geom::Vec2f;
use sim::orca::{Orca, OrcaAgent, OrcaParams};
use sim::rvo::{ObstacleSet, Simulator};

struct Scene {
    params: OrcaParams,
    symmetric: bool,
    /// Vertex lists in `addObstacle` order (v2 files; none in v1).
    obstacles: Vec<Vec<Vec2f>>,
    /// (radius, max speed) per agent.
    agents: Vec<(f32, f32)>,
    /// rows[step][agent] = (px, py, vx, vy, pref_vx, pref_vy)
    rows: Vec<Vec<[f32; 6]>>,
}

fn kv<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    line.split_whitespace()
        .find_map(|tok| tok.strip_prefix(key).and_then(|r| r.strip_prefix('=')))
}

fn num(s: &str, what: &str, path: &Path) -> f32 {
    // %.9g round-trips float32: parse as f64 and cast, as the data's README says.
    s.trim()
        .parse::<f64>()
        .unwrap_or_else(|e| panic!("{}: bad number {what} = {s:?}: {e}", path.display())) as f32
}

fn parse(path: &Path) -> Scene {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let mut params = None;
    let mut symmetric = false;
    let mut agents = Vec::new();
    let mut obstacles: Vec<Vec<Vec2f>> = Vec::new();
    let mut rows: BTreeMap<usize, Vec<[f32; 6]>> = BTreeMap::new();
    for line in text.lines() {
        if let Some(meta) = line.strip_prefix('#') {
            let meta = meta.trim();
            if meta.starts_with("params") {
                let get = |k: &str| {
                    num(
                        kv(meta, k).unwrap_or_else(|| panic!("{}: no {k}", path.display())),
                        k,
                        path,
                    )
                };
                params = Some(OrcaParams {
                    neighbor_dist_m: get("neighbor_dist"),
                    max_neighbors: get("max_neighbors") as usize,
                    time_horizon_s: get("time_horizon"),
                    time_step_s: get("time_step"),
                    time_horizon_obst_s: get("time_horizon_obst"),
                });
            } else if meta.starts_with("scene_kind") {
                if let Some(p) = kv(meta, "perturbation") {
                    symmetric = num(p, "perturbation", path) == 0.0;
                }
            } else if let Some(rest) = meta.strip_prefix("agent,") {
                let f: Vec<&str> = rest.split(',').collect();
                assert!(f.len() >= 8, "{}: bad agent line {line}", path.display());
                agents.push((num(f[5], "radius", path), num(f[6], "max_speed", path)));
            } else if let Some(rest) = meta.strip_prefix("obstacle,") {
                let f: Vec<&str> = rest.split(',').collect();
                assert_eq!(f.len(), 4, "{}: bad obstacle line {line}", path.display());
                let (o, k): (usize, usize) = (
                    f[0].parse().expect("obstacle index"),
                    f[1].parse().expect("vertex index"),
                );
                assert!(
                    o <= obstacles.len(),
                    "{}: obstacles out of order",
                    path.display()
                );
                if o == obstacles.len() {
                    obstacles.push(Vec::new());
                }
                assert_eq!(
                    obstacles[o].len(),
                    k,
                    "{}: vertices out of order",
                    path.display()
                );
                obstacles[o].push(Vec2f::new(
                    num(f[2], "obstacle x", path),
                    num(f[3], "obstacle y", path),
                ));
            }
            continue;
        }
        if line.starts_with("step") || line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 9, "{}: bad row {line}", path.display());
        let step: usize = f[0].parse().expect("step index");
        let agent: usize = f[2].parse().expect("agent index");
        let entry = rows.entry(step).or_default();
        assert_eq!(entry.len(), agent, "{}: rows out of order", path.display());
        let mut r = [0f32; 6];
        for (k, v) in r.iter_mut().enumerate() {
            *v = num(f[3 + k], "row value", path);
        }
        entry.push(r);
    }
    let rows: Vec<Vec<[f32; 6]>> = rows.into_values().collect();
    assert!(rows.len() >= 2, "{}: fewer than two steps", path.display());
    for r in &rows {
        assert_eq!(r.len(), agents.len(), "{}: agent count", path.display());
    }
    Scene {
        params: params.unwrap_or_else(|| panic!("{}: no params line", path.display())),
        symmetric,
        obstacles,
        agents,
        rows,
    }
}

fn scene_files() -> (PathBuf, Vec<PathBuf>) {
    support::reference_csvs(
        "FSRL_ORCA_REF_DIR",
        &["orca_ref", "orca_ref_obstacles"],
        "ORCA",
    )
}

fn obstacle_set(scene: &Scene, path: &Path) -> ObstacleSet {
    ObstacleSet::new(&scene.obstacles)
        .unwrap_or_else(|e| panic!("{}: bad obstacles: {e}", path.display()))
}

#[test]
fn whole_runs_match_rvo2_bit_for_bit() {
    let (dir, files) = scene_files();
    let (mut compared, mut with_obstacles) = (0usize, 0usize);
    let mut worst_m = 0f32;
    let mut failures = Vec::new();
    for path in &files {
        let scene = parse(path);
        with_obstacles += usize::from(!scene.obstacles.is_empty());
        let mut sim = Simulator::new(scene.params, obstacle_set(&scene, path));
        for (i, r) in scene.rows[0].iter().enumerate() {
            sim.add_agent(Vec2f::new(r[0], r[1]), scene.agents[i].0, scene.agents[i].1);
        }
        'steps: for step in 0..scene.rows.len() - 1 {
            for (i, r) in scene.rows[step].iter().enumerate() {
                sim.set_pref_velocity(i, Vec2f::new(r[4], r[5]));
            }
            sim.do_step();
            for (i, (ours, theirs)) in sim.agents().iter().zip(&scene.rows[step + 1]).enumerate() {
                let rvo2_position = Vec2f::new(theirs[0], theirs[1]);
                let rvo2_velocity = Vec2f::new(theirs[2], theirs[3]);
                worst_m = worst_m.max((ours.position - rvo2_position).norm());
                compared += 1;
                let same = |a: Vec2f, b: Vec2f| {
                    a.x.to_bits() == b.x.to_bits() && a.y.to_bits() == b.y.to_bits()
                };
                if !same(ours.position, rvo2_position) || !same(ours.velocity, rvo2_velocity) {
                    failures.push(format!(
                        "{} step {} agent {i}: ours p {:?} v {:?}, RVO2 p {rvo2_position:?} v {rvo2_velocity:?}",
                        path.display(),
                        step + 1,
                        ours.position,
                        ours.velocity,
                    ));
                    break 'steps;
                }
            }
        }
    }
    println!(
        "replayed {} scenes ({with_obstacles} with obstacles) from {}: {compared} agent-steps, \
         worst position difference {worst_m:e} m",
        files.len(),
        dir.display()
    );
    assert!(
        failures.is_empty(),
        "{} of {} scenes differ from RVO2 (first difference of each):\n{}",
        failures.len(),
        files.len(),
        failures.join("\n")
    );
}

#[test]
fn one_step_velocities_match_rvo2() {
    let (dir, files) = scene_files();
    let (mut scenes, mut compared) = (0usize, 0usize);
    let mut failures = Vec::new();
    for path in &files {
        let scene = parse(path);
        if scene.symmetric {
            println!("skipping symmetric scene {}", path.display());
            continue;
        }
        scenes += 1;
        let obstacles = obstacle_set(&scene, path);
        let mut orca = Orca::new(scene.params);
        let mut agents = Vec::with_capacity(scene.agents.len());
        for step in 0..scene.rows.len() - 1 {
            agents.clear();
            for (i, r) in scene.rows[step].iter().enumerate() {
                agents.push(OrcaAgent {
                    position: Vec2f::new(r[0], r[1]),
                    velocity: Vec2f::new(r[2], r[3]),
                    pref_velocity: Vec2f::new(r[4], r[5]),
                    radius_m: scene.agents[i].0,
                    max_speed_mps: scene.agents[i].1,
                    // RVO2 is always reciprocal, standing agents (max speed 0) included.
                    reciprocal: true,
                });
            }
            for i in 0..agents.len() {
                let ours = if obstacles.is_empty() {
                    orca.new_velocity(i, &agents)
                } else {
                    orca.new_velocity_among(i, &agents, &obstacles)
                };
                let next = scene.rows[step + 1][i];
                compared += 1;
                if (ours.x, ours.y) != (next[2], next[3]) && failures.len() < 20 {
                    failures.push(format!(
                        "{} step {step} agent {i}: ours {ours:?} rvo2 ({}, {})",
                        path.display(),
                        next[2],
                        next[3]
                    ));
                }
            }
        }
    }
    println!(
        "compared {compared} agent-steps one step at a time over {scenes} scenes from {}",
        dir.display()
    );
    assert!(scenes > 0, "every scene in {} was symmetric", dir.display());
    assert!(
        failures.is_empty(),
        "ORCA's one-step velocities differ from RVO2's:\n{}",
        failures.join("\n")
    );
}
