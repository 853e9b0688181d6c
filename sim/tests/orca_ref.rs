//! Replays RVO2 reference scenes one step at a time: from the reference state at every step, our
//! ORCA velocities must match RVO2's within 1e-4 m/s for every agent of every non-symmetric scene.
//!
//! The directory defaults to the repository's `testdata/orca_ref` (where the scenes come from:
//! `testdata/README.md`) and can be changed with `FSRL_ORCA_REF_DIR`; every `*.csv` below it
//! (subdirectories included) is replayed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use sim::geom::Vec2f;
use sim::orca::{Orca, OrcaAgent, OrcaParams};

const TOLERANCE_MPS: f32 = 1e-4;

struct Scene {
    params: OrcaParams,
    symmetric: bool,
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
                });
            } else if meta.starts_with("scene_kind") {
                if let Some(p) = kv(meta, "perturbation") {
                    symmetric = num(p, "perturbation", path) == 0.0;
                }
            } else if let Some(rest) = meta.strip_prefix("agent,") {
                let f: Vec<&str> = rest.split(',').collect();
                assert!(f.len() >= 8, "{}: bad agent line {line}", path.display());
                agents.push((num(f[5], "radius", path), num(f[6], "max_speed", path)));
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
        agents,
        rows,
    }
}

fn csv_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| {
        panic!(
            "cannot read ORCA reference directory {}: {e}",
            dir.display()
        )
    });
    for entry in entries {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            csv_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "csv") {
            out.push(path);
        }
    }
}

#[test]
fn one_step_velocities_match_rvo2() {
    let dir = std::env::var_os("FSRL_ORCA_REF_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../testdata/orca_ref"))
        });
    let mut files = Vec::new();
    csv_files(&dir, &mut files);
    files.sort();
    assert!(
        !files.is_empty(),
        "no ORCA reference scenes (*.csv) found in {}: nothing was compared",
        dir.display()
    );

    let (mut scenes, mut compared, mut worst) = (0usize, 0usize, 0f32);
    let mut failures = Vec::new();
    for path in &files {
        let scene = parse(path);
        if scene.symmetric {
            println!("skipping symmetric scene {}", path.display());
            continue;
        }
        scenes += 1;
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
                let ours = orca.new_velocity(i, &agents);
                let next = scene.rows[step + 1][i];
                let err = (ours - Vec2f::new(next[2], next[3])).norm();
                worst = worst.max(err);
                compared += 1;
                if err > TOLERANCE_MPS && failures.len() < 20 {
                    failures.push(format!(
                        "{} step {step} agent {i}: ours {ours:?} rvo2 ({}, {}) err {err:e}",
                        path.display(),
                        next[2],
                        next[3]
                    ));
                }
            }
        }
    }
    println!(
        "compared {compared} agent-steps over {scenes} scenes from {} (worst error {worst:e} m/s)",
        dir.display()
    );
    assert!(scenes > 0, "every scene in {} was symmetric", dir.display());
    assert!(
        failures.is_empty(),
        "ORCA differs from RVO2 by more than {TOLERANCE_MPS} m/s:\n{}",
        failures.join("\n")
    );
}
