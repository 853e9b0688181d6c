//! The learner process: receives episodes from any number of actors, trains at the configured
//! replay ratio, broadcasts versioned weights, announces ε and flow-control credits, and never
//! loses an acknowledged episode (write-ahead log + checkpoints + actor re-sends).
//!
//! Flow control (Reverb-style): each actor may run at most `in_flight_per_actor` episodes ahead
//! of what the learner has accepted; when the learner is busy training, actors wait instead of
//! data being dropped.
//!
//! A run, in the order [`run`] goes through it (each phase a named function or module):
//!
//! 1. **restore** (`restore`): lock the run directory, load the last checkpoint (or start a
//!    new run), cut the training log back to it;
//! 2. **recover** (`Learner::replay_wal`): the episodes acknowledged after that checkpoint,
//!    from the write-ahead log, trained on again;
//! 3. **warm start** (`warm_start`): imitation, unless the checkpoint is past it;
//! 4. **train** (`training::train`): the RL phase, episodes taken and trained on as the replay
//!    schedule says (`schedule`: fixed or adaptive, one trait), then the updates the adaptive
//!    schedule still owes (`Schedule::top_up`);
//! 5. **finish** (`training::finish`): final checkpoint, weights, `Finished`, and the final
//!    figures ([`crate::record`]); then **linger** (`training::linger`) until the actors and
//!    evaluators have left.
//!
//! A stop (Ctrl-C) ends the run with [`LearnerExit::Stopped`]: in training, the top-up
//! included, after a checkpoint and the figures of that moment; in the warm start at once (it is
//! done again on the next start). The learner's state and its handlers (accepting,
//! acknowledging, publishing) are `Learner`'s; who is alive is `alive`'s (one capped tracker
//! for every phase).

mod alive;
mod schedule;
#[cfg(test)]
mod tests;
mod training;
mod warm_start;
mod window;

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use policy::method::RunSpec;
use policy::wire::{from_batch, weights_message};
use proto::{
    keys, Ack, Control, CreditGrant, Metrics, ProcessState, Role, RunPhase, TransitionBatch,
};
use sim::Outcome;
use transport::{AliveEvent, Heartbeat, Publisher, Transport, TransportError};

use self::alive::{Members, Membership};
use self::window::Window;
use crate::checkpoint::{self, RunInfo};
use crate::core::{LearnerCore, LearnerError};
use crate::store::RunLock;
use crate::wal::Wal;

/// Learner process settings.
#[derive(Debug, Clone)]
pub struct LearnerOptions {
    /// Checkpoints and the write-ahead log live here.
    pub run_dir: PathBuf,
    pub run_id: String,
    /// Episodes an actor may run ahead of what the learner has accepted.
    pub in_flight_per_actor: u64,
    /// How often metrics and acknowledgements are re-published.
    pub metrics_interval: Duration,
    /// How long to wait, after the run ends, for actors and evaluators to leave.
    pub linger: Duration,
}

/// Why the learner failed.
#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Learner(#[from] LearnerError),
    #[error(transparent)]
    Checkpoint(#[from] checkpoint::CheckpointError),
    #[error("{what}: {source}")]
    Io {
        what: String,
        source: std::io::Error,
    },
    #[error(transparent)]
    Record(#[from] crate::record::RecordError),
    #[error("invalid weights: {0}")]
    Weights(String),
    #[error("the adaptive mode made no update in {rounds} rounds in a row ({skipped} batches skipped for a non-finite loss or gradient): training has diverged")]
    NoProgress { rounds: u64, skipped: u64 },
}

/// How a learner run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LearnerExit {
    Finished,
    Stopped,
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> ProcessError {
    let what = what.into();
    move |source| ProcessError::Io { what, source }
}

/// How a phase of the run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ended {
    /// It did its work; the next phase follows.
    Done,
    /// `stop` was set first.
    Stopped,
}

/// Runs the learner until the run's RL episodes are done or `stop` is set (then checkpoints).
pub fn run(
    transport: &Transport,
    spec: &RunSpec,
    opts: &LearnerOptions,
    stop: &AtomicBool,
) -> Result<LearnerExit, ProcessError> {
    run_with_probe(transport, spec, opts, stop, crate::store::Probe::none())
}

