//! `fsrl sim`: the ORCA robot on the six settings, the paper's metrics as a table, and an episode
//! as an SVG picture (drawn by `viz`, as `fsrl plot episode` draws it); or the ORCA robot on explicit scenes from a file (`--scenes`), e.g.
//! CrowdNav's 500 test scenes beside CrowdNav's own numbers.

use std::path::{Path, PathBuf};

use anyhow::Context;
use sim::Env;
use sim::{
    parse_scenes, run_episode_with, Aggregate, EnvKind, Kinematics, SceneCase, SceneFile,
    SceneFormat, Semantics, Setting, SimConfig,
};

use crate::config::FileConfig;
use crate::picture;

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Episodes per setting [default: 500]; with --scenes, the number of cases to run
    /// (default: every case of the file).
    #[arg(long)]
    pub episodes: Option<u32>,
    /// First episode seed; episodes use seeds seed_start, seed_start+1, ... (CrowdNav's test
    /// seeds start at 1000).
    #[arg(long, default_value_t = 1000)]
    pub seed_start: u64,
    /// Settings to run, comma-separated (default: all six).
    #[arg(long, value_delimiter = ',')]
    pub settings: Vec<String>,
    /// Run configuration (TOML); its [sim] table overrides the defaults.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Extra radius the ORCA robot keeps from humans (CrowdNav: 0 at test time).
    #[arg(long, default_value_t = 0.0)]
    pub safety_space_m: f64,
    /// Write one episode as an SVG picture to this file (panels at a third, two thirds and the
    /// end of the episode, drawn as `fsrl plot episode` draws them).
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Setting of the pictured episode (default: the first one run).
    #[arg(long)]
    pub svg_setting: Option<String>,
    /// Seed of the pictured episode (default: seed_start).
    #[arg(long)]
    pub svg_seed: Option<u64>,
    /// Run the explicit scenes of FILE instead of generated episodes, each once per visibility.
    /// FILE is CSV in CrowdNav's format (`case,agent,px,py,gx,gy`, e.g. its
    /// test_h10_scenes.csv; radii and speeds from the config) or fsrl's (the same plus optional
    /// `radius_m`, `v_pref_mps`, `standing` columns); see the `sim::scenes` docs. On CrowdNav's
    /// 500 test scenes the table shows CrowdNav's numbers beside ours.
    #[arg(long, value_name = "FILE")]
    pub scenes: Option<PathBuf>,
    /// With --scenes: visibilities to run, comma-separated: invisible, visible
    /// [default: invisible,visible].
    #[arg(long, value_delimiter = ',')]
    pub visibility: Vec<String>,
    /// Robot kinematics, overriding the config's `robot.kinematics`: `unicycle` (SPEC's robot:
    /// ORCA's velocity mapped to the nearest of its actions) or `holonomic` (CrowdNav's ORCA
    /// robot: it executes ORCA's velocity directly).
    #[arg(long, value_name = "KINEMATICS")]
    pub robot: Option<Kinematics>,
    /// Step semantics, overriding the config's `sim.semantics`: `spec` (SPEC §2) or `crowdnav`
    /// (CrowdNav's step exactly: collision from the humans' previous velocities, timeout first
    /// at ≥ time_limit − 1 s, ...), for comparing with CrowdNav's numbers.
    #[arg(long, value_name = "SEMANTICS")]
    pub semantics: Option<Semantics>,
}

/// CrowdNav's holonomic ORCA robot on its 500 test scenes with 10 humans, as CrowdNav reports it
/// (`shared/data/crowdnav_cases/README.md`; the paper's ORCA row): success, collision, timeout,
/// nav time (s), danger steps / steps; invisible then visible.
const CROWDNAV_ORCA_H10: [(bool, [f64; 5]); 2] = [
    (false, [0.210, 0.790, 0.000, 12.49, 0.392]),
    (true, [0.994, 0.000, 0.006, 11.99, 0.410]),
];

const ALL_NAMES: [&str; 6] = [
    "env1-invisible",
    "env2-invisible",
    "env3-invisible",
    "env1-visible",
    "env2-visible",
    "env3-visible",
];

