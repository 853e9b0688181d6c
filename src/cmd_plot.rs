//! `fsrl plot ...`: the pictures, each as SVG and PNG (and a GIF of an episode):
//! `bars` (outcome rates per setting and method, paper Fig. 5), `curves` (learning curves from
//! metrics.jsonl, and the validation curves against RL episodes and wall-clock time, seeds of a
//! method together), `ablation` (paper Fig. 8–9) and `episode` (a trajectory with attention
//! weights at chosen times, paper Fig. 7, plus an animated GIF) and `frontier` (every validated
//! snapshot of runs as Nav. Time against Disc., beside the paper's rows).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{bail, Context};
use policy::lookahead::{HumanModel, Lookahead};
use policy::method::Method;
use sim::{run_episode, Env, Setting};
use viz::{Interval, OutcomeCell};

use crate::cmd_compare::{group, load_sources, Group};
use crate::cmd_eval::{label_of, load_policy, resolve_input};
use crate::config::FileConfig;
use crate::report::{Metric, SubjectReport};

#[derive(Debug, clap::Args)]
pub struct PlotArgs {
    #[command(subcommand)]
    pub what: PlotCommand,
}

#[derive(Debug, clap::Subcommand)]
pub enum PlotCommand {
    /// Success / collision / timeout rates per setting and method (paper Fig. 5).
    Bars(BarsArgs),
    /// Success rate, return and loss against RL episodes, and the validation success, collision
    /// and Disc. against RL episodes and wall-clock time, from runs' metrics.jsonl.
    Curves(CurvesArgs),
    /// The reward ablation: sarl (R_c), sarl+foresight (+R_f), sarl+efficiency (+R_t), fsrl (all).
    Ablation(AblationArgs),
    /// One episode: trajectory with every human's attention weight at chosen times, and a GIF.
    Episode(EpisodeArgs),
    /// Every validated snapshot of runs as Nav. Time against Disc., beside the paper's rows: is
    /// the paper's point among the policies the runs passed through? Writes a table too, with
    /// the methods compared at a common speed and over their whole trajectories.
    Frontier(FrontierArgs),
}

#[derive(Debug, clap::Args)]
pub struct FrontierArgs {
    /// Run directories of `fsrl train` or `fsrl reproduce` (their config.toml,
    /// metrics.jsonl and validation snapshots).
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Output path without extension: writes OUT.svg, OUT.png and OUT.md (the table).
    #[arg(long, default_value = "frontier")]
    pub out: PathBuf,
    #[arg(long)]
    pub title: Option<String>,
    /// For directories without config.toml (a metrics.jsonl alone): the method they trained.
    #[arg(long)]
    pub method: Option<String>,
    /// For directories without config.toml: the setting they trained in.
    #[arg(long)]
    pub setting: Option<String>,
    /// For directories without config.toml: the RL episode at which their ε decay ended.
    #[arg(long)]
    pub decay_end: Option<u64>,
    /// The success a validation line needs to be drawn (default: the one `low-disc` needs).
    #[arg(long, default_value_t = policy::method::LOW_DISC_MIN_SUCCESS)]
    pub min_success: f64,
    /// Print the snapshots that would be drawn, one `RUN<TAB>RL_EPISODES` line each (the
    /// snapshot file is RUN/checkpoints/validation/ep-<RL_EPISODES, 6 digits>.fsrlm), and
    /// write nothing.
    #[arg(long)]
    pub list: bool,
    /// Print one snapshot per run and write nothing: `common-speed` takes the gentlest good
    /// snapshot no slower than the median validation Nav. Time of all runs given in its setting
    /// (docs/REPRODUCTION.md, Experiment 15). One `RUN<TAB>RL_EPISODES<TAB>T*<TAB>HOW` line a
    /// run; RL_EPISODES is `last` where the run ships its last weights.
    #[arg(long, value_enum, conflicts_with = "list")]
    pub pick: Option<Pick>,
}

/// Rules of `fsrl plot frontier --pick`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Pick {
    CommonSpeed,
}