/// [`run`] with every file-system step of the run directory reported to `probe` (tests inject a
/// full disk through it, `crate::store::Probe`). The process's status heartbeats tell its state
/// (starting, running; idle while no actor is alive in training; stopping; failed with why) and
/// its last warning.
pub fn run_with_probe(
    transport: &Transport,
    spec: &RunSpec,
    opts: &LearnerOptions,
    stop: &AtomicBool,
    probe: crate::store::Probe,
) -> Result<LearnerExit, ProcessError> {
    let status = Heartbeat::new(transport)?;
    let exit = run_inner(transport, spec, opts, stop, probe, &status);
    status.finish(exit)
}

/// The run's phases, in order (module docs).
fn run_inner(
    transport: &Transport,
    spec: &RunSpec,
    opts: &LearnerOptions,
    stop: &AtomicBool,
    probe: crate::store::Probe,
    status: &Heartbeat,
) -> Result<LearnerExit, ProcessError> {
    let Restored {
        lock: _lock,
        wal_records,
        state,
    } = restore(spec, opts, probe)?;
    // Episodes in and who is alive, before anything is replayed (what comes meanwhile queues).
    let run = transport.run().clone();
    let subscriber = transport.subscriber(&keys::all_transitions(&run))?;
    let alive = transport.watch_alive()?;
    let mut l = Learner::new(transport, status, spec, opts, state)?;
    l.replay_wal(&wal_records)?;
    let _token = transport.declare_alive()?;
    status.set_state(ProcessState::Running);
    l.publish_control();
    l.publish_metrics()?;

    if !l.core.counters().imitation_done
        && warm_start::run(&mut l, &subscriber, &alive, stop)? == Ended::Stopped
    {
        return Ok(LearnerExit::Stopped);
    }
    l.start_rl()?;
    let mut schedule = schedule::of(spec);
    let mut ended = training::train(&mut l, schedule.as_mut(), &subscriber, &alive, stop)?;
    if ended == Ended::Done {
        ended = schedule.top_up(&mut l, stop)?;
    }
    if ended == Ended::Stopped {
        return l.stopped();
    }

    training::finish(&mut l)?;
    training::linger(&mut l, |wait| alive.recv_timeout(wait), stop)?;
    Ok(LearnerExit::Finished)
}

/// What the run directory holds for the learner: its lock (held until the learner ends), the
/// write-ahead log's records (not yet replayed) and the learner's state.
struct Restored {
    lock: RunLock,
    wal_records: Vec<Vec<u8>>,
    state: State,
}

/// The learner's state as the run directory left it: the last checkpoint's (or a new run's),
/// the write-ahead log, and the training log cut back to the checkpoint.
struct State {
    core: LearnerCore,
    accepted_below: BTreeMap<u32, u64>,
    wal: Wal,
    sim_cfg: sim::SimConfig,
    /// The training log (`metrics.jsonl`), open for appending, and the clock of its last line.
    log: std::fs::File,
    wall0: Duration,
}

/// The run directory: locked for as long as the learner runs, its write-ahead log recovered
/// from a crash mid-append, corruption refused (`store`); the last checkpoint (refused if it
/// is of another run), or a new run; an earlier process's final figures removed.
fn restore(
    spec: &RunSpec,
    opts: &LearnerOptions,
    probe: crate::store::Probe,
) -> Result<Restored, ProcessError> {
    let store = crate::store::Store::open(&opts.run_dir, probe)
        .map_err(|e| io("cannot start the learner")(std::io::Error::other(e)))?;
    crate::record::remove_stale(&opts.run_dir)?;
    let sim_cfg = spec.method_sim();
    let expected = checkpoint::RunIdentity {
        run_id: opts.run_id.clone(),
        method: spec.method,
        setting: spec.setting.name().to_string(),
        run_seed: spec.seed,
    };
    let (mut core, accepted_below) = match store.load_checkpoint(&expected)? {
        Some(loaded) => {
            tracing::info!(
                rl_episodes = loaded.core.counters().rl_episodes,
                "resuming from {}",
                store.checkpoint_path().display()
            );
            (loaded.core, loaded.run.accepted_below)
        }
        None => {
            let core = LearnerCore::new(
                spec.method,
                spec.train.clone(),
                spec.sim.entities(spec.setting),
                spec.sim.dt_s,
                spec.seed,
            )?;
            (core, BTreeMap::new())
        }
    };
    core.set_action_count(sim::ActionSet::for_config(&sim_cfg).len());
    let (lock, wal, wal_records) = store.into_parts();
    let (log, wall0) = open_log(opts, &core)?;
    Ok(Restored {
        lock,
        wal_records,
        state: State {
            core,
            accepted_below,
            wal,
            sim_cfg,
            log,
            wall0,
        },
    })
}

