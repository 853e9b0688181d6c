//! The ORCA robot as a baseline: the paper's metrics over generated episodes of the six settings
//! and the walled ones ([`run_settings`], [`table`]: wall and people collisions and frozen robots
//! apart among walls) or over explicit scenes ([`run_scene_cases`], [`scenes_table`]:
//! CrowdNav's 500 test scenes beside CrowdNav's own numbers). What `fsrl sim` prints.

use std::path::Path;

use anyhow::Context;
use sim::{
    parse_scenes, run_episode_with, Aggregate, Env, EnvKind, Kinematics, SceneCase, SceneFile,
    SceneFormat, Semantics, Setting, SimConfig,
};

/// CrowdNav's holonomic ORCA robot on its 500 test scenes with 10 humans, as CrowdNav reports it
/// (`testdata/crowdnav_cases/README.md`; the paper's ORCA row): success, collision, timeout,
/// nav time (s), danger steps / steps; invisible then visible.
const CROWDNAV_ORCA_H10: [(bool, [f64; 5]); 2] = [
    (false, [0.210, 0.790, 0.000, 12.49, 0.392]),
    (true, [0.994, 0.000, 0.006, 11.99, 0.410]),
];

/// "ORCA robot" plus what differs from SPEC's defaults.
pub fn robot_description(cfg: &SimConfig) -> String {
    let mut s = match cfg.robot.kinematics {
        Kinematics::Unicycle => {
            "ORCA robot (unicycle: nearest action to ORCA's velocity)".to_string()
        }
        Kinematics::Holonomic => "ORCA robot (holonomic: executes ORCA's velocity)".to_string(),
    };
    if cfg.semantics != Semantics::Spec {
        s += &format!(", {} step semantics", cfg.semantics);
    }
    s
}

/// Reads and parses a scene file; errors name the file and the line.
pub fn load_scenes(path: &Path, cfg: &SimConfig) -> anyhow::Result<SceneFile> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read scene file {}", path.display()))?;
    parse_scenes(&text, cfg).with_context(|| format!("invalid scene file {}", path.display()))
}

/// Whether `file` is CrowdNav's test set with 10 humans (500 cases numbered 0..499), the scenes
/// CrowdNav's reference numbers are for.
pub fn is_crowdnav_h10_test_set(file: &SceneFile) -> bool {
    file.format == SceneFormat::CrowdNav
        && file.cases.len() == 500
        && file
            .cases
            .iter()
            .enumerate()
            .all(|(i, c)| c.case == i as u64 && c.scenario.humans.len() == 10)
}

