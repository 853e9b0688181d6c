//! A live page of training runs (`fsrl dashboard`, `fsrl train --dashboard PORT`): the metrics,
//! status heartbeats and liveliness of one run, or of every run it sees ([`Scope`]), read over
//! zenoh like any other tool (`transport`, a monitor's session: through a secured cluster's
//! router it sees what the monitor's credentials may read), kept in a [`hub::Hub`] and pushed
//! to the browser as Server-Sent Events by a small HTTP server ([`http`]) that also serves the
//! page itself (`src/page/`: HTML, one script, one style sheet, compiled in; no CDN). The page
//! draws a run's validation curves (success, collision, Disc., Nav. Time against RL episodes),
//! throughput, policy lag and the replay ratio, lists the runs it sees, and every process with
//! its liveliness, its state and its last error (from its `proto::Status`), redrawn as each
//! event arrives.
//!
//! Security, in short ([`http`] has the details): on a loopback address the page answers only
//! requests whose `Host` is a literal loopback address or `localhost` and whose `Origin`, if
//! any, is an http page of such a host (no DNS rebinding, no other site); it serves at most
//! [`http::MAX_CONNECTIONS`] connections at once, each with a deadline on reading its request
//! and a timeout on every write (a client that stops reading is dropped). A run whose
//! liveliness cannot be watched (its keys refused by the router, say) is shown with that error
//! and tried again later; the page goes on with the other runs.

pub mod http;
pub mod hub;

use std::collections::BTreeMap;
use std::net::TcpListener;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use proto::{keys, Message, Metrics, Role, RunId, Status};
use transport::{AliveEvent, AliveWatcher, Subscriber, Transport, TransportError};

pub use hub::Hub;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("the dashboard's HTTP server: {0}")]
    Http(#[from] std::io::Error),
}

/// Which runs the page shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// The transport's own run.
    Run,
    /// Every run whose metrics or status reach this transport (`fsrl/*/metrics/**`,
    /// `fsrl/*/status/**`); a run's liveliness is watched from its first message on, for at
    /// most [`MAX_RUNS`] runs.
    EveryRun,
}

/// Runs whose liveliness a page of [`Scope::EveryRun`] watches (or tries to: a run whose watch
/// failed counts until it is tried again; their metrics and status are shown whatever their
/// number; the history is bounded in messages, [`hub::KEEP_OTHERS`]).
pub const MAX_RUNS: usize = 64;

/// How long after a failed watch of a run's liveliness it is tried again (when the run is heard
/// from next).
pub const WATCH_RETRY: Duration = Duration::from_secs(30);

/// Serves the page on `listener` and feeds it from the runs of `scope` until `stop` is set.
pub fn run(
    t: &Transport,
    scope: Scope,
    listener: TcpListener,
    stop: &AtomicBool,
) -> Result<(), Error> {
    let (hub, feed) = match scope {
        Scope::Run => (
            Hub::new(Some(t.run().as_str())),
            Zenoh {
                t,
                metrics: t.subscriber(&keys::all_metrics(t.run()))?,
                status: t.subscriber(&keys::all_status(t.run()))?,
            },
        ),
        Scope::EveryRun => (
            Hub::new(None),
            Zenoh {
                t,
                metrics: t.subscriber(&keys::every_run_metrics())?,
                status: t.subscriber(&keys::every_run_status())?,
            },
        ),
    };
    http::spawn(listener, hub.clone())?;
    let own = (scope == Scope::Run).then(|| t.run());
    follow(&feed, &hub, own, stop)
}

/// Where the page's events come from: the transport ([`Zenoh`]), or a test's stand-in.
trait Feed {
    /// One run's liveliness being watched.
    type Watch;
    fn metrics(&self, wait: Duration) -> Result<Option<Message<Metrics>>, TransportError>;
    fn status(&self) -> Result<Option<Message<Status>>, TransportError>;
    fn watch(&self, run: &RunId) -> Result<Self::Watch, TransportError>;
    fn alive(&self, watch: &Self::Watch) -> Result<Option<AliveEvent>, TransportError>;
}

struct Zenoh<'a> {
    t: &'a Transport,
    metrics: Subscriber<Metrics>,
    status: Subscriber<Status>,
}