/// The training log, cut back to the checkpoint (the write-ahead log's episodes after it are
/// replayed and logged again; without a checkpoint the run starts again from nothing), open
/// for appending; and the clock of its last line.
fn open_log(
    opts: &LearnerOptions,
    core: &LearnerCore,
) -> Result<(std::fs::File, Duration), ProcessError> {
    let log_path = opts.run_dir.join("metrics.jsonl");
    let (rl_done, trim) = if core.counters().imitation_done || core.counters().rl_episodes > 0 {
        (core.counters().rl_episodes, crate::runlog::Trim::Rl)
    } else {
        (0, crate::runlog::Trim::Restart)
    };
    crate::runlog::trim(&log_path, rl_done, trim)
        .map_err(io(format!("cannot rewrite {}", log_path.display())))?;
    let wall0 = crate::runlog::last_wall(&log_path);
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .map_err(io(format!("cannot open {}", log_path.display())))?;
    Ok((log, wall0))
}

/// The learner process's state, with its handlers: accepting, acknowledging, training on and
/// logging episodes, checkpointing, publishing weights, control and metrics.
struct Learner<'a> {
    t: &'a Transport,
    /// Status heartbeats: the state, and every warning below as the last error.
    status: &'a Heartbeat,
    spec: &'a RunSpec,
    opts: &'a LearnerOptions,
    core: LearnerCore,
    accepted_below: BTreeMap<u32, u64>,
    acks: HashMap<u32, Publisher<Ack>>,
    weights: transport::LatestPublisher<proto::Weights>,
    control: transport::LatestPublisher<Control>,
    metrics: Publisher<Metrics>,
    wal: Wal,
    /// The actors and evaluators alive (capped, [`alive`]).
    members: Members,
    /// Liveliness tokens the watcher did not track (too many instances of one id: the oldest
    /// displaced; too many senders), as of the last metrics tick.
    alive_tokens_refused: u64,
    window: Window,
    rejected_episodes: u64,
    duplicates: u64,
    /// Episodes ahead of the next expected one (the actor re-sends from the gap).
    out_of_order: u64,
    /// Episodes refused while imitation runs (no actor should send then).
    refused_in_imitation: u64,
    /// Episodes not stored because the write-ahead log could not take them (full disk).
    wal_failures: u64,
    /// Checkpoints that failed (full disk); retried at the next occasion.
    checkpoint_failures: u64,
    /// Control and ack publications that failed (counted, never fatal).
    publish_failures: u64,
    start: Instant,
    /// When RL started in this process, with the RL episodes and updates done then.
    rl_start: (Instant, u64, u64),
    /// Time the RL loop spent waiting for an episode (nothing to train on) and training.
    wait: Duration,
    train: Duration,
    last_loss: f32,
    sim_cfg: sim::SimConfig,
    /// The run's training log (`metrics.jsonl`): one line per RL episode trained, as the
    /// single-process mode writes it; `wall0` is the clock of the log's earlier lines.
    log: std::fs::File,
    wall0: Duration,
    /// The episode just stored: (outcome, steps, return, ε, actor, the actor's episode index).
    stored: Option<(Outcome, u32, f64, f64, u32, u64)>,
    /// Log lines that could not be written (a full disk): counted, never fatal.
    log_failures: u64,
}

