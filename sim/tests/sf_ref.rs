//! Replays pysocialforce 1.1.2 reference trajectories (format `sf_ref v1`, described in
//! `testdata/sf_ref/README.md`) through [`sim::social_force::SocialForceSim`] two ways:
//!
//! - (a) one step from every recorded state: positions and velocities within 1e-9 of the next
//!   row, on every scene;
//! - (b) the free run from the initial state: every row within 1e-6 m on the scenes the
//!   README's table marks as not chaotic (drift bracket `(-)`); on a chaotic scene only the
//!   steps before the bracket's step are held to it. A scene the README does not list is
//!   checked by (a) only.
//!
//! Parameters, agents, obstacles and groups come from each file's header only (`# param`,
//! `# agent`, `# obstacle`, `# group`); the header's `# derived` max speeds and group coherence
//! factors and its `obstacle_samples` are checked against the model's own. The scenes default to
//! `testdata/sf_ref`; `FSRL_SF_REF_DIR` names another directory. Every `*.csv` below it
//! (subdirectories included) is replayed. Run with `-- --nocapture` to see the worst difference
//! per scene.

use std::path::{Path, PathBuf};

mod support;

use sim::geom::Vec2;
use sim::social_force::{
    group_coherence_factor, Pedestrian, Segment, SocialForceParams, SocialForceSim,
};

const ONE_STEP_TOL: f64 = 1e-9;
const FREE_RUN_TOL_M: f64 = 1e-6;

const GROUP_FORCES: [&str; 3] = [
    "group_coherence_force_alt",
    "group_repulsive_force",
    "group_gaze_force_alt",
];

/// One reference scene, as its header and table give it.
struct Scene {
    name: String,
    params: SocialForceParams,
    peds: Vec<Pedestrian>,
    obstacles: Vec<Segment>,
    obstacle_samples: Option<Vec<usize>>,
    groups: Vec<Vec<usize>>,
    derived_max_speeds: Vec<(usize, f64)>,
    derived_coherence: Vec<(usize, f64)>,
    /// rows[step][agent] = (position, velocity)
    rows: Vec<Vec<(Vec2, Vec2)>>,
}

/// `path:line: message`.
fn at(path: &Path, line: usize, msg: impl std::fmt::Display) -> String {
    format!("{}:{line}: {msg}", path.display())
}

fn num(s: &str, what: &str, path: &Path, line: usize) -> Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .map_err(|e| at(path, line, format!("bad number for {what}: {s:?} ({e})")))
}

fn index(s: &str, what: &str, path: &Path, line: usize) -> Result<usize, String> {
    s.trim()
        .parse::<usize>()
        .map_err(|e| at(path, line, format!("bad index for {what}: {s:?} ({e})")))
}

fn kv<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    text.split_whitespace()
        .find_map(|tok| tok.strip_prefix(key).and_then(|r| r.strip_prefix('=')))
}

/// Splits `rest` into exactly `n` comma-separated fields.
fn fields<'a>(
    rest: &'a str,
    n: usize,
    what: &str,
    path: &Path,
    line: usize,
) -> Result<Vec<&'a str>, String> {
    let f: Vec<&str> = rest.split(',').collect();
    if f.len() != n {
        return Err(at(
            path,
            line,
            format!("a {what} line needs {n} fields, found {}", f.len()),
        ));
    }
    Ok(f)
}

