//! `fsrl export-model`: a run's trained policy as a small self-describing model file (`.fsrlm`,
//! `learner::model`): method, network and weights, trained setting, seed, the run's configs and
//! counters, and a check (the greedy policy's outcome, steps and return on recorded test seeds
//! of its setting) that `tests/models.rs` replays for every model shipped in `models/`.

use std::path::PathBuf;

use anyhow::{bail, Context};
use learner::model::{
    load_policy, Model, DEFAULT_CHECK_EPISODES, DEFAULT_CHECK_SEED_START, EXTENSION,
};
use sim::Outcome;

use lab::policy_choice::resolve_input;

#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// A run directory of `fsrl train` (its checkpoints/latest.ckpt, or the validation
    /// snapshot its `train.select` chooses), a checkpoint, or a model file (its check is
    /// recorded again).
    pub input: PathBuf,
    /// Which weights of a run directory: last, best-validation, low-disc, best-return or
    /// revalidated-return (the best validation returns scored again on fresh validation seeds,
    /// kept in the run's revalidation.jsonl) [default: the run's train.select].
    #[arg(long, value_parser = crate::cmd_eval::parse_select)]
    pub select: Option<policy::method::Select>,
    /// The model file to write (conventionally models/<method>-<setting>-s<seed>.fsrlm).
    #[arg(long)]
    pub out: PathBuf,
    /// Greedy test episodes of the trained setting recorded as the model's check.
    #[arg(long, default_value_t = DEFAULT_CHECK_EPISODES)]
    pub check_episodes: u32,
    /// First check seed (test seeds start at 1000).
    #[arg(long, default_value_t = DEFAULT_CHECK_SEED_START)]
    pub check_seed_start: u64,
    /// Worker threads for the check [default: all cores].
    #[arg(long)]
    pub threads: Option<usize>,
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    if args.check_episodes == 0 {
        bail!("--check-episodes must be at least 1: a model carries the proof of its record");
    }
    if args.out.extension().is_none_or(|e| e != EXTENSION) {
        eprintln!(
            "note: {} does not end in .{EXTENSION} (readers go by content, so it still works)",
            args.out.display()
        );
    }
    let input = resolve_input(&args.input, args.select)?;
    let path = &input.checkpoint;
    let (mut model, _) =
        load_policy(path).with_context(|| format!("cannot load {}", path.display()))?;
    // The model records the rule that chose its weights: --select's, where it overrode the run's.
    if let (Some(rule), Some(_)) = (args.select, &input.run_dir) {
        model.train.select = rule;
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    model
        .record_check(args.check_seed_start, args.check_episodes, threads)
        .with_context(|| format!("checking {}", path.display()))?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    model.save(&args.out)?;
    // Read back what was written: the file is the product.
    let written = Model::load(&args.out)?;
    if written.check != model.check || written.net.params() != model.net.params() {
        bail!(
            "{}: the written model differs from the exported one",
            args.out.display()
        );
    }
    let size = std::fs::metadata(&args.out)
        .with_context(|| format!("cannot stat {}", args.out.display()))?
        .len();
    println!("{}", summary(&written, size, &args.out));
    Ok(())
}

/// What `export-model` prints: the file, what it holds and its check.
fn summary(m: &Model, size: u64, path: &std::path::Path) -> String {
    use std::fmt::Write as _;
    let mut s = format!(
        "wrote {} ({size} bytes, {:.1} KiB)\n  method {}, {} network with {} parameters\n  trained on {}, run seed {}, run id {}\n  policy version {}, {} RL episodes, {} env steps, chosen by train.select = \"{}\"\n",
        path.display(),
        size as f64 / 1024.0,
        m.method,
        m.net.kind().name(),
        m.net.num_params(),
        m.setting,
        m.run_seed,
        m.run_id,
        m.counters.policy_version,
        m.counters.rl_episodes,
        m.counters.env_steps,
        m.train.select.name(),
    );
    let count = |o: Outcome| m.check.iter().filter(|e| e.outcome == o).count();
    let (first, last) = (
        m.check.first().map_or(0, |e| e.seed),
        m.check.last().map_or(0, |e| e.seed),
    );
    let _ = writeln!(
        s,
        "  check: {} greedy episodes of {}, seeds {first}..={last}: {} reach-goal, {} collision, {} timeout",
        m.check.len(),
        m.setting,
        count(Outcome::ReachGoal),
        count(Outcome::Collision),
        count(Outcome::Timeout),
    );
    for e in &m.check {
        let _ = writeln!(
            s,
            "    seed {:>5}  {:<10}  {:>3} steps  return {:>9.4}",
            e.seed,
            e.outcome.name(),
            e.steps,
            e.return_sum
        );
    }
    s.trim_end().to_string()
}