impl<'a> Learner<'a> {
    /// The learner on `state`, with its publishers of weights, control and metrics.
    fn new(
        t: &'a Transport,
        status: &'a Heartbeat,
        spec: &'a RunSpec,
        opts: &'a LearnerOptions,
        state: State,
    ) -> Result<Self, ProcessError> {
        let run = t.run();
        Ok(Learner {
            t,
            status,
            spec,
            opts,
            core: state.core,
            accepted_below: state.accepted_below,
            acks: HashMap::new(),
            weights: t.latest_publisher(&keys::weights(run))?,
            control: t.latest_publisher(&keys::control(run))?,
            metrics: t.publisher(&keys::metrics(run, t.sender()))?,
            wal: state.wal,
            members: Members::default(),
            alive_tokens_refused: 0,
            window: Window::default(),
            rejected_episodes: 0,
            duplicates: 0,
            out_of_order: 0,
            refused_in_imitation: 0,
            wal_failures: 0,
            checkpoint_failures: 0,
            publish_failures: 0,
            start: Instant::now(),
            rl_start: (Instant::now(), 0, 0),
            wait: Duration::ZERO,
            train: Duration::ZERO,
            last_loss: f32::NAN,
            sim_cfg: state.sim_cfg,
            log: state.log,
            wall0: state.wall0,
            stored: None,
            log_failures: 0,
        })
    }

    /// Episodes acknowledged after the last checkpoint: back from the write-ahead log, trained
    /// on again; those the checkpoint already holds (a crash before the log was emptied) are
    /// dropped. The log stays as it is: it already holds exactly these records.
    fn replay_wal(&mut self, wal_records: &[Vec<u8>]) -> Result<(), ProcessError> {
        let plan = crate::store::replay_plan(wal_records, &self.accepted_below);
        self.duplicates += plan.duplicates;
        let mut replayed = 0;
        for msg in &plan.episodes {
            if self.accept(
                msg.header.sender.index,
                &msg.body,
                msg.header.policy_version,
                false,
            )? {
                self.train_stored()?;
                replayed += 1;
            }
        }
        if plan.unreadable > 0 {
            tracing::warn!(
                records = plan.unreadable,
                "skipped write-ahead log records that are not an actor's episode"
            );
        }
        if !wal_records.is_empty() {
            tracing::info!(
                replayed,
                duplicates = plan.duplicates,
                "write-ahead log replayed"
            );
        }
        Ok(())
    }

    /// RL starts in this process: its replay ratio counts from here; the weights and control
    /// go out, the actors that joined during the warm start learn where to go on, and the
    /// first metrics of training name where the ratio is counted from (`rl_start_*`).
    fn start_rl(&mut self) -> Result<(), ProcessError> {
        self.rl_start = (
            Instant::now(),
            self.core.counters().rl_episodes,
            self.core.counters().updates,
        );
        self.publish_weights()?;
        self.publish_control();
        for id in self.live_actor_ids() {
            self.ack(id);
        }
        self.publish_metrics()
    }

    /// A stop in training: the checkpoint and the figures of this moment, then the exit.
    fn stopped(&mut self) -> Result<LearnerExit, ProcessError> {
        self.status.set_state(ProcessState::Stopping);
        self.checkpoint()?;
        crate::record::write(&self.opts.run_dir, &self.metrics_now())?;
        Ok(LearnerExit::Stopped)
    }
    fn ckpt_path(&self) -> PathBuf {
        self.opts.run_dir.join("checkpoints").join("latest.ckpt")
    }

    fn run_info(&self) -> RunInfo {
        RunInfo {
            run_id: self.opts.run_id.clone(),
            setting: self.spec.setting.name().to_string(),
            run_seed: self.spec.seed,
            accepted_below: self.accepted_below.clone(),
        }
    }

    fn checkpoint(&mut self) -> Result<(), ProcessError> {
        let path = self.ckpt_path();
        let run = self.run_info();
        // Durable (synced, renamed, directory synced) before the log is emptied; on error (a
        // full disk) the log is untouched, the partial file removed, and a later call retries.
        crate::store::commit_checkpoint(&path, &mut self.wal, &self.core, &self.sim_cfg, &run)?;
        tracing::info!(rl_episodes = self.core.counters().rl_episodes, path = %path.display(), "checkpoint written");
        Ok(())
    }

    /// A checkpoint whose failure (a full disk) is logged and counted, not fatal: the
    /// write-ahead log keeps every acknowledged episode meanwhile. Returns whether it was written.
    fn try_checkpoint(&mut self) -> bool {
        match self.checkpoint() {
            Ok(()) => true,
            Err(e) => {
                self.checkpoint_failures += 1;
                warn_sometimes(
                    self.status,
                    "checkpoint",
                    self.checkpoint_failures,
                    format_args!("checkpoint failed (retried later; the write-ahead log holds the episodes): {e}"),
                );
                false
            }
        }
    }

