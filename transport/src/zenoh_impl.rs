//! zenoh backend: session, per-topic QoS, latest-value (queryable cache) and liveliness.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use proto::{Delivery, Fanout};
use zenoh::bytes::ZBytes;
use zenoh::handlers::{FifoChannel, FifoChannelHandler};
use zenoh::liveliness::LivelinessToken;
use zenoh::matching::MatchingListener;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::query::{ConsolidationMode, Querier, QueryTarget, Queryable};
use zenoh::sample::{Sample, SampleKind};
use zenoh::{Session, Wait};

use crate::config::ZenohConfig;
use crate::error::{zenoh_err, TransportError};

/// How long a late joiner's query for the current value may take.
const LATEST_QUERY_TIMEOUT: Duration = Duration::from_secs(5);

pub(crate) fn open(cfg: &ZenohConfig, max_message_bytes: usize) -> Result<Session, TransportError> {
    let config = cfg.to_zenoh(max_message_bytes)?;
    zenoh::open(config)
        .wait()
        .map_err(zenoh_err("open session"))
}

/// QoS per topic: reliable topics block (never dropped silently), best-effort topics drop.
pub(crate) fn declare_publisher(
    session: &Session,
    key: &str,
    delivery: Delivery,
    fanout: Fanout,
) -> Result<Publisher<'static>, TransportError> {
    let b = session.declare_publisher(key.to_string());
    let b = match (delivery, fanout) {
        (Delivery::BestEffort, _) => b
            .congestion_control(CongestionControl::Drop)
            .priority(Priority::DataLow)
            .express(true),
        // Weights, control and acks overtake bulk transitions.
        (Delivery::Latest, _) | (Delivery::Reliable, Fanout::OneToMany) => b
            .congestion_control(CongestionControl::Block)
            .priority(Priority::DataHigh),
        (Delivery::Reliable, Fanout::ManyToOne) => b
            .congestion_control(CongestionControl::Block)
            .priority(Priority::Data),
    };
    b.wait().map_err(zenoh_err("declare publisher"))
}

pub(crate) fn put(publisher: &Publisher<'static>, bytes: Vec<u8>) -> Result<(), TransportError> {
    publisher
        .put(ZBytes::from(bytes))
        .wait()
        .map_err(zenoh_err("put"))
}

pub(crate) fn has_subscribers(publisher: &Publisher<'static>) -> Result<bool, TransportError> {
    Ok(publisher
        .matching_status()
        .wait()
        .map_err(zenoh_err("matching status"))?
        .matching())
}

pub(crate) type SampleQueue = Subscriber<FifoChannelHandler<Sample>>;

pub(crate) fn declare_subscriber(
    session: &Session,
    key: &str,
    capacity: usize,
) -> Result<SampleQueue, TransportError> {
    session
        .declare_subscriber(key.to_string())
        .with(FifoChannel::new(capacity))
        .wait()
        .map_err(zenoh_err("declare subscriber"))
}

/// The payload bytes of a sample and its key (the "source" used for rejection logs).
pub(crate) fn with_payload<R>(
    sample: &Sample,
    f: impl FnOnce(&[u8], &dyn std::fmt::Display) -> R,
) -> R {
    let bytes = sample.payload().to_bytes();
    f(&bytes, &sample.key_expr().as_str())
}

/// Publisher of a latest-value topic: a publisher plus a queryable that answers late joiners
/// with the last published value.
pub(crate) struct LatestPublisher {
    publisher: Publisher<'static>,
    last: Arc<Mutex<Option<ZBytes>>>,
    _queryable: Queryable<()>,
}

impl LatestPublisher {
    pub(crate) fn declare(
        session: &Session,
        key: &str,
        delivery: Delivery,
        fanout: Fanout,
    ) -> Result<Self, TransportError> {
        let publisher = declare_publisher(session, key, delivery, fanout)?;
        let last: Arc<Mutex<Option<ZBytes>>> = Arc::new(Mutex::new(None));
        let served = Arc::clone(&last);
        let reply_key = key.to_string();
        let queryable = session
            .declare_queryable(key.to_string())
            .complete(true)
            .callback(move |query| {
                let value = match served.lock() {
                    Ok(g) => g.clone(),
                    Err(p) => p.into_inner().clone(),
                };
                if let Some(v) = value {
                    if let Err(e) = query.reply(reply_key.clone(), v).wait() {
                        tracing::debug!(key = %reply_key, error = %e, "latest-value reply failed");
                    }
                }
            })
            .wait()
            .map_err(zenoh_err("declare queryable"))?;
        Ok(Self {
            publisher,
            last,
            _queryable: queryable,
        })
    }