#[derive(Debug, clap::Args)]
pub struct BarsArgs {
    /// Run directories or eval.json files (as for `fsrl compare`).
    #[arg(required = true)]
    pub sources: Vec<PathBuf>,
    /// Output path without extension: writes OUT.svg and OUT.png.
    #[arg(long, default_value = "outcomes")]
    pub out: PathBuf,
    #[arg(long)]
    pub title: Option<String>,
}

#[derive(Debug, clap::Args)]
pub struct CurvesArgs {
    /// Run directories (their metrics.jsonl) or metrics.jsonl files. Runs named alike but for
    /// a final `-s<seed>` (fsrl-env1-invisible-s0, fsrl-env1-invisible-s1, ...) share a colour
    /// in the validation curves: their mean and min–max band.
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Output path without extension: writes OUT.svg and OUT.png, and, from the runs with
    /// validation lines, OUT-validation-episodes.{svg,png} and OUT-validation-time.{svg,png}.
    #[arg(long, default_value = "curves")]
    pub out: PathBuf,
    /// Moving-average window (episodes) for return and loss.
    #[arg(long, default_value_t = 100)]
    pub window: usize,
    #[arg(long)]
    pub title: Option<String>,
}

#[derive(Debug, clap::Args)]
pub struct AblationArgs {
    /// Run directories or eval.json files of sarl, sarl+foresight, sarl+efficiency and fsrl.
    #[arg(required = true)]
    pub sources: Vec<PathBuf>,
    /// Average over Env 1–3 of this visibility: invisible (as the paper) or visible.
    #[arg(long, default_value = "invisible")]
    pub visibility: String,
    /// Output path without extension: writes OUT.svg, OUT.png and OUT.md (the numbers drawn,
    /// with Welch's test of each arm against R_c).
    #[arg(long, default_value = "ablation")]
    pub out: PathBuf,
    #[arg(long)]
    pub title: Option<String>,
}

#[derive(Debug, clap::Args)]
pub struct EpisodeArgs {
    /// A model file, checkpoint or run directory (omit with --orca).
    pub input: Option<PathBuf>,
    /// Picture the ORCA baseline instead.
    #[arg(long)]
    pub orca: bool,
    /// Setting [default: the run's trained setting, env2-invisible for ORCA].
    #[arg(long)]
    pub setting: Option<String>,
    /// Episode seed (test seeds start at 1000).
    #[arg(long, default_value_t = 1000)]
    pub seed: u64,
    /// Times (s) of the panels, comma-separated [default: a third, two thirds and the end].
    #[arg(long, value_delimiter = ',')]
    pub times: Vec<f64>,
    /// Output path without extension: writes OUT.svg, OUT.png and OUT.gif.
    #[arg(long, default_value = "episode")]
    pub out: PathBuf,
    /// Do not write the GIF.
    #[arg(long)]
    pub no_gif: bool,
    /// Side of the GIF's scene in pixels.
    #[arg(long, default_value_t = 360)]
    pub gif_size: u32,
    /// Milliseconds per GIF frame.
    #[arg(long, default_value_t = 150)]
    pub frame_ms: u32,
    /// One GIF frame every this many steps (smaller files).
    #[arg(long, default_value_t = 1)]
    pub stride: usize,
}

pub fn run(args: PlotArgs) -> anyhow::Result<()> {
    let written = match args.what {
        PlotCommand::Bars(a) => bars(a)?,
        PlotCommand::Curves(a) => curves(a)?,
        PlotCommand::Ablation(a) => ablation(a)?,
        PlotCommand::Episode(a) => episode(a)?,
        PlotCommand::Frontier(a) => frontier(a)?,
    };
    for p in written {
        println!("written: {}", p.display());
    }
    Ok(())
}

