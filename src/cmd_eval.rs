//! `fsrl eval`: scores model files, checkpoints (or the ORCA baseline) on the test seeds of the
//! six settings (or those named, walled ones too; a model trained among walls on its own) with the paper's five metrics plus path length, smoothness and return, with 95% intervals, and
//! writes `eval.md` (the paper's table layout beside the paper's numbers), `eval.csv` and
//! `eval.json`.
//!
//! Every episode is one call of `evaluator::evaluate`, so the numbers are exactly those of the
//! evaluator (and of `fsrl train`'s report) while the per-episode values give the intervals.

use std::path::PathBuf;

use anyhow::bail;
use indicatif::ProgressBar;
use lab::evaluation::{default_settings, evaluate_orca, Crowd, EvalPlan, LoadedPolicy};
use lab::policy_choice::resolve_input;
use lab::policy_file::Input;
use policy::method::Select;
use sim::{CrowdModel, Setting, SimConfig};

use crate::config::FileConfig;
use lab::report::{EvalReport, EVAL_KIND};

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Model files (.fsrlm, from `fsrl export-model`), checkpoints (.ckpt files) or run
    /// directories of `fsrl train` (their checkpoints/latest.ckpt, or the validation snapshot
    /// their `train.select` chooses); a file's kind is read from its first bytes.
    pub inputs: Vec<PathBuf>,
    /// Which weights of a run directory: last, best-validation, low-disc, best-return or
    /// revalidated-return (the best validation returns scored again on fresh validation seeds,
    /// kept in the run's revalidation.jsonl) [default: the run's train.select].
    #[arg(long, value_parser = parse_select)]
    pub select: Option<Select>,
    /// Also evaluate the ORCA baseline.
    #[arg(long)]
    pub orca: bool,
    /// Test episodes per setting.
    #[arg(long, default_value_t = 500)]
    pub episodes: u32,
    /// First test seed (CrowdNav's test seeds start at 1000).
    #[arg(long, default_value_t = 1000)]
    pub seed_start: u64,
    /// Settings, comma-separated: the paper's six (env1-invisible ... env3-visible) and the
    /// walled ones (corridor, doorway, room-invisible, room-visible, pillars-invisible,
    /// pillars-visible) [default: the paper's six; for a model trained in a walled setting,
    /// that setting].
    #[arg(long, value_delimiter = ',')]
    pub settings: Vec<String>,
    /// Output directory for eval.md, eval.csv and eval.json [default: RUN/eval for a single run
    /// directory, else ./eval].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Worker threads [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Simulator config for the ORCA baseline (TOML with a [sim] table; models and checkpoints
    /// carry their own).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Extra radius the ORCA robot keeps from humans (CrowdNav: 0 at test time).
    #[arg(long, default_value_t = 0.0)]
    pub safety_space_m: f64,
    /// Decide with depth-2 planning over the K best first steps, whatever the models were
    /// trained with (`train.planning_top_k`; 0: the paper's one-step lookahead) [default: each
    /// model's own].
    #[arg(long, value_name = "K")]
    pub planning_top_k: Option<usize>,
    /// When planning, try the M best one-step actions as second steps (0: every action),
    /// whatever the models say (`train.planning_breadth`) [default: each model's own].
    #[arg(long, value_name = "M")]
    pub planning_breadth: Option<usize>,
    /// Moving people per episode instead of each setting's own (the paper's six only; Env 2's
    /// and Env 3's five standing people stay, in the paper's arena): how a policy holds in a
    /// larger or smaller crowd than it was trained with.
    #[arg(long, value_name = "N")]
    pub people: Option<usize>,
    /// How the people walk, instead of as each policy was trained: orca, social-force or mixed
    /// (`humans.social_force_fraction` of them social force).
    #[arg(long, value_name = "MODEL", value_parser = parse_crowd)]
    pub crowd: Option<CrowdModel>,
    /// Decide with the people shield over this many seconds, whatever the models were trained
    /// with (`train.shield_s`; 0: off): an action that, held this long, meets a person walking
    /// on at constant velocity is never chosen while another keeps clear [default: each
    /// model's own].
    #[arg(long, value_name = "SECONDS")]
    pub shield_s: Option<f64>,
    /// Decide with the progress tie-break, whatever the models were trained with
    /// (`train.progress_tolerance`; 0: off): among the actions whose lookahead value is within
    /// this much of the best, the one whose step ends nearest the goal [default: each model's
    /// own].
    #[arg(long, value_name = "VALUE")]
    pub progress_tolerance: Option<f64>,
}

/// `--crowd`: a `humans.model` value.
pub fn parse_crowd(s: &str) -> Result<CrowdModel, String> {
    s.parse()
        .map_err(|e: sim::config::UnknownName| e.to_string())
}

