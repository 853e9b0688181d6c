//! `actor`: the actor role. Runs RL episodes of its setting with the newest weights it has and
//! the ε the learner announces, publishes every finished episode, and keeps every episode until
//! the learner acknowledges it (re-sending them to a restarted learner).
//!
//! It holds off — simulates nothing — while no learner is alive, before it has weights, while
//! the run is not in its training phase, or when its flow-control budget is used up (the learner
//! is behind); it resumes by itself when the condition clears.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use policy::lookahead::Lookahead;
use policy::method::RunSpec;
use policy::rollout::{episode_seed, rollout, Behaviour};
use policy::wire::{net_from_weights, to_batch};
use policy::ValueNet;
use proto::{keys, Metrics, ProcessState, Role, RunPhase, TransitionBatch};
use sim::Env;
use transport::{AliveEvent, Heartbeat, Transport, TransportError};

/// Episode-seed stream of actor `id` (stream 0 is the demonstrator's, 1 the single-process
/// mode's one in-process actor, [`LOCKSTEP_STREAM`]).
pub fn actor_stream(id: u32) -> u64 {
    100 + id as u64
}

/// Episode-seed stream of the in-process actor of a single-process run (kept at 1, so that
/// runs trained before the modes shared this code replay bit for bit).
pub const LOCKSTEP_STREAM: u64 = 1;

/// An actor's episode loop without the transport: the run's environment and lookahead, playing
/// one RL episode at a time with the given weights and ε. The actor process and the
/// single-process mode (`trainer::run`) both act through it.
pub struct Player {
    env: Env,
    lookahead: Lookahead,
    run_seed: u64,
}

impl Player {
    pub fn new(spec: &RunSpec) -> Result<Self, ActorError> {
        let env = Env::new(spec.method_sim(), spec.setting, 0)
            .map_err(|e| ActorError::Sim(e.to_string()))?;
        let lookahead = spec.train.training_lookahead(spec.method.human_order());
        Ok(Self {
            env,
            lookahead,
            run_seed: spec.seed,
        })
    }

    /// Actions in the run's action set.
    pub fn n_actions(&self) -> usize {
        self.env.action_set().len()
    }

    /// Episode `episode` of seed stream `stream`, acting ε-greedily with `net` (weights
    /// `version`).
    pub fn play(
        &mut self,
        stream: u64,
        episode: u64,
        net: &ValueNet,
        version: u64,
        epsilon: f64,
    ) -> Result<policy::rollout::EpisodeData, ActorError> {
        let seed = episode_seed(self.run_seed, stream, episode);
        rollout(
            &mut self.env,
            seed,
            Behaviour::Net {
                net,
                lookahead: &mut self.lookahead,
                epsilon,
                policy_version: version,
            },
        )
        .map_err(|e| ActorError::Sim(e.to_string()))
    }
}

/// Why an actor stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ActorError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("simulation: {0}")]
    Sim(String),
    #[error("method {0} has no network to act with")]
    NotLearned(policy::method::Method),
}

/// How an actor run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ActorExit {
    /// The learner announced the end of the run.
    Finished,
    /// Asked to stop (signal).
    Stopped,
}

/// Counters of an actor, also published as metrics.
#[derive(Debug, Clone, Default)]
pub struct ActorStats {
    /// The newest warning not yet handed to the status heartbeat (its last error).
    pub last_error: Option<String>,
    pub episodes: u64,
    pub env_steps: u64,
    pub resent: u64,
    pub acked: u64,
    pub weights_version: u64,
    /// Weights messages that did not fit this run's network (skipped).
    pub bad_weights: u64,
    /// Time spent simulating episodes, and waiting (no learner, no weights, no credit).
    pub sim: Duration,
    pub wait: Duration,
    /// Publications of an episode that timed out (the learner did not drain in time, e.g.
    /// while it wrote a checkpoint on a busy machine): the episode stays in the outbox and is
    /// sent again; never fatal.
    pub publish_timeouts: u64,
    /// Episodes an earlier learner acknowledged that the learner alive now does not hold (its
    /// store was restored from an older checkpoint or its log moved aside): lost, reported.
    pub lost: u64,
    /// Acknowledgements from a learner other than the one alive now (ignored).
    pub foreign_acks: u64,
}