impl Feed for Zenoh<'_> {
    type Watch = AliveWatcher;
    fn metrics(&self, wait: Duration) -> Result<Option<Message<Metrics>>, TransportError> {
        self.metrics.recv_timeout(wait)
    }
    fn status(&self) -> Result<Option<Message<Status>>, TransportError> {
        self.status.try_recv()
    }
    fn watch(&self, run: &RunId) -> Result<AliveWatcher, TransportError> {
        self.t.watch_alive_of(run)
    }
    fn alive(&self, watch: &AliveWatcher) -> Result<Option<AliveEvent>, TransportError> {
        watch.recv_timeout(Duration::ZERO)
    }
}

/// Hands every message of `feed` to the hub until `stop` is set, watching the liveliness of
/// `own` from the start and of every other run from its first message on. Only a failure of
/// the subscriptions every run shares ends it.
fn follow<F: Feed>(
    feed: &F,
    hub: &Hub,
    own: Option<&RunId>,
    stop: &AtomicBool,
) -> Result<(), Error> {
    let mut alive = Liveliness::default();
    if let Some(run) = own {
        alive.see(feed, hub, run);
    }
    while !stop.load(Ordering::Relaxed) {
        if let Some(m) = feed.metrics(Duration::from_millis(100))? {
            alive.see(feed, hub, &m.header.run);
            let sender = m.header.sender;
            let validation =
                sender.role == Role::Evaluator && m.body.values.contains_key("validation_episode");
            hub.publish(
                hub::metrics_event(&m.header.run, sender, &m.body),
                validation,
            );
        }
        while let Some(s) = feed.status()? {
            alive.see(feed, hub, &s.header.run);
            hub.publish(
                hub::status_event(&s.header.run, s.header.sender, &s.body),
                false,
            );
        }
        alive.poll(feed, hub);
    }
    Ok(())
}

/// The runs whose liveliness is watched, and those whose watch failed (with when to try
/// again): a failure is that run's, told on the page under its id, never the page's.
struct Liveliness<W> {
    watching: BTreeMap<RunId, W>,
    failed: BTreeMap<RunId, Instant>,
}

impl<W> Default for Liveliness<W> {
    fn default() -> Self {
        Liveliness {
            watching: BTreeMap::new(),
            failed: BTreeMap::new(),
        }
    }
}

impl<W> Liveliness<W> {
    /// A message of `run` came: watch its liveliness if that is not done yet (nor failed
    /// lately), for at most [`MAX_RUNS`] runs.
    fn see<F: Feed<Watch = W>>(&mut self, feed: &F, hub: &Hub, run: &RunId) {
        if self.watching.contains_key(run) {
            return;
        }
        match self.failed.get(run) {
            Some(retry) if Instant::now() < *retry => return,
            Some(_) => {}
            None if self.watching.len() + self.failed.len() >= MAX_RUNS => return,
            None => {}
        }
        match feed.watch(run) {
            Ok(w) => {
                if self.failed.remove(run).is_some() {
                    hub.publish(hub::watch_error_event(run, ""), false);
                }
                self.watching.insert(run.clone(), w);
            }
            Err(e) => self.fail(hub, run, format!("cannot watch its liveliness: {e}")),
        }
    }

    /// Each watched run's liveliness events to the hub; a watch that fails is dropped (and
    /// tried again later).
    fn poll<F: Feed<Watch = W>>(&mut self, feed: &F, hub: &Hub) {
        let mut broken = Vec::new();
        for (run, w) in &self.watching {
            loop {
                match feed.alive(w) {
                    Ok(Some(e)) => {
                        let (m, up) = match e {
                            AliveEvent::Joined(m) => (m, true),
                            AliveEvent::Left(m) => (m, false),
                        };
                        hub.publish(hub::alive_event(run, m.sender, up), false);
                    }
                    Ok(None) => break,
                    Err(e) => {
                        broken.push((run.clone(), e));
                        break;
                    }
                }
            }
        }
        for (run, e) in broken {
            self.watching.remove(&run);
            self.fail(hub, &run, format!("lost its liveliness: {e}"));
        }
    }