fn frontier(a: FrontierArgs) -> anyhow::Result<Vec<PathBuf>> {
    if !(0.0..=1.0).contains(&a.min_success) {
        bail!("--min-success {}: not a rate in [0, 1]", a.min_success);
    }
    let assumed = crate::frontier::Assumed {
        method: a.method,
        setting: a.setting,
        decay_end: a.decay_end,
    };
    let runs = a
        .runs
        .iter()
        .map(|r| crate::frontier::read_run(r, &assumed, a.min_success))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if a.list {
        for r in &runs {
            for v in &r.good {
                println!("{}\t{}", r.run.display(), v.rl_episodes);
            }
        }
        return Ok(Vec::new());
    }
    if let Some(Pick::CommonSpeed) = a.pick {
        for p in crate::frontier::common_speed_picks(&runs) {
            println!(
                "{}\t{}\t{}\t{}",
                p.run.run.display(),
                p.pick
                    .map_or_else(|| "last".to_string(), |v| v.rl_episodes.to_string()),
                p.nav_time
                    .map_or_else(|| "-".to_string(), |t| format!("{t:.3}")),
                p.how.name()
            );
        }
        return Ok(Vec::new());
    }
    let table = crate::frontier::markdown(&runs, a.min_success);
    print!("{table}");
    let mut written = viz::save(
        &crate::frontier::figure(&runs, a.title, a.min_success),
        &a.out,
    )?;
    let md = viz::with_ext(&a.out, "md");
    std::fs::write(&md, &table).with_context(|| format!("cannot write {}", md.display()))?;
    written.push(md);
    Ok(written)
}

fn clip(x: f64) -> f64 {
    x.clamp(0.0, 1.0)
}

/// A rate's bar: a single run's Wilson interval, or mean ± std over runs.
fn rate_interval(g: &Group, metric: Metric, setting: Setting) -> Option<Interval> {
    if let Some(r) = g.single(setting) {
        let (v, ci) = metric.of(r)?;
        let [lo, hi] = ci.unwrap_or([v, v]);
        return Some(Interval { mean: v, lo, hi });
    }
    let st = g.stat(metric, setting)?;
    let sd = st.std.unwrap_or(0.0);
    Some(Interval {
        mean: st.mean,
        lo: clip(st.mean - sd),
        hi: clip(st.mean + sd),
    })
}

fn outcome_cell(g: &Group, setting: Setting) -> Option<OutcomeCell> {
    Some(OutcomeCell {
        success: rate_interval(g, Metric::Success, setting)?,
        collision: rate_interval(g, Metric::Collision, setting)?,
        timeout: rate_interval(g, Metric::Timeout, setting)?,
    })
}

const INTERVAL_NOTE: &str =
    "error bars: 95% Wilson interval for a single run, ± standard deviation over runs otherwise";

fn pretty_setting(s: Setting) -> String {
    let name = s.name();
    let (env, vis) = name.split_once('-').unwrap_or((name, ""));
    format!("Env {} ({vis})", env.trim_start_matches("env"))
}

/// A method's runs per setting: `3`, or `1–3` where the settings have different numbers of runs
/// (a grid whose seeds are not all trained yet).
fn runs_label(g: &Group) -> String {
    let (lo, hi) = (g.runs_by_setting().min(), g.runs_per_setting());
    match lo {
        Some(lo) if lo != hi => format!("{lo}–{hi}"),
        _ => hi.to_string(),
    }
}

fn bars(a: BarsArgs) -> anyhow::Result<Vec<PathBuf>> {
    let groups = group(load_sources(&a.sources)?);
    let settings: Vec<Setting> = Setting::ALL
        .iter()
        .copied()
        .filter(|&s| {
            groups
                .iter()
                .any(|g| g.single(s).is_some() || g.stat(Metric::Success, s).is_some())
        })
        .collect();
    if settings.is_empty() {
        bail!("no results in {:?}", a.sources);
    }
    let fig = viz::OutcomeBars {
        title: a
            .title
            .unwrap_or_else(|| "Outcome rates per setting and method".into()),
        settings: settings.iter().map(|&s| pretty_setting(s)).collect(),
        methods: groups
            .iter()
            .map(|g| format!("{} ({})", g.method, runs_label(g)))
            .collect(),
        cells: settings
            .iter()
            .map(|&s| groups.iter().map(|g| outcome_cell(g, s)).collect())
            .collect(),
        interval_note: format!("{INTERVAL_NOTE}; (n) = runs per setting"),
    };
    Ok(viz::save(&fig, &a.out)?)
}

