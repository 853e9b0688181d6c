//! Counting and logging of messages rejected on receive.

use std::collections::HashSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use proto::DecodeError;

/// Why a received message was dropped.
#[derive(Debug)]
pub(crate) enum Rejection {
    /// It did not decode or validate.
    Decode(DecodeError),
    /// It belongs to another run.
    WrongRun(String),
    /// Its header names another sender than the key it was published under.
    WrongSender(String),
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Rejection::Decode(e) => write!(f, "{e}"),
            Rejection::WrongRun(r) => write!(f, "message of run {r:?}"),
            Rejection::WrongSender(who) => write!(f, "header names {who}, not the key's sender"),
        }
    }
}

/// Sources remembered for "first rejection" logging; beyond this many distinct sources (a
/// flood of fresh keys), rejections are logged at powers of two of the total only.
const MAX_WARNED_SOURCES: usize = 256;

/// Transport-wide rejection counter; logs the first rejection of each source once (for at most
/// [`MAX_WARNED_SOURCES`] sources).
#[derive(Debug, Default)]
pub(crate) struct Rejections {
    total: AtomicU64,
    warned: Mutex<HashSet<String>>,
    /// What the newest rejection was (for the process's status: its last error).
    last: Mutex<String>,
}

impl Rejections {
    pub(crate) fn total(&self) -> u64 {
        self.total.load(Ordering::Relaxed)
    }

    /// The newest rejection, in words (empty before the first).
    pub(crate) fn last(&self) -> String {
        lock(&self.last).clone()
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Per-subscriber view: its own count plus the transport-wide tracker.
#[derive(Debug, Clone)]
pub(crate) struct RejectCounter {
    local: Arc<AtomicU64>,
    shared: Arc<Rejections>,
    topic: Arc<str>,
}

impl RejectCounter {
    pub(crate) fn new(shared: Arc<Rejections>, topic: &str) -> Self {
        Self {
            local: Arc::new(AtomicU64::new(0)),
            shared,
            topic: topic.into(),
        }
    }

    pub(crate) fn count(&self) -> u64 {
        self.local.load(Ordering::Relaxed)
    }

    /// Counts a rejected message from `source` (a key expression or publisher id) and logs
    /// it if it is the first from that source. `source` is formatted here, only on rejection.
    pub(crate) fn reject(&self, source: &dyn std::fmt::Display, why: &Rejection) {
        self.local.fetch_add(1, Ordering::Relaxed);
        self.shared.total.fetch_add(1, Ordering::Relaxed);
        let source = source.to_string();
        {
            let mut last = lock(&self.shared.last);
            last.clear();
            use std::fmt::Write;
            let _ = write!(
                last,
                "rejected a message on {} from {source}: {why}",
                self.topic
            );
        }
        let first = {
            let mut w = lock(&self.shared.warned);
            if w.len() < MAX_WARNED_SOURCES {
                w.insert(source.clone())
            } else {
                // Past the bound: log at powers of two of the total instead of per source.
                self.shared.total.load(Ordering::Relaxed).is_power_of_two()
            }
        };
        if first {
            tracing::warn!(
                topic = %self.topic,
                source = %source,
                error = %why,
                "rejected a message (further rejections from this source are only counted)"
            );
        }
    }
}
