//! A process's [`proto::Status`] heartbeats on `fsrl/<run>/status/<role>/<index>`: its
//! life-cycle state and the last error it hit, sent soon after the state changes or a new error
//! comes (at most every [`ERROR_GAP`]) and every [`HEARTBEAT_EVERY`] otherwise. Best
//! effort, as the topic: a heartbeat that cannot be sent is skipped, never an error of the
//! process. Messages this transport's subscribers rejected count as errors too (their text from
//! [`Transport::last_rejection`]).

use std::fmt;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use proto::reports::MAX_STATUS_DETAIL_LEN;
use proto::{keys, ProcessState, Status};

use crate::{lock, Publisher, Transport, TransportError};

/// How often a heartbeat goes out when nothing changed.
pub const HEARTBEAT_EVERY: Duration = Duration::from_secs(2);
/// Least time between two heartbeats sent for new errors: a flood of errors costs a few
/// messages a second, each with the newest error.
pub const ERROR_GAP: Duration = Duration::from_millis(250);

/// Status heartbeats of this process; see the module docs. `Send + Sync`, every method takes
/// `&self`.
pub struct Heartbeat {
    transport: Transport,
    publisher: Publisher<Status>,
    started: Instant,
    beat: Mutex<Beat>,
}

struct Beat {
    state: ProcessState,
    /// The last error (empty: none yet).
    error: String,
    /// An error (or a state) not yet sent.
    unsent: bool,
    /// Rejections of the transport already taken as errors.
    rejected: u64,
    env_steps: u64,
    episodes: u64,
    sent: Option<Instant>,
}

impl Heartbeat {
    /// Heartbeats of `t`'s process, starting in [`ProcessState::Starting`] (sent at once).
    pub fn new(t: &Transport) -> Result<Self, TransportError> {
        let hb = Heartbeat {
            transport: t.clone(),
            publisher: t.publisher(&keys::status(t.run(), t.sender()))?,
            started: Instant::now(),
            beat: Mutex::new(Beat {
                state: ProcessState::Starting,
                error: String::new(),
                unsent: true,
                rejected: t.rejected_count(),
                env_steps: 0,
                episodes: 0,
                sent: None,
            }),
        };
        hb.beat();
        Ok(hb)
    }

    /// The state now. A change is sent at once, or [`ERROR_GAP`] after the last heartbeat if
    /// that was sooner (a process going back and forth between running and idle sends a few
    /// heartbeats a second at most, each with the state of its time); stopping and failing are
    /// sent at once always.
    pub fn set_state(&self, state: ProcessState) {
        let changed = {
            let mut b = lock(&self.beat);
            let changed = b.state != state;
            b.state = state;
            b.unsent |= changed;
            changed
        };
        if changed && matches!(state, ProcessState::Stopping | ProcessState::Failed) {
            self.send();
        } else if changed {
            self.beat();
        }
    }

    /// The state now.
    pub fn state(&self) -> ProcessState {
        lock(&self.beat).state
    }

    /// An error the process hit (and goes on after): the status's detail from now on, sent
    /// with the next [`Heartbeat::beat`].
    pub fn error(&self, what: impl fmt::Display) {
        let mut b = lock(&self.beat);
        b.error.clear();
        use fmt::Write;
        let _ = write!(b.error, "{what}");
        truncate(&mut b.error, MAX_STATUS_DETAIL_LEN);
        b.unsent = true;
    }

    /// The process failed: [`ProcessState::Failed`] with why, sent at once.
    pub fn fail(&self, why: impl fmt::Display) {
        self.error(why);
        lock(&self.beat).state = ProcessState::Failed;
        self.send();
    }

    /// The process's run is over with `result`: stopping when it ended well, failed with its
    /// error otherwise (sent at once either way). Returns `result`, for the caller to return.
    pub fn finish<T, E: fmt::Display>(&self, result: Result<T, E>) -> Result<T, E> {
        match &result {
            Ok(_) => self.set_state(ProcessState::Stopping),
            Err(e) => self.fail(e),
        }
        result
    }

    /// Environment steps and episodes so far (sent with the next heartbeat).
    pub fn progress(&self, env_steps: u64, episodes: u64) {
        let mut b = lock(&self.beat);
        b.env_steps = env_steps;
        b.episodes = episodes;
    }

    /// Sends a heartbeat if one is due: something unsent (at most every [`ERROR_GAP`]) or
    /// [`HEARTBEAT_EVERY`] since the last. Call it often; it costs a lock and a clock read.
    pub fn beat(&self) {
        let due = {
            let mut b = lock(&self.beat);
            let rejected = self.transport.rejected_count();
            if rejected > b.rejected {
                b.rejected = rejected;
                b.error = self.transport.last_rejection();
                truncate(&mut b.error, MAX_STATUS_DETAIL_LEN);
                b.unsent = true;
            }
            match b.sent {
                None => true,
                Some(t) => {
                    let since = t.elapsed();
                    since >= HEARTBEAT_EVERY || (b.unsent && since >= ERROR_GAP)
                }
            }
        };
        if due {
            self.send();
        }
    }

    fn send(&self) {
        let status = {
            let mut b = lock(&self.beat);
            b.unsent = false;
            b.sent = Some(Instant::now());
            Status {
                state: b.state,
                uptime_s: self.started.elapsed().as_secs_f64(),
                env_steps: b.env_steps,
                episodes: b.episodes,
                detail: b.error.clone(),
            }
        };
        if let Err(e) = self.publisher.publish(0, &status) {
            tracing::debug!(error = %e, "a status heartbeat was not sent");
        }
    }
}

/// Cuts `s` to at most `max` bytes, on a character boundary.
fn truncate(s: &mut String, max: usize) {
    if s.len() > max {
        let mut end = max;
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        s.truncate(end);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truncation_keeps_whole_characters() {
        let mut s = "aé".repeat(3000);
        truncate(&mut s, MAX_STATUS_DETAIL_LEN);
        assert!(s.len() <= MAX_STATUS_DETAIL_LEN && s.len() >= MAX_STATUS_DETAIL_LEN - 1);
        let mut short = String::from("ok");
        truncate(&mut short, 10);
        assert_eq!(short, "ok");
    }
}