fn curves(a: CurvesArgs) -> anyhow::Result<Vec<PathBuf>> {
    let mut runs = Vec::new();
    for path in &a.runs {
        let file = if path.is_dir() {
            path.join("metrics.jsonl")
        } else {
            path.clone()
        };
        let metrics = viz::metrics::read_metrics(&file)?;
        if metrics.torn_last_line {
            eprintln!(
                "warning: {}: the last line is cut short (the run stopped while writing it); left out",
                file.display()
            );
        }
        let dir = if path.is_dir() {
            path.clone()
        } else {
            path.parent().map(PathBuf::from).unwrap_or_default()
        };
        let label = dir
            .canonicalize()
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| path.display().to_string());
        runs.push(viz::CurveRun { label, metrics });
    }
    if runs.iter().all(|r| {
        let m = &r.metrics;
        m.rl.is_empty() && m.imitation.is_empty() && m.validation.is_empty()
    }) {
        bail!("no imitation, RL or validation lines in {:?}", a.runs);
    }
    let title = a.title.unwrap_or_else(|| "Learning curves".into());
    let validated: Vec<viz::CurveRun> = runs
        .iter()
        .filter(|r| !r.metrics.validation.is_empty())
        .cloned()
        .collect();
    for r in runs.iter().filter(|r| r.metrics.validation.is_empty()) {
        eprintln!(
            "note: {} has no validation lines (`fsrl train` writes them every \
             train.validation_every_episodes RL episodes); it is in the learning curves only",
            r.label
        );
    }
    let mut written = viz::save(
        &viz::LearningCurves {
            title: title.clone(),
            runs,
            window: a.window.max(1),
        },
        &a.out,
    )?;
    if validated.is_empty() {
        eprintln!("note: no run has validation lines: no validation curves drawn");
        return Ok(written);
    }
    let groups = viz::group_runs(validated);
    for (axis, suffix, against) in [
        (
            viz::ValidationAxis::Episodes,
            "validation-episodes",
            "RL episodes",
        ),
        (
            viz::ValidationAxis::WallClock,
            "validation-time",
            "wall-clock time",
        ),
    ] {
        let mut stem = a.out.clone().into_os_string();
        stem.push(format!("-{suffix}"));
        let fig = viz::ValidationCurves {
            title: format!("{title}: validation against {against}"),
            groups: groups.clone(),
            axis,
        };
        written.extend(viz::save(&fig, &PathBuf::from(stem))?);
    }
    Ok(written)
}

fn ablation(a: AblationArgs) -> anyhow::Result<Vec<PathBuf>> {
    let visible = match a.visibility.as_str() {
        "invisible" => false,
        "visible" => true,
        v => bail!("--visibility must be invisible or visible, got {v:?}"),
    };
    let groups = group(load_sources(&a.sources)?);
    let envs: Vec<Setting> = Setting::ALL
        .iter()
        .copied()
        .filter(|s| s.robot_visible == visible)
        .collect();
    let variants = [
        ("sarl", "R_c (sarl)"),
        ("sarl+foresight", "+R_f"),
        ("sarl+efficiency", "+R_t"),
        ("fsrl", "all (fsrl)"),
    ];
    let interval = |g: Option<&Group>, metric: Metric, rate: bool| -> Option<Interval> {
        let (mean, std) = crate::report::mean_std(&seed_averages(&g?.members, &envs, metric))?;
        let sd = std.unwrap_or(0.0);
        let (lo, hi) = (mean - sd, mean + sd);
        Some(if rate {
            Interval {
                mean,
                lo: clip(lo),
                hi: clip(hi),
            }
        } else {
            Interval {
                mean,
                lo: lo.max(0.0),
                hi,
            }
        })
    };
    let find = |m: &str| groups.iter().find(|g| g.method == m);
    if variants.iter().all(|(m, _)| find(m).is_none()) {
        bail!(
            "none of sarl, sarl+foresight, sarl+efficiency, fsrl in {:?}",
            a.sources
        );
    }
    let fig = viz::Ablation {
        title: a.title.unwrap_or_else(|| {
            format!("Reward ablation: averages over Env 1–3 ({})", a.visibility)
        }),
        variants: variants
            .iter()
            .map(|(m, label)| {
                let seeds = find(m).map_or(0, |g| {
                    seed_averages(&g.members, &envs, Metric::Success).len()
                });
                format!("{label} ({seeds})")
            })
            .collect(),
        outcomes: variants
            .iter()
            .map(|(m, _)| {
                let g = find(m);
                Some(OutcomeCell {
                    success: interval(g, Metric::Success, true)?,
                    collision: interval(g, Metric::Collision, true)?,
                    timeout: interval(g, Metric::Timeout, true)?,
                })
            })
            .collect(),
        nav_time_s: variants
            .iter()
            .map(|(m, _)| interval(find(m), Metric::NavTime, false))
            .collect(),
        disc: variants
            .iter()
            .map(|(m, _)| interval(find(m), Metric::Disc, false))
            .collect(),
        interval_note:
            "error bars: ± standard deviation over seeds (none for one); (n) = seeds with all three envs"
                .into(),
    };
    let members = |m: &str| find(m).map_or(&[][..], |g| g.members.as_slice());
    let table = ablation_markdown(&variants, members, &envs, &a.visibility);
    print!("{table}");
    let mut written = viz::save(&fig, &a.out)?;
    let md = viz::with_ext(&a.out, "md");
    std::fs::write(&md, &table).with_context(|| format!("cannot write {}", md.display()))?;
    written.push(md);
    Ok(written)
}