/// Sets one `# param` value; returns an error for an unknown name or a bad value.
fn set_param(
    p: &mut SocialForceParams,
    name: &str,
    value: &str,
    path: &Path,
    line: usize,
) -> Result<(), String> {
    if name == "scene.enable_group" {
        p.scene.enable_group = match value {
            "true" => true,
            "false" => false,
            _ => {
                return Err(at(
                    path,
                    line,
                    format!("enable_group must be true or false: {value:?}"),
                ))
            }
        };
        return Ok(());
    }
    let v = num(value, name, path, line)?;
    let slot: &mut f64 = match name {
        "scene.step_width" => &mut p.scene.step_width_s,
        "scene.max_speed_multiplier" => &mut p.scene.max_speed_multiplier,
        "scene.agent_radius" => &mut p.scene.agent_radius_m,
        "scene.tau" => &mut p.scene.tau_s,
        "scene.resolution" => &mut p.scene.resolution_per_m,
        "scene.arrive_radius" => &mut p.scene.arrive_radius_m,
        "desired_force.factor" => &mut p.desired_force.factor,
        "desired_force.relaxation_time" => &mut p.desired_force.relaxation_time_s,
        "desired_force.goal_threshold" => &mut p.desired_force.goal_threshold_m,
        "social_force.factor" => &mut p.social_force.factor,
        "social_force.lambda_importance" => &mut p.social_force.lambda_importance,
        "social_force.gamma" => &mut p.social_force.gamma,
        "social_force.n" => &mut p.social_force.n,
        "social_force.n_prime" => &mut p.social_force.n_prime,
        "obstacle_force.factor" => &mut p.obstacle_force.factor,
        "obstacle_force.sigma" => &mut p.obstacle_force.sigma_m,
        "obstacle_force.threshold" => &mut p.obstacle_force.threshold_m,
        "group_coherence_force_alt.factor" => &mut p.group_coherence_force_alt.factor,
        "group_repulsive_force.factor" => &mut p.group_repulsive_force.factor,
        "group_repulsive_force.threshold" => &mut p.group_repulsive_force.threshold_m,
        "group_gaze_force_alt.factor" => &mut p.group_gaze_force_alt.factor,
        _ => return Err(at(path, line, format!("unknown param {name:?}"))),
    };
    *slot = v;
    Ok(())
}

/// The parameters every file must give (group ones only when group forces are on).
const REQUIRED_PARAMS: [&str; 19] = [
    "scene.step_width",
    "scene.max_speed_multiplier",
    "scene.agent_radius",
    "scene.tau",
    "scene.resolution",
    "scene.enable_group",
    "scene.arrive_radius",
    "forces",
    "desired_force.factor",
    "desired_force.relaxation_time",
    "desired_force.goal_threshold",
    "social_force.factor",
    "social_force.lambda_importance",
    "social_force.gamma",
    "social_force.n",
    "social_force.n_prime",
    "obstacle_force.factor",
    "obstacle_force.sigma",
    "obstacle_force.threshold",
];
const REQUIRED_GROUP_PARAMS: [&str; 4] = [
    "group_coherence_force_alt.factor",
    "group_repulsive_force.factor",
    "group_repulsive_force.threshold",
    "group_gaze_force_alt.factor",
];

