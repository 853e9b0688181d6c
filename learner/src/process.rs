//! The learner process: receives episodes from any number of actors, trains at the configured
//! replay ratio, broadcasts versioned weights, announces ε and flow-control credits, and never
//! loses an acknowledged episode (write-ahead log + checkpoints + actor re-sends).
//!
//! Flow control (Reverb-style): each actor may run at most `in_flight_per_actor` episodes ahead
//! of what the learner has accepted; when the learner is busy training, actors wait instead of
//! data being dropped.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use policy::method::RunSpec;
use policy::wire::{from_batch, weights_message};
use proto::{
    keys, Ack, Control, CreditGrant, Metrics, ProcessState, Role, RunPhase, TransitionBatch,
};
use sim::Outcome;
use transport::{AliveEvent, Heartbeat, Publisher, Transport, TransportError};

use crate::checkpoint::{self, RunInfo};
use crate::core::{LearnerCore, LearnerError};
use crate::imitation::{self, ImitationProgress};
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

struct Window {
    outcomes: VecDeque<Outcome>,
    lags: VecDeque<u64>,
    losses: VecDeque<f32>,
}

impl Window {
    fn push(&mut self, o: Outcome, lag: u64, loss: f32) {
        if self.outcomes.len() == 100 {
            self.outcomes.pop_front();
            self.lags.pop_front();
            self.losses.pop_front();
        }
        self.outcomes.push_back(o);
        self.lags.push_back(lag);
        self.losses.push_back(loss);
    }
    /// The `q` quantile of the window's policy lags (nearest rank; 0 without episodes).
    fn lag_quantile(&self, q: f64) -> u64 {
        let mut lags: Vec<u64> = self.lags.iter().copied().collect();
        if lags.is_empty() {
            return 0;
        }
        lags.sort_unstable();
        let rank = ((q * lags.len() as f64).ceil() as usize).clamp(1, lags.len());
        lags[rank - 1]
    }
    fn rate(&self, o: Outcome) -> f64 {
        if self.outcomes.is_empty() {
            return 0.0;
        }
        self.outcomes.iter().filter(|x| **x == o).count() as f64 / self.outcomes.len() as f64
    }
}

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
    /// The actors alive: id → the instances (liveliness tokens) alive under it. Counted and
    /// capped by id ([`MAX_ACTORS`]); the watcher keeps at most
    /// [`transport::MAX_INSTANCES_PER_SENDER`] instances of an id (the newest), so a flood of
    /// tokens under one id neither fills the table nor crowds out other actors.
    actors_alive: AliveActors,
    evaluators_alive: HashSet<proto::Member>,
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
    /// The last stored episode: outcome, steps, return, ε of its index (for its log line).
    /// The episode just stored: (outcome, steps, return, ε, actor, the actor's episode index).
    stored: Option<(Outcome, u32, f64, f64, u32, u64)>,
    /// Log lines that could not be written (a full disk): counted, never fatal.
    log_failures: u64,
    /// Rounds of the adaptive mode in a row that made no update (see [`MAX_IDLE_ROUNDS`]).
    idle_rounds: u64,
}

