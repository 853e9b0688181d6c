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
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Rejection::Decode(e) => write!(f, "{e}"),
            Rejection::WrongRun(r) => write!(f, "message of run {r:?}"),
        }
    }
}

/// Transport-wide rejection counter; logs the first rejection of each source once.
#[derive(Debug, Default)]
pub(crate) struct Rejections {
    total: AtomicU64,
    warned: Mutex<HashSet<String>>,
}

impl Rejections {
    pub(crate) fn total(&self) -> u64 {
        self.total.load(Ordering::Relaxed)
    }
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
        let first = match self.shared.warned.lock() {
            Ok(mut w) => w.insert(source.clone()),
            Err(poisoned) => poisoned.into_inner().insert(source.clone()),
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