pub fn run(args: SimArgs) -> anyhow::Result<()> {
    let file = FileConfig::load(args.config.as_deref())?;
    let mut cfg = file.sim;
    if let Some(k) = args.robot {
        cfg.robot.kinematics = k;
    }
    if let Some(s) = args.semantics {
        cfg.semantics = s;
    }
    if let Some(path) = &args.scenes {
        return run_scenes(&args, cfg, path);
    }
    let episodes = args.episodes.unwrap_or(500);
    let mut names: Vec<String> = if args.settings.is_empty() {
        ALL_NAMES.iter().map(|s| s.to_string()).collect()
    } else {
        args.settings.clone()
    };
    let svg_setting_name = args.svg_setting.clone();
    if let Some(name) = &svg_setting_name {
        names.push(name.clone());
    }
    let mut problems = match cfg.resolve_settings(&names) {
        Ok(_) => Vec::new(),
        Err(e) => e.problems,
    };
    if episodes == 0 {
        problems.push("--episodes must be at least 1".into());
    }
    check_safety_space(args.safety_space_m, &mut problems);
    if !args.visibility.is_empty() {
        problems.push("--visibility only applies with --scenes".into());
    }
    if !problems.is_empty() {
        return Err(sim::ConfigError { problems }.into());
    }
    if svg_setting_name.is_some() {
        names.pop();
    }
    let settings: Vec<Setting> = names
        .iter()
        .map(|n| n.parse().expect("validated"))
        .collect();

    let results = run_settings(
        &cfg,
        &settings,
        args.seed_start,
        episodes,
        args.safety_space_m,
    )?;
    println!(
        "{}, {} episodes per setting, seeds {}..{}\n",
        robot_description(&cfg),
        episodes,
        args.seed_start,
        args.seed_start + episodes as u64 - 1
    );
    print!("{}", table(&results, cfg.max_steps()));

    if let Some(path) = &args.svg {
        let setting = match &svg_setting_name {
            Some(n) => n.parse().expect("validated"),
            None => settings[0],
        };
        let seed = args.svg_seed.unwrap_or(args.seed_start);
        let mut env = Env::new(cfg.clone(), setting, seed)?;
        let humans = env.humans().to_vec();
        let safety = args.safety_space_m;
        let episode = run_episode_with(&mut env, |env| env.orca_robot_command(safety), true)?;
        let title = format!("ORCA robot on {setting}, seed {seed}");
        let trace = picture::trace(title.clone(), &episode, &humans, &[]);
        let times_s = picture::default_times(&trace);
        let svg = viz::to_svg_string(&viz::Trajectory { trace, times_s })
            .with_context(|| format!("cannot draw {}", path.display()))?;
        std::fs::write(path, svg).with_context(|| format!("cannot write {}", path.display()))?;
        let sum = &episode.summary;
        println!(
            "\nwrote {} ({title}: {}, path {:.2} m, {} danger steps, closest {:.3} m)",
            path.display(),
            picture::outcome(sum),
            sum.path_length_m,
            sum.danger_steps,
            sum.min_closest_m
        );
    }
    Ok(())
}

fn check_safety_space(safety_space_m: f64, problems: &mut Vec<String>) {
    if !safety_space_m.is_finite() || safety_space_m < 0.0 {
        problems.push(format!(
            "--safety-space-m must be a finite number >= 0, got {safety_space_m}"
        ));
    }
}

