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
use proto::{keys, Metrics, Role, RunPhase, TransitionBatch};
use sim::Env;
use transport::{AliveEvent, Transport, TransportError};

/// Episode-seed stream of actor `id` (streams 0 and 1 belong to the single-process trainer).
pub fn actor_stream(id: u32) -> u64 {
    100 + id as u64
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
#[derive(Debug, Clone, Copy, Default)]
pub struct ActorStats {
    pub episodes: u64,
    pub env_steps: u64,
    pub resent: u64,
    pub acked: u64,
    pub weights_version: u64,
}

struct State {
    outbox: BTreeMap<u64, TransitionBatch>,
    outbox_versions: BTreeMap<u64, u64>,
    next_episode: Option<u64>,
    learner: Option<u64>,
    net: Option<(u64, ValueNet)>,
}

/// Runs actor `id` until the learner finishes the run or `stop` is set.
pub fn run(
    transport: &Transport,
    spec: &RunSpec,
    id: u32,
    stop: &AtomicBool,
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

    let cfg = spec.method_sim();
    let mut env = Env::new(cfg, spec.setting, 0).map_err(|e| ActorError::Sim(e.to_string()))?;
    let n_actions = env.action_set().len() as u16;
    let mut lookahead = Lookahead::new(
        spec.train.gamma,
        spec.train.human_model.into(),
        spec.method.human_order(),
    );
    let mut st = State {
        outbox: BTreeMap::new(),
        outbox_versions: BTreeMap::new(),
        next_episode: None,
        learner: None,
        net: None,
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
        // Membership: a (new) learner gets every unacknowledged episode again.
        while let Some(ev) = alive.recv_timeout(Duration::ZERO)? {
            match ev {
                AliveEvent::Joined(m)
                    if m.sender.role == Role::Learner && st.learner != Some(m.instance) =>
                {
                    tracing::info!(actor = id, learner = %m, unacked = st.outbox.len(), "learner joined");
                    st.learner = Some(m.instance);
                    for (ep, batch) in &st.outbox {
                        let v = st.outbox_versions.get(ep).copied().unwrap_or(0);
                        publisher.publish(v, batch)?;
                        stats.resent += 1;
                    }
                }
                AliveEvent::Left(m)
                    if m.sender.role == Role::Learner && st.learner == Some(m.instance) =>
                {
                    tracing::warn!(actor = id, learner = %m, "learner left; holding off");
                    st.learner = None;
                }
                _ => {}
            }
        }
        // Acknowledgements: drop what the learner holds; learn where to continue.
        while let Some(msg) = acks.try_recv()? {
            apply_ack(&mut st, &mut stats, id, &msg.body);
        }
        // Newest weights.
        if let Some(w) = weights.latest()? {
            let version = w.body.version;
            if st.net.as_ref().is_none_or(|(v, _)| *v < version) {
                match net_from_weights(&w.body, &net_cfg) {
                    Ok(net) => {
                        st.net = Some((version, net));
                        stats.weights_version = version;
                    }
                    Err(e) => tracing::warn!(actor = id, version, "ignoring weights: {e}"),
                }
            }
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
        if last_metrics.elapsed() >= Duration::from_secs(1) {
            publish_metrics(&metrics, &stats, start, st.outbox.len())?;
            last_metrics = Instant::now();
        }
        if !ready {
            if waiting_since.is_none() {
                waiting_since = Some(Instant::now());
            }
            // Block on the next acknowledgement (or time out and re-check everything).
            if let Some(msg) = acks.recv_timeout(Duration::from_millis(50))? {
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
        let seed = episode_seed(spec.seed, actor_stream(id), episode);
        let data = rollout(
            &mut env,
            seed,
            Behaviour::Net {
                net,
                lookahead: &mut lookahead,
                epsilon,
                policy_version: *version,
            },
        )
        .map_err(|e| ActorError::Sim(e.to_string()))?;
        let batch =
            to_batch(&data, episode, n_actions).map_err(|e| ActorError::Sim(e.to_string()))?;
        publisher.publish(*version, &batch)?;
        st.outbox.insert(episode, batch);
        st.outbox_versions.insert(episode, *version);
        st.next_episode = Some(episode + 1);
        stats.episodes += 1;
        stats.env_steps += data.steps() as u64;
    }
}

/// Drops what the learner holds and learns where to continue.
fn apply_ack(st: &mut State, stats: &mut ActorStats, id: u32, ack: &proto::Ack) {
    if ack.actor != id {
        return;
    }
    let before = st.outbox.len();
    st.outbox.retain(|ep, _| !ack.covers(*ep));
    st.outbox_versions.retain(|ep, _| !ack.covers(*ep));
    stats.acked += (before - st.outbox.len()) as u64;
    let next = st.next_episode.get_or_insert(ack.acked_below);
    *next = (*next).max(ack.acked_below);
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
    ] {
        m.values.insert(k.to_string(), v);
    }
    p.publish(s.weights_version, &m).map(|_| ())
}