/// The ablation's numbers: per arm, mean ± std over its seeds' averages over `envs`, and Welch's
/// test of each arm against the first (R_c) over those seed averages.
fn ablation_markdown<'a>(
    variants: &[(&str, &str)],
    members: impl Fn(&str) -> &'a [SubjectReport],
    envs: &[Setting],
    visibility: &str,
) -> String {
    const METRICS: [Metric; 5] = [
        Metric::Success,
        Metric::Collision,
        Metric::Timeout,
        Metric::NavTime,
        Metric::Disc,
    ];
    let mut s = format!(
        "Reward ablation, {visibility}: each arm's value is the mean ± std over its training seeds of the seed's average over Env 1–3 (seeds with a result in all three; per seed in seed order in brackets below the table); p: Welch's test against R_c over the seed averages.\n\n| arm | seeds | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. |\n|---|---|---|---|---|---|---|\n"
    );
    let base: Vec<Vec<f64>> = METRICS
        .iter()
        .map(|&m| seed_averages(members(variants[0].0), envs, m))
        .collect();
    let mut per_seed = String::new();
    for (i, (method, label)) in variants.iter().enumerate() {
        let values: Vec<Vec<f64>> = METRICS
            .iter()
            .map(|&m| seed_averages(members(method), envs, m))
            .collect();
        let cells: Vec<String> = METRICS
            .iter()
            .zip(&values)
            .zip(&base)
            .map(|((metric, xs), b)| {
                let mut c = crate::report::mean_std_cell(xs, metric.digits());
                if i > 0 {
                    if let Some(w) = crate::report::welch(xs, b) {
                        let _ = write!(c, " (p = {:.2})", w.p);
                    }
                }
                c
            })
            .collect();
        let _ = writeln!(
            s,
            "| {label} | {} | {} |",
            values[0].len(),
            cells.join(" | ")
        );
        let fmt = |k: usize| {
            values[k]
                .iter()
                .map(|v| format!("{v:.prec$}", prec = METRICS[k].digits()))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let _ = writeln!(
            per_seed,
            "- {label}: Succ. [{}], Nav. Time [{}], Disc. [{}]",
            fmt(0),
            fmt(3),
            fmt(4)
        );
    }
    s.push('\n');
    s.push_str(&per_seed);
    s
}

/// A method's `metric` averaged over `envs`, one value per training seed, as the paper's ablation
/// averages each arm over the three environments. The members of one seed are taken together: a
/// grid of `fsrl reproduce` has one member per setting (each trained there), an evaluation of one
/// model on all six settings a single member with every setting; a seed counts only with a result
/// in each of `envs` (an average over fewer would not be the same quantity). Members that do not
/// know their seed count each on their own.
fn seed_averages(members: &[SubjectReport], envs: &[Setting], metric: Metric) -> Vec<f64> {
    let mut by_seed: BTreeMap<(Option<u64>, usize), Vec<Vec<f64>>> = BTreeMap::new();
    for (i, m) in members.iter().enumerate() {
        let key = m.run_seed.map_or((None, i), |s| (Some(s), 0));
        let per_env = by_seed
            .entry(key)
            .or_insert_with(|| vec![Vec::new(); envs.len()]);
        for (vals, &s) in per_env.iter_mut().zip(envs) {
            if let Some((v, _)) = m.setting(s).and_then(|r| metric.of(r)) {
                vals.push(v);
            }
        }
    }
    by_seed
        .values()
        .filter_map(|per_env| {
            let means = per_env
                .iter()
                .map(|v| crate::report::mean_std(v).map(|m| m.0))
                .collect::<Option<Vec<f64>>>()?;
            crate::report::mean_std(&means).map(|m| m.0)
        })
        .collect()
}

fn episode(a: EpisodeArgs) -> anyhow::Result<Vec<PathBuf>> {
    if a.orca == a.input.is_some() {
        bail!("name one model file, checkpoint or run directory, or pass --orca");
    }
    let loaded = match &a.input {
        Some(p) => {
            let input = resolve_input(p, None)?;
            let label = label_of(&input);
            Some((load_policy(&input.checkpoint)?.0, label))
        }
        None => None,
    };
    let (method, sim_cfg, trained) = match &loaded {
        Some((l, _)) => (l.method, l.sim.clone(), Some(l.setting.name().to_string())),
        None => (Method::Orca, FileConfig::default().sim, None),
    };
    let setting_name = a
        .setting
        .clone()
        .or(trained)
        .unwrap_or_else(|| "env2-invisible".into());
    let setting = sim_cfg.resolve_settings(&[setting_name.as_str()])?[0];
    let mut env = Env::new(method.sim_config(&sim_cfg), setting, a.seed)
        .with_context(|| format!("cannot build {setting} seed {}", a.seed))?;
    let humans0 = env.humans().to_vec();
    let n = humans0.len();
    let mut attention: Vec<Option<Vec<f64>>> = Vec::new();
    let mut failure = None;
    let episode = match &loaded {
        None => run_episode(&mut env, |env| env.orca_robot_action(0.0), true)?,
        Some((l, _)) => {
            let train = &l.train;
            let human_model: HumanModel = train.human_model.into();
            let mut la = Lookahead::new(train.gamma, human_model, method.human_order())
                .with_terminal_previews(train.terminal_previews);
            let net = &l.net;
            run_episode(
                &mut env,
                |env| match la.decide(env, net) {
                    Ok(d) => {
                        let row = la.attention(net).and_then(|att| {
                            att.get(d.action * n..(d.action + 1) * n)
                                .map(|r| r.iter().map(|&w| w as f64).collect())
                        });
                        attention.push(row);
                        d.action
                    }
                    Err(e) => {
                        failure.get_or_insert(e);
                        attention.push(None);
                        0
                    }
                },
                true,
            )?
        }
    };
    if let Some(e) = failure {
        return Err(anyhow::Error::new(e).context("the policy failed during the episode"));
    }
    let who = loaded.as_ref().map_or_else(
        || "orca".to_string(),
        |(_, label)| format!("{method} ({label})"),
    );
    let title = format!("{who} on {setting}, seed {}", a.seed);
    let trace = crate::picture::trace(title, &episode, &humans0, &attention);
    let times = if a.times.is_empty() {
        crate::picture::default_times(&trace)
    } else {
        a.times.clone()
    };
    if let Some(t) = times.iter().find(|t| !t.is_finite() || **t < 0.0) {
        bail!("--times: {t} is not a time within the episode");
    }
    let mut written = viz::save(
        &viz::Trajectory {
            trace: trace.clone(),
            times_s: times,
        },
        &a.out,
    )?;
    if !a.no_gif {
        written.push(viz::save_gif(
            &trace,
            &viz::with_ext(&a.out, "gif"),
            a.gif_size.clamp(120, 2000),
            a.frame_ms.max(10),
            a.stride,
        )?);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::SettingReport;

    fn result(setting: Setting, success: f64) -> SettingReport {
        SettingReport {
            setting: setting.name().to_string(),
            episodes: 100,
            successes: (success * 100.0) as u32,
            collisions: 0,
            timeouts: 0,
            success,
            success_ci95: None,
            collision: 0.0,
            collision_ci95: None,
            timeout: 0.0,
            timeout_ci95: None,
            nav_time_s: Some(10.0),
            nav_time_ci95_s: None,
            nav_time_std_s: None,
            disc: 0.0,
            danger_steps: 0,
            steps: 0,
            path_length_m: None,
            path_length_std_m: None,
            mean_abs_rotation_rad: 0.0,
            mean_return: 0.0,
            return_std: None,
        }
    }

    fn member(seed: Option<u64>, results: &[(usize, f64)]) -> SubjectReport {
        SubjectReport {
            label: String::new(),
            method: "sarl".into(),
            checkpoint: None,
            checkpoint_sha256: None,
            policy_version: 0,
            run_seed: seed,
            trained_setting: None,
            settings: results
                .iter()
                .map(|&(i, v)| result(Setting::ALL[i], v))
                .collect(),
        }
    }

    #[test]
    fn the_ablation_averages_each_seed_over_the_three_environments() {
        let envs = [Setting::ALL[0], Setting::ALL[1], Setting::ALL[2]];
        assert!(envs.iter().all(|s| !s.robot_visible));
        let members = [
            // Seed 0 as a grid: one run per environment.
            member(Some(0), &[(0, 0.9)]),
            member(Some(0), &[(1, 0.6)]),
            member(Some(0), &[(2, 0.3)]),
            // Seed 1 trained in Env 1 only: not an average over the three, left out.
            member(Some(1), &[(0, 1.0)]),
            // A model evaluated everywhere, seed unknown: its own average (visible ignored).
            member(None, &[(0, 0.5), (1, 0.5), (2, 0.8), (3, 0.0)]),
        ];
        let v = seed_averages(&members, &envs, Metric::Success);
        assert_eq!(v.len(), 2, "{v:?}");
        assert!(
            (v[0] - 0.6).abs() < 1e-12 && (v[1] - 0.6).abs() < 1e-12,
            "{v:?}"
        );
        // Two runs of one seed in the same environment count as their mean there.
        let twice = [
            member(Some(3), &[(0, 0.2), (1, 0.2), (2, 0.2)]),
            member(Some(3), &[(2, 0.8)]),
        ];
        let v = seed_averages(&twice, &envs, Metric::Success);
        assert_eq!(v.len(), 1);
        assert!((v[0] - 0.3).abs() < 1e-12, "{v:?}");
        assert!(seed_averages(&[], &envs, Metric::Success).is_empty());
    }

    #[test]
    fn the_ablation_table_tests_each_arm_against_r_c_over_seed_averages() {
        let envs = [Setting::ALL[0], Setting::ALL[1], Setting::ALL[2]];
        let grid = |seed: u64, s: [f64; 3]| -> Vec<SubjectReport> {
            (0..3).map(|i| member(Some(seed), &[(i, s[i])])).collect()
        };
        // R_c: seed averages 0.6 and 0.7; +R_f: 0.9 and 0.95; +R_t and fsrl: nothing.
        let rc: Vec<SubjectReport> = [grid(0, [0.9, 0.6, 0.3]), grid(1, [0.7, 0.7, 0.7])].concat();
        let rf: Vec<SubjectReport> = [grid(0, [0.9, 0.9, 0.9]), grid(1, [1.0, 0.9, 0.95])].concat();
        let variants = [
            ("sarl", "R_c"),
            ("sarl+foresight", "+R_f"),
            ("sarl+efficiency", "+R_t"),
        ];
        let md = ablation_markdown(
            &variants,
            |m| match m {
                "sarl" => rc.as_slice(),
                "sarl+foresight" => rf.as_slice(),
                _ => &[],
            },
            &envs,
            "invisible",
        );
        assert!(
            md.contains("| R_c | 2 | 0.650 ± 0.071 | 0.000 ± 0.000 |"),
            "{md}"
        );
        let w = crate::report::welch(&[0.9, 0.95], &[0.6, 0.7]).unwrap();
        assert!(
            md.contains(&format!("| +R_f | 2 | 0.925 ± 0.035 (p = {:.2}) |", w.p)),
            "{md}"
        );
        assert!(md.contains("| +R_t | 0 | – | – | – | – | – |"), "{md}");
        assert!(
            md.contains("- +R_f: Succ. [0.900, 0.950], Nav. Time [10.00, 10.00]"),
            "{md}"
        );
    }
}