    /// Tracks who is alive; returns whether the set of actor ids alive changed. At most
    /// [`MAX_ACTORS`] actor ids are tracked (further ones refused, counted and logged); an
    /// actor that joins is acknowledged, an actor id whose last instance leaves loses its ack
    /// publisher.
    fn on_alive(&mut self, ev: AliveEvent) -> bool {
        match self.members.track(self.status, ev) {
            Membership::Unchanged => false,
            Membership::ActorJoined { index, new_id } => {
                self.ack(index);
                new_id
            }
            Membership::ActorGone(index) => {
                self.acks.remove(&index);
                true
            }
        }
    }

    /// The indices of the actors alive now, ascending, each once.
    fn live_actor_ids(&self) -> Vec<u32> {
        self.members.actors.ids().collect()
    }

    fn phase(&self) -> RunPhase {
        if !self.core.counters().imitation_done {
            RunPhase::Imitation
        } else if self.core.counters().rl_episodes >= self.spec.train.rl.episodes {
            RunPhase::Finished
        } else {
            RunPhase::Training
        }
    }

    /// Announces phase, ε and credits. Credits go only to actors alive now (at most
    /// [`proto::control::MAX_CREDIT_GRANTS`], lowest ids first); a failed publication is counted and
    /// logged, never fatal (the next one repeats everything).
    fn publish_control(&mut self) {
        let mut ids = self.live_actor_ids();
        ids.truncate(proto::control::MAX_CREDIT_GRANTS);
        let credits = ids
            .iter()
            .map(|&actor| CreditGrant {
                actor,
                episode_budget: self
                    .accepted_below
                    .get(&actor)
                    .copied()
                    .unwrap_or(0)
                    .saturating_add(self.opts.in_flight_per_actor),
            })
            .collect();
        let phase = self.phase();
        let c = Control {
            phase,
            epsilon: self.core.epsilon() as f32,
            credits,
            final_rl_episodes: (phase == RunPhase::Finished)
                .then(|| self.core.counters().rl_episodes),
        };
        if let Err(e) = self
            .control
            .publish(self.core.counters().policy_version, &c)
        {
            self.publish_failures += 1;
            warn_sometimes(
                self.status,
                "control",
                self.publish_failures,
                format_args!("publishing control failed: {e}"),
            );
        }
    }

    /// Sends the current weights and control again, the same messages (a subscriber that has
    /// them sees nothing new; one for which they were dropped gets them). Failures counted.
    fn republish_latest(&mut self) {
        for (what, sent) in [
            ("weights", self.weights.republish()),
            ("control", self.control.republish()),
        ] {
            if let Err(e) = sent {
                self.publish_failures += 1;
                warn_sometimes(
                    self.status,
                    "republish",
                    self.publish_failures,
                    format_args!("publishing the {what} again failed: {e}"),
                );
            }
        }
    }

    fn publish_weights(&mut self) -> Result<(), ProcessError> {
        let version = self.core.counters().policy_version;
        let w = weights_message(self.core.online(), version)
            .map_err(|e| ProcessError::Weights(e.to_string()))?
            .with_rl_episodes(self.core.counters().rl_episodes);
        self.weights.publish(version, &w)?;
        Ok(())
    }

    /// Tells `actor` how far it is stored (everything below is in the write-ahead log or a
    /// checkpoint). Only for actors alive or known; a failed publication is counted, never fatal.
    fn ack(&mut self, actor: u32) {
        let below = self.accepted_below.get(&actor).copied().unwrap_or(0);
        if !self.acks.contains_key(&actor) {
            // Dropped, not waited on, for an actor that does not read: each ack supersedes the
            // last and every live actor gets its ack again on each metrics tick.
            match self.t.dropping_publisher(&keys::ack(self.t.run(), actor)) {
                Ok(p) => {
                    self.acks.insert(actor, p);
                }
                Err(e) => {
                    self.publish_failures += 1;
                    warn_sometimes(
                        self.status,
                        "ack",
                        self.publish_failures,
                        format_args!("declaring the ack publisher of actor {actor} failed: {e}"),
                    );
                    return;
                }
            }
        }
        let version = self.core.counters().policy_version;
        let sent = self.acks[&actor].publish(
            version,
            &Ack {
                actor,
                acked_below: below,
                episodes: Vec::new(),
                learner: self.t.member().instance,
            },
        );
        if let Err(e) = sent {
            self.publish_failures += 1;
            warn_sometimes(
                self.status,
                "ack",
                self.publish_failures,
                format_args!("acknowledging actor {actor} failed: {e}"),
            );
        }
    }

