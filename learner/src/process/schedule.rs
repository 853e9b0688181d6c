//! The two replay schedules of the training loop ([`super::training`]), behind one small trait:
//! how updates are tied to the episodes the actors send.
//!
//! - [`Fixed`] (`train.rl.replay_ratio` absent): every episode is taken as it comes and trained
//!   on at once, `batches_per_episode` updates, then the new weights go out.
//! - [`Adaptive`] (`train.rl.replay_ratio = { min, max }`): updates are not tied to an episode.
//!   The next episode is taken only once at least `min` updates per episode taken are done;
//!   while fewer than `max` are done, the learner trains in rounds without waiting for one; the
//!   last episodes get their `min` share after the last one is taken ([`Schedule::top_up`]).
//!
//! Both count from where this process started RL ([`Learner::rl_progress`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use policy::method::{ReplayRatio, RunSpec};

use super::{Ended, Learner, ProcessError};

/// What the schedule allows in one turn of the training loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Turn {
    /// The loop may take the next episode.
    pub(super) take: bool,
    /// The loop may train without a new episode ([`Schedule::train_between`]).
    pub(super) train: bool,
}

/// A replay schedule: when the training loop takes episodes and when it trains.
pub(super) trait Schedule {
    /// What this turn of the loop may do.
    fn turn(&self, l: &Learner<'_>) -> Turn;

    /// A round of updates not tied to an episode, then the new weights; asked only when
    /// [`Schedule::turn`] allowed it.
    fn train_between(&mut self, l: &mut Learner<'_>) -> Result<(), ProcessError>;

    /// The episode just stored: trained on now, or only logged (its updates come in rounds).
    fn on_stored(&mut self, l: &mut Learner<'_>) -> Result<(), ProcessError>;

    /// After the run's last episode: the updates still owed to the episodes taken.
    /// [`Ended::Stopped`] when `stop` is set before they are done.
    fn top_up(&mut self, l: &mut Learner<'_>, stop: &AtomicBool) -> Result<Ended, ProcessError>;
}

/// The schedule `spec` asks for.
pub(super) fn of(spec: &RunSpec) -> Box<dyn Schedule> {
    match spec.train.rl.replay_ratio {
        None => Box::new(Fixed),
        Some(ratio) => Box::new(Adaptive::new(ratio, spec.train.rl.batches_per_episode)),
    }
}

/// `batches_per_episode` updates on each episode as it is taken (the paper's schedule, and
/// `fsrl train --single-process`'s).
pub(super) struct Fixed;

impl Schedule for Fixed {
    fn turn(&self, _: &Learner<'_>) -> Turn {
        Turn {
            take: true,
            train: false,
        }
    }

    fn train_between(&mut self, _: &mut Learner<'_>) -> Result<(), ProcessError> {
        // Never asked: every update belongs to an episode.
        Ok(())
    }

    fn on_stored(&mut self, l: &mut Learner<'_>) -> Result<(), ProcessError> {
        l.train_stored()?;
        l.publish_weights()
    }

    fn top_up(&mut self, _: &mut Learner<'_>, _: &AtomicBool) -> Result<Ended, ProcessError> {
        Ok(Ended::Done)
    }
}

/// Between `min` and `max` updates per episode taken, in rounds of at most
/// `batches_per_episode` updates.
pub(super) struct Adaptive {
    ratio: ReplayRatio,
    /// The most updates in one round (at least 1).
    round: u64,
    /// Rounds in a row that made no update (see [`MAX_IDLE_ROUNDS`]).
    idle_rounds: u64,
}

/// Rounds of the adaptive mode in a row without an update before the learner gives up.
pub(super) const MAX_IDLE_ROUNDS: u64 = 1000;

impl Adaptive {
    pub(super) fn new(ratio: ReplayRatio, batches_per_episode: u32) -> Self {
        Self {
            ratio,
            round: batches_per_episode.max(1) as u64,
            idle_rounds: 0,
        }
    }

    /// One round of `batches` updates. Its episodes wait for updates, so rounds that make none
    /// would starve the actors for ever: a skipped refresh of the targets re-synchronises the
    /// target network or fails ([`crate::core::LearnerCore::train_round`]), and
    /// [`MAX_IDLE_ROUNDS`] rounds in a row without an update (every batch non-finite) fail too,
    /// loudly.
    fn train_round(&mut self, l: &mut Learner<'_>, batches: u64) -> Result<(), ProcessError> {
        let trained = Instant::now();
        let before = l.core.counters().updates;
        let loss = l.core.train_round(batches as u32)?;
        l.train += trained.elapsed();
        if loss.is_finite() {
            l.last_loss = loss;
        }
        if l.core.counters().updates > before {
            self.idle_rounds = 0;
        } else {
            self.idle_rounds += 1;
            if self.idle_rounds >= MAX_IDLE_ROUNDS {
                return Err(ProcessError::NoProgress {
                    rounds: self.idle_rounds,
                    skipped: l.core.skipped_batches(),
                });
            }
        }
        Ok(())
    }
}

impl Schedule for Adaptive {
    fn turn(&self, l: &Learner<'_>) -> Turn {
        let (episodes, updates) = l.rl_progress();
        Turn {
            take: updates as f64 >= self.ratio.min * episodes as f64,
            train: (updates as f64) < self.ratio.max * episodes as f64
                && !l.core.replay().is_empty(),
        }
    }

    /// A round of at most `batches_per_episode` updates, no further than `max` per episode;
    /// new weights go out after each round (a bounded rate, whatever the number of actors).
    fn train_between(&mut self, l: &mut Learner<'_>) -> Result<(), ProcessError> {
        let (episodes, updates) = l.rl_progress();
        let room = (self.ratio.max * episodes as f64).ceil() as u64 - updates;
        self.train_round(l, room.clamp(1, self.round))?;
        l.publish_weights()
    }

    fn on_stored(&mut self, l: &mut Learner<'_>) -> Result<(), ProcessError> {
        l.log_stored();
        Ok(())
    }

    /// The last episodes taken get their share too: at least `min` updates per episode.
    fn top_up(&mut self, l: &mut Learner<'_>, stop: &AtomicBool) -> Result<Ended, ProcessError> {
        loop {
            let (episodes, updates) = l.rl_progress();
            let owed = (self.ratio.min * episodes as f64).ceil() as u64;
            if updates >= owed || l.core.replay().is_empty() {
                return Ok(Ended::Done);
            }
            if stop.load(Ordering::SeqCst) {
                return Ok(Ended::Stopped);
            }
            self.train_round(l, (owed - updates).min(self.round))?;
        }
    }
}