fn parse(path: &Path) -> Result<Scene, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let mut params = SocialForceParams::default();
    let mut seen_params: Vec<String> = Vec::new();
    let mut forces: Option<Vec<String>> = None;
    let (mut n_agents, mut steps, mut n_obstacles, mut n_groups) = (None, None, None, None);
    let mut name = None;
    let mut peds = Vec::new();
    let mut obstacles = Vec::new();
    let mut obstacle_samples = None;
    let mut groups = Vec::new();
    let mut derived_max_speeds = Vec::new();
    let mut derived_coherence = Vec::new();
    let mut rows: Vec<Vec<(Vec2, Vec2)>> = Vec::new();
    let mut table_header = false;
    for (k, raw) in text.lines().enumerate() {
        let ln = k + 1;
        if ln == 1 {
            if !raw.starts_with("# sf_ref v1;") {
                return Err(at(
                    path,
                    ln,
                    "not an sf_ref v1 file (first line must start with '# sf_ref v1;')",
                ));
            }
            continue;
        }
        if let Some(meta) = raw.strip_prefix("# ") {
            if table_header {
                return Err(at(path, ln, "metadata after the table header"));
            }
            if meta.starts_with("scene_kind=") {
                let get = |key: &str| {
                    kv(meta, key)
                        .ok_or_else(|| at(path, ln, format!("no {key}= on the scene line")))
                };
                n_agents = Some(index(get("n_agents")?, "n_agents", path, ln)?);
                steps = Some(index(get("steps")?, "steps", path, ln)?);
                n_obstacles = Some(index(get("n_obstacles")?, "n_obstacles", path, ln)?);
                n_groups = Some(index(get("n_groups")?, "n_groups", path, ln)?);
                name = Some(get("name")?.to_string());
            } else if let Some(rest) = meta.strip_prefix("param,") {
                let (key, value) = rest
                    .split_once(',')
                    .ok_or_else(|| at(path, ln, "a param line needs a name and a value"))?;
                if seen_params.iter().any(|s| s == key) {
                    return Err(at(path, ln, format!("param {key} given twice")));
                }
                seen_params.push(key.to_string());
                if key == "forces" {
                    forces = Some(value.split(';').map(str::to_string).collect());
                } else {
                    set_param(&mut params, key, value, path, ln)?;
                }
            } else if let Some(rest) = meta.strip_prefix("derived,") {
                let f = fields(rest, 3, "derived", path, ln)?;
                let v = num(f[2], f[0], path, ln)?;
                let i = index(f[1], f[0], path, ln)?;
                match f[0] {
                    "max_speed" => derived_max_speeds.push((i, v)),
                    "group_coherence_factor" => derived_coherence.push((i, v)),
                    other => return Err(at(path, ln, format!("unknown derived value {other:?}"))),
                }
            } else if let Some(rest) = meta.strip_prefix("agent,") {
                let f = fields(rest, 8, "agent", path, ln)?;
                if index(f[0], "agent", path, ln)? != peds.len() {
                    return Err(at(path, ln, "agents out of order"));
                }
                let v: Vec<f64> = f[1..]
                    .iter()
                    .map(|s| num(s, "agent value", path, ln))
                    .collect::<Result<_, _>>()?;
                if v[6] != params.scene.tau_s {
                    return Err(at(path, ln, "agent tau differs from param scene.tau"));
                }
                peds.push(Pedestrian {
                    position: Vec2::new(v[0], v[1]),
                    velocity: Vec2::new(v[2], v[3]),
                    goal: Vec2::new(v[4], v[5]),
                });
            } else if let Some(rest) = meta.strip_prefix("obstacle,") {
                let f = fields(rest, 5, "obstacle", path, ln)?;
                if index(f[0], "obstacle", path, ln)? != obstacles.len() {
                    return Err(at(path, ln, "obstacles out of order"));
                }
                let mut c = [0.0; 4];
                for (slot, s) in c.iter_mut().zip(&f[1..]) {
                    *slot = num(s, "obstacle coordinate", path, ln)?;
                }
                obstacles.push(Segment::from_psf(c));
            } else if let Some(rest) = meta.strip_prefix("obstacle_samples=") {
                obstacle_samples = Some(
                    rest.split(',')
                        .map(|s| index(s, "obstacle_samples", path, ln))
                        .collect::<Result<Vec<_>, _>>()?,
                );
            } else if let Some(rest) = meta.strip_prefix("group,") {
                let f = fields(rest, 2, "group", path, ln)?;
                if index(f[0], "group", path, ln)? != groups.len() {
                    return Err(at(path, ln, "groups out of order"));
                }
                groups.push(
                    f[1].split(';')
                        .map(|s| index(s, "group member", path, ln))
                        .collect::<Result<Vec<_>, _>>()?,
                );
            } else if meta == "agent_columns=agent,px0,py0,vx0,vy0,gx,gy,tau"
                || meta == "obstacle_columns=obstacle,x1,x2,y1,y2"
                || meta == "group_columns=group,members"
                || meta.starts_with("env ")
                || meta.starts_with("note ")
                || meta.starts_with("config_file=")
                || meta.starts_with("toml,")
                || meta.starts_with("params ")
                || meta.starts_with("config,")
            {
                // Informational (the README: `# config` is never what psf reads).
            } else {
                return Err(at(path, ln, format!("unknown metadata line {raw:?}")));
            }
            continue;
        }
        if raw.starts_with('#') {
            return Err(at(path, ln, format!("unknown metadata line {raw:?}")));
        }
        if !table_header {
            if raw != "step,agent,px,py,vx,vy" {
                return Err(at(
                    path,
                    ln,
                    format!("expected the header step,agent,px,py,vx,vy, found {raw:?}"),
                ));
            }
            table_header = true;
            continue;
        }
        let f = fields(raw, 6, "table", path, ln)?;
        let step = index(f[0], "step", path, ln)?;
        let agent = index(f[1], "agent", path, ln)?;
        if step == rows.len() && agent == 0 {
            rows.push(Vec::new());
        }
        if step + 1 != rows.len() || agent != rows[step].len() {
            return Err(at(
                path,
                ln,
                format!("row (step {step}, agent {agent}) out of order"),
            ));
        }
        let v: Vec<f64> = f[2..]
            .iter()
            .map(|s| num(s, "table value", path, ln))
            .collect::<Result<_, _>>()?;
        rows[step].push((Vec2::new(v[0], v[1]), Vec2::new(v[2], v[3])));
    }
    let end = text.lines().count();
    let missing = |what: &str| at(path, end, format!("the header has no {what}"));
    let n_agents = n_agents.ok_or_else(|| missing("scene_kind line"))?;
    let steps = steps.ok_or_else(|| missing("steps"))?;
    let n_obstacles = n_obstacles.ok_or_else(|| missing("n_obstacles"))?;
    let n_groups = n_groups.ok_or_else(|| missing("n_groups"))?;
    let name = name.ok_or_else(|| missing("name"))?;
    let forces = forces.ok_or_else(|| missing("param forces"))?;
    let group_on = forces.len() == 6 && forces[3..] == GROUP_FORCES;
    let base_ok =
        forces.len() >= 3 && forces[..3] == ["desired_force", "social_force", "obstacle_force"];
    if !base_ok || !(forces.len() == 3 || group_on) {
        return Err(at(path, end, format!("unexpected force list {forces:?}")));
    }
    if group_on != params.scene.enable_group {
        return Err(at(
            path,
            end,
            "param forces disagrees with scene.enable_group",
        ));
    }
    let mut required: Vec<&str> = REQUIRED_PARAMS.to_vec();
    if group_on {
        required.extend(REQUIRED_GROUP_PARAMS);
    }
    for key in required {
        if !seen_params.iter().any(|s| s == key) {
            return Err(missing(&format!("param {key}")));
        }
    }
    let counts = [
        ("agent lines", peds.len(), n_agents),
        ("obstacle lines", obstacles.len(), n_obstacles),
        ("group lines", groups.len(), n_groups),
        ("steps", rows.len(), steps + 1),
    ];
    for (what, got, want) in counts {
        if got != want {
            return Err(at(
                path,
                end,
                format!("{got} {what}, the scene line says {want}"),
            ));
        }
    }
    if let Some(r) = rows.iter().position(|r| r.len() != n_agents) {
        return Err(at(
            path,
            end,
            format!("step {r} has {} rows, not {n_agents}", rows[r].len()),
        ));
    }
    for (i, (row_state, ped)) in rows[0].iter().zip(&peds).enumerate() {
        if row_state.0 != ped.position || row_state.1 != ped.velocity {
            return Err(at(
                path,
                end,
                format!("step 0 of agent {i} is not its agent line"),
            ));
        }
    }
    Ok(Scene {
        name,
        params,
        peds,
        obstacles,
        obstacle_samples,
        groups,
        derived_max_speeds,
        derived_coherence,
        rows,
    })
}

