//! `trainer`: one training run in one process. The same parts as the distributed run — the
//! learner's core (`learner::LearnerCore`) and its warm start (`learner::imitation::run`), the
//! actor's episode loop (`actor::Player`) and the evaluator's validation
//! (`evaluator::process::validate`) — called in lockstep instead of over a transport: one
//! episode, then its `batches_per_episode` updates, then (when due) a validation and a
//! checkpoint. Nothing runs concurrently, so a run is a pure function of its config and seed
//! and is replayed bit for bit (the shipped models were trained this way).
//!
//! The run directory is the same as a distributed run's: `checkpoints/latest.ckpt` (and
//! `imitation.ckpt`), `checkpoints/validation/ep-<N>.fsrlm` (every validation's weights when
//! `train.select` chooses among them, written before its line), and `metrics.jsonl` (imitation
//! epochs, one line per RL episode, validations: `learner::runlog`, as the learner process
//! writes it). Progress is reported through [`Progress`]; the
//! binary draws it.

use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use learner::checkpoint::{self, RunInfo};
use learner::imitation::{self, ImitationProgress};
use learner::model::{snapshot_dir, snapshot_path, Model};
use learner::runlog;
use learner::LearnerCore;
use policy::method::{RunSpec, Select};
use sim::Outcome;

/// Why a run stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum TrainerError {
    #[error(transparent)]
    Learner(#[from] learner::LearnerError),
    #[error(transparent)]
    Checkpoint(#[from] checkpoint::CheckpointError),
    #[error(transparent)]
    Model(#[from] learner::model::ModelError),
    #[error(transparent)]
    Actor(#[from] actor::ActorError),
    #[error(transparent)]
    Evaluator(#[from] evaluator::process::ProcessError),
    #[error("{what}: {source}")]
    Io {
        what: String,
        source: std::io::Error,
    },
    #[error(
        "interrupted during the demonstrations (nothing to checkpoint yet; rerun the same command)"
    )]
    InterruptedInWarmStart,
    #[error(
        "train.rl.replay_ratio (the adaptive mode: the learner trains flat out while actors add experience) needs a distributed run; --single-process runs the fixed schedule of train.rl.batches_per_episode updates per episode: drop --single-process or the replay_ratio line"
    )]
    AdaptiveNeedsProcesses,
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> TrainerError {
    let what = what.into();
    move |source| TrainerError::Io { what, source }
}

/// How a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exit {
    /// Every RL episode of the schedule was trained (the last checkpoint is written).
    Finished,
    /// Stopped on request after a checkpoint; `--resume` goes on from it.
    Stopped,
}

/// What a run reports as it goes (the binary draws progress bars from it).
pub trait Progress {
    fn demos(&mut self, _done: u64, _total: u64) {}
    fn imitation_epoch(&mut self, _epoch: u32, _total: u32, _loss: f32) {}
    fn imitation_done(&mut self, _loss: f32, _transitions: usize) {}
    fn rl_start(&mut self, _first: u64, _total: u64) {}
    fn rl_episode(&mut self, _line: &RlLine<'_>, _episodes_per_s: f64) {}
    fn validated(&mut self, _line: &serde_json::Value) {}
    fn rl_end(&mut self) {}
}

/// A [`Progress`] that shows nothing.
pub struct Quiet;
impl Progress for Quiet {}

/// Where the time of this invocation went (seconds).
#[derive(Debug, Clone, Copy, Default)]
pub struct Timing {
    pub warm_start_s: f64,
    pub rl_s: f64,
    pub validation_s: f64,
}

pub use learner::runlog::RlLine;

/// The run: its spec (method, setting, configs, seed), its directory and identity.
pub struct Run<'a> {
    pub spec: &'a RunSpec,
    pub out: &'a Path,
    pub run_id: String,
    /// Whether `core` comes from the run's checkpoint (its log is then cut back to it).
    pub resumed: bool,
}

impl Run<'_> {
    fn latest(&self) -> PathBuf {
        self.out.join("checkpoints").join("latest.ckpt")
    }
}