/// `--select`: a `train.select` value.
pub fn parse_select(s: &str) -> Result<Select, String> {
    Select::ALL
        .into_iter()
        .find(|r| r.name() == s)
        .ok_or_else(|| {
            let names: Vec<&str> = Select::ALL.iter().map(|r| r.name()).collect();
            format!("{s:?}: not one of {}", names.join(", "))
        })
}

pub fn progress(len: u64, what: &str) -> ProgressBar {
    launch::progress::bar(len, what, 12, false)
}

/// The settings named on the command line (`None` when none: each subject's defaults,
/// [`default_settings`]), every problem reported at once.
pub fn parse_settings(names: &[String]) -> anyhow::Result<Option<Vec<Setting>>> {
    if names.is_empty() {
        return Ok(None);
    }
    Ok(Some(SimConfig::default().resolve_settings(names)?))
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    if args.inputs.is_empty() && !args.orca {
        bail!(
            "nothing to evaluate: name model files, checkpoints or run directories, or pass --orca"
        );
    }
    if args.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let max = policy::lookahead::MAX_PLANNING_TOP_K;
    for (flag, v) in [
        ("--planning-top-k", args.planning_top_k),
        ("--planning-breadth", args.planning_breadth),
    ] {
        if let Some(v) = v.filter(|&v| v > max) {
            bail!("{flag} must be in 0..={max}, got {v}");
        }
    }
    if let Some(s) = args
        .shield_s
        .filter(|s| !(s.is_finite() && (0.0..=policy::method::MAX_SHIELD_S).contains(s)))
    {
        bail!(
            "--shield-s must be in [0, {}] seconds, got {s}",
            policy::method::MAX_SHIELD_S
        );
    }
    if let Some(t) = args
        .progress_tolerance
        .filter(|t| !(t.is_finite() && (0.0..=policy::method::MAX_PROGRESS_TOLERANCE).contains(t)))
    {
        bail!(
            "--progress-tolerance must be in [0, {}], got {t}",
            policy::method::MAX_PROGRESS_TOLERANCE
        );
    }
    let settings = parse_settings(&args.settings)?;
    let crowd = Crowd {
        people: args.people,
        model: args.crowd,
    };
    crowd.check(settings.as_deref().unwrap_or(&Setting::ALL))?;
    let inputs = args
        .inputs
        .iter()
        .map(|p| resolve_input(p, args.select))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let out = match &args.out {
        Some(o) => o.clone(),
        None => match inputs.as_slice() {
            [Input {
                run_dir: Some(d), ..
            }] if !args.orca => d.join("eval"),
            _ => PathBuf::from("eval"),
        },
    };
    let mut plan = EvalPlan {
        settings: Vec::new(),
        seed_start: args.seed_start,
        episodes: args.episodes,
        threads,
        orca_safety_space_m: args.safety_space_m,
        planning_top_k: args.planning_top_k,
        planning_breadth: args.planning_breadth,
        crowd,
        shield_s: args.shield_s,
        progress_tolerance: args.progress_tolerance,
    };
    let mut subjects = Vec::new();
    let per_subject = |plan: &EvalPlan| plan.settings.len() as u64 * args.episodes as u64;
    if args.orca {
        let sim = FileConfig::load(args.config.as_deref())?.sim;
        sim.validate()?;
        plan.settings = settings.clone().unwrap_or_else(|| Setting::ALL.to_vec());
        let bar = progress(per_subject(&plan), "orca");
        subjects.push(evaluate_orca(&sim, &plan, &|| bar.inc(1))?);
        bar.finish_and_clear();
    }
    for input in &inputs {
        let policy = LoadedPolicy::read(input)?;
        plan.settings = settings
            .clone()
            .unwrap_or_else(|| default_settings(policy.model.setting));
        let bar = progress(
            per_subject(&plan),
            &policy.label.chars().take(12).collect::<String>(),
        );
        subjects.push(policy.evaluate(&plan, &|| bar.inc(1))?);
        bar.finish_and_clear();
        let m = &policy.model;
        eprintln!(
            "evaluated {} ({} trained on {}, policy version {})",
            policy.label, m.method, m.setting, m.counters.policy_version
        );
    }
    let report = EvalReport {
        kind: EVAL_KIND.into(),
        test_seed_start: args.seed_start,
        episodes_per_setting: args.episodes,
        crowd: plan.crowd.label(),
        subjects,
    };
    report.write(&out)?;
    println!("{}", report.markdown());
    println!("written: {}/eval.md, eval.csv, eval.json", out.display());
    Ok(())
}