impl Learner<'_> {
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
        match track_alive(
            &mut self.actors_alive,
            &mut self.evaluators_alive,
            self.status,
            ev,
        ) {
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
        self.actors_alive.ids().collect()
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
        let c = Control {
            phase: self.phase(),
            epsilon: self.core.epsilon() as f32,
            credits,
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
            ("actors_alive", self.actors_alive.len() as f64),
            ("alive_refused", self.actors_alive.refused as f64),
            ("alive_tokens_refused", self.alive_tokens_refused as f64),
            ("imitation_done", if c.imitation_done { 1.0 } else { 0.0 }),
        ] {
            m.values.insert(k.to_string(), v);
        }
        self.metrics.publish(c.policy_version, &m)?;
        self.status.progress(c.env_steps, c.rl_episodes);
        self.status.beat();
        Ok(())
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

    /// The adaptive mode's round of `batches` updates, not tied to an episode. Its episodes
    /// wait for updates, so rounds that make none would starve the actors for ever: a skipped
    /// refresh of the targets re-synchronises the target network or fails
    /// ([`LearnerCore::train_round`]), and [`MAX_IDLE_ROUNDS`] rounds in a row without an update
    /// (every batch non-finite) fail too, loudly.
    fn train_round(&mut self, batches: u32) -> Result<(), ProcessError> {
        let trained = Instant::now();
        let before = self.core.counters().updates;
        let loss = self.core.train_round(batches)?;
        self.train += trained.elapsed();
        if loss.is_finite() {
            self.last_loss = loss;
        }
        if self.core.counters().updates > before {
            self.idle_rounds = 0;
        } else {
            self.idle_rounds += 1;
            if self.idle_rounds >= MAX_IDLE_ROUNDS {
                return Err(ProcessError::NoProgress {
                    rounds: self.idle_rounds,
                    skipped: self.core.skipped_batches(),
                });
            }
        }
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

/// What a liveliness event changed (see [`track_alive`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Membership {
    Unchanged,
    /// An instance of actor `index` joined (`new_id`: the id's first).
    ActorJoined {
        index: u32,
        new_id: bool,
    },
    /// The last instance of actor `index` left.
    ActorGone(u32),
}

/// Tracks who is alive, with the log lines (at most [`MAX_ACTORS`] actor ids and as many
/// evaluators; a refusal is counted and logged at powers of two). It needs no more of the
/// learner than these two sets, so the warm start drains liveliness with it too (a flood of
/// tokens then cannot fill the watcher's bounded queue while nothing reads it).
fn track_alive(
    actors: &mut AliveActors,
    evaluators: &mut HashSet<proto::Member>,
    status: &Heartbeat,
    ev: AliveEvent,
) -> Membership {
    match ev {
        AliveEvent::Joined(m) if m.sender.role == Role::Actor => {
            let index = m.sender.index;
            match actors.join(index, m.instance, MAX_ACTORS) {
                Joined::Refused => {
                    warn_sometimes(
                        status,
                        "alive",
                        actors.refused,
                        format_args!("ignoring actor {m}: {MAX_ACTORS} actor ids are alive"),
                    );
                    Membership::Unchanged
                }
                Joined::Known => Membership::Unchanged,
                joined => {
                    tracing::info!(actor = %m, "actor joined");
                    Membership::ActorJoined {
                        index,
                        new_id: joined == Joined::NewId,
                    }
                }
            }
        }
        AliveEvent::Left(m) if m.sender.role == Role::Actor => {
            let index = m.sender.index;
            match actors.leave(index, m.instance) {
                Left::Unknown => Membership::Unchanged,
                Left::Instance => {
                    tracing::warn!(actor = %m, "actor left");
                    Membership::Unchanged
                }
                Left::LastInstance => {
                    tracing::warn!(actor = %m, "actor left");
                    Membership::ActorGone(index)
                }
            }
        }
        AliveEvent::Joined(m) if m.sender.role == Role::Evaluator => {
            if evaluators.len() < MAX_ACTORS {
                evaluators.insert(m);
            }
            Membership::Unchanged
        }
        AliveEvent::Left(m) if m.sender.role == Role::Evaluator => {
            evaluators.remove(&m);
            Membership::Unchanged
        }
        _ => Membership::Unchanged,
    }
}

/// The actors alive, by id: each id with the liveliness instances alive under it. At most `cap`
/// ids are admitted, however many instances an id declares (a flood of tokens under one id
/// takes one place, so the actors that join after it are still admitted).
#[derive(Debug, Default)]
struct AliveActors {
    ids: BTreeMap<u32, BTreeSet<u64>>,
    /// Joins refused because `cap` ids were alive.
    refused: u64,
}

/// What a liveliness token's arrival changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Joined {
    /// The id's first instance.
    NewId,
    /// Another instance of an id alive already.
    NewInstance,
    /// An instance already known.
    Known,
    /// A new id while `cap` ids were alive.
    Refused,
}

/// What a liveliness token's departure changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Left {
    /// The id's last instance: the id is gone.
    LastInstance,
    /// One of several instances.
    Instance,
    Unknown,
}

impl AliveActors {
    fn join(&mut self, id: u32, instance: u64, cap: usize) -> Joined {
        let new_id = !self.ids.contains_key(&id);
        if new_id && self.ids.len() >= cap {
            self.refused += 1;
            return Joined::Refused;
        }
        if !self.ids.entry(id).or_default().insert(instance) {
            Joined::Known
        } else if new_id {
            Joined::NewId
        } else {
            Joined::NewInstance
        }
    }