fn scene_files() -> Vec<PathBuf> {
    support::reference_csvs("FSRL_SF_REF_DIR", &["sf_ref"], "social-force").1
}

/// How the README beside a file rates its scene: `Some(None)` not chaotic (drift bracket `-`),
/// `Some(Some(k))` chaotic from step k, `None` not listed (or no README).
fn chaos_rating(path: &Path) -> Option<Option<usize>> {
    let readme = std::fs::read_to_string(path.parent()?.join("README.md")).ok()?;
    let file = path.file_name()?.to_str()?;
    let mut drift_col = None;
    for line in readme.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.first() != Some(&"") || cells.len() < 3 {
            continue;
        }
        if let Some(c) = cells.iter().position(|c| c.starts_with("drift")) {
            drift_col = Some(c);
            continue;
        }
        if cells[1] == format!("`{file}`") {
            let drift = cells.get(drift_col?)?;
            let bracket = drift.split_once('(')?.1.strip_suffix(')')?;
            return Some(if bracket == "-" {
                None
            } else {
                Some(bracket.parse().ok()?)
            });
        }
    }
    None
}

fn worst_diff(sim: &SocialForceSim, row: &[(Vec2, Vec2)]) -> (f64, f64) {
    let mut worst_p = 0f64;
    let mut worst_v = 0f64;
    // A NaN difference counts as infinite (`f64::max` would drop it).
    let d = |x: f64| if x.is_nan() { f64::INFINITY } else { x.abs() };
    for (ped, (p, v)) in sim.pedestrians().iter().zip(row) {
        let (dp, dv) = (ped.position - p, ped.velocity - v);
        worst_p = worst_p.max(d(dp.x)).max(d(dp.y));
        worst_v = worst_v.max(d(dv.x)).max(d(dv.y));
    }
    (worst_p, worst_v)
}

