//! `fsrl sim`: the ORCA robot on the six settings, the paper's metrics as a table, and an episode
//! as an SVG picture (drawn by `viz`, as `fsrl plot episode` draws it); or the ORCA robot on explicit scenes from a file (`--scenes`), e.g.
//! CrowdNav's 500 test scenes beside CrowdNav's own numbers.

use std::path::{Path, PathBuf};

use anyhow::Context;
use lab::baseline::{
    is_crowdnav_h10_test_set, load_scenes, robot_description, run_scene_cases, run_settings,
    scenes_table, table,
};
use sim::{run_episode_with, Env, Kinematics, SceneFormat, Semantics, Setting, SimConfig};

use crate::config::FileConfig;
use lab::picture;

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
    /// `radius_m`, `v_pref_mps`, `standing` columns), or TOML with static obstacles (polygons,
    /// walls, bounding walls; e.g. examples/scenes/*.toml), checked before anything runs; see the
    /// `sim::scenes` and `sim::scene_map` docs. On CrowdNav's 500 test scenes the table shows
    /// CrowdNav's numbers beside ours.
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
    #[command(flatten)]
    pub robot_link: crate::cmd_robot::AsRobotArgs,
}

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
    if args.robot_link.as_robot {
        let seeds = args.seed_start..args.seed_start + episodes as u64;
        return crate::cmd_robot::as_robot(&args.robot_link, cfg, &args.settings, seeds);
    }
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
        let map = env.walls().map(|w| w.map());
        let trace = picture::trace(title.clone(), &episode, &humans, &[], map);
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
            SceneFormat::Toml => "fsrl TOML",
        }
    );
    let reference = crowdnav_reference && n == file.cases.len();
    print!("{}", scenes_table(&results, cfg.max_steps(), reference));
    if reference {
        println!(
            "\nCrowdNav: its holonomic ORCA robot (safety space 0) in its own simulator on the same \
             500 scenes, as reported in testdata/crowdnav_cases/README.md (the paper's ORCA row)."
        );
    }
    Ok(())
}
