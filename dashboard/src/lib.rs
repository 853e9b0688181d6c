//! A live page of a training run (`fsrl dashboard`, `fsrl train --dashboard PORT`): the run's
//! metrics, status and liveliness read over zenoh like any other tool (`transport`, a monitor's
//! session: through a secured cluster's router it sees what the monitor's credentials may
//! read), kept in a [`hub::Hub`] and pushed to the browser as Server-Sent Events by a small
//! HTTP server ([`http`]) that also serves the page itself (`src/page/`: HTML, one script, one
//! style sheet, compiled in; no CDN). The page draws the validation curves (success, collision,
//! Disc., Nav. Time against RL episodes), throughput, policy lag, the replay ratio and the
//! processes alive with their last error, redrawn as each event arrives.

pub mod http;
pub mod hub;

use std::net::TcpListener;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use proto::{keys, Role};
use transport::{AliveEvent, Transport, TransportError};

pub use hub::Hub;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("the dashboard's HTTP server: {0}")]
    Http(#[from] std::io::Error),
}

/// Serves the page on `listener` and feeds it from `t`'s run until `stop` is set.
pub fn run(t: &Transport, listener: TcpListener, stop: &AtomicBool) -> Result<(), Error> {
    let hub = Hub::new(t.run().as_str());
    let metrics = t.subscriber(&keys::all_metrics(t.run()))?;
    let status = t.subscriber(&keys::all_status(t.run()))?;
    let alive = t.watch_alive()?;
    http::spawn(listener, hub.clone())?;
    while !stop.load(Ordering::Relaxed) {
        if let Some(m) = metrics.recv_timeout(Duration::from_millis(100))? {
            let sender = m.header.sender;
            let validation =
                sender.role == Role::Evaluator && m.body.values.contains_key("validation_episode");
            hub.publish(hub::metrics_event(sender, &m.body), validation);
        }
        while let Some(s) = status.try_recv()? {
            hub.publish(hub::status_event(s.header.sender, &s.body), false);
        }
        while let Some(e) = alive.recv_timeout(Duration::ZERO)? {
            let (m, up) = match e {
                AliveEvent::Joined(m) => (m, true),
                AliveEvent::Left(m) => (m, false),
            };
            hub.publish(hub::alive_event(m.sender, up), false);
        }
    }
    Ok(())
}