/// Publishes one episode; a publication that times out is counted and logged (at powers of
/// two) and reported as `Ok(false)`: the episode is in the outbox and goes again with the next
/// re-send. Any other transport error is returned.
fn send(
    publisher: &transport::Publisher<TransitionBatch>,
    version: u64,
    batch: &TransitionBatch,
    stats: &mut ActorStats,
) -> Result<bool, TransportError> {
    match publisher.publish(version, batch) {
        Ok(_) => Ok(true),
        Err(e @ TransportError::PublishTimeout { .. }) => {
            stats.publish_timeouts += 1;
            stats.last_error = Some(format!(
                "episode {}: {e}; it stays in the outbox and is sent again",
                batch.episode
            ));
            if stats.publish_timeouts.is_power_of_two() {
                tracing::warn!(
                    episode = batch.episode,
                    count = stats.publish_timeouts,
                    "{e}; the episode stays in the outbox and is sent again (logged at powers of two of the count)"
                );
            }
            Ok(false)
        }
        Err(e) => Err(e),
    }
}

struct State {
    outbox: BTreeMap<u64, TransitionBatch>,
    outbox_versions: BTreeMap<u64, u64>,
    next_episode: Option<u64>,
    learner: Option<u64>,
    net: Option<(u64, ValueNet)>,
    /// Header of the last weights message tried (loaded or refused): the newest message on the
    /// latest-value topic wins, whatever its version number, so a learner restarted from an
    /// older checkpoint (lower versions) is followed and no stale high version pins the actor.
    weights_tried: Option<proto::Header>,
    /// When the outbox is re-sent if no acknowledgement has moved meanwhile.
    resend_at: Option<Instant>,
}

/// How long the actor waits for its oldest unacknowledged episode to be acknowledged before it
/// re-sends the outbox (the learner refuses episodes past a gap, so a lost one must come again).
const RESEND_AFTER: Duration = Duration::from_secs(5);

impl State {
    /// Re-sends every unacknowledged episode, oldest first.
    fn resend(
        &mut self,
        publisher: &transport::Publisher<TransitionBatch>,
        stats: &mut ActorStats,
    ) -> Result<(), TransportError> {
        for (ep, batch) in &self.outbox {
            let v = self.outbox_versions.get(ep).copied().unwrap_or(0);
            if !send(publisher, v, batch, stats)? {
                // The learner is not draining: the rest waits for the next re-send.
                break;
            }
            stats.resent += 1;
        }
        self.resend_at = (!self.outbox.is_empty()).then(|| Instant::now() + RESEND_AFTER);
        Ok(())
    }

