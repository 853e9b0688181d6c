//! What the page is told: every metrics, status and liveliness event of the run as one JSON
//! object, kept (bounded) so that a page opened late draws the whole run, and handed to every
//! open page as it arrives.

use std::collections::VecDeque;
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};

use proto::{Metrics, Role, SenderId, Status};

/// Messages of each kind kept for a page opened later: the evaluator's (the learning curve,
/// one per validation) all up to [`KEEP_VALIDATIONS`], the others the newest [`KEEP_OTHERS`]
/// (at one message per process and second, about an hour of a four-process run).
pub const KEEP_VALIDATIONS: usize = 20_000;
pub const KEEP_OTHERS: usize = 15_000;
/// Events a page may fall behind by before it is dropped (its browser reconnects and starts
/// again from the kept history).
pub const PAGE_BACKLOG: usize = 4096;

/// One event as the page reads it.
pub fn metrics_event(sender: SenderId, m: &Metrics) -> String {
    serde_json::json!({
        "k": "m", "s": sender.to_string(), "role": role(sender.role),
        "e": m.episodes, "t": m.wall_time_s, "v": m.values,
    })
    .to_string()
}

pub fn status_event(sender: SenderId, s: &Status) -> String {
    let state = serde_json::to_value(s.state).unwrap_or_default();
    serde_json::json!({
        "k": "s", "s": sender.to_string(), "role": role(sender.role),
        "state": state, "detail": s.detail, "uptime": s.uptime_s,
    })
    .to_string()
}

pub fn alive_event(sender: SenderId, up: bool) -> String {
    serde_json::json!({"k": "a", "s": sender.to_string(), "role": role(sender.role), "up": up})
        .to_string()
}

fn role(r: Role) -> &'static str {
    match r {
        Role::Learner => "learner",
        Role::Actor => "actor",
        Role::Evaluator => "evaluator",
        Role::Monitor => "monitor",
    }
}

#[derive(Default)]
struct State {
    /// The run's first event (its id), then the kept history.
    head: Vec<Arc<str>>,
    validations: VecDeque<Arc<str>>,
    others: VecDeque<Arc<str>>,
    pages: Vec<SyncSender<Arc<str>>>,
}

/// The events of one run, and the pages listening.
#[derive(Clone, Default)]
pub struct Hub {
    state: Arc<Mutex<State>>,
}

impl Hub {
    /// A hub whose history starts with the run's id.
    pub fn new(run: &str) -> Self {
        let hub = Hub::default();
        hub.lock().head.push(
            serde_json::json!({"k": "run", "run": run})
                .to_string()
                .into(),
        );
        hub
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Keeps `event` and hands it to every page; `validation` says which history keeps it.
    pub fn publish(&self, event: String, validation: bool) {
        let event: Arc<str> = event.into();
        let mut st = self.lock();
        let (kept, cap) = if validation {
            (&mut st.validations, KEEP_VALIDATIONS)
        } else {
            (&mut st.others, KEEP_OTHERS)
        };
        if kept.len() >= cap {
            kept.pop_front();
        }
        kept.push_back(event.clone());
        st.pages.retain(|p| {
            !matches!(
                p.try_send(event.clone()),
                Err(TrySendError::Full(_) | TrySendError::Disconnected(_))
            )
        });
    }

    /// A new page: what was kept so far (in order of arrival within each kind, validations
    /// first), and a receiver of what comes next.
    pub fn subscribe(&self) -> (Vec<Arc<str>>, Receiver<Arc<str>>) {
        let mut st = self.lock();
        let (tx, rx) = sync_channel(PAGE_BACKLOG);
        st.pages.push(tx);
        let history = st
            .head
            .iter()
            .chain(&st.validations)
            .chain(&st.others)
            .cloned()
            .collect();
        (history, rx)
    }

    /// Pages listening now.
    pub fn pages(&self) -> usize {
        self.lock().pages.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_late_page_gets_the_history_then_what_follows() {
        let hub = Hub::new("r");
        let learner = SenderId::new(Role::Learner, 0);
        hub.publish(metrics_event(learner, &Metrics::default()), false);
        let (history, rx) = hub.subscribe();
        assert_eq!(history.len(), 2);
        assert!(history[0].contains("\"run\":\"r\""));
        hub.publish(alive_event(SenderId::new(Role::Actor, 1), false), false);
        let next = rx.try_recv().unwrap();
        assert!(
            next.contains("\"s\":\"actor-1\"") && next.contains("\"up\":false"),
            "{next}"
        );
        // A page gone is forgotten at the next event.
        drop(rx);
        hub.publish(alive_event(learner, true), false);
        assert_eq!(hub.pages(), 0);
    }

    #[test]
    fn a_page_that_falls_behind_is_dropped_and_the_history_is_bounded() {
        let hub = Hub::new("r");
        let (_, _rx) = hub.subscribe();
        for _ in 0..PAGE_BACKLOG + 1 {
            hub.publish("{}".into(), false);
        }
        assert_eq!(hub.pages(), 0);
        for _ in 0..KEEP_OTHERS {
            hub.publish("{}".into(), false);
        }
        hub.publish("{\"v\":1}".into(), true);
        let (history, _) = hub.subscribe();
        assert_eq!(history.len(), 1 + 1 + KEEP_OTHERS);
        assert_eq!(&*history[1], "{\"v\":1}");
    }
}
