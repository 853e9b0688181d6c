//! The warm start: imitation of ORCA demonstrations ([`crate::imitation`]), in this process,
//! before any actor may send an episode. Meanwhile the learner keeps following who is alive,
//! refuses (and counts) the episodes that come anyway, shows its progress in the live metrics,
//! and, once done, writes the imitation lines of the training log and the checkpoint that makes
//! the warm start durable (retried on a full disk).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use proto::{keys, Metrics, TransitionBatch};
use transport::{AliveWatcher, Subscriber};

use super::{warn_sometimes, Ended, Learner, ProcessError};
use crate::imitation::{self, ImitationProgress};
use crate::runlog::ImitationLog;

/// Runs the warm start to its checkpoint; [`Ended::Stopped`] when `stop` came first.
pub(super) fn run(
    l: &mut Learner<'_>,
    subscriber: &Subscriber<TransitionBatch>,
    alive: &AliveWatcher,
    stop: &AtomicBool,
) -> Result<Ended, ProcessError> {
    let Some(log) = imitate(l, subscriber, alive, stop)? else {
        return Ok(Ended::Stopped);
    };
    for line in log.lines() {
        l.log_line(&line);
    }
    if checkpoint_with_retries(l, stop) == Ended::Stopped {
        return Ok(Ended::Stopped);
    }
    tracing::info!(transitions = l.core.replay().len(), "imitation done");
    Ok(Ended::Done)
}

/// What the metrics tick shows: the newest demonstration count or finished epoch.
#[derive(Clone, Copy)]
enum Shown {
    Demo(u64, u64),
    Epoch(u32, u32, f32),
}

impl Shown {
    /// The live metrics of the warm start.
    fn metrics(self, refused: u64, actors_alive: usize) -> Metrics {
        let mut m = Metrics::default();
        match self {
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
        m.values.insert("actors_alive".into(), actors_alive as f64);
        m
    }
}

/// Imitation itself; the log's imitation lines (written once the warm start is done, as in one
/// process), or None when stopped.
fn imitate(
    l: &mut Learner<'_>,
    subscriber: &Subscriber<TransitionBatch>,
    alive: &AliveWatcher,
    stop: &AtomicBool,
) -> Result<Option<ImitationLog>, ProcessError> {
    let (status, spec, opts) = (l.status, l.spec, l.opts);
    let mut last = Instant::now();
    let metrics = l.t.publisher(&keys::metrics(l.t.run(), l.t.sender()))?;
    let mut refused = 0u64;
    let mut log = ImitationLog::default();
    let (wall0, start) = (l.wall0, l.start);
    let mut shown = Shown::Demo(0, spec.train.imitation.episodes);
    let members = &mut l.members;
    let finished = imitation::run(&mut l.core, spec, stop, |p| {
        log.observe(&p, (wall0 + start.elapsed()).as_secs_f64());
        status.beat();
        // Who is alive, as in training: the watcher's queue is bounded and, once full, leaves
        // the zenoh thread that fills it waiting. Actors that join are acknowledged when
        // training starts.
        while let Ok(Some(ev)) = alive.recv_timeout(Duration::ZERO) {
            members.track(status, ev);
        }
        // Nobody should send episodes now (actors wait for the training phase): drain and
        // count, so nothing piles up in the subscriber's queue during imitation. Progress comes
        // after every demonstration and every batch, so a long epoch cannot leave the queue
        // (and the router's link to this process) full.
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
            ImitationProgress::DemosDone { .. } | ImitationProgress::Batch { .. } => {}
            ImitationProgress::Epoch { done, total, loss } => {
                shown = Shown::Epoch(done, total, loss)
            }
        }
        if last.elapsed() >= opts.metrics_interval {
            last = Instant::now();
            let _ = metrics.publish(0, &shown.metrics(refused, members.actors.len()));
        }
    })?;
    l.refused_in_imitation = refused;
    Ok(finished.then_some(log))
}

/// The warm start is only in memory until this checkpoint: on a full disk, retry with back-off
/// (each failure counted and logged) instead of dying and redoing it.
fn checkpoint_with_retries(l: &mut Learner<'_>, stop: &AtomicBool) -> Ended {
    let mut retry_in = Duration::from_millis(500);
    while !l.try_checkpoint() {
        if stop.load(Ordering::SeqCst) {
            tracing::error!("stopped before the checkpoint after imitation could be written; the warm start is done again on the next start");
            return Ended::Stopped;
        }
        tracing::warn!(
            retry_in_ms = retry_in.as_millis() as u64,
            "the checkpoint after imitation failed (free disk space in the run directory); retrying"
        );
        std::thread::sleep(retry_in);
        retry_in = (retry_in * 2).min(Duration::from_secs(30));
    }
    Ended::Done
}
