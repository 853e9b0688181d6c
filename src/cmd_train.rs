//! `fsrl train`: trains one method on one setting, as a learner, actors and an evaluator
//! (`launch.rs`) or, with `--single-process`, in this process (`trainer::run`: the same parts in
//! lockstep), with progress, Ctrl-C handling, `--resume`, and the same final evaluation on the
//! setting's test seeds in both modes.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use learner::checkpoint;
use learner::LearnerCore;
use policy::method::{ReplayRatio, RunSpec, Select};
use transport::DataPlane;

use crate::config::{check_train, run_checkpoint, ReplayRatioArg, Resolved, RunOverrides};
use lab::evaluation::final_evaluation;
use lab::run::RunTiming;

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    #[command(flatten)]
    pub run: RunOverrides,
    /// Test episodes of the final evaluation [default: 500]
    #[arg(long)]
    pub eval_episodes: Option<u32>,
    /// Checkpoint every N RL episodes [default: 500]
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// Run directory [default: runs/<method>-<setting>-s<seed>]
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Train in this one process instead of learner + actors + evaluator processes.
    #[arg(long)]
    pub single_process: bool,
    /// Actor processes (multi-process mode)
    #[arg(long, default_value_t = 2)]
    pub actors: u32,
    /// Data plane of the local run: iceoryx2 (shared memory) or zenoh
    #[arg(long, default_value = "iceoryx2")]
    pub transport: String,
    /// Skip the evaluator process (multi-process mode)
    #[arg(long)]
    pub no_evaluator: bool,
    /// Updates per RL episode of a distributed run: `MIN,MAX` (the adaptive replay ratio: the
    /// learner trains flat out, taking episodes while it has done between MIN and MAX updates
    /// per episode) or `fixed` (train.rl.batches_per_episode each) [default: the config's
    /// train.rl.replay_ratio, else 4,20; a resumed run keeps its own; --single-process: fixed]
    #[arg(long, value_name = "MIN,MAX|fixed", allow_hyphen_values = true, value_parser = ReplayRatioArg::parse)]
    pub replay_ratio: Option<ReplayRatioArg>,
    /// Serve a live page of the run on http://127.0.0.1:PORT/ (`fsrl dashboard`; the
    /// distributed mode, whose processes publish live metrics)
    #[arg(long, value_name = "PORT", conflicts_with = "single_process")]
    pub dashboard: Option<u16>,
    /// Write no TensorBoard files (runs/<run>/tb/); to measure what they cost (`cargo bench
    /// --bench watch_cost`) or where nobody reads them
    #[arg(long)]
    pub no_tensorboard: bool,
}

fn resolve(args: &TrainArgs) -> anyhow::Result<Resolved> {
    let mut file = args.run.load()?;
    let mut problems = Vec::new();
    if let Some(n) = args.eval_episodes {
        file.train.eval_episodes = n;
    }
    if let Some(n) = args.checkpoint_every {
        file.train.checkpoint_every_episodes = n;
    }
    if file.run.method == "orca" {
        problems.push("method orca is not trainable; evaluate it with `fsrl sim`".to_string());
    }
    Ok(file.resolve(problems)?)
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr_with_hz(4));
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{what:>10} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} ({{per_sec}}, ETA {{eta}}) {{msg}}"
        ))
        .expect("valid template"),
    );
    bar
}

/// Prints a plain progress line when stderr is not a terminal (CI logs), at most every 10 s.
struct PlainProgress {
    last: Instant,
}

impl PlainProgress {
    fn tick(&mut self, bar: &ProgressBar, force: bool) {
        if bar.is_hidden() && (force || self.last.elapsed() >= Duration::from_secs(10)) {
            self.last = Instant::now();
            let elapsed = bar.elapsed().as_secs_f64();
            let rate = bar.position() as f64 / elapsed.max(1e-9);
            let left =
                bar.length().unwrap_or(0).saturating_sub(bar.position()) as f64 / rate.max(1e-9);
            eprintln!(
                "{}/{} ({rate:.2}/s, ETA {left:.0} s) {}",
                bar.position(),
                bar.length().unwrap_or(0),
                bar.message()
            );
        }
    }
}

