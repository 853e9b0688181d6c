//! A run in one process (`fsrl train --single-process`): `trainer::run` (the learner's core, the
//! actor's episode loop and the evaluator's validation in lockstep) with progress bars, the
//! run's lock and `--resume`, its TensorBoard files, `run.json`, and the final evaluation of
//! the run's policy on the setting's test seeds, as a distributed run ends. Read top to bottom:
//! [`run`] checks the schedule, takes the run directory, starts or resumes the learner's core,
//! trains, and evaluates.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Context;
use learner::checkpoint;
use learner::LearnerCore;
use policy::method::{ReplayRatio, RunSpec};

use lab::evaluation::final_evaluation;
use lab::run::RunTiming;

use crate::config::{replay_ratio, run_checkpoint, Mode, RatioSource, Resolved};
use crate::progress::Bars;

/// What to train.
pub struct SingleRun {
    /// The run's configuration (validated).
    pub resolved: Resolved,
    /// The run directory.
    pub out: PathBuf,
    /// Continue the run in `out` from its last checkpoint.
    pub resume: bool,
    /// `--rl-episodes` (a resumed run trains to this many instead of its own count).
    pub rl_episodes: Option<u64>,
    /// `--replay-ratio` (`Some(None)`: `fixed`); one process runs only the fixed schedule.
    pub replay_ratio: Option<Option<ReplayRatio>>,
    /// Keep the run's TensorBoard files (`tb/`) in step with its log.
    pub tensorboard: bool,
}

/// Trains the run to the end of its schedule (or until `stop` is set: a checkpoint, and
/// `resume` goes on), then evaluates the run's policy; progress on stderr.
pub fn run(r: SingleRun, stop: &AtomicBool) -> anyhow::Result<()> {
    refuse_adaptive(&r)?;
    let out = &r.out;
    let ckpt_dir = out.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)
        .with_context(|| format!("cannot create {}", ckpt_dir.display()))?;
    // One training per run directory, as the learner process holds it in multi-process mode.
    let _lock = learner::store::RunLock::acquire(out)?;
    let latest = run_checkpoint(out, r.resume)?;
    let (mut core, resolved) = start_or_resume(&r, &latest)?;
    std::fs::write(out.join("config.toml"), toml::to_string(&resolved.file)?)
        .with_context(|| format!("cannot write {}", out.join("config.toml").display()))?;
    let spec = RunSpec {
        train: core.config().clone(),
        ..resolved.spec()
    };
    let start = Instant::now();
    // Where the time goes (run.json; a resumed run adds to what the earlier ones recorded).
    let mut timing = RunTiming::read(out, "single-process");
    let exit = train(&r, &spec, &mut core, stop, &mut timing, start)?;
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
    final_evaluation(out, &spec, &lab::policy_choice::run_policy(out, None)?)?;
    timing.add_s("final_evaluation_s", final_start.elapsed().as_secs_f64());
    timing.add_s("total_s", final_start.elapsed().as_secs_f64());
    timing.write(out)?;
    println!(
        "run directory: {} (config.toml, checkpoints/, metrics.jsonl, report.md, report.json); {:.1} s in all",
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Before anything is written: one process runs the fixed schedule only ([`replay_ratio`]).
fn refuse_adaptive(r: &SingleRun) -> anyhow::Result<()> {
    let file = r.resolved.file.train.rl.replay_ratio;
    match replay_ratio(Mode::SingleProcess, r.replay_ratio, None, file) {
        Ok(_) => Ok(()),
        Err(RatioSource::Flag) => anyhow::bail!(
            "--replay-ratio MIN,MAX (the adaptive mode) needs a distributed run; --single-process runs the fixed schedule of train.rl.batches_per_episode updates per episode: drop one of the two"
        ),
        // The lockstep schedule has one round per episode.
        Err(_) => Err(trainer::TrainerError::AdaptiveNeedsProcesses.into()),
    }
}

/// The learner's core and the run's config: new, or the run's checkpoint (its own method,
/// setting, seed, simulator and schedule; `--rl-episodes` may lengthen it).
fn start_or_resume(r: &SingleRun, latest: &Path) -> anyhow::Result<(LearnerCore, Resolved)> {
    let resolved = &r.resolved;
    if !r.resume {
        let core = LearnerCore::new(
            resolved.method,
            resolved.file.train.clone(),
            resolved.file.sim.entities(resolved.setting),
            resolved.file.sim.dt_s,
            resolved.file.run.seed,
        )?;
        return Ok((core, resolved.clone()));
    }
    let mut loaded = checkpoint::load(latest)?;
    let own = loaded.core.config().rl.replay_ratio;
    if let (Err(_), Some(b)) = (
        replay_ratio(Mode::SingleProcess, None, Some(own), None),
        own,
    ) {
        // A distributed run in the adaptive mode (the default): its schedule is in its own
        // config.toml and checkpoint, not in anything the user wrote.
        anyhow::bail!(
            "{} was trained as a distributed run with the adaptive replay ratio {},{} (needs a distributed run; --single-process runs only the fixed schedule): resume it without --single-process",
            r.out.display(),
            b.min,
            b.max
        );
    }
    if let Some(n) = r.rl_episodes {
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
        r.out.display(),
        latest.display(),
        c.rl_episodes,
        c.policy_version
    );
    Ok((loaded.core, file.resolve(Vec::new())?))
}

/// The training itself (`trainer::run`) with progress bars and TensorBoard files; its time
/// goes into `run.json`.
fn train(
    r: &SingleRun,
    spec: &RunSpec,
    core: &mut LearnerCore,
    stop: &AtomicBool,
    timing: &mut RunTiming,
    start: Instant,
) -> anyhow::Result<trainer::Exit> {
    let out = &r.out;
    let train = &spec.train;
    let run = trainer::Run {
        spec,
        out,
        run_id: out
            .file_name()
            .map_or_else(|| "run".into(), |n| n.to_string_lossy().into_owned()),
        resumed: r.resume,
    };
    eprintln!(
        "training {} on {} (seed {}) in {}: {} demonstrations × {} epochs, {} RL episodes",
        spec.method,
        spec.setting,
        spec.seed,
        out.display(),
        train.imitation.episodes,
        train.imitation.epochs,
        train.rl.episodes
    );
    let mut bars = Bars::default();
    // TensorBoard files in out/tb/, from metrics.jsonl as it grows (a thread of its own).
    let board = r.tensorboard.then(|| {
        tboard::Follower::spawn(
            out,
            tboard::Mode::SingleProcess {
                updates_per_episode: train.rl.batches_per_episode as f64,
            },
        )
    });
    let (exit, t) = trainer::run(core, &run, stop, &mut bars)?;
    drop(board);
    timing.add_s("warm_start_s", t.warm_start_s);
    timing.add_s("rl_s", t.rl_s);
    timing.add_s("validation_s", t.validation_s);
    timing.add_s("total_s", start.elapsed().as_secs_f64());
    timing.write(out)?;
    Ok(exit)
}