    pub(crate) fn has_subscribers(&self) -> Result<bool, TransportError> {
        has_subscribers(&self.publisher)
    }

    pub(crate) fn put(&self, bytes: Vec<u8>) -> Result<(), TransportError> {
        let z = ZBytes::from(bytes);
        match self.last.lock() {
            Ok(mut g) => *g = Some(z.clone()),
            Err(p) => *p.into_inner() = Some(z.clone()),
        }
        self.publisher
            .put(z)
            .wait()
            .map_err(zenoh_err("put latest"))
    }
}

/// Subscriber of a latest-value topic: live samples go to `on_live`; the publisher's current
/// value goes to `on_initial`. The current value is queried at once and again whenever a
/// matching queryable (a latest-value publisher) appears, so a subscriber that starts before
/// the publisher, or before the publisher's declaration reached it, still gets the value.
pub(crate) struct LatestSubscriber {
    // Drop order: the listener (whose callback holds the querier) goes first.
    _matching: MatchingListener<()>,
    _querier: Arc<Querier<'static>>,
    _subscriber: Subscriber<()>,
}

impl LatestSubscriber {
    pub(crate) fn declare(
        session: &Session,
        key: &str,
        on_live: impl Fn(&[u8], &dyn std::fmt::Display) + Send + Sync + 'static,
        on_initial: impl Fn(&[u8], &dyn std::fmt::Display) + Send + Sync + 'static,
    ) -> Result<Self, TransportError> {
        let subscriber = session
            .declare_subscriber(key.to_string())
            .callback(move |sample| {
                if sample.kind() == SampleKind::Put {
                    with_payload(&sample, &on_live);
                }
            })
            .wait()
            .map_err(zenoh_err("declare subscriber"))?;
        let querier = Arc::new(
            session
                .declare_querier(key.to_string())
                .target(QueryTarget::BestMatching)
                .consolidation(ConsolidationMode::None)
                .timeout(LATEST_QUERY_TIMEOUT)
                .wait()
                .map_err(zenoh_err("declare querier"))?,
        );
        let on_initial = Arc::new(on_initial);
        let query = {
            let querier = Arc::clone(&querier);
            move || {
                let on_initial = Arc::clone(&on_initial);
                let sent = querier
                    .get()
                    .callback(move |reply| {
                        if let Ok(sample) = reply.result() {
                            with_payload(sample, &*on_initial);
                        }
                    })
                    .wait();
                if let Err(e) = sent {
                    tracing::debug!(error = %e, "latest-value query failed");
                }
            }
        };
        query();
        let matching = querier
            .matching_listener()
            .callback(move |status| {
                if status.matching() {
                    query();
                }
            })
            .wait()
            .map_err(zenoh_err("declare matching listener"))?;
        Ok(Self {
            _matching: matching,
            _querier: querier,
            _subscriber: subscriber,
        })
    }
}

pub(crate) fn declare_token(
    session: &Session,
    key: &str,
) -> Result<LivelinessToken, TransportError> {
    session
        .liveliness()
        .declare_token(key.to_string())
        .wait()
        .map_err(zenoh_err("declare liveliness token"))
}

pub(crate) fn watch_liveliness(
    session: &Session,
    key: &str,
) -> Result<SampleQueue, TransportError> {
    session
        .liveliness()
        .declare_subscriber(key.to_string())
        .history(true)
        .with(FifoChannel::new(1024))
        .wait()
        .map_err(zenoh_err("declare liveliness subscriber"))
}

/// Keys of the liveliness tokens alive now (snapshot query).
pub(crate) fn alive_keys(
    session: &Session,
    key: &str,
    timeout: Duration,
) -> Result<Vec<String>, TransportError> {
    let replies = session
        .liveliness()
        .get(key.to_string())
        .timeout(timeout)
        .wait()
        .map_err(zenoh_err("liveliness get"))?;
    let mut keys = Vec::new();
    while let Ok(reply) = replies.recv() {
        if let Ok(sample) = reply.result() {
            keys.push(sample.key_expr().as_str().to_string());
        }
    }
    Ok(keys)
}