/// Runs every case once per visibility with the ORCA robot, visibilities on their own threads.
pub fn run_scene_cases(
    cfg: &SimConfig,
    cases: &[SceneCase],
    visibilities: &[bool],
    safety_space_m: f64,
) -> anyhow::Result<Vec<(bool, Aggregate)>> {
    anyhow::ensure!(!cases.is_empty(), "no scene to run");
    std::thread::scope(|scope| {
        let handles: Vec<_> = visibilities
            .iter()
            .map(|&visible| {
                scope.spawn(move || -> anyhow::Result<(bool, Aggregate)> {
                    let setting = Setting::new(EnvKind::Env1, visible);
                    let first = &cases[0];
                    let mut env = Env::from_scenario(
                        cfg.clone(),
                        setting,
                        first.case,
                        first.scenario.clone(),
                    )?;
                    let mut agg = Aggregate::default();
                    for (k, c) in cases.iter().enumerate() {
                        if k > 0 {
                            env.reset_to_scenario(c.case, c.scenario.clone());
                        }
                        let ep = run_episode_with(
                            &mut env,
                            |env| env.orca_robot_command(safety_space_m),
                            false,
                        )?;
                        agg.add(&ep.summary);
                    }
                    Ok((visible, agg))
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .map_err(|_| anyhow::anyhow!("a simulation thread panicked"))?
            })
            .collect()
    })
}

/// The table of `testdata/crowdnav_cases/README.md`: one row per visibility, with CrowdNav's
/// reported numbers beside ours when `crowdnav_reference`.
pub fn scenes_table(
    results: &[(bool, Aggregate)],
    time_limit_steps: u32,
    crowdnav_reference: bool,
) -> String {
    let mut s = String::from(
        "| robot | run | success | collision | timeout | nav time (s) | danger steps / steps |\n|---|---|---|---|---|---|---|\n",
    );
    let name = |visible: bool| if visible { "visible" } else { "invisible" };
    for (visible, a) in results {
        s += &format!(
            "| {} | fsrl | {:.3} | {:.3} | {:.3} | {} | {:.3} |\n",
            name(*visible),
            a.success_rate(),
            a.collision_rate(),
            a.timeout_rate(),
            opt(a.nav_time_s(), 2),
            a.danger_frequency(time_limit_steps)
        );
        if crowdnav_reference {
            if let Some((_, r)) = CROWDNAV_ORCA_H10.iter().find(|(v, _)| v == visible) {
                s += &format!(
                    "| {} | CrowdNav | {:.3} | {:.3} | {:.3} | {:.2} | {:.3} |\n",
                    name(*visible),
                    r[0],
                    r[1],
                    r[2],
                    r[3],
                    r[4]
                );
            }
        }
    }
    s
}

/// Runs `episodes` ORCA-robot episodes per setting ([`Env::orca_robot_command`]: a holonomic
/// robot executes ORCA's velocity), settings spread over the available cores.
pub fn run_settings(
    cfg: &SimConfig,
    settings: &[Setting],
    seed_start: u64,
    episodes: u32,
    safety_space_m: f64,
) -> anyhow::Result<Vec<(Setting, Aggregate)>> {
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(settings.len().max(1));
    let chunks: Vec<Vec<Setting>> = (0..workers)
        .map(|w| settings.iter().copied().skip(w).step_by(workers).collect())
        .collect();
    let mut results: Vec<(Setting, Aggregate)> = std::thread::scope(|scope| {
        let handles: Vec<_> = chunks
            .iter()
            .map(|chunk| {
                scope.spawn(move || -> anyhow::Result<Vec<(Setting, Aggregate)>> {
                    let mut out = Vec::new();
                    for &setting in chunk {
                        let mut env = Env::new(cfg.clone(), setting, seed_start)?;
                        let mut agg = Aggregate::default();
                        for k in 0..episodes as u64 {
                            env.reset(seed_start + k)?;
                            let ep = run_episode_with(
                                &mut env,
                                |env| env.orca_robot_command(safety_space_m),
                                false,
                            )?;
                            agg.add(&ep.summary);
                        }
                        out.push((setting, agg));
                    }
                    Ok(out)
                })
            })
            .collect();
        let mut all = Vec::new();
        for h in handles {
            all.extend(
                h.join()
                    .map_err(|_| anyhow::anyhow!("a simulation thread panicked"))??,
            );
        }
        Ok::<_, anyhow::Error>(all)
    })?;
    results.sort_by_key(|(s, _)| settings.iter().position(|x| x == s));
    Ok(results)
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".to_string(), |x| format!("{x:.digits$}"))
}

/// The metrics as a Markdown table, one row per setting plus averages per visibility over the
/// paper's settings; with a walled setting among the results, its wall collisions, people
/// collisions and frozen robots in columns of their own ("–" in the other rows).
///
/// Disc. is CrowdNav's danger frequency: a timed-out episode counts as `time_limit_steps`
/// steps. Under SPEC semantics a timeout takes exactly that many steps, so this is danger steps /
/// all steps; under `crowdnav` semantics CrowdNav's 97-step timeouts are booked as 100.
pub fn table(results: &[(Setting, Aggregate)], time_limit_steps: u32) -> String {
    let walled = results.iter().any(|(s, _)| !s.is_paper());
    let mut s = String::from(
        "| setting | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. | Path (m) | mean abs dθ (rad/step) |",
    );
    if walled {
        s += " Wall coll. | People coll. | Frozen |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
    } else {
        s += "\n|---|---|---|---|---|---|---|---|\n";
    }
    let row = |name: &str, a: &Aggregate, among_walls: bool| {
        let mut r = format!(
            "| {name} | {:.3} | {:.3} | {:.3} | {} | {:.3} | {} | {:.4} |",
            a.success_rate(),
            a.collision_rate(),
            a.timeout_rate(),
            opt(a.nav_time_s(), 2),
            a.danger_frequency(time_limit_steps),
            opt(a.path_length_m(), 2),
            a.mean_abs_rotation_rad()
        );
        match (walled, among_walls) {
            (false, _) => {}
            (true, false) => r += " – | – | – |",
            (true, true) => {
                r += &format!(
                    " {:.3} | {:.3} | {:.3} |",
                    a.wall_collision_rate(),
                    a.people_collision_rate(),
                    a.frozen_rate()
                )
            }
        }
        r.push('\n');
        r
    };
    for (setting, agg) in results {
        s += &row(setting.name(), agg, !setting.is_paper());
    }
    for visible in [false, true] {
        let mut sum = Aggregate::default();
        let mut n = 0;
        for (_, agg) in results
            .iter()
            .filter(|(st, _)| st.is_paper() && st.robot_visible == visible)
        {
            sum.merge(agg);
            n += 1;
        }
        if n > 1 {
            let label = if visible {
                "visible (all)"
            } else {
                "invisible (all)"
            };
            s += &row(label, &sum, false);
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCENES: &str = "case,agent,px,py,gx,gy\n0,robot,0,-4,0,4\n0,0,-3,0.1,3,-0.1\n\
                          1,robot,0,-4,0,4\n1,0,0.2,3.9,-0.2,-3.9\n";

    #[test]
    fn scene_cases_run_per_visibility() {
        let mut cfg = SimConfig::default();
        cfg.robot.kinematics = Kinematics::Holonomic;
        cfg.semantics = Semantics::CrowdNav;
        let file = parse_scenes(SCENES, &cfg).unwrap();
        assert!(!is_crowdnav_h10_test_set(&file));
        let results = run_scene_cases(&cfg, &file.cases, &[false, true], 0.0).unwrap();
        assert_eq!(results.len(), 2);
        for (_, a) in &results {
            assert_eq!(a.episodes, 2);
        }
        let table = scenes_table(&results, cfg.max_steps(), true);
        assert!(table.contains("| invisible | fsrl |"), "{table}");
        assert!(table.contains("| visible | CrowdNav | 0.994 | 0.000 | 0.006 | 11.99 | 0.410 |"));
        assert!(!scenes_table(&results, 100, false).contains("CrowdNav"));
    }

    #[test]
    fn a_malformed_scene_file_names_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.csv");
        std::fs::write(
            &path,
            "# scenes\ncase,agent,px,py,gx,gy\n0,robot,0,-4,0,4\n0,0,1,oops,2,2\n",
        )
        .unwrap();
        let err = load_scenes(&path, &SimConfig::default()).unwrap_err();
        let text = format!("{err:#}");
        assert!(text.contains("invalid scene file"), "{text}");
        assert!(text.contains("bad.csv"), "{text}");
        assert!(
            text.contains("line 4: column `py`: not a number, got `oops`"),
            "{text}"
        );
        let err = load_scenes(&dir.path().join("missing.csv"), &SimConfig::default()).unwrap_err();
        assert!(format!("{err:#}").contains("cannot read scene file"));
    }

    #[test]
    fn walled_settings_get_their_own_columns_and_stay_out_of_the_averages() {
        let cfg = SimConfig::default();
        let settings: Vec<Setting> = ["env1-invisible", "env2-invisible", "pillars-invisible"]
            .iter()
            .map(|s| s.parse().unwrap())
            .collect();
        let results = run_settings(&cfg, &settings, 1000, 4, 0.0).unwrap();
        let paper = table(&results[..2], cfg.max_steps());
        assert!(!paper.contains("Wall"), "{paper}");
        let all = table(&results, cfg.max_steps());
        let lines: Vec<&str> = all.lines().collect();
        assert!(
            lines[0].ends_with("| Wall coll. | People coll. | Frozen |"),
            "{all}"
        );
        assert!(lines[2].starts_with("| env1-invisible |") && lines[2].ends_with("| – | – | – |"));
        let pillars = &results[2].1;
        assert!(lines[4].starts_with("| pillars-invisible |"), "{all}");
        assert!(lines[4].ends_with(&format!(
            "| {:.3} | {:.3} | {:.3} |",
            pillars.wall_collision_rate(),
            pillars.people_collision_rate(),
            pillars.frozen_rate()
        )));
        // The average of the paper's two invisible settings, as without the walled one.
        let paper_avg = paper.lines().last().unwrap();
        assert!(paper_avg.starts_with("| invisible (all) |"), "{paper}");
        assert_eq!(lines[5], format!("{paper_avg} – | – | – |"));
    }

    #[test]
    fn the_repositorys_crowdnav_scenes_are_recognised() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../testdata/crowdnav_cases/test_h10_scenes.csv"
        ));
        let file = load_scenes(path, &SimConfig::default())
            .unwrap_or_else(|e| panic!("the repository's CrowdNav scenes: {e:#}"));
        assert!(is_crowdnav_h10_test_set(&file));
    }
}