/// Progress bars of a single-process run (plain lines every 10 s when stderr is not a terminal).
#[derive(Default)]
struct Bars {
    bar: Option<ProgressBar>,
    plain: Option<PlainProgress>,
}

impl Bars {
    fn show(&mut self, len: u64, what: &str) -> &ProgressBar {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
        self.plain.get_or_insert(PlainProgress {
            last: Instant::now(),
        });
        self.bar.insert(progress_bar(len, what))
    }
    fn tick(&mut self) {
        if let (Some(bar), Some(plain)) = (&self.bar, &mut self.plain) {
            plain.tick(bar, false);
        }
    }
}

impl trainer::Progress for Bars {
    fn demos(&mut self, done: u64, total: u64) {
        if done == 1 {
            self.show(total, "demos");
        }
        if let Some(b) = &self.bar {
            b.set_position(done);
        }
        self.tick();
    }
    fn imitation_epoch(&mut self, epoch: u32, total: u32, loss: f32) {
        if epoch == 1 {
            self.show(total as u64, "imitation");
        }
        if let Some(b) = &self.bar {
            b.set_position(epoch as u64);
            b.set_message(format!("loss {loss:.5}"));
        }
        self.tick();
    }
    fn imitation_done(&mut self, loss: f32, transitions: usize) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
        eprintln!("imitation done: loss {loss:.5}, {transitions} transitions");
    }
    fn rl_start(&mut self, first: u64, total: u64) {
        let bar = self.show(total, "rl");
        bar.set_position(first);
        bar.reset_eta();
    }
    fn rl_episode(&mut self, line: &trainer::RlLine<'_>, episodes_per_s: f64) {
        if let Some(b) = &self.bar {
            b.inc(1);
            b.set_message(format!(
                "ε {:.3} success {:.2} loss {:.5} {episodes_per_s:.2} ep/s",
                line.epsilon, line.success_rate_window, line.loss
            ));
        }
        self.tick();
    }
    fn validated(&mut self, _line: &serde_json::Value) {
        if let Some(b) = &self.bar {
            b.reset_eta();
        }
    }
    fn rl_end(&mut self) {
        if let (Some(bar), Some(plain)) = (&self.bar, &mut self.plain) {
            plain.tick(bar, true);
        }
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }
}

/// The default mode: learner, actors and an evaluator as child processes (`launch::local`).
fn distributed(args: TrainArgs) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
            eprintln!("\ninterrupted: stopping the learner (it checkpoints), actors and evaluator; Ctrl-C again to quit at once");
        })
        .context("cannot install the Ctrl-C handler")?;
    }
    let mut problems = Vec::new();
    let data_plane = match args.transport.as_str() {
        "iceoryx2" => DataPlane::Iceoryx2,
        "zenoh" => DataPlane::Zenoh,
        other => {
            problems.push(format!(
                "--transport must be iceoryx2 or zenoh, got `{other}`"
            ));
            DataPlane::Zenoh
        }
    };
    if args.actors == 0 {
        problems.push("--actors must be at least 1".to_string());
    }
    let mut resolved = match resolve(&args) {
        Ok(r) => r,
        Err(e) => {
            if problems.is_empty() {
                return Err(e);
            }
            anyhow::bail!("{e:#}\n  - {}", problems.join("\n  - "));
        }
    };
    if !problems.is_empty() {
        return Err(sim::ConfigError { problems }.into());
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| resolved.default_run_dir());
    let (ratio, whence) = distributed_replay_ratio(&args, &resolved, &out)?;
    resolved.file.train.rl.replay_ratio = ratio;
    resolved.file.train.select = distributed_select(&args, &resolved, &out)?;
    // The schedule with its ratio, before anything is written or started (a bad ratio would
    // otherwise start every process and be refused by the learner).
    check_train(&resolved.file.train, &whence)?;
    let select = &mut resolved.file.train.select;
    if args.no_evaluator && *select != Select::Last {
        // Without the evaluator nothing is validated and no snapshot is kept: the run's policy
        // can only be its last weights (recorded in the run's config.toml).
        eprintln!(
            "note: --no-evaluator: no validations, so the run's policy is its last weights (train.select = \"last\" instead of \"{}\")",
            select.name()
        );
        *select = Select::Last;
    }
    let launch = launch::local::Launch {
        exe: std::env::current_exe().context("cannot find the fsrl executable")?,
        resolved,
        out,
        resume: args.resume,
        actors: args.actors,
        data_plane,
        evaluator: !args.no_evaluator,
        eval_episodes: args.eval_episodes,
        dashboard: args.dashboard,
        tensorboard: !args.no_tensorboard,
    };
    launch::local::run(launch, &stop)
}

