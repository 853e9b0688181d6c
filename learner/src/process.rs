//! The learner process: receives episodes from any number of actors, trains at the configured
//! replay ratio, broadcasts versioned weights, announces ε and flow-control credits, and never
//! loses an acknowledged episode (write-ahead log + checkpoints + actor re-sends).
//!
//! Flow control (Reverb-style): each actor may run at most `in_flight_per_actor` episodes ahead
//! of what the learner has accepted; when the learner is busy training, actors wait instead of
//! data being dropped.

use std::collections::{BTreeMap, HashMap, HashSet, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use policy::method::RunSpec;
use policy::wire::{from_batch, weights_message};
use proto::{keys, Ack, Control, CreditGrant, Metrics, Role, RunPhase, TransitionBatch};
use sim::Outcome;
use transport::{AliveEvent, Publisher, Transport, TransportError};

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
    fn rate(&self, o: Outcome) -> f64 {
        if self.outcomes.is_empty() {
            return 0.0;
        }
        self.outcomes.iter().filter(|x| **x == o).count() as f64 / self.outcomes.len() as f64
    }
}

struct Learner<'a> {
    t: &'a Transport,
    spec: &'a RunSpec,
    opts: &'a LearnerOptions,
    core: LearnerCore,
    accepted_below: BTreeMap<u32, u64>,
    acks: HashMap<u32, Publisher<Ack>>,
    weights: transport::LatestPublisher<proto::Weights>,
    control: transport::LatestPublisher<Control>,
    metrics: Publisher<Metrics>,
    wal: Wal,
    actors_alive: HashSet<proto::Member>,
    evaluators_alive: HashSet<proto::Member>,
    window: Window,
    rejected_episodes: u64,
    duplicates: u64,
    start: Instant,
    rl_start: (Instant, u64),
    last_loss: f32,
    sim_cfg: sim::SimConfig,
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
        checkpoint::save(&path, &self.core, &self.sim_cfg, &self.run_info())?;
        self.wal
            .truncate()
            .map_err(io("truncating the write-ahead log"))?;
        tracing::info!(rl_episodes = self.core.counters().rl_episodes, path = %path.display(), "checkpoint written");
        Ok(())
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

    fn publish_control(&mut self) -> Result<(), ProcessError> {
        let mut ids: BTreeMap<u32, u64> = self.accepted_below.clone();
        for m in &self.actors_alive {
            ids.entry(m.sender.index).or_insert(0);
        }
        let credits = ids
            .iter()
            .map(|(&actor, &below)| CreditGrant {
                actor,
                episode_budget: below + self.opts.in_flight_per_actor,
            })
            .collect();
        let c = Control {
            phase: self.phase(),
            epsilon: self.core.epsilon() as f32,
            credits,
        };
        self.control
            .publish(self.core.counters().policy_version, &c)?;
        Ok(())
    }

    fn publish_weights(&mut self) -> Result<(), ProcessError> {
        let version = self.core.counters().policy_version;
        let w = weights_message(self.core.online(), version)
            .map_err(|e| ProcessError::Weights(e.to_string()))?;
        self.weights.publish(version, &w)?;
        Ok(())
    }

    fn ack(&mut self, actor: u32) -> Result<(), ProcessError> {
        let below = self.accepted_below.get(&actor).copied().unwrap_or(0);
        if !self.acks.contains_key(&actor) {
            let p = self.t.publisher(&keys::ack(self.t.run(), actor))?;
            self.acks.insert(actor, p);
        }
        let version = self.core.counters().policy_version;
        self.acks[&actor].publish(
            version,
            &Ack {
                actor,
                acked_below: below,
                episodes: Vec::new(),
            },
        )?;
        Ok(())
    }

    fn publish_metrics(&self) -> Result<(), ProcessError> {
        let c = self.core.counters();
        let wall = self.start.elapsed().as_secs_f64();
        let (t0, e0) = self.rl_start;
        let rl_wall = t0.elapsed().as_secs_f64().max(1e-9);
        let lag_mean = if self.window.lags.is_empty() {
            0.0
        } else {
            self.window.lags.iter().sum::<u64>() as f64 / self.window.lags.len() as f64
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
            ("replay_size", self.core.replay().len() as f64),
            ("updates", c.updates as f64),
            ("rejected_messages", self.t.rejected_count() as f64),
            ("rejected_episodes", self.rejected_episodes as f64),
            ("duplicate_episodes", self.duplicates as f64),
            ("actors_alive", self.actors_alive.len() as f64),
            ("imitation_done", if c.imitation_done { 1.0 } else { 0.0 }),
        ] {
            m.values.insert(k.to_string(), v);
        }
        self.metrics.publish(c.policy_version, &m)?;
        Ok(())
    }

    /// Accepts one episode (not yet trained on). Returns false for a duplicate or a rejection.
    fn accept(
        &mut self,
        actor: u32,
        batch: &TransitionBatch,
        version: u64,
        log: bool,
    ) -> Result<bool, ProcessError> {
        let below = self.accepted_below.get(&actor).copied().unwrap_or(0);
        if batch.episode < below {
            self.duplicates += 1;
            return Ok(false);
        }
        let ep = match from_batch(batch, version, &self.sim_cfg) {
            Ok(ep) if ep.setting == self.spec.setting => ep,
            Ok(ep) => {
                self.rejected_episodes += 1;
                tracing::warn!(actor, setting = %ep.setting, "rejected an episode of another setting");
                return Ok(false);
            }
            Err(e) => {
                self.rejected_episodes += 1;
                tracing::warn!(actor, episode = batch.episode, "rejected an episode: {e}");
                return Ok(false);
            }
        };
        if let Err(e) = self.core.add_episode(&ep, false) {
            self.rejected_episodes += 1;
            tracing::warn!(actor, episode = batch.episode, "rejected an episode: {e}");
            return Ok(false);
        }
        self.accepted_below.insert(actor, batch.episode + 1);
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
        Ok(true)
    }
}