    fn fail(&mut self, hub: &Hub, run: &RunId, detail: String) {
        tracing::warn!(run = run.as_str(), "the dashboard {detail}");
        hub.publish(hub::watch_error_event(run, &detail), false);
        self.failed
            .insert(run.clone(), Instant::now() + WATCH_RETRY);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::{keys::Member, SenderId};
    use std::cell::RefCell;
    use std::collections::VecDeque;

    /// Metrics of a few runs; watching run `bad` fails, run `flaky`'s watch breaks at its
    /// first read, every other run has its learner alive. Stops when it has no more messages.
    struct Injected<'a> {
        metrics: RefCell<VecDeque<Message<Metrics>>>,
        stop: &'a AtomicBool,
    }

    fn refused(run: &RunId) -> TransportError {
        TransportError::Zenoh {
            op: "declare liveliness subscriber",
            detail: format!("access to fsrl/{run}/alive/** denied"),
        }
    }

    impl Feed for Injected<'_> {
        type Watch = (RunId, RefCell<VecDeque<AliveEvent>>);
        fn metrics(&self, _: Duration) -> Result<Option<Message<Metrics>>, TransportError> {
            let m = self.metrics.borrow_mut().pop_front();
            if m.is_none() {
                self.stop.store(true, Ordering::Relaxed);
            }
            Ok(m)
        }
        fn status(&self) -> Result<Option<Message<Status>>, TransportError> {
            Ok(None)
        }
        fn watch(&self, run: &RunId) -> Result<Self::Watch, TransportError> {
            if run.as_str() == "bad" {
                return Err(refused(run));
            }
            let learner = Member {
                sender: SenderId::new(Role::Learner, 0),
                instance: 1,
            };
            Ok((
                run.clone(),
                RefCell::new(VecDeque::from([AliveEvent::Joined(learner)])),
            ))
        }
        fn alive(&self, (run, w): &Self::Watch) -> Result<Option<AliveEvent>, TransportError> {
            if run.as_str() == "flaky" {
                return Err(refused(run));
            }
            Ok(w.borrow_mut().pop_front())
        }
    }

    fn metrics_of(run: &str) -> Message<Metrics> {
        Message::new(
            RunId::new(run).unwrap(),
            SenderId::new(Role::Learner, 0),
            0,
            0,
            Metrics::default(),
        )
    }

    #[test]
    fn a_run_that_cannot_be_watched_is_told_on_its_own_and_the_others_go_on() {
        let stop = AtomicBool::new(false);
        let feed = Injected {
            metrics: RefCell::new(
                ["bad", "flaky", "good", "bad"]
                    .map(metrics_of)
                    .into_iter()
                    .collect(),
            ),
            stop: &stop,
        };
        let hub = Hub::new(None);
        let (_, page) = hub.subscribe();
        let own = RunId::new("bad").unwrap();
        follow(&feed, &hub, Some(&own), &stop).expect("one run's failure ended the page");
        let events: Vec<serde_json::Value> = page
            .try_iter()
            .map(|e| serde_json::from_str(&e).unwrap())
            .collect();
        let of = |run: &str, kind: &str| {
            events
                .iter()
                .filter(|e| e["r"] == run && e["k"] == kind)
                .collect::<Vec<_>>()
        };
        // The run that cannot be watched: its error, once (tried again only after
        // WATCH_RETRY), and its metrics all the same.
        let bad = of("bad", "w");
        assert_eq!(bad.len(), 1, "{events:?}");
        assert!(
            bad[0]["detail"].as_str().unwrap().contains("denied"),
            "{bad:?}"
        );
        assert_eq!(of("bad", "m").len(), 2, "{events:?}");
        // The one whose watch broke: its error.
        assert!(
            of("flaky", "w")[0]["detail"]
                .as_str()
                .unwrap()
                .contains("lost its liveliness"),
            "{events:?}"
        );
        // The others: watched, their metrics shown.
        let up = of("good", "a");
        assert_eq!(up.len(), 1, "{events:?}");
        assert_eq!(up[0]["up"], true);
        assert_eq!(of("good", "m").len(), 1, "{events:?}");
    }
}
