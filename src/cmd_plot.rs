//! `fsrl plot ...`: the pictures, each as SVG and PNG (and a GIF of an episode):
//! `bars` (outcome rates per setting and method, paper Fig. 5), `curves` (learning curves from
//! metrics.jsonl, and the validation curves against RL episodes and wall-clock time, seeds of a
//! method together), `ablation` (paper Fig. 8–9) and `episode` (a trajectory with attention
//! weights at chosen times, paper Fig. 7, plus an animated GIF) and `frontier` (every validated
//! snapshot of runs as Nav. Time against Disc., beside the paper's rows).

use std::path::PathBuf;

use anyhow::{bail, Context};
use lab::compare::{group, load_sources};
use lab::policy_choice::resolve_input;
use lab::policy_file::{label_of, load_policy};

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
    /// One episode: trajectory with every human's attention weight at chosen times, and a GIF;
    /// a walled setting's walls and obstacles are drawn with it.
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
    let assumed = lab::frontier::Assumed {
        method: a.method,
        setting: a.setting,
        decay_end: a.decay_end,
    };
    let runs = a
        .runs
        .iter()
        .map(|r| lab::frontier::read_run(r, &assumed, a.min_success))
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
        for p in lab::frontier::common_speed_picks(&runs) {
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
    let table = lab::frontier::markdown(&runs, a.min_success);
    print!("{table}");
    let mut written = viz::save(
        &lab::frontier::figure(&runs, a.title, a.min_success),
        &a.out,
    )?;
    let md = viz::with_ext(&a.out, "md");
    std::fs::write(&md, &table).with_context(|| format!("cannot write {}", md.display()))?;
    written.push(md);
    Ok(written)
}

fn bars(a: BarsArgs) -> anyhow::Result<Vec<PathBuf>> {
    let groups = group(load_sources(&a.sources)?);
    let Some(fig) = lab::figures::outcome_bars(&groups, a.title) else {
        bail!("no results in {:?}", a.sources);
    };
    Ok(viz::save(&fig, &a.out)?)
}

fn curves(a: CurvesArgs) -> anyhow::Result<Vec<PathBuf>> {
    let runs = a
        .runs
        .iter()
        .map(|p| lab::figures::curve_run(p))
        .collect::<anyhow::Result<Vec<_>>>()?;
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
    let (fig, table) = lab::figures::ablation(&groups, visible, a.title)
        .with_context(|| format!("sources {:?}", a.sources))?;
    print!("{table}");
    let mut written = viz::save(&fig, &a.out)?;
    let md = viz::with_ext(&a.out, "md");
    std::fs::write(&md, &table).with_context(|| format!("cannot write {}", md.display()))?;
    written.push(md);
    Ok(written)
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
    let trace = lab::picture::play(
        loaded.as_ref().map(|(m, l)| (m, l.as_str())),
        a.setting.as_deref(),
        a.seed,
    )?;
    let times = if a.times.is_empty() {
        lab::picture::default_times(&trace)
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
