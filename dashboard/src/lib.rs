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

pub mod http;
pub mod hub;

use std::collections::BTreeMap;
use std::net::TcpListener;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use proto::{keys, Role, RunId};
use transport::{AliveEvent, AliveWatcher, Transport, TransportError};

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

/// Runs whose liveliness a page of [`Scope::EveryRun`] watches (their metrics and status are
/// shown whatever their number; the history is bounded in messages, [`hub::KEEP_OTHERS`]).
pub const MAX_RUNS: usize = 64;

/// Serves the page on `listener` and feeds it from the runs of `scope` until `stop` is set.
pub fn run(
    t: &Transport,
    scope: Scope,
    listener: TcpListener,
    stop: &AtomicBool,
) -> Result<(), Error> {
    let (hub, metrics, status) = match scope {
        Scope::Run => (
            Hub::new(Some(t.run().as_str())),
            t.subscriber(&keys::all_metrics(t.run()))?,
            t.subscriber(&keys::all_status(t.run()))?,
        ),
        Scope::EveryRun => (
            Hub::new(None),
            t.subscriber(&keys::every_run_metrics())?,
            t.subscriber(&keys::every_run_status())?,
        ),
    };
    let mut alive: BTreeMap<RunId, AliveWatcher> = BTreeMap::new();
    if scope == Scope::Run {
        alive.insert(t.run().clone(), t.watch_alive()?);
    }
    // A run seen for the first time: its members from now on (and those alive already).
    let watch = |alive: &mut BTreeMap<RunId, AliveWatcher>, run: &RunId| {
        if scope == Scope::EveryRun && !alive.contains_key(run) && alive.len() < MAX_RUNS {
            alive.insert(run.clone(), t.watch_alive_of(run)?);
        }
        Ok::<_, TransportError>(())
    };
    http::spawn(listener, hub.clone())?;
    while !stop.load(Ordering::Relaxed) {
        if let Some(m) = metrics.recv_timeout(Duration::from_millis(100))? {
            watch(&mut alive, &m.header.run)?;
            let sender = m.header.sender;
            let validation =
                sender.role == Role::Evaluator && m.body.values.contains_key("validation_episode");
            hub.publish(
                hub::metrics_event(&m.header.run, sender, &m.body),
                validation,
            );
        }
        while let Some(s) = status.try_recv()? {
            watch(&mut alive, &s.header.run)?;
            hub.publish(
                hub::status_event(&s.header.run, s.header.sender, &s.body),
                false,
            );
        }
        for (run, w) in &alive {
            while let Some(e) = w.recv_timeout(Duration::ZERO)? {
                let (m, up) = match e {
                    AliveEvent::Joined(m) => (m, true),
                    AliveEvent::Left(m) => (m, false),
                };
                hub.publish(hub::alive_event(run, m.sender, up), false);
            }
        }
    }
    Ok(())
}
