//! Training, the end of the run and the linger after it.
//!
//! [`train`] is the loop of the RL phase, one turn at a time: follow who is alive, do the
//! metrics tick's work, ask the replay schedule ([`super::schedule`]) what this turn may do,
//! take in what the transport holds, and store and acknowledge the next episode (trained on as
//! the schedule says). [`finish`] sends the run's last word (final checkpoint, weights, then
//! `Finished`, then the final figures, `crate::record`); [`linger`] waits, bounded, for the
//! actors and evaluators to leave.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use proto::{Message, ProcessState, RunPhase, TransitionBatch};
use transport::{AliveEvent, AliveWatcher, Subscriber, TransportError};

use super::schedule::Schedule;
use super::{Accepted, Ended, Learner, ProcessError};

/// Most received episodes held between rounds of updates (every actor's transport queue is
/// bounded too; duplicates among them are acknowledged and dropped at once).
const MAX_PENDING: usize = 4096;

/// How long one turn waits for an episode when it has nothing else to do.
const WAIT_FOR_EPISODE: Duration = Duration::from_millis(50);

/// How long one turn of the linger waits for a liveliness event.
const LINGER_WAIT: Duration = Duration::from_millis(100);

/// The training loop's state between turns.
struct Turns {
    /// The last metrics tick.
    last_tick: Instant,
    /// A checkpoint failed (a full disk): retried at the next tick or episode.
    checkpoint_due: bool,
    /// Episodes received, not yet taken, in the order they came.
    pending: VecDeque<Message<TransitionBatch>>,
    /// Weights or control went out since the last tick (otherwise the tick repeats them).
    published_since_tick: bool,
}

/// The RL phase until its last episode is stored ([`Ended::Done`]) or `stop` is set.
pub(super) fn train(
    l: &mut Learner<'_>,
    schedule: &mut dyn Schedule,
    subscriber: &Subscriber<TransitionBatch>,
    alive: &AliveWatcher,
    stop: &AtomicBool,
) -> Result<Ended, ProcessError> {
    let mut t = Turns {
        last_tick: Instant::now(),
        checkpoint_due: false,
        pending: VecDeque::new(),
        published_since_tick: true,
    };
    while l.phase() == RunPhase::Training {
        if stop.load(Ordering::SeqCst) {
            return Ok(Ended::Stopped);
        }
        follow_members(l, alive)?;
        if t.last_tick.elapsed() >= l.opts.metrics_interval {
            t.tick(l, alive)?;
        }
        let turn = schedule.turn(l);
        t.receive(l, subscriber, turn.train)?;
        if !turn.take || t.pending.is_empty() {
            if turn.train {
                schedule.train_between(l)?;
                t.published_since_tick = true;
            }
            continue;
        }
        let Some(msg) = t.pending.pop_front() else {
            continue;
        };
        if l.take(msg) != Accepted::Stored {
            continue;
        }
        schedule.on_stored(l)?;
        if l.phase() != RunPhase::Training {
            // The last episode: "finished" goes out only after the final weights ([`finish`]),
            // so that what the evaluator takes as the run's last weights are those (issue 44).
            break;
        }
        l.publish_control();
        t.published_since_tick = true;
        t.checkpoint_on_schedule(l);
    }
    Ok(Ended::Done)
}

/// Takes in the liveliness events queued; the state follows (idle while no actor is alive:
/// nothing can arrive, running otherwise), and control goes out again when the actors changed.
fn follow_members(l: &mut Learner<'_>, alive: &AliveWatcher) -> Result<(), ProcessError> {
    let mut membership_changed = false;
    while let Some(ev) = alive.recv_timeout(Duration::ZERO)? {
        membership_changed |= l.on_alive(ev);
    }
    l.status.set_state(if l.members.actors.is_empty() {
        ProcessState::Idle
    } else {
        ProcessState::Running
    });
    l.status.beat();
    if membership_changed {
        l.publish_control();
    }
    Ok(())
}