fn build(scene: &Scene, path: &Path) -> SocialForceSim {
    SocialForceSim::new(scene.params, &scene.peds, &scene.obstacles, &scene.groups)
        .unwrap_or_else(|e| panic!("{}: cannot build the model: {e}", path.display()))
}

/// The header's check values: obstacle sample counts, max speeds, coherence factors.
fn check_header_values(scene: &Scene, sim: &SocialForceSim, path: &Path) -> Vec<String> {
    let mut failures = Vec::new();
    if let Some(samples) = &scene.obstacle_samples {
        let total: usize = samples.iter().sum();
        if total != sim.obstacle_points().len() {
            failures.push(format!(
                "{}: {} obstacle points, the header's obstacle_samples sum to {total}",
                path.display(),
                sim.obstacle_points().len()
            ));
        }
    }
    for &(i, v) in &scene.derived_max_speeds {
        if sim.max_speeds_mps().get(i) != Some(&v) {
            failures.push(format!(
                "{}: max speed of agent {i}: ours {:?}, psf {v}",
                path.display(),
                sim.max_speeds_mps().get(i)
            ));
        }
    }
    for &(size, v) in &scene.derived_coherence {
        if group_coherence_factor(size) != v {
            failures.push(format!(
                "{}: group coherence factor for size {size}: ours {}, psf {v}",
                path.display(),
                group_coherence_factor(size)
            ));
        }
    }
    failures
}