/// Trains `core` (new, or loaded from the run's checkpoint) through the rest of its schedule:
/// the warm start unless the core has it, then the RL episodes from its count on, validating
/// and checkpointing on schedule. Returns how it ended and where the time went. `stop` ends the
/// run after the current episode with a checkpoint.
pub fn run(
    core: &mut LearnerCore,
    run: &Run<'_>,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
) -> Result<(Exit, Timing), TrainerError> {
    let spec = run.spec;
    let out = run.out;
    let sim_cfg = spec.method_sim();
    core.set_action_count(sim::ActionSet::for_config(&sim_cfg).len());
    let train = core.config().clone();
    if train.rl.replay_ratio.is_some() {
        return Err(TrainerError::AdaptiveNeedsProcesses);
    }
    let run_info = RunInfo {
        run_id: run.run_id.clone(),
        setting: spec.setting.name().to_string(),
        run_seed: spec.seed,
        accepted_below: Default::default(),
    };
    let latest = run.latest();
    let metrics_path = out.join("metrics.jsonl");
    // A resumed run's log is cut back to its checkpoint, and its clock goes on from there.
    let wall0 = if run.resumed {
        let dropped = runlog::trim(
            &metrics_path,
            core.counters().rl_episodes,
            runlog::Trim::RlAndValidations,
        )
        .map_err(io(format!("cannot rewrite {}", metrics_path.display())))?;
        if dropped > 0 {
            eprintln!(
                "{}: dropped {dropped} lines logged after the checkpoint (the resumed run does that work again)",
                metrics_path.display()
            );
        }
        runlog::last_wall(&metrics_path)
    } else {
        Duration::ZERO
    };
    let mut metrics = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&metrics_path)
        .map_err(io(format!("cannot open {}", metrics_path.display())))?;
    let save = |core: &LearnerCore, path: &Path| -> Result<(), TrainerError> {
        checkpoint::save(path, core, &sim_cfg, &run_info)?;
        Ok(())
    };
    let start = Instant::now();
    let mut timing = Timing::default();

    // The warm start (skipped when the checkpoint already has it): the learner process's own.
    if !core.counters().imitation_done {
        let mut log = runlog::ImitationLog::default();
        let finished = imitation::run(core, spec, stop, |p| {
            log.observe(&p, (wall0 + start.elapsed()).as_secs_f64());
            match p {
                ImitationProgress::Demo { done, total } => progress.demos(done, total),
                ImitationProgress::Epoch { done, total, loss } => {
                    progress.imitation_epoch(done, total, loss)
                }
                ImitationProgress::DemosDone { .. } | ImitationProgress::Batch { .. } => {}
            }
        })?;
        if !finished {
            return Err(TrainerError::InterruptedInWarmStart);
        }
        for line in log.lines() {
            writeln!(metrics, "{line}").map_err(io("cannot append to metrics.jsonl"))?;
        }
        save(core, &out.join("checkpoints").join("imitation.ckpt"))?;
        save(core, &latest)?;
        progress.imitation_done(core.imitation_loss()?, core.replay().len());
        timing.warm_start_s = start.elapsed().as_secs_f64();
    }

    // Deep V-learning: the actor's episode loop and the learner's updates, in lockstep.
    let mut player = actor::Player::new(spec)?;
    let mut window: VecDeque<Outcome> = VecDeque::with_capacity(100);
    let first = core.counters().rl_episodes;
    progress.rl_start(first, train.rl.episodes);
    let rl_start = Instant::now();
    let mut interrupted = false;
    let validate_every = train.validation_every_episodes;
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut validation_time = Duration::ZERO;
    let mut validate = |core: &LearnerCore,
                        metrics: &mut std::fs::File,
                        progress: &mut dyn Progress|
     -> Result<(), TrainerError> {
        let t0 = Instant::now();
        let c = core.counters();
        let point = evaluator::process::validate(
            spec,
            core.online(),
            threads,
            c.rl_episodes,
            wall0 + start.elapsed(),
        )?;
        let mut line = serde_json::to_value(&point).map_err(|e| io("validation line")(e.into()))?;
        line["env_steps"] = c.env_steps.into();
        line["policy_version"] = c.policy_version.into();
        if train.select != Select::Last {
            // The snapshot before its line: a line always has its weights on disk.
            let dir = snapshot_dir(out);
            std::fs::create_dir_all(&dir)
                .map_err(io(format!("cannot create {}", dir.display())))?;
            Model::from_core(core, &sim_cfg, &run_info)?
                .save(&snapshot_path(out, c.rl_episodes))?;
        }
        writeln!(metrics, "{line}").map_err(io("cannot append to metrics.jsonl"))?;
        progress.validated(&line);
        validation_time += t0.elapsed();
        Ok(())
    };
    if validate_every > 0 && first == 0 {
        validate(core, &mut metrics, progress)?;
    }
    for k in first..train.rl.episodes {
        let epsilon = core.epsilon();
        let version = core.counters().policy_version;
        let ep = player.play(actor::LOCKSTEP_STREAM, k, core.online(), version, epsilon)?;
        core.add_episode(&ep, false)?;
        let loss = core.train_rl(train.rl.batches_per_episode)?;
        if window.len() == 100 {
            window.pop_front();
        }
        window.push_back(ep.outcome);
        let rate =
            |o: Outcome| window.iter().filter(|x| **x == o).count() as f64 / window.len() as f64;
        let c = core.counters();
        let done = (k + 1 - first) as f64;
        let eps_per_s = done / rl_start.elapsed().as_secs_f64().max(1e-9);
        let line = RlLine {
            phase: "rl",
            episode: k,
            epsilon,
            outcome: ep.outcome.name(),
            steps: ep.summary.steps,
            return_sum: ep.summary.return_sum,
            loss,
            success_rate_window: rate(Outcome::ReachGoal),
            collision_rate_window: rate(Outcome::Collision),
            timeout_rate_window: rate(Outcome::Timeout),
            policy_version: c.policy_version,
            env_steps: c.env_steps,
            replay_size: core.replay().len(),
            wall_s: (wall0 + start.elapsed()).as_secs_f64(),
            actor: None,
            actor_episode: None,
        };
        runlog::append(&mut metrics, &line).map_err(io("cannot append to metrics.jsonl"))?;
        progress.rl_episode(&line, eps_per_s);
        if validate_every > 0 && ((k + 1) % validate_every == 0 || k + 1 == train.rl.episodes) {
            validate(core, &mut metrics, progress)?;
        }
        let every = train.checkpoint_every_episodes;
        if every > 0 && (k + 1) % every == 0 {
            save(core, &latest)?;
        }
        if stop.load(Ordering::SeqCst) {
            interrupted = true;
            break;
        }
    }
    progress.rl_end();
    save(core, &latest)?;
    metrics.flush().map_err(io("cannot flush metrics.jsonl"))?;
    timing.validation_s = validation_time.as_secs_f64();
    timing.rl_s = rl_start
        .elapsed()
        .saturating_sub(validation_time)
        .as_secs_f64();
    Ok((
        if interrupted {
            Exit::Stopped
        } else {
            Exit::Finished
        },
        timing,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(path: &Path) -> Vec<serde_json::Value> {
        std::fs::read_to_string(path)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    }

    /// The lockstep run is a pure function of its config and seed: two runs of a tiny
    /// schedule write the same checkpoint bytes, and a run stopped half-way and resumed ends
    /// where the uninterrupted one does.
    #[test]
    fn a_run_replays_bit_for_bit_and_a_resumed_run_ends_where_an_uninterrupted_one_does() {
        let mut train = policy::method::TrainConfig::default();
        train.imitation.episodes = 6;
        train.imitation.epochs = 2;
        train.rl.episodes = 8;
        train.rl.epsilon_decay_episodes = 4;
        train.rl.batches_per_episode = 3;
        train.rl.target_update_episodes = 2;
        train.rl.replay_capacity = 2000;
        train.validation_every_episodes = 4;
        train.validation_episodes = 2;
        train.checkpoint_every_episodes = 4;
        let sim = sim::SimConfig::default();
        let spec = RunSpec {
            method: policy::method::Method::Sarl,
            setting: "env1-invisible".parse().unwrap(),
            sim: sim.clone(),
            train: train.clone(),
            seed: 5,
        };
        let fresh =
            || LearnerCore::new(spec.method, train.clone(), sim.humans.count, sim.dt_s, 5).unwrap();
        let train_in = |dir: &Path, stop_after_validation: bool| {
            std::fs::create_dir_all(dir.join("checkpoints")).unwrap();
            let run = Run {
                spec: &spec,
                out: dir,
                run_id: "unit".into(),
                resumed: false,
            };
            let mut core = fresh();
            // Stops at the first checkpoint after the request (raised during the validation
            // after 4 episodes, so the run stops after episode 4 and checkpoints).
            struct StopAt<'a>(&'a AtomicBool, bool);
            impl Progress for StopAt<'_> {
                fn validated(&mut self, line: &serde_json::Value) {
                    if self.1 && line["episode"] == 4 {
                        self.0.store(true, Ordering::SeqCst);
                    }
                }
            }
            let stop = AtomicBool::new(false);
            let (exit, _) = super::run(
                &mut core,
                &run,
                &stop,
                &mut StopAt(&stop, stop_after_validation),
            )
            .unwrap();
            exit
        };
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        let c = tempfile::tempdir().unwrap();
        assert_eq!(train_in(a.path(), false), Exit::Finished);
        assert_eq!(train_in(b.path(), false), Exit::Finished);
        let ckpt = |d: &Path| std::fs::read(d.join("checkpoints").join("latest.ckpt")).unwrap();
        assert_eq!(ckpt(a.path()), ckpt(b.path()), "same run, same bytes");
        // Stopped after 4 episodes, then resumed from its checkpoint.
        assert_eq!(train_in(c.path(), true), Exit::Stopped);
        let mut loaded = checkpoint::load(&c.path().join("checkpoints").join("latest.ckpt"))
            .unwrap()
            .core;
        assert_eq!(loaded.counters().rl_episodes, 4);
        let run = Run {
            spec: &spec,
            out: c.path(),
            run_id: "unit".into(),
            resumed: true,
        };
        let (exit, _) = super::run(&mut loaded, &run, &AtomicBool::new(false), &mut Quiet).unwrap();
        assert_eq!(exit, Exit::Finished);
        assert_eq!(ckpt(a.path()), ckpt(c.path()), "resumed, same bytes");
        // The same snapshots, and each validation logged once, in order.
        for ep in [0, 4, 8] {
            assert_eq!(
                std::fs::read(snapshot_path(a.path(), ep)).unwrap(),
                std::fs::read(snapshot_path(c.path(), ep)).unwrap()
            );
        }
        let episodes = |d: &Path, phase: &str| -> Vec<u64> {
            lines(&d.join("metrics.jsonl"))
                .iter()
                .filter(|v| v["phase"] == phase)
                .map(|v| v["episode"].as_u64().unwrap())
                .collect()
        };
        assert_eq!(episodes(c.path(), "validation"), [0, 4, 8]);
        assert_eq!(episodes(c.path(), "rl"), (0..8).collect::<Vec<_>>());
    }
}