impl Turns {
    /// Every metrics interval: metrics, the latest weights and control again if nothing newer
    /// went out, every live actor's ack again, and a checkpoint that failed earlier retried.
    fn tick(&mut self, l: &mut Learner<'_>, alive: &AliveWatcher) -> Result<(), ProcessError> {
        self.last_tick = Instant::now();
        l.alive_tokens_refused = alive.refused_count()?;
        l.publish_metrics()?;
        if !self.published_since_tick {
            // Weights and control are dropped for a subscriber that does not keep up
            // (`transport`): with nothing newer to send, the current values again.
            l.republish_latest();
        }
        self.published_since_tick = false;
        // Re-acknowledge periodically: an actor that missed an ack learns where to go on.
        for id in l.live_actor_ids() {
            l.ack(id);
        }
        if self.checkpoint_due {
            // A checkpoint failed earlier (a full disk): try again.
            self.checkpoint_due = !l.try_checkpoint();
        }
        Ok(())
    }

    /// Everything the transport holds is taken in before one episode is trained on: a
    /// transport that serves its senders in a fixed order (iceoryx2 reads its publishers'
    /// queues one after the other) would otherwise hand over the first actor's next episode
    /// every time and starve the others until their queues fill up. Arrivals are then trained
    /// in the order they came, one per round of updates. With nothing pending and nothing to
    /// train (`may_train`), the turn waits a little for an episode.
    fn receive(
        &mut self,
        l: &mut Learner<'_>,
        subscriber: &Subscriber<TransitionBatch>,
        may_train: bool,
    ) -> Result<(), ProcessError> {
        if self.pending.is_empty() && !may_train {
            let waited = Instant::now();
            let first = subscriber.recv_timeout(WAIT_FOR_EPISODE)?;
            l.wait += waited.elapsed();
            self.pending.extend(first);
        }
        while self.pending.len() < MAX_PENDING {
            match subscriber.try_recv()? {
                Some(m) => self.pending.push_back(m),
                None => break,
            }
        }
        Ok(())
    }

    /// A checkpoint every `checkpoint_every_episodes` RL episodes, or one that failed earlier.
    fn checkpoint_on_schedule(&mut self, l: &mut Learner<'_>) {
        let every = l.spec.train.checkpoint_every_episodes;
        let done = l.core.counters().rl_episodes;
        if (every > 0 && done.is_multiple_of(every)) || self.checkpoint_due {
            self.checkpoint_due = !l.try_checkpoint();
        }
    }
}

/// The run is over: the final checkpoint, then the final weights (carrying the final RL
/// episode count) before the `Finished` control, which names their version (its header's
/// policy version): an evaluator that sees `Finished` validates weights of at least that
/// version. Then the final figures, durable (`crate::record`) and live.
pub(super) fn finish(l: &mut Learner<'_>) -> Result<(), ProcessError> {
    l.checkpoint()?;
    l.publish_weights()?;
    l.publish_control();
    l.publish_final_metrics()?;
    tracing::info!(
        rl_episodes = l.core.counters().rl_episodes,
        "run finished; waiting for actors and evaluators to leave"
    );
    l.status.set_state(ProcessState::Stopping);
    Ok(())
}

/// Waits, at most `linger`, for the actors and evaluators to leave (or `stop`), following who
/// is alive with the same capped tracker as training ([`Learner::on_alive`]) and repeating the
/// final weights and `Finished` control for a subscriber they were dropped for. `next_event`
/// is the liveliness watcher's `recv_timeout`.
pub(super) fn linger(
    l: &mut Learner<'_>,
    mut next_event: impl FnMut(Duration) -> Result<Option<AliveEvent>, TransportError>,
    stop: &AtomicBool,
) -> Result<(), ProcessError> {
    let deadline = Instant::now() + l.opts.linger;
    let mut last_repeat = Instant::now();
    while Instant::now() < deadline && !l.members.nobody() {
        l.status.beat();
        if last_repeat.elapsed() >= l.opts.metrics_interval {
            last_repeat = Instant::now();
            l.republish_latest();
        }
        if let Some(ev) = next_event(LINGER_WAIT)? {
            l.on_alive(ev);
        }
        if stop.load(Ordering::SeqCst) {
            break;
        }
    }
    Ok(())
}