/// On `--resume`, the config the run was started with (its `config.toml`), if it has one.
fn started_config(
    args: &TrainArgs,
    out: &std::path::Path,
) -> anyhow::Result<Option<crate::config::FileConfig>> {
    let started = out.join("config.toml");
    if !(args.resume && started.exists()) {
        return Ok(None);
    }
    crate::config::FileConfig::load(Some(&started))
        .with_context(|| {
            format!(
                "{} (the run's own config) is not readable",
                started.display()
            )
        })
        .map(Some)
}

/// The snapshot choice of a distributed run: on `--resume`, the one the run was started with
/// (its `config.toml`); else the config's own `[train] select` or the method's, else
/// [`Select::DISTRIBUTED_DEFAULT`] (Experiments 26–27).
fn distributed_select(
    args: &TrainArgs,
    resolved: &Resolved,
    out: &std::path::Path,
) -> anyhow::Result<Select> {
    if let Some(file) = started_config(args, out)? {
        return Ok(file.train.select);
    }
    Ok(resolved.file.distributed_select())
}

/// The replay ratio of a distributed run: `--replay-ratio` if given; on `--resume`, the one the
/// run was started with (its `config.toml`), so that a run resumes to its own schedule; else
/// the config's, else [`ReplayRatio::LOCAL_DEFAULT`] (Experiment 18: level with the shipped
/// models in about half the time of one process). With it, where it comes from (for errors).
fn distributed_replay_ratio(
    args: &TrainArgs,
    resolved: &Resolved,
    out: &std::path::Path,
) -> anyhow::Result<(Option<ReplayRatio>, String)> {
    if let Some(ReplayRatioArg(r)) = args.replay_ratio {
        return Ok((r, "--replay-ratio".into()));
    }
    if let Some(file) = started_config(args, out)? {
        let whence = format!(
            "{} (the run's own config; --replay-ratio overrides it)",
            out.join("config.toml").display()
        );
        return Ok((file.train.rl.replay_ratio, whence));
    }
    Ok((
        resolved
            .file
            .train
            .rl
            .replay_ratio
            .or(Some(ReplayRatio::LOCAL_DEFAULT)),
        "the run's config".into(),
    ))
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    if !args.single_process {
        return distributed(args);
    }
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::SeqCst) {
                eprintln!("second interrupt: exiting without a final checkpoint");
                std::process::exit(130);
            }
            eprintln!("\ninterrupted: finishing the current episode and writing a checkpoint (Ctrl-C again to quit at once)");
        })
        .context("cannot install the Ctrl-C handler")?;
    }
    let resolved = resolve(&args)?;
    if let Some(ReplayRatioArg(Some(_))) = args.replay_ratio {
        anyhow::bail!(
            "--replay-ratio MIN,MAX (the adaptive mode) needs a distributed run; --single-process runs the fixed schedule of train.rl.batches_per_episode updates per episode: drop one of the two"
        );
    }
    if resolved.file.train.rl.replay_ratio.is_some() {
        // Before anything is written: the lockstep schedule has one round per episode.
        return Err(trainer::TrainerError::AdaptiveNeedsProcesses.into());
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| resolved.default_run_dir());
    let ckpt_dir = out.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)
        .with_context(|| format!("cannot create {}", ckpt_dir.display()))?;
    // One training per run directory, as the learner process holds it in multi-process mode.
    let _lock = learner::store::RunLock::acquire(&out)?;
    let latest = run_checkpoint(&out, args.resume)?;

    let (mut core, resolved) = if args.resume {
        let mut loaded = checkpoint::load(&latest)?;
        if let Some(r) = loaded.core.config().rl.replay_ratio {
            // A distributed run in the adaptive mode (the default): its schedule is in its own
            // config.toml and checkpoint, not in anything the user wrote.
            anyhow::bail!(
                "{} was trained as a distributed run with the adaptive replay ratio {},{} (needs a distributed run; --single-process runs only the fixed schedule): resume it without --single-process",
                out.display(),
                r.min,
                r.max
            );
        }
        if let Some(n) = args.run.rl_episodes {
            loaded.core.set_rl_episodes(n);
        }
        let mut file = resolved.file.clone();
        file.run.method = loaded.core.method().name().to_string();
        file.run.setting = loaded.run.setting.clone();
        file.run.seed = loaded.run.run_seed;
        file.sim = loaded.sim.clone();
        file.train = loaded.core.config().clone();
        let c = loaded.core.counters();
        eprintln!(
            "resuming {} from {}: {} RL episodes done, policy version {}",
            out.display(),
            latest.display(),
            c.rl_episodes,
            c.policy_version
        );
        (loaded.core, file.resolve(Vec::new())?)
    } else {
        let core = LearnerCore::new(
            resolved.method,
            resolved.file.train.clone(),
            resolved.file.sim.humans.count,
            resolved.file.sim.dt_s,
            resolved.file.run.seed,
        )?;
        (core, resolved)
    };
    let file = &resolved.file;
    let method = resolved.method;
    let setting = resolved.setting;
    let run_seed = file.run.seed;
    let train = core.config().clone();
    std::fs::write(out.join("config.toml"), toml::to_string(file)?)
        .with_context(|| format!("cannot write {}", out.join("config.toml").display()))?;
    let spec = RunSpec {
        method,
        setting,
        sim: file.sim.clone(),
        train: train.clone(),
        seed: run_seed,
    };
    let run = trainer::Run {
        spec: &spec,
        out: &out,
        run_id: out
            .file_name()
            .map_or_else(|| "run".into(), |n| n.to_string_lossy().into_owned()),
        resumed: args.resume,
    };
    let start = Instant::now();
    // Where the time goes (run.json; a resumed run adds to what the earlier ones recorded).
    let mut timing = RunTiming::read(&out, "single-process");
    eprintln!(
        "training {method} on {setting} (seed {run_seed}) in {}: {} demonstrations × {} epochs, {} RL episodes",
        out.display(),
        train.imitation.episodes,
        train.imitation.epochs,
        train.rl.episodes
    );
    let mut bars = Bars::default();
    // TensorBoard files in out/tb/, from metrics.jsonl as it grows (a thread of its own).
    let board = (!args.no_tensorboard).then(|| {
        tboard::Follower::spawn(
            &out,
            tboard::Mode::SingleProcess {
                updates_per_episode: train.rl.batches_per_episode as f64,
            },
        )
    });
    let (exit, t) = trainer::run(&mut core, &run, &stop, &mut bars)?;
    drop(board);
    timing.add_s("warm_start_s", t.warm_start_s);
    timing.add_s("rl_s", t.rl_s);
    timing.add_s("validation_s", t.validation_s);
    timing.add_s("total_s", start.elapsed().as_secs_f64());
    timing.write(&out)?;
    if exit == trainer::Exit::Stopped {
        eprintln!(
            "checkpoint written to {} after {} RL episodes; continue with the same command and --resume",
            latest.display(),
            core.counters().rl_episodes
        );
        return Ok(());
    }

    // Final evaluation on the setting's test seeds: the run's policy by its selection rule.
    let final_start = Instant::now();
    final_evaluation(&out, &spec)?;
    timing.add_s("final_evaluation_s", final_start.elapsed().as_secs_f64());
    timing.add_s("total_s", final_start.elapsed().as_secs_f64());
    timing.write(&out)?;
    println!(
        "run directory: {} (config.toml, checkpoints/, metrics.jsonl, report.md, report.json); {:.1} s in all",
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        train: TrainArgs,
    }

    fn try_args(extra: &[&str]) -> Result<TrainArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("fsrl-train").chain(extra.iter().copied()))
            .map(|c| c.train)
    }

    fn args(extra: &[&str]) -> TrainArgs {
        try_args(extra).unwrap()
    }

    /// A distributed run chooses by `best-return` unless its config (or its method) chooses,
    /// and a resumed run by the rule it was started with (Experiments 26–27).
    #[test]
    fn a_distributed_runs_choice_comes_from_its_own_config_the_file_the_method_or_the_default() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let o = out.to_str().unwrap();
        let select = |a: &TrainArgs| distributed_select(a, &resolve(a).unwrap(), &out).unwrap();
        assert_eq!(select(&args(&["--out", o])), Select::DISTRIBUTED_DEFAULT);
        assert_eq!(Select::DISTRIBUTED_DEFAULT, Select::BestReturn);
        let cfg = dir.path().join("c.toml");
        std::fs::write(&cfg, "[train]\nselect = \"low-disc\"\n").unwrap();
        let c = cfg.to_str().unwrap();
        assert_eq!(select(&args(&["--out", o, "--config", c])), Select::LowDisc);
        let plan = args(&["--out", o, "--config", c, "--method", "fsrl-plan"]);
        assert_eq!(
            select(&plan),
            Select::LowDisc,
            "the file's own choice stays"
        );
        assert_eq!(
            select(&args(&["--out", o, "--method", "fsrl-plan"])),
            Select::BestReturn
        );
        // A run started with low-disc resumes with it.
        std::fs::create_dir_all(&out).unwrap();
        std::fs::copy(&cfg, out.join("config.toml")).unwrap();
        assert_eq!(select(&args(&["--out", o, "--resume"])), Select::LowDisc);
    }

    #[test]
    fn a_distributed_runs_replay_ratio_comes_from_the_flag_its_own_config_the_file_or_the_default()
    {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let o = out.to_str().unwrap();
        let ratio =
            |a: &TrainArgs| distributed_replay_ratio(a, &resolve(a).unwrap(), &out).map(|r| r.0);
        let bounds = |min, max| Some(ReplayRatio { min, max });

        assert_eq!(
            ratio(&args(&["--out", o])).unwrap(),
            Some(ReplayRatio::LOCAL_DEFAULT)
        );
        let cfg = dir.path().join("c.toml");
        std::fs::write(&cfg, "[train.rl]\nreplay_ratio = { min = 2, max = 9 }\n").unwrap();
        let c = cfg.to_str().unwrap();
        assert_eq!(
            ratio(&args(&["--out", o, "--config", c])).unwrap(),
            bounds(2.0, 9.0)
        );
        assert_eq!(
            ratio(&args(&[
                "--out",
                o,
                "--config",
                c,
                "--replay-ratio",
                "fixed"
            ]))
            .unwrap(),
            None
        );
        assert_eq!(
            ratio(&args(&["--out", o, "--replay-ratio", "5,6"])).unwrap(),
            bounds(5.0, 6.0)
        );
        // A bad flag is refused as the arguments are parsed (issue 44): syntax and bounds.
        for (bad, says) in [
            ("5", "MIN,MAX"),
            ("nan", "MIN,MAX"),
            ("inf", "MIN,MAX"),
            ("5,1", "must not exceed"),
            ("-1,4", "min >= 0"),
            ("0,0", "max > 0"),
            ("nan,4", "finite"),
            ("2,inf", "finite"),
        ] {
            let e = try_args(&["--out", o, "--replay-ratio", bad]).err();
            let e = e.map(|e| e.to_string()).unwrap_or_default();
            assert!(
                e.contains(says) && e.contains("--replay-ratio"),
                "{bad}: {e}"
            );
        }

        // A run started with the fixed schedule resumes with it, whatever today's default.
        std::fs::create_dir_all(&out).unwrap();
        let started = resolve(&args(&["--out", o])).unwrap();
        assert_eq!(started.file.train.rl.replay_ratio, None);
        std::fs::write(
            out.join("config.toml"),
            toml::to_string(&started.file).unwrap(),
        )
        .unwrap();
        assert_eq!(ratio(&args(&["--out", o, "--resume"])).unwrap(), None);
        assert_eq!(
            ratio(&args(&["--out", o, "--resume", "--replay-ratio", "4,20"])).unwrap(),
            Some(ReplayRatio::LOCAL_DEFAULT)
        );
        std::fs::write(out.join("config.toml"), "[train.rl]\nnot_a_key = 1\n").unwrap();
        let e = ratio(&args(&["--out", o, "--resume"])).unwrap_err();
        assert!(format!("{e:#}").contains("the run's own config"), "{e:#}");
    }
}