    fn publish_metrics(&self) -> Result<(), ProcessError> {
        self.publish(&self.metrics_now())
    }

    /// The final figures: durable in the run directory (`crate::record`, part of the run's
    /// record), then live.
    fn publish_final_metrics(&self) -> Result<(), ProcessError> {
        let m = self.metrics_now();
        crate::record::write(&self.opts.run_dir, &m)?;
        self.publish(&m)
    }

    fn publish(&self, m: &Metrics) -> Result<(), ProcessError> {
        let c = self.core.counters();
        self.metrics.publish(c.policy_version, m)?;
        self.status.progress(c.env_steps, c.rl_episodes);
        self.status.beat();
        Ok(())
    }

    /// The learner's figures now: counters, rates of the window, the realised replay ratio,
    /// time waited and trained, everything refused or failed.
    fn metrics_now(&self) -> Metrics {
        let c = self.core.counters();
        let wall = self.start.elapsed().as_secs_f64();
        let (t0, e0, u0) = self.rl_start;
        let rl_wall = t0.elapsed().as_secs_f64().max(1e-9);
        let lag_mean = if self.window.lags.is_empty() {
            0.0
        } else {
            self.window.lags.iter().sum::<u64>() as f64 / self.window.lags.len() as f64
        };
        // The replay ratio this process realised: updates per accepted RL episode.
        let rl_done = c.rl_episodes.saturating_sub(e0);
        let updates_per_episode = if rl_done == 0 {
            0.0
        } else {
            c.updates.saturating_sub(u0) as f64 / rl_done as f64
        };
        let mut m = Metrics {
            env_steps: c.env_steps,
            episodes: c.rl_episodes,
            wall_time_s: wall,
            values: Default::default(),
        };
        let loss = if self.last_loss.is_finite() {
            self.last_loss as f64
        } else {
            0.0
        };
        for (k, v) in [
            ("episodes", c.rl_episodes as f64),
            ("episodes_target", self.spec.train.rl.episodes as f64),
            ("demo_episodes", c.demo_episodes as f64),
            ("episodes_per_s", (c.rl_episodes - e0) as f64 / rl_wall),
            ("env_steps_per_s", c.env_steps as f64 / wall.max(1e-9)),
            ("epsilon", self.core.epsilon()),
            ("success_rate", self.window.rate(Outcome::ReachGoal)),
            ("collision_rate", self.window.rate(Outcome::Collision)),
            ("timeout_rate", self.window.rate(Outcome::Timeout)),
            ("loss", loss),
            ("policy_version", c.policy_version as f64),
            ("policy_lag_mean", lag_mean),
            (
                "policy_lag_max",
                self.window.lags.iter().copied().max().unwrap_or(0) as f64,
            ),
            ("policy_lag_p95", self.window.lag_quantile(0.95) as f64),
            ("updates_per_episode", updates_per_episode),
            // Where this process started counting the ratio: with the final counters of the
            // checkpoint, the run's realised ratio whichever message arrives last (`launch`).
            ("rl_start_episodes", e0 as f64),
            ("rl_start_updates", u0 as f64),
            ("wait_s", self.wait.as_secs_f64()),
            ("train_s", self.train.as_secs_f64()),
            ("replay_size", self.core.replay().len() as f64),
            ("updates", c.updates as f64),
            ("rejected_messages", self.t.rejected_count() as f64),
            ("rejected_episodes", self.rejected_episodes as f64),
            ("duplicate_episodes", self.duplicates as f64),
            ("out_of_order_episodes", self.out_of_order as f64),
            ("refused_in_imitation", self.refused_in_imitation as f64),
            ("wal_failures", self.wal_failures as f64),
            ("checkpoint_failures", self.checkpoint_failures as f64),
            ("publish_failures", self.publish_failures as f64),
            ("log_failures", self.log_failures as f64),
            ("skipped_batches", self.core.skipped_batches() as f64),
            ("skipped_refreshes", self.core.skipped_refreshes() as f64),
            ("actors_alive", self.members.actors.len() as f64),
            ("alive_refused", self.members.actors.refused as f64),
            ("alive_tokens_refused", self.alive_tokens_refused as f64),
            ("imitation_done", if c.imitation_done { 1.0 } else { 0.0 }),
        ] {
            m.values.insert(k.to_string(), v);
        }
        m
    }