/// Runs the learner until the run's RL episodes are done or `stop` is set (then checkpoints).
pub fn run(
    transport: &Transport,
    spec: &RunSpec,
    opts: &LearnerOptions,
    stop: &AtomicBool,
) -> Result<LearnerExit, ProcessError> {
    let run = transport.run().clone();
    std::fs::create_dir_all(opts.run_dir.join("checkpoints"))
        .map_err(io(format!("creating {}", opts.run_dir.display())))?;
    let ckpt = opts.run_dir.join("checkpoints").join("latest.ckpt");
    let wal_path = opts.run_dir.join("wal.bin");
    let sim_cfg = spec.method_sim();

    // State: the last checkpoint, or a new run.
    let (core, accepted_below) = if ckpt.exists() {
        let loaded = checkpoint::load(&ckpt)?;
        tracing::info!(
            rl_episodes = loaded.core.counters().rl_episodes,
            "resuming from {}",
            ckpt.display()
        );
        (loaded.core, loaded.run.accepted_below)
    } else {
        let core = LearnerCore::new(
            spec.method,
            spec.train.clone(),
            spec.sim.humans.count,
            spec.sim.dt_s,
            spec.seed,
        )?;
        (core, BTreeMap::new())
    };
    let wal_records = Wal::read_all(&wal_path).map_err(io("reading the write-ahead log"))?;
    let subscriber = transport.subscriber(&keys::all_transitions(&run))?;
    let alive = transport.watch_alive()?;
    let mut l = Learner {
        t: transport,
        spec,
        opts,
        core,
        accepted_below,
        acks: HashMap::new(),
        weights: transport.latest_publisher(&keys::weights(&run))?,
        control: transport.latest_publisher(&keys::control(&run))?,
        metrics: transport.publisher(&keys::metrics(&run, transport.sender()))?,
        wal: Wal::open(&wal_path).map_err(io("opening the write-ahead log"))?,
        actors_alive: HashSet::new(),
        evaluators_alive: HashSet::new(),
        window: Window {
            outcomes: VecDeque::new(),
            lags: VecDeque::new(),
            losses: VecDeque::new(),
        },
        rejected_episodes: 0,
        duplicates: 0,
        start: Instant::now(),
        rl_start: (Instant::now(), 0),
        last_loss: f32::NAN,
        sim_cfg,
    };
    // Episodes acknowledged after the last checkpoint: back from the log, trained on again.
    let mut replayed = 0;
    for rec in &wal_records {
        match proto::decode::<TransitionBatch>(rec) {
            Ok(msg) if msg.header.sender.role == Role::Actor => {
                if l.accept(
                    msg.header.sender.index,
                    &msg.body,
                    msg.header.policy_version,
                    false,
                )? {
                    l.last_loss = l.core.train_rl(spec.train.rl.batches_per_episode)?;
                    replayed += 1;
                }
            }
            _ => tracing::warn!("skipping an unreadable write-ahead log record"),
        }
    }
    if !wal_records.is_empty() {
        tracing::info!(replayed, "write-ahead log replayed");
        // Keep the records: they are still only in the log until the next checkpoint.
        let mut fresh = Wal::open(&wal_path).map_err(io("reopening the write-ahead log"))?;
        fresh
            .truncate()
            .map_err(io("truncating the write-ahead log"))?;
        for rec in &wal_records {
            fresh
                .append(rec)
                .map_err(io("rewriting the write-ahead log"))?;
        }
        l.wal = fresh;
    }
    let _token = transport.declare_alive()?;
    l.publish_control()?;
    l.publish_metrics()?;

    if !l.core.counters().imitation_done {
        let mut last = Instant::now();
        let metrics = transport.publisher(&keys::metrics(&run, transport.sender()))?;
        let finished = imitation::run(&mut l.core, spec, stop, |p| {
            if last.elapsed() >= opts.metrics_interval {
                last = Instant::now();
                let mut m = Metrics::default();
                match p {
                    ImitationProgress::Demo { done, total } => {
                        m.values.insert("demo_episodes".into(), done as f64);
                        m.values.insert("demo_target".into(), total as f64);
                    }
                    ImitationProgress::Epoch { done, total, loss } => {
                        m.values.insert("imitation_epoch".into(), done as f64);
                        m.values.insert("imitation_epochs".into(), total as f64);
                        m.values.insert("loss".into(), loss as f64);
                    }
                }
                let _ = metrics.publish(0, &m);
            }
        })?;
        if !finished {
            return Ok(LearnerExit::Stopped);
        }
        l.checkpoint()?;
        tracing::info!(transitions = l.core.replay().len(), "imitation done");
    }
    l.rl_start = (Instant::now(), l.core.counters().rl_episodes);
    l.publish_weights()?;
    l.publish_control()?;
    let mut last_tick = Instant::now();
    let every = spec.train.checkpoint_every_episodes;

    while l.phase() == RunPhase::Training {
        if stop.load(Ordering::SeqCst) {
            l.checkpoint()?;
            return Ok(LearnerExit::Stopped);
        }
        let mut membership_changed = false;
        while let Some(ev) = alive.recv_timeout(Duration::ZERO)? {
            membership_changed = true;
            match ev {
                AliveEvent::Joined(m) if m.sender.role == Role::Actor => {
                    tracing::info!(actor = %m, "actor joined");
                    l.actors_alive.insert(m);
                    l.ack(m.sender.index)?;
                }
                AliveEvent::Left(m) if m.sender.role == Role::Actor => {
                    tracing::warn!(actor = %m, "actor left");
                    l.actors_alive.remove(&m);
                }
                AliveEvent::Joined(m) if m.sender.role == Role::Evaluator => {
                    l.evaluators_alive.insert(m);
                }
                AliveEvent::Left(m) if m.sender.role == Role::Evaluator => {
                    l.evaluators_alive.remove(&m);
                }
                _ => {}
            }
        }
        if membership_changed {
            l.publish_control()?;
        }
        if last_tick.elapsed() >= opts.metrics_interval {
            last_tick = Instant::now();
            l.publish_metrics()?;
            // Re-acknowledge periodically: an actor that missed an ack learns where to go on.
            let ids: Vec<u32> = l.actors_alive.iter().map(|m| m.sender.index).collect();
            for id in ids {
                l.ack(id)?;
            }
        }
        let Some(msg) = subscriber.recv_timeout(Duration::from_millis(50))? else {
            continue;
        };
        if msg.header.sender.role != Role::Actor {
            l.rejected_episodes += 1;
            tracing::warn!(sender = %msg.header.sender, "transitions from a non-actor ignored");
            continue;
        }
        let actor = msg.header.sender.index;
        let bytes =
            proto::encode_message(&msg).map_err(|e| ProcessError::Weights(e.to_string()))?;
        let accepted = l.accept(actor, &msg.body, msg.header.policy_version, true)?;
        if accepted {
            // Durable before acknowledged.
            l.wal
                .append(&bytes)
                .map_err(io("appending to the write-ahead log"))?;
        }
        l.ack(actor)?;
        if !accepted {
            continue;
        }
        l.last_loss = l.core.train_rl(spec.train.rl.batches_per_episode)?;
        if let Some(last) = l.window.losses.back_mut() {
            *last = l.last_loss;
        }
        l.publish_weights()?;
        l.publish_control()?;
        let done = l.core.counters().rl_episodes;
        if every > 0 && done.is_multiple_of(every) {
            l.checkpoint()?;
        }
    }

    // The run is over.
    l.checkpoint()?;
    l.publish_weights()?;
    l.publish_control()?;
    l.publish_metrics()?;
    tracing::info!(
        rl_episodes = l.core.counters().rl_episodes,
        "run finished; waiting for actors and evaluators to leave"
    );
    let deadline = Instant::now() + opts.linger;
    while Instant::now() < deadline && !(l.actors_alive.is_empty() && l.evaluators_alive.is_empty())
    {
        if let Some(ev) = alive.recv_timeout(Duration::from_millis(100))? {
            match ev {
                AliveEvent::Left(m) => {
                    l.actors_alive.remove(&m);
                    l.evaluators_alive.remove(&m);
                }
                AliveEvent::Joined(m) if m.sender.role == Role::Actor => {
                    l.actors_alive.insert(m);
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