    /// Applies membership events: a (new) learner gets every unacknowledged episode again.
    fn on_membership(
        &mut self,
        alive: &transport::AliveWatcher,
        publisher: &transport::Publisher<TransitionBatch>,
        stats: &mut ActorStats,
        id: u32,
    ) -> Result<(), TransportError> {
        while let Some(ev) = alive.recv_timeout(Duration::ZERO)? {
            match ev {
                AliveEvent::Joined(m)
                    if m.sender.role == Role::Learner && self.learner != Some(m.instance) =>
                {
                    tracing::info!(actor = id, learner = %m, unacked = self.outbox.len(), "learner joined");
                    self.learner = Some(m.instance);
                    self.resend(publisher, stats)?;
                }
                AliveEvent::Left(m)
                    if m.sender.role == Role::Learner && self.learner == Some(m.instance) =>
                {
                    tracing::warn!(actor = id, learner = %m, "learner left; holding off");
                    self.learner = None;
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// Runs actor `id` until the learner finishes the run or `stop` is set. Its status heartbeats
/// tell its state (starting until it has weights and a learner; running while it plays; idle
/// while it holds off; stopping; failed with why) and its last warning.
pub fn run(
    transport: &Transport,
    spec: &RunSpec,
    id: u32,
    stop: &AtomicBool,
) -> Result<ActorExit, ActorError> {
    let status = Heartbeat::new(transport)?;
    status.finish(run_inner(transport, spec, id, stop, &status))
}

fn run_inner(
    transport: &Transport,
    spec: &RunSpec,
    id: u32,
    stop: &AtomicBool,
    status: &Heartbeat,
) -> Result<ActorExit, ActorError> {
    let net_cfg = spec
        .method
        .net()
        .ok_or(ActorError::NotLearned(spec.method))?;
    let run = transport.run().clone();
    let acks = transport.subscriber(&keys::ack(&run, id))?;
    let weights = transport.latest_subscriber(&keys::weights(&run))?;
    let control = transport.latest_subscriber(&keys::control(&run))?;
    let alive = transport.watch_alive()?;
    let publisher = transport.publisher(&keys::transitions(&run, id))?;
    let metrics = transport.publisher(&keys::metrics(&run, transport.sender()))?;
    let _token = transport.declare_alive()?;

    let mut player = Player::new(spec)?;
    let n_actions = player.n_actions() as u16;
    let mut st = State {
        outbox: BTreeMap::new(),
        outbox_versions: BTreeMap::new(),
        next_episode: None,
        learner: None,
        net: None,
        weights_tried: None,
        resend_at: None,
    };
    let mut stats = ActorStats::default();
    let start = Instant::now();
    let mut last_metrics = Instant::now();
    let mut waiting_since: Option<Instant> = None;
    tracing::info!(actor = id, setting = %spec.setting, "actor started; waiting for a learner");

    loop {
        if stop.load(Ordering::SeqCst) {
            return Ok(ActorExit::Stopped);
        }
        st.on_membership(&alive, &publisher, &mut stats, id)?;
        // Acknowledgements: drop what the learner holds; learn where to continue.
        while let Some(msg) = acks.try_recv()? {
            apply_ack(&mut st, &mut stats, id, &msg.body);
        }
        // Newest weights (each message tried once).
        if let Some(w) = weights.latest()? {
            if st.weights_tried.as_ref() != Some(&w.header) {
                st.weights_tried = Some(w.header.clone());
                let version = w.body.version;
                match net_from_weights(&w.body, &net_cfg) {
                    Ok(net) => {
                        st.net = Some((version, net));
                        stats.weights_version = version;
                    }
                    Err(e) => {
                        stats.bad_weights += 1;
                        stats.last_error = Some(format!("ignoring weights version {version}: {e}"));
                        if stats.bad_weights.is_power_of_two() {
                            tracing::warn!(
                                actor = id,
                                version,
                                count = stats.bad_weights,
                                "ignoring weights: {e}"
                            );
                        }
                    }
                }
            }
        }
        // Nothing acknowledged for a while: something was lost in flight; send it again.
        if st.learner.is_some() && st.resend_at.is_some_and(|t| Instant::now() >= t) {
            tracing::debug!(
                actor = id,
                unacked = st.outbox.len(),
                "re-sending the outbox"
            );
            st.resend(&publisher, &mut stats)?;
        }
        let ctl = control.latest()?;
        if let Some(c) = &ctl {
            if c.body.phase == RunPhase::Finished {
                tracing::info!(actor = id, episodes = stats.episodes, "run finished");
                publish_metrics(&metrics, &stats, start, st.outbox.len())?;
                return Ok(ActorExit::Finished);
            }
        }
        let budget = ctl.as_ref().and_then(|c| c.body.budget_for(id));
        let ready = match (&ctl, st.learner, st.next_episode, &st.net, budget) {
            (Some(c), Some(_), Some(next), Some(_), Some(budget)) => {
                c.body.phase == RunPhase::Training && next < budget
            }
            _ => false,
        };
        if let Some(e) = stats.last_error.take() {
            status.error(e);
        }
        status.set_state(if ready {
            ProcessState::Running
        } else if st.net.is_none() {
            ProcessState::Starting
        } else {
            ProcessState::Idle
        });
        status.progress(stats.env_steps, stats.episodes);
        status.beat();
        if last_metrics.elapsed() >= Duration::from_secs(1) {
            publish_metrics(&metrics, &stats, start, st.outbox.len())?;
            last_metrics = Instant::now();
        }
        if !ready {
            if waiting_since.is_none() {
                waiting_since = Some(Instant::now());
            }
            // Block on the next acknowledgement (or time out and re-check everything).
            let t0 = Instant::now();
            let msg = acks.recv_timeout(Duration::from_millis(50))?;
            stats.wait += t0.elapsed();
            if let Some(msg) = msg {
                apply_ack(&mut st, &mut stats, id, &msg.body);
            }
            continue;
        }
        if let Some(since) = waiting_since.take() {
            tracing::debug!(
                actor = id,
                waited_ms = since.elapsed().as_millis() as u64,
                "resuming"
            );
        }
        let episode = st.next_episode.expect("ready implies a start index");
        let (version, net) = st.net.as_ref().expect("ready implies weights");
        let epsilon = ctl.as_ref().map_or(0.0, |c| c.body.epsilon as f64);
        let t0 = Instant::now();
        let data = player.play(actor_stream(id), episode, net, *version, epsilon)?;
        stats.sim += t0.elapsed();
        let batch =
            to_batch(&data, episode, n_actions).map_err(|e| ActorError::Sim(e.to_string()))?;
        let version = *version;
        // A learner that joined during the episode gets the outbox first, in order.
        st.on_membership(&alive, &publisher, &mut stats, id)?;
        send(&publisher, version, &batch, &mut stats)?;
        st.outbox.insert(episode, batch);
        st.outbox_versions.insert(episode, version);
        st.resend_at
            .get_or_insert_with(|| Instant::now() + RESEND_AFTER);
        st.next_episode = Some(episode + 1);
        stats.episodes += 1;
        stats.env_steps += data.steps() as u64;
    }
}

/// Drops what the learner holds and learns where to continue. Only the learner alive now is
/// listened to (a stale learner's acknowledgements are counted and ignored). When it expects an
/// episode below the oldest one this actor still holds, the episodes between were acknowledged
/// by an earlier learner and are not in this one's store: they are reported lost and the
/// outbox and the numbering go on from the episode the learner expects.
fn apply_ack(st: &mut State, stats: &mut ActorStats, id: u32, ack: &proto::Ack) {
    if ack.actor != id {
        return;
    }
    if st.learner != Some(ack.learner) {
        stats.foreign_acks += 1;
        stats.last_error = Some(format!(
            "ignoring an acknowledgement from learner {:016x}, not the one alive",
            ack.learner
        ));
        if stats.foreign_acks.is_power_of_two() {
            tracing::warn!(
                actor = id,
                from = format_args!("{:016x}", ack.learner),
                count = stats.foreign_acks,
                "ignoring an acknowledgement from a learner that is not the one alive (logged at powers of two of the count)"
            );
        }
        return;
    }
    resync(st, stats, id, ack.acked_below);
    let before = st.outbox.len();
    st.outbox.retain(|ep, _| {
        let acked = ack.covers(*ep);
        if acked {
            // The per-episode evidence tests/partitions.rs checks against the learner's store.
            tracing::debug!(
                actor = id,
                episode = *ep,
                "acknowledged; dropped from the outbox"
            );
        }
        !acked
    });
    st.outbox_versions.retain(|ep, _| !ack.covers(*ep));
    stats.acked += (before - st.outbox.len()) as u64;
    if st.outbox.len() < before || st.outbox.is_empty() {
        // Progress: the oldest unacknowledged episode gets a fresh grace period.
        st.resend_at = (!st.outbox.is_empty()).then(|| Instant::now() + RESEND_AFTER);
    }
    let next = st.next_episode.get_or_insert(ack.acked_below);
    *next = (*next).max(ack.acked_below);
}

/// The learner expects `expected` next: if this actor's oldest held episode (or its next one,
/// with nothing held) is past it, the episodes between are lost (acknowledged by an earlier
/// learner whose store this one does not have); renumber the held episodes from `expected` on,
/// in order, and continue the numbering after them.
fn resync(st: &mut State, stats: &mut ActorStats, id: u32, expected: u64) {
    let Some(next) = st.next_episode else {
        return;
    };
    let oldest = st.outbox.keys().next().copied().unwrap_or(next);
    if expected >= oldest {
        return;
    }
    let lost = oldest - expected;
    stats.lost += lost;
    stats.last_error = Some(format!(
        "episodes {expected}..{oldest} were acknowledged by an earlier learner and are lost"
    ));
    tracing::warn!(
        actor = id,
        lost,
        first = expected,
        last = oldest - 1,
        "the learner expects episode {expected}, but episodes {expected}..{oldest} were acknowledged by an earlier learner and are not in its store (an older checkpoint, a moved log): they are lost; numbering goes on from {expected}"
    );
    let outbox = std::mem::take(&mut st.outbox);
    let versions = std::mem::take(&mut st.outbox_versions);
    for (ep, mut batch) in outbox {
        let renumbered = ep - lost;
        batch.episode = renumbered;
        if let Some(v) = versions.get(&ep) {
            st.outbox_versions.insert(renumbered, *v);
        }
        st.outbox.insert(renumbered, batch);
    }
    st.next_episode = Some(next - lost);
    // The held episodes go at once, from the one the learner expects.
    st.resend_at = (!st.outbox.is_empty()).then(Instant::now);
}

fn publish_metrics(
    p: &transport::Publisher<Metrics>,
    s: &ActorStats,
    start: Instant,
    unacked: usize,
) -> Result<(), TransportError> {
    let wall = start.elapsed().as_secs_f64();
    let mut m = Metrics {
        env_steps: s.env_steps,
        episodes: s.episodes,
        wall_time_s: wall,
        values: Default::default(),
    };
    for (k, v) in [
        ("env_steps_per_s", s.env_steps as f64 / wall.max(1e-9)),
        ("episodes_resent", s.resent as f64),
        ("episodes_acked", s.acked as f64),
        ("episodes_unacked", unacked as f64),
        ("weights_version", s.weights_version as f64),
        ("bad_weights", s.bad_weights as f64),
        ("sim_s", s.sim.as_secs_f64()),
        ("publish_timeouts", s.publish_timeouts as f64),
        ("episodes_lost", s.lost as f64),
        ("foreign_acks", s.foreign_acks as f64),
        ("wait_s", s.wait.as_secs_f64()),
    ] {
        m.values.insert(k.to_string(), v);
    }
    p.publish(s.weights_version, &m).map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(learner: u64, held: &[u64], next: u64) -> State {
        let mut st = State {
            outbox: BTreeMap::new(),
            outbox_versions: BTreeMap::new(),
            next_episode: Some(next),
            learner: Some(learner),
            net: None,
            weights_tried: None,
            resend_at: None,
        };
        for &ep in held {
            st.outbox.insert(ep, proto::fixtures::episode(5, 2, ep));
            st.outbox_versions.insert(ep, 100 + ep);
        }
        st
    }

    fn ack(learner: u64, acked_below: u64) -> proto::Ack {
        proto::Ack {
            actor: 0,
            acked_below,
            episodes: Vec::new(),
            learner,
        }
    }

    #[test]
    fn a_stale_learners_acknowledgement_is_ignored() {
        let mut st = state(0xa, &[8, 9], 10);
        let mut stats = ActorStats::default();
        apply_ack(&mut st, &mut stats, 0, &ack(0xb, 9));
        apply_ack(&mut st, &mut stats, 0, &ack(0xb, 3));
        assert_eq!(stats.foreign_acks, 2);
        assert_eq!(st.outbox.keys().copied().collect::<Vec<_>>(), [8, 9]);
        assert_eq!((st.next_episode, stats.lost, stats.acked), (Some(10), 0, 0));
        // The learner alive now is listened to.
        apply_ack(&mut st, &mut stats, 0, &ack(0xa, 9));
        assert_eq!(st.outbox.keys().copied().collect::<Vec<_>>(), [9]);
        assert_eq!(stats.acked, 1);
    }

    #[test]
    fn a_learner_expecting_an_earlier_episode_resynchronises_the_numbering() {
        // Episodes 0..8 were acknowledged by an earlier learner; this one holds 0..5 only.
        let mut st = state(0xa, &[8, 9], 10);
        let mut stats = ActorStats::default();
        apply_ack(&mut st, &mut stats, 0, &ack(0xa, 5));
        assert_eq!(stats.lost, 3, "episodes 5, 6, 7");
        assert_eq!(st.outbox.keys().copied().collect::<Vec<_>>(), [5, 6]);
        assert!(st.outbox.iter().all(|(k, b)| b.episode == *k));
        assert_eq!(
            st.outbox_versions
                .iter()
                .map(|(k, v)| (*k, *v))
                .collect::<Vec<_>>(),
            [(5, 108), (6, 109)],
            "each episode keeps the policy version that played it"
        );
        assert_eq!(st.next_episode, Some(7));
        assert!(st.resend_at.is_some(), "sent again at once");
        // In step again: nothing more is lost; acknowledgements drop as usual.
        apply_ack(&mut st, &mut stats, 0, &ack(0xa, 6));
        assert_eq!((stats.lost, stats.acked), (3, 1));
        assert_eq!(st.outbox.keys().copied().collect::<Vec<_>>(), [6]);
        // Nothing held: the numbering alone goes back.
        let mut st = state(0xa, &[], 12);
        apply_ack(&mut st, &mut stats, 0, &ack(0xa, 4));
        assert_eq!((st.next_episode, stats.lost), (Some(4), 11));
    }
}
