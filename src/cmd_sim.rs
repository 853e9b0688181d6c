//! `fsrl sim`: the ORCA robot on the six settings, the paper's metrics as a table, and an episode
//! as an SVG picture.

use std::path::PathBuf;

use anyhow::Context;
use sim::{run_episode, Aggregate, Env, Setting, SimConfig};

use crate::config::FileConfig;
use crate::svg;

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Episodes per setting.
    #[arg(long, default_value_t = 500)]
    pub episodes: u32,
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
    /// Write one episode as an SVG picture to this file.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Setting of the pictured episode (default: the first one run).
    #[arg(long)]
    pub svg_setting: Option<String>,
    /// Seed of the pictured episode (default: seed_start).
    #[arg(long)]
    pub svg_seed: Option<u64>,
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
    let cfg = file.sim;
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
    if args.episodes == 0 {
        problems.push("--episodes must be at least 1".into());
    }
    if !args.safety_space_m.is_finite() || args.safety_space_m < 0.0 {
        problems.push(format!(
            "--safety-space-m must be a finite number >= 0, got {}",
            args.safety_space_m
        ));
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
        args.episodes,
        args.safety_space_m,
    )?;
    println!(
        "ORCA robot, {} episodes per setting, seeds {}..{}\n",
        args.episodes,
        args.seed_start,
        args.seed_start + args.episodes as u64 - 1
    );
    print!("{}", table(&results));

    if let Some(path) = &args.svg {
        let setting = match &svg_setting_name {
            Some(n) => n.parse().expect("validated"),
            None => settings[0],
        };
        let seed = args.svg_seed.unwrap_or(args.seed_start);
        let mut env = Env::new(cfg.clone(), setting, seed)?;
        let humans = env.humans().to_vec();
        let safety = args.safety_space_m;
        let episode = run_episode(&mut env, |env| env.orca_robot_action(safety), true)?;
        let title = format!(
            "{setting} · seed {seed} · ORCA robot · {} after {:.2} s",
            episode.summary.outcome.name(),
            episode.summary.time_s
        );
        let picture = svg::render(
            &episode,
            &humans,
            cfg.dt_s,
            &svg::PictureInfo {
                title: &title,
                policy: "ORCA",
            },
        );
        std::fs::write(path, picture)
            .with_context(|| format!("cannot write {}", path.display()))?;
        println!("\nwrote {} ({title})", path.display());
    }
    Ok(())
}

/// Runs `episodes` ORCA-robot episodes per setting, settings spread over the available cores.
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
                            let ep = run_episode(
                                &mut env,
                                |env| env.orca_robot_action(safety_space_m),
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
pub fn table(results: &[(Setting, Aggregate)]) -> String {
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
            a.discomfort(),
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
