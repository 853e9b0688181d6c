//! What the page is told: every metrics, status and liveliness event as one JSON object naming
//! its run (`r`), kept (bounded) so that a page opened late draws the whole of each run, and
//! handed to every open page as it arrives.

use std::collections::VecDeque;
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};

use proto::{Metrics, Role, RunId, SenderId, Status};

/// Messages of each kind kept for a page opened later: the evaluator's (the learning curve,
/// one per validation) all up to [`KEEP_VALIDATIONS`], the others the newest [`KEEP_OTHERS`]
/// (at one message per process and second, about an hour of a four-process run).
pub const KEEP_VALIDATIONS: usize = 20_000;
pub const KEEP_OTHERS: usize = 15_000;
/// Events a page may fall behind by before it is dropped (its browser reconnects and starts
/// again from the kept history).
pub const PAGE_BACKLOG: usize = 4096;

/// One event as the page reads it.
pub fn metrics_event(run: &RunId, sender: SenderId, m: &Metrics) -> String {
    serde_json::json!({
        "k": "m", "r": run.as_str(), "s": sender.to_string(), "role": role(sender.role),
        "e": m.episodes, "t": m.wall_time_s, "v": m.values,
    })
    .to_string()
}

/// A heartbeat: the state (`starting`, `running`, `idle`, `stopping`, `failed`) and `detail`,
/// the process's last error.
pub fn status_event(run: &RunId, sender: SenderId, s: &Status) -> String {
    let state = serde_json::to_value(s.state).unwrap_or_default();
    serde_json::json!({
        "k": "s", "r": run.as_str(), "s": sender.to_string(), "role": role(sender.role),
        "state": state, "detail": s.detail, "uptime": s.uptime_s, "e": s.episodes,
    })
    .to_string()
}

pub fn alive_event(run: &RunId, sender: SenderId, up: bool) -> String {
    serde_json::json!({
        "k": "a", "r": run.as_str(), "s": sender.to_string(), "role": role(sender.role), "up": up,
    })
    .to_string()
}

/// The page's own trouble with a run (`detail`, empty once it is over): its liveliness
/// cannot be watched (the router refused its keys, say). The run's other events go on.
pub fn watch_error_event(run: &RunId, detail: &str) -> String {
    serde_json::json!({"k": "w", "r": run.as_str(), "detail": detail}).to_string()
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
    /// The first event (the run shown, or `null` for every run), then the kept history.
    head: Vec<Arc<str>>,
    validations: VecDeque<Arc<str>>,
    others: VecDeque<Arc<str>>,
    /// Each open page's id and its channel.
    pages: Vec<(u64, SyncSender<Arc<str>>)>,
    next_page: u64,
}

/// The events of the runs shown, and the pages listening.
#[derive(Clone, Default)]
pub struct Hub {
    state: Arc<Mutex<State>>,
}

impl Hub {
    /// A hub whose history starts with the run shown (`None`: every run it sees).
    pub fn new(run: Option<&str>) -> Self {
        let hub = Hub::default();
        hub.lock().head.push(
            serde_json::json!({"k": "run", "run": run, "every": run.is_none()})
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
        st.pages.retain(|(_, p)| {
            !matches!(
                p.try_send(event.clone()),
                Err(TrySendError::Full(_) | TrySendError::Disconnected(_))
            )
        });
    }

    /// A new page: what was kept so far (in order of arrival within each kind, validations
    /// first), and a receiver of what comes next (the page is forgotten when it is dropped).
    pub fn subscribe(&self) -> (Vec<Arc<str>>, Page) {
        let mut st = self.lock();
        let (tx, rx) = sync_channel(PAGE_BACKLOG);
        let id = st.next_page;
        st.next_page += 1;
        st.pages.push((id, tx));
        let history = st
            .head
            .iter()
            .chain(&st.validations)
            .chain(&st.others)
            .cloned()
            .collect();
        let page = Page {
            rx,
            id,
            hub: self.clone(),
        };
        (history, page)
    }

    /// Drops the page of this id ([`Page::id`]): its receiver ends at once.
    pub fn forget(&self, page: u64) {
        self.lock().pages.retain(|(id, _)| *id != page);
    }

    /// Pages listening now.
    pub fn pages(&self) -> usize {
        self.lock().pages.len()
    }
}

/// One page's receiver of the hub's events. Dropped, it leaves the hub at once (not at the
/// next event: a hub with nothing new to say would otherwise keep every closed page's channel).
pub struct Page {
    rx: Receiver<Arc<str>>,
    id: u64,
    hub: Hub,
}

impl std::ops::Deref for Page {
    type Target = Receiver<Arc<str>>;
    fn deref(&self) -> &Self::Target {
        &self.rx
    }
}

impl Page {
    /// Its id, for [`Hub::forget`].
    pub fn id(&self) -> u64 {
        self.id
    }
}

impl Drop for Page {
    fn drop(&mut self) {
        self.hub.forget(self.id);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_late_page_gets_the_history_then_what_follows() {
        let hub = Hub::new(Some("r"));
        let r = RunId::new("r").unwrap();
        let learner = SenderId::new(Role::Learner, 0);
        hub.publish(metrics_event(&r, learner, &Metrics::default()), false);
        let (history, rx) = hub.subscribe();
        assert_eq!(history.len(), 2);
        assert!(history[0].contains("\"run\":\"r\""));
        hub.publish(alive_event(&r, SenderId::new(Role::Actor, 1), false), false);
        let next = rx.try_recv().unwrap();
        assert!(
            next.contains("\"s\":\"actor-1\"") && next.contains("\"up\":false"),
            "{next}"
        );
        // A page gone is forgotten at once.
        drop(rx);
        assert_eq!(hub.pages(), 0);
        hub.publish(alive_event(&r, learner, true), false);
        assert_eq!(hub.pages(), 0);
    }

    #[test]
    fn a_page_that_falls_behind_is_dropped_and_the_history_is_bounded() {
        let hub = Hub::new(None);
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

    #[test]
    fn each_event_names_its_run_and_a_heartbeat_its_state_and_last_error() {
        let hub = Hub::new(None);
        let (history, _) = hub.subscribe();
        assert!(history[0].contains("\"every\":true"), "{}", history[0]);
        let b = RunId::new("run-b").unwrap();
        let s = Status {
            state: proto::ProcessState::Idle,
            uptime_s: 3.5,
            env_steps: 10,
            episodes: 2,
            detail: "rejected a message".into(),
        };
        let e: serde_json::Value =
            serde_json::from_str(&status_event(&b, SenderId::new(Role::Learner, 0), &s)).unwrap();
        assert_eq!(e["r"], "run-b");
        assert_eq!(e["state"], "idle");
        assert_eq!(e["detail"], "rejected a message");
        let m: serde_json::Value = serde_json::from_str(&metrics_event(
            &b,
            SenderId::new(Role::Actor, 2),
            &Metrics::default(),
        ))
        .unwrap();
        assert_eq!(
            (m["r"].as_str(), m["s"].as_str()),
            (Some("run-b"), Some("actor-2"))
        );
    }
}