#[test]
fn one_step_from_every_row_matches_pysocialforce() {
    let mut failures = Vec::new();
    let mut compared = 0usize;
    for path in scene_files() {
        let scene = parse(&path).unwrap_or_else(|e| panic!("{e}"));
        let mut sim = build(&scene, &path);
        failures.extend(check_header_values(&scene, &sim, &path));
        let (mut worst, mut worst_step) = (0f64, 0usize);
        let mut exact = 0usize;
        for step in 0..scene.rows.len() - 1 {
            let (ps, vs): (Vec<Vec2>, Vec<Vec2>) = scene.rows[step].iter().copied().unzip();
            sim.set_kinematics(&ps, &vs)
                .unwrap_or_else(|e| panic!("{}: step {step}: {e}", path.display()));
            sim.step()
                .unwrap_or_else(|e| panic!("{}: step {step}: {e}", path.display()));
            let (dp, dv) = worst_diff(&sim, &scene.rows[step + 1]);
            let d = dp.max(dv);
            exact += usize::from(d == 0.0);
            if d > worst {
                (worst, worst_step) = (d, step + 1);
            }
            compared += 1;
        }
        println!(
            "one step  {:<28} worst |diff| {worst:.3e} (step {worst_step}), bit-exact {exact}/{} steps",
            scene.name,
            scene.rows.len() - 1
        );
        if worst > ONE_STEP_TOL {
            failures.push(format!(
                "{}: one step off by {worst:e} at step {worst_step} (tolerance {ONE_STEP_TOL:e})",
                path.display()
            ));
        }
    }
    assert!(compared > 0, "no steps compared");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn free_runs_match_pysocialforce_on_non_chaotic_scenes() {
    let mut failures = Vec::new();
    let mut held = 0usize;
    for path in scene_files() {
        let scene = parse(&path).unwrap_or_else(|e| panic!("{e}"));
        let rating = chaos_rating(&path);
        let mut sim = build(&scene, &path);
        let (mut worst, mut worst_step) = (0f64, 0usize);
        let (mut worst_held, mut first_off) = (0f64, None);
        let limit = match rating {
            Some(None) => scene.rows.len(),
            Some(Some(k)) => k.min(scene.rows.len()),
            None => 0,
        };
        for step in 1..scene.rows.len() {
            sim.step()
                .unwrap_or_else(|e| panic!("{}: step {step}: {e}", path.display()));
            let (dp, _) = worst_diff(&sim, &scene.rows[step]);
            if dp > worst {
                (worst, worst_step) = (dp, step);
            }
            if dp > 0.0 && first_off.is_none() {
                first_off = Some(step);
            }
            if step < limit {
                worst_held = worst_held.max(dp);
            }
        }
        let note = match rating {
            Some(None) => "not chaotic: held over every step".to_string(),
            Some(Some(k)) => format!("chaotic: held before step {k}"),
            None => "not in the README's table: not held".to_string(),
        };
        let first = first_off.map_or("never".to_string(), |s| format!("step {s}"));
        println!(
            "free run  {:<28} worst |Δp| {worst:.3e} m (step {worst_step}), first nonzero {first}; {note}",
            scene.name
        );
        if rating.is_some() {
            held += 1;
            if worst_held > FREE_RUN_TOL_M {
                failures.push(format!(
                    "{}: free run off by {worst_held:e} m (tolerance {FREE_RUN_TOL_M:e})",
                    path.display()
                ));
            }
        }
    }
    assert!(
        held > 0,
        "no scene rated by a README: no free run was held to a tolerance"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn a_malformed_file_names_its_file_and_line() {
    let dir = std::env::temp_dir().join(format!("fsrl_sf_ref_bad_{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let good = scene_files().into_iter().next().expect("a scene");
    let text = std::fs::read_to_string(&good).expect("read");
    let bad = dir.join("bad.csv");
    // Corrupt the first agent line's x.
    let broken: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with("# agent,0,") {
                l.replacen("# agent,0,", "# agent,0,x", 1)
            } else {
                l.to_string()
            }
        })
        .collect();
    std::fs::write(&bad, broken.join("\n")).expect("write");
    let line = text
        .lines()
        .position(|l| l.starts_with("# agent,0,"))
        .expect("an agent line")
        + 1;
    let err = parse(&bad).err().expect("a malformed file must not parse");
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        err.contains(&format!("bad.csv:{line}:")) && err.contains("agent value"),
        "{err}"
    );
}