    fn leave(&mut self, id: u32, instance: u64) -> Left {
        let Some(instances) = self.ids.get_mut(&id) else {
            return Left::Unknown;
        };
        if !instances.remove(&instance) {
            return Left::Unknown;
        }
        if instances.is_empty() {
            self.ids.remove(&id);
            Left::LastInstance
        } else {
            Left::Instance
        }
    }

    fn len(&self) -> usize {
        self.ids.len()
    }

    fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// The ids alive, ascending.
    fn ids(&self) -> impl Iterator<Item = u32> + '_ {
        self.ids.keys().copied()
    }
}

/// What became of a received episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Accepted {
    Stored,
    Duplicate,
    Refused,
}

/// Rounds of the adaptive mode in a row without an update before the learner gives up.
const MAX_IDLE_ROUNDS: u64 = 1000;

/// Most received episodes held between rounds of updates (every actor's transport queue is
/// bounded too; duplicates among them are acknowledged and dropped at once).
const MAX_PENDING: usize = 4096;

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
    status.finish(run_inner(transport, spec, opts, stop, probe, &status))
}

fn run_inner(
    transport: &Transport,
    spec: &RunSpec,
    opts: &LearnerOptions,
    stop: &AtomicBool,
    probe: crate::store::Probe,
    status: &Heartbeat,
) -> Result<LearnerExit, ProcessError> {
    let run = transport.run().clone();
    // The run directory: locked for as long as this function runs (`_lock`), its log recovered
    // from a crash mid-append, corruption refused (`store`).
    let store = crate::store::Store::open(&opts.run_dir, probe)
        .map_err(|e| io("cannot start the learner")(std::io::Error::other(e)))?;
    let sim_cfg = spec.method_sim();

    // State: the last checkpoint (refused if it is of another run), or a new run.
    let expected = checkpoint::RunIdentity {
        run_id: opts.run_id.clone(),
        method: spec.method,
        setting: spec.setting.name().to_string(),
        run_seed: spec.seed,
    };
    let log_path = opts.run_dir.join("metrics.jsonl");
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
                spec.sim.humans.count,
                spec.sim.dt_s,
                spec.seed,
            )?;
            (core, BTreeMap::new())
        }
    };
    core.set_action_count(sim::ActionSet::for_config(&sim_cfg).len());
    let (_lock, wal, wal_records) = store.into_parts();
    // The log goes back to the checkpoint (the log's episodes after it are replayed below and
    // logged again); without a checkpoint the run starts again from nothing.
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
    let subscriber = transport.subscriber(&keys::all_transitions(&run))?;
    let alive = transport.watch_alive()?;
    let mut l = Learner {
        t: transport,
        status,
        spec,
        opts,
        core,
        accepted_below,
        acks: HashMap::new(),
        weights: transport.latest_publisher(&keys::weights(&run))?,
        control: transport.latest_publisher(&keys::control(&run))?,
        metrics: transport.publisher(&keys::metrics(&run, transport.sender()))?,
        wal,
        actors_alive: AliveActors::default(),
        evaluators_alive: HashSet::new(),
        alive_tokens_refused: 0,
        window: Window {
            outcomes: VecDeque::new(),
            lags: VecDeque::new(),
            losses: VecDeque::new(),
        },
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
        sim_cfg,
        log,
        wall0,
        stored: None,
        log_failures: 0,
        idle_rounds: 0,
    };
    // Episodes acknowledged after the last checkpoint: back from the log, trained on again;
    // those the checkpoint already holds (a crash before the log was emptied) are dropped. The
    // log stays as it is: it already holds exactly these records.
    let plan = crate::store::replay_plan(&wal_records, &l.accepted_below);
    l.duplicates += plan.duplicates;
    let mut replayed = 0;
    for msg in &plan.episodes {
        if l.accept(
            msg.header.sender.index,
            &msg.body,
            msg.header.policy_version,
            false,
        )? {
            l.train_stored()?;
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
    let _token = transport.declare_alive()?;
    status.set_state(ProcessState::Running);
    l.publish_control();
    l.publish_metrics()?;

    if !l.core.counters().imitation_done {
        let mut last = Instant::now();
        let metrics = transport.publisher(&keys::metrics(&run, transport.sender()))?;
        let mut refused = 0u64;
        // The imitation lines of the log, written once the warm start is done (as in one
        // process).
        let mut log = crate::runlog::ImitationLog::default();
        let (wall0, start) = (l.wall0, l.start);
        // What the metrics tick shows: the newest demonstration count or finished epoch.
        #[derive(Clone, Copy)]
        enum Shown {
            Demo(u64, u64),
            Epoch(u32, u32, f32),
        }
        let mut shown = Shown::Demo(0, spec.train.imitation.episodes);
        let (actors_alive, evaluators_alive) = (&mut l.actors_alive, &mut l.evaluators_alive);
        let finished = imitation::run(&mut l.core, spec, stop, |p| {
            log.observe(&p, (wall0 + start.elapsed()).as_secs_f64());
            status.beat();
            // Who is alive, as in training: the watcher's queue is bounded and, once full,
            // leaves the zenoh thread that fills it waiting. Actors that join are acknowledged
            // when training starts.
            while let Ok(Some(ev)) = alive.recv_timeout(Duration::ZERO) {
                track_alive(actors_alive, evaluators_alive, status, ev);
            }
            // Nobody should send episodes now (actors wait for the training phase): drain and
            // count, so nothing piles up in the subscriber's queue during imitation. Progress
            // comes after every demonstration and every batch, so a long epoch cannot leave the
            // queue (and the router's link to this process) full.
            while let Ok(Some(msg)) = subscriber.try_recv() {
                refused += 1;
                warn_sometimes(
                    status,
                    "imitation",
                    refused,
                    format_args!(
                        "refused episode {} of {} during imitation",
                        msg.body.episode, msg.header.sender
                    ),
                );
            }
            match p {
                ImitationProgress::Demo { done, total } => shown = Shown::Demo(done, total),
                ImitationProgress::DemosDone { .. } => {}
                ImitationProgress::Batch { .. } => {}
                ImitationProgress::Epoch { done, total, loss } => {
                    shown = Shown::Epoch(done, total, loss)
                }
            }
            if last.elapsed() >= opts.metrics_interval {
                last = Instant::now();
                let mut m = Metrics::default();
                match shown {
                    Shown::Demo(done, total) => {
                        m.values.insert("demo_episodes".into(), done as f64);
                        m.values.insert("demo_target".into(), total as f64);
                    }
                    Shown::Epoch(done, total, loss) => {
                        m.values.insert("imitation_epoch".into(), done as f64);
                        m.values.insert("imitation_epochs".into(), total as f64);
                        m.values.insert("loss".into(), loss as f64);
                    }
                }
                m.values
                    .insert("refused_in_imitation".into(), refused as f64);
                m.values
                    .insert("actors_alive".into(), actors_alive.len() as f64);
                let _ = metrics.publish(0, &m);
            }
        })?;
        l.refused_in_imitation = refused;
        if !finished {
            return Ok(LearnerExit::Stopped);
        }
        for line in log.lines() {
            l.log_line(&line);
        }
        // The warm start is only in memory until this checkpoint: on a full disk, retry with
        // back-off (each failure counted and logged) instead of dying and redoing it.
        let mut retry_in = Duration::from_millis(500);
        while !l.try_checkpoint() {
            if stop.load(Ordering::SeqCst) {
                tracing::error!("stopped before the checkpoint after imitation could be written; the warm start is done again on the next start");
                return Ok(LearnerExit::Stopped);
            }
            tracing::warn!(
                retry_in_ms = retry_in.as_millis() as u64,
                "the checkpoint after imitation failed (free disk space in the run directory); retrying"
            );
            std::thread::sleep(retry_in);
            retry_in = (retry_in * 2).min(Duration::from_secs(30));
        }
        tracing::info!(transitions = l.core.replay().len(), "imitation done");
    }
    l.rl_start = (
        Instant::now(),
        l.core.counters().rl_episodes,
        l.core.counters().updates,
    );
    l.publish_weights()?;
    l.publish_control();
    // The actors that joined during the warm start learn where to go on; the first metrics
    // of training name where its replay ratio is counted from (`rl_start_*`).
    for id in l.live_actor_ids() {
        l.ack(id);
    }
    l.publish_metrics()?;
    let mut last_tick = Instant::now();
    let every = spec.train.checkpoint_every_episodes;
    let mut checkpoint_due = false;
    let mut pending = VecDeque::new();
    let mut published_since_tick = true;
    let ratio = spec.train.rl.replay_ratio;

    while l.phase() == RunPhase::Training {
        if stop.load(Ordering::SeqCst) {
            status.set_state(ProcessState::Stopping);
            l.checkpoint()?;
            return Ok(LearnerExit::Stopped);
        }
        let mut membership_changed = false;
        while let Some(ev) = alive.recv_timeout(Duration::ZERO)? {
            membership_changed |= l.on_alive(ev);
        }
        // Idle while no actor is alive (nothing can arrive), running otherwise.
        status.set_state(if l.actors_alive.is_empty() {
            ProcessState::Idle
        } else {
            ProcessState::Running
        });
        status.beat();
        if membership_changed {
            l.publish_control();
        }
        if last_tick.elapsed() >= opts.metrics_interval {
            last_tick = Instant::now();
            l.alive_tokens_refused = alive.refused_count()?;
            l.publish_metrics()?;
            if !published_since_tick {
                // Weights and control are dropped for a subscriber that does not keep up
                // (`transport`): with nothing newer to send, the current values again.
                l.republish_latest();
            }
            published_since_tick = false;
            // Re-acknowledge periodically: an actor that missed an ack learns where to go on.
            for id in l.live_actor_ids() {
                l.ack(id);
            }
            if checkpoint_due {
                // A checkpoint failed earlier (a full disk): try again.
                checkpoint_due = !l.try_checkpoint();
            }
        }
        // The adaptive mode (`train.rl.replay_ratio`): may the learner take the next episode
        // (it has done at least `min` updates per episode taken), and may it train without one
        // (fewer than `max` per episode)? The fixed schedule takes every episode and trains on it.
        let (episodes, updates) = l.rl_progress();
        let (may_take, may_train) = match ratio {
            None => (true, false),
            Some(r) => (
                updates as f64 >= r.min * episodes as f64,
                (updates as f64) < r.max * episodes as f64 && !l.core.replay().is_empty(),
            ),
        };
        // Everything the transport holds is taken in before one episode is trained on: a
        // transport that serves its senders in a fixed order (iceoryx2 reads its publishers'
        // queues one after the other) would otherwise hand over the first actor's next
        // episode every time and starve the others until their queues fill up. Arrivals are
        // then trained in the order they came, one per round of updates.
        if pending.is_empty() && !may_train {
            let waited = Instant::now();
            let first = subscriber.recv_timeout(Duration::from_millis(50))?;
            l.wait += waited.elapsed();
            pending.extend(first);
        }
        while pending.len() < MAX_PENDING {
            match subscriber.try_recv()? {
                Some(m) => pending.push_back(m),
                None => break,
            }
        }
        if !may_take || pending.is_empty() {
            if may_train {
                // Train on: a round of at most `batches_per_episode` updates, no further than
                // `max` per episode; new weights go out after each round (a bounded rate,
                // whatever the number of actors).
                let r = ratio.expect("may_train only in the adaptive mode");
                let room = (r.max * episodes as f64).ceil() as u64 - updates;
                let batches = room.clamp(1, spec.train.rl.batches_per_episode.max(1) as u64);
                l.train_round(batches as u32)?;
                l.publish_weights()?;
                published_since_tick = true;
            }
            continue;
        }
        let Some(msg) = pending.pop_front() else {
            continue;
        };
        if l.take(msg) != Accepted::Stored {
            continue;
        }
        if ratio.is_some() {
            l.log_stored();
        } else {
            l.train_stored()?;
            l.publish_weights()?;
        }
        if l.phase() != RunPhase::Training {
            // The last episode: "finished" goes out only after the final weights (below), so
            // that what the evaluator takes as the run's last weights are those (issue 44).
            break;
        }
        l.publish_control();
        published_since_tick = true;
        let done = l.core.counters().rl_episodes;
        if (every > 0 && done.is_multiple_of(every)) || checkpoint_due {
            checkpoint_due = !l.try_checkpoint();
        }
    }
    if let (Some(r), RunPhase::Finished) = (ratio, l.phase()) {
        // The last episodes taken get their share too: at least `min` updates per episode.
        loop {
            let (episodes, updates) = l.rl_progress();
            let owed = (r.min * episodes as f64).ceil() as u64;
            if updates >= owed || l.core.replay().is_empty() || stop.load(Ordering::SeqCst) {
                break;
            }
            let batches = (owed - updates).min(spec.train.rl.batches_per_episode.max(1) as u64);
            l.train_round(batches as u32)?;
        }
    }

    // The run is over: the final weights (carrying the final RL episode count) before the
    // `Finished` control, which names their version (its header's policy version): an evaluator
    // that sees `Finished` validates weights of at least that version.
    l.checkpoint()?;
    l.publish_weights()?;
    l.publish_control();
    l.publish_metrics()?;
    tracing::info!(
        rl_episodes = l.core.counters().rl_episodes,
        "run finished; waiting for actors and evaluators to leave"
    );
    status.set_state(ProcessState::Stopping);
    let deadline = Instant::now() + opts.linger;
    let mut last_repeat = Instant::now();
    while Instant::now() < deadline && !(l.actors_alive.is_empty() && l.evaluators_alive.is_empty())
    {
        status.beat();
        // The final weights and the `Finished` control reach a subscriber they were dropped for.
        if last_repeat.elapsed() >= opts.metrics_interval {
            last_repeat = Instant::now();
            l.republish_latest();
        }
        if let Some(ev) = alive.recv_timeout(Duration::from_millis(100))? {
            match ev {
                AliveEvent::Left(m) if m.sender.role == Role::Actor => {
                    l.on_alive(ev);
                }
                AliveEvent::Left(m) => {
                    l.evaluators_alive.remove(&m);
                }
                AliveEvent::Joined(m) if m.sender.role == Role::Actor => {
                    l.on_alive(ev);
                }
                AliveEvent::Joined(m) if m.sender.role == Role::Evaluator => {
                    l.evaluators_alive.insert(m);
                }
                _ => {}
            }
        }
        if stop.load(Ordering::SeqCst) {
            break;
        }
    }
    Ok(LearnerExit::Finished)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 35, item 1: the cap counts actor ids, not liveliness tokens, so one id's flood of
    /// instances (under its own credentials) leaves room for every other actor.
    #[test]
    fn a_flood_of_one_ids_instances_takes_one_place() {
        let mut alive = AliveActors::default();
        assert_eq!(alive.join(0, 1, 3), Joined::NewId);
        for instance in 2..5000 {
            assert_eq!(alive.join(0, instance, 3), Joined::NewInstance);
        }
        assert_eq!(alive.join(0, 7, 3), Joined::Known);
        assert_eq!(alive.len(), 1);
        assert_eq!(alive.join(1, 1, 3), Joined::NewId);
        assert_eq!(alive.join(2, 1, 3), Joined::NewId);
        assert_eq!(alive.join(3, 1, 3), Joined::Refused);
        assert_eq!(alive.refused, 1);
        assert_eq!(alive.ids().collect::<Vec<_>>(), [0, 1, 2]);
        // Id 0 stays until its last instance leaves; then id 3 gets the place.
        assert_eq!(alive.leave(0, 1), Left::Instance);
        assert_eq!(alive.leave(0, 1), Left::Unknown);
        for instance in 2..4999 {
            assert_eq!(alive.leave(0, instance), Left::Instance);
        }
        assert_eq!(alive.leave(0, 4999), Left::LastInstance);
        assert_eq!(alive.leave(9, 1), Left::Unknown);
        assert_eq!(alive.join(3, 1, 3), Joined::NewId);
        assert!(!alive.is_empty());
    }

    #[test]
    fn the_lag_quantile_is_the_nearest_rank() {
        let mut w = Window {
            outcomes: VecDeque::new(),
            lags: VecDeque::new(),
            losses: VecDeque::new(),
        };
        assert_eq!(w.lag_quantile(0.95), 0);
        for lag in [3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 7] {
            w.push(Outcome::ReachGoal, lag, 0.0);
        }
        // 20 lags: the 19th smallest is 3, the largest 7.
        assert_eq!(w.lag_quantile(0.95), 3);
        assert_eq!(w.lag_quantile(1.0), 7);
        assert_eq!(w.lag_quantile(0.5), 1);
    }
}