    /// Trains on the episode just stored (`batches_per_episode` updates) and logs its line.
    fn train_stored(&mut self) -> Result<(), ProcessError> {
        let trained = Instant::now();
        self.last_loss = self.core.train_rl(self.spec.train.rl.batches_per_episode)?;
        self.train += trained.elapsed();
        if let Some(last) = self.window.losses.back_mut() {
            *last = self.last_loss;
        }
        self.log_stored();
        Ok(())
    }

    /// RL episodes and updates since this process started RL.
    fn rl_progress(&self) -> (u64, u64) {
        let c = self.core.counters();
        let (_, e0, u0) = self.rl_start;
        (
            c.rl_episodes.saturating_sub(e0),
            c.updates.saturating_sub(u0),
        )
    }

    /// Writes the log line of the episode just stored (with the latest loss).
    fn log_stored(&mut self) {
        let Some((outcome, steps, return_sum, epsilon, actor, actor_episode)) = self.stored.take()
        else {
            return;
        };
        let c = self.core.counters();
        let line = crate::runlog::RlLine {
            phase: "rl",
            episode: c.rl_episodes - 1,
            epsilon,
            outcome: outcome.name(),
            steps,
            return_sum,
            loss: self.last_loss,
            success_rate_window: self.window.rate(Outcome::ReachGoal),
            collision_rate_window: self.window.rate(Outcome::Collision),
            timeout_rate_window: self.window.rate(Outcome::Timeout),
            policy_version: c.policy_version,
            env_steps: c.env_steps,
            replay_size: self.core.replay().len(),
            wall_s: (self.wall0 + self.start.elapsed()).as_secs_f64(),
            actor: Some(actor),
            actor_episode: Some(actor_episode),
        };
        self.log_line(&line);
    }

    /// Appends a line to the run's log; a line that cannot be written (a full disk) is counted
    /// and logged, never fatal.
    fn log_line(&mut self, line: &impl serde::Serialize) {
        if let Err(e) = crate::runlog::append(&mut self.log, line) {
            self.log_failures += 1;
            warn_sometimes(
                self.status,
                "log",
                self.log_failures,
                format_args!("metrics.jsonl: a line was not written: {e}"),
            );
        }
    }

    /// Takes one received message: refused unless an actor's; made durable, stored and
    /// acknowledged if it is the actor's next episode (a duplicate is acknowledged again).
    fn take(&mut self, msg: proto::Message<TransitionBatch>) -> Accepted {
        if msg.header.sender.role != Role::Actor {
            self.rejected_episodes += 1;
            warn_sometimes(
                self.status,
                "rejected",
                self.rejected_episodes,
                format_args!(
                    "transitions from a non-actor ({}) ignored",
                    msg.header.sender
                ),
            );
            return Accepted::Refused;
        }
        let actor = msg.header.sender.index;
        let bytes = match proto::encode_message(&msg) {
            Ok(b) => b,
            Err(e) => {
                self.rejected_episodes += 1;
                warn_sometimes(
                    self.status,
                    "rejected",
                    self.rejected_episodes,
                    format_args!("episode of actor {actor} does not re-encode: {e}"),
                );
                return Accepted::Refused;
            }
        };
        let accepted = self.accept_logged(
            actor,
            &msg.body,
            msg.header.policy_version,
            true,
            Some(&bytes),
        );
        // Acknowledge stored and duplicate episodes; a refused one from an unknown actor gets
        // nothing (no per-actor state for strangers).
        if accepted != Accepted::Refused || self.accepted_below.contains_key(&actor) {
            self.ack(actor);
        }
        accepted
    }

    /// Accepts one episode (not yet trained on). Returns false for a duplicate or a rejection.
    /// Replaying the write-ahead log: `wal` is None (the record is already there).
    fn accept(
        &mut self,
        actor: u32,
        batch: &TransitionBatch,
        version: u64,
        log: bool,
    ) -> Result<bool, ProcessError> {
        Ok(self.accept_logged(actor, batch, version, log, None) == Accepted::Stored)
    }