/// "ORCA robot" plus what differs from SPEC's defaults.
fn robot_description(cfg: &SimConfig) -> String {
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
fn is_crowdnav_h10_test_set(file: &SceneFile) -> bool {
    file.format == SceneFormat::CrowdNav
        && file.cases.len() == 500
        && file
            .cases
            .iter()
            .enumerate()
            .all(|(i, c)| c.case == i as u64 && c.scenario.humans.len() == 10)
}

fn run_scenes(args: &SimArgs, cfg: SimConfig, path: &Path) -> anyhow::Result<()> {
    let mut problems = match cfg.validate() {
        Ok(()) => Vec::new(),
        Err(e) => e.problems,
    };
    check_safety_space(args.safety_space_m, &mut problems);
    if args.episodes == Some(0) {
        problems.push("--episodes must be at least 1".into());
    }
    for (given, flag) in [
        (!args.settings.is_empty(), "--settings"),
        (args.svg.is_some(), "--svg"),
        (args.svg_setting.is_some(), "--svg-setting"),
        (args.svg_seed.is_some(), "--svg-seed"),
    ] {
        if given {
            problems.push(format!(
                "{flag} does not apply with --scenes (choose visibilities with --visibility)"
            ));
        }
    }
    let mut visibilities = Vec::new();
    let names: Vec<&str> = if args.visibility.is_empty() {
        vec!["invisible", "visible"]
    } else {
        args.visibility.iter().map(String::as_str).collect()
    };
    for name in names {
        match name {
            "invisible" => visibilities.push(false),
            "visible" => visibilities.push(true),
            other => problems.push(format!(
                "unknown visibility `{other}`; expected invisible or visible"
            )),
        }
    }
    if !problems.is_empty() {
        return Err(sim::ConfigError { problems }.into());
    }
    let file = load_scenes(path, &cfg)?;
    let crowdnav_reference = is_crowdnav_h10_test_set(&file);
    let n = args
        .episodes
        .map_or(file.cases.len(), |e| (e as usize).min(file.cases.len()));
    let cases = &file.cases[..n];
    let results = run_scene_cases(&cfg, cases, &visibilities, args.safety_space_m)?;
    println!(
        "{}, {} scene{} from {} (cases {}..{}, {} format)\n",
        robot_description(&cfg),
        cases.len(),
        if cases.len() == 1 { "" } else { "s" },
        path.display(),
        cases[0].case,
        cases[cases.len() - 1].case,
        match file.format {
            SceneFormat::CrowdNav => "CrowdNav",
            SceneFormat::Fsrl => "fsrl",
        }
    );
    let reference = crowdnav_reference && n == file.cases.len();
    print!("{}", scenes_table(&results, cfg.max_steps(), reference));
    if reference {
        println!(
            "\nCrowdNav: its holonomic ORCA robot (safety space 0) in its own simulator on the same \
             500 scenes, as reported in shared/data/crowdnav_cases/README.md (the paper's ORCA row)."
        );
    }
    Ok(())
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

/// The table of `shared/data/crowdnav_cases/README.md`: one row per visibility, with CrowdNav's
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

/// The metrics as a Markdown table, one row per setting plus averages per visibility.
///
/// Disc. is CrowdNav's danger frequency: a timed-out episode counts as `time_limit_steps`
/// steps. Under SPEC semantics a timeout takes exactly that many steps, so this is danger steps /
/// all steps; under `crowdnav` semantics CrowdNav's 97-step timeouts are booked as 100.
pub fn table(results: &[(Setting, Aggregate)], time_limit_steps: u32) -> String {
    let mut s = String::from(
        "| setting | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. | Path (m) | mean abs dθ (rad/step) |\n|---|---|---|---|---|---|---|---|\n",
    );
    let row = |name: &str, a: &Aggregate| {
        format!(
            "| {name} | {:.3} | {:.3} | {:.3} | {} | {:.3} | {} | {:.4} |\n",
            a.success_rate(),
            a.collision_rate(),
            a.timeout_rate(),
            opt(a.nav_time_s(), 2),
            a.danger_frequency(time_limit_steps),
            opt(a.path_length_m(), 2),
            a.mean_abs_rotation_rad()
        )
    };
    for (setting, agg) in results {
        s += &row(setting.name(), agg);
    }
    for visible in [false, true] {
        let mut sum = Aggregate::default();
        let mut n = 0;
        for (_, agg) in results.iter().filter(|(st, _)| st.robot_visible == visible) {
            sum.merge(agg);
            n += 1;
        }
        if n > 1 {
            let label = if visible {
                "visible (all)"
            } else {
                "invisible (all)"
            };
            s += &row(label, &sum);
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
    fn the_shared_crowdnav_scenes_are_recognised() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/crowdnav_cases/test_h10_scenes.csv");
        let Ok(file) = load_scenes(&path, &SimConfig::default()) else {
            return; // the shared data is not on this machine
        };
        assert!(is_crowdnav_h10_test_set(&file));
    }
}