    /// Accepts one episode: only the next one the actor owes (`episode == accepted_below`), of
    /// this run's setting, passing every check; made durable (`wal`: its encoded message) before
    /// it is stored and `accepted_below` moves. Nothing changes for a refused episode.
    fn accept_logged(
        &mut self,
        actor: u32,
        batch: &TransitionBatch,
        version: u64,
        log: bool,
        wal: Option<&[u8]>,
    ) -> Accepted {
        let known = self.accepted_below.get(&actor).copied();
        let below = known.unwrap_or(0);
        if batch.episode < below {
            self.duplicates += 1;
            return Accepted::Duplicate;
        }
        if batch.episode > below {
            // A gap: an earlier episode was lost in flight. Storing this one would let the
            // high-water-mark ack cover the lost one, so the actor re-sends from the gap.
            self.out_of_order += 1;
            warn_sometimes(
                self.status,
                "out-of-order",
                self.out_of_order,
                format_args!(
                    "actor {actor} sent episode {} while {below} is due; waiting for a re-send",
                    batch.episode
                ),
            );
            return Accepted::Refused;
        }
        if known.is_none() && self.accepted_below.len() >= MAX_ACTORS {
            self.rejected_episodes += 1;
            warn_sometimes(
                self.status,
                "rejected",
                self.rejected_episodes,
                format_args!("refused actor {actor}: this run already has {MAX_ACTORS} actors"),
            );
            return Accepted::Refused;
        }
        let refuse = |l: &mut Self, why: &dyn std::fmt::Display| {
            l.rejected_episodes += 1;
            warn_sometimes(
                l.status,
                "rejected",
                l.rejected_episodes,
                format_args!("rejected episode {} of actor {actor}: {why}", batch.episode),
            );
            Accepted::Refused
        };
        let ep = match from_batch(batch, version, &self.sim_cfg) {
            Ok(ep) if ep.setting == self.spec.setting => ep,
            Ok(ep) => return refuse(self, &format_args!("setting {}", ep.setting)),
            Err(e) => return refuse(self, &e),
        };
        let prepared = match self.core.prepare_episode(&ep, false) {
            Ok(p) => p,
            Err(e) => return refuse(self, &e),
        };
        let Some(next) = batch.episode.checked_add(1) else {
            return refuse(self, &"episode index at its limit");
        };
        if let Some(bytes) = wal {
            // Durable before stored, stored before acknowledged.
            if let Err(e) = self.wal.append(bytes) {
                self.wal_failures += 1;
                warn_sometimes(
                    self.status,
                    "wal",
                    self.wal_failures,
                    format_args!(
                        "episode {} of actor {actor} not stored (the actor re-sends it): write-ahead log: {e}",
                        batch.episode
                    ),
                );
                return Accepted::Refused;
            }
        }
        let epsilon = self.core.epsilon();
        self.core.commit_episode(prepared);
        self.accepted_below.insert(actor, next);
        self.stored = Some((
            ep.outcome,
            ep.summary.steps,
            ep.summary.return_sum,
            epsilon,
            actor,
            batch.episode,
        ));
        let lag = self.core.counters().policy_version.saturating_sub(version);
        self.window.push(ep.outcome, lag, self.last_loss);
        if log {
            tracing::debug!(
                actor,
                episode = batch.episode,
                outcome = ep.outcome.name(),
                lag,
                "accepted"
            );
        }
        Accepted::Stored
    }
}

/// What became of a received episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Accepted {
    Stored,
    Duplicate,
    Refused,
}

/// Most actor ids a run keeps state for (accepted episodes, credits, ack publishers); more are
/// refused. Equal to the most credit grants one control message carries.
const MAX_ACTORS: usize = proto::control::MAX_CREDIT_GRANTS;

/// Rate-limited warning: the 1st, 2nd, 4th, 8th, … occurrence of each kind (`count`, its
/// running total) is logged, so a flood of bad input costs a handful of log lines; every one is
/// the status's last error (`status`, sent at most every [`transport::ERROR_GAP`]).
fn warn_sometimes(
    status: &Heartbeat,
    kind: &'static str,
    count: u64,
    what: std::fmt::Arguments<'_>,
) {
    status.error(what);
    if count.is_power_of_two() {
        tracing::warn!(kind, count, "{what} (logged at powers of two of the count)");
    }
}
