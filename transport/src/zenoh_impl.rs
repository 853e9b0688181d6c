//! zenoh backend: session, per-topic QoS, latest-value (queryable cache) and liveliness.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use proto::{Delivery, Fanout};
use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::matching::MatchingListener;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::query::{ConsolidationMode, Querier, QueryTarget, Queryable};
use zenoh::sample::{Sample, SampleKind};
use zenoh::{Session, Wait};

use crate::config::ZenohConfig;
use crate::error::{zenoh_err, TransportError};

/// Congestion control of latest-value topics (weights, control), their publications and the
/// late joiners' queries (whose answers travel with the query's congestion control): dropped
/// for a receiver whose queue stays full, never waited on.
const LATEST_CONGESTION: CongestionControl = CongestionControl::Drop;

/// How long a late joiner's query for the current value may take.
const LATEST_QUERY_TIMEOUT: Duration = Duration::from_secs(5);

pub(crate) fn open(cfg: &ZenohConfig, max_message_bytes: usize) -> Result<Session, TransportError> {
    let config = cfg.to_zenoh(max_message_bytes)?;
    zenoh::open(config)
        .wait()
        .map_err(zenoh_err("open session"))
}

/// How a publication meets a receiver whose queue stays full.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Congestion {
    /// As the topic's delivery says ([`declare_publisher`]).
    ByDelivery,
    /// Dropped for that receiver whatever the delivery: for messages of a reliable topic that
    /// each supersede the previous one and that the publisher repeats (acknowledgements).
    Drop,
}

/// QoS per topic: reliable topics block (never dropped silently), best-effort topics drop, and
/// so do latest-value topics (weights, control): a newer value supersedes the one dropped, the
/// publisher repeats its current value when idle ([`LatestPublisher::republish`]), and a
/// subscriber that never reads (a hung or hostile client) must not hold up the learner for the
/// link's `wait_before_close` on every value; zenoh drops for that subscriber only.
/// [`Congestion::Drop`] makes a reliable topic's publisher drop too (still over reliable
/// links: a receiver that keeps up loses nothing).
pub(crate) fn declare_publisher(
    session: &Session,
    key: &str,
    delivery: Delivery,
    fanout: Fanout,
    congestion: Congestion,
) -> Result<Publisher<'static>, TransportError> {
    let b = session.declare_publisher(key.to_string());
    let b = match (delivery, fanout) {
        (Delivery::BestEffort, _) => b
            .congestion_control(CongestionControl::Drop)
            .priority(Priority::DataLow)
            .express(true),
        // Weights, control and acks overtake bulk transitions.
        (Delivery::Latest, _) => b
            .congestion_control(LATEST_CONGESTION)
            .priority(Priority::DataHigh),
        (Delivery::Reliable, Fanout::OneToMany) => b
            .congestion_control(CongestionControl::Block)
            .priority(Priority::DataHigh),
        (Delivery::Reliable, Fanout::ManyToOne) => b
            .congestion_control(CongestionControl::Block)
            .priority(Priority::Data),
    };
    let b = match congestion {
        Congestion::ByDelivery => b,
        Congestion::Drop => b.congestion_control(CongestionControl::Drop),
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

pub(crate) type SampleQueue = Subscriber<ByteQueue>;

/// A subscriber's queue bounded in messages **and in bytes** of payload: when either bound is
/// reached, zenoh's receiving task waits (reliable traffic is held back at the sender, as with
/// a full `FifoChannel`) until the reader takes something. One message larger than the byte
/// bound is still admitted into an empty queue, so nothing valid is refused for its size.
#[derive(Clone)]
pub(crate) struct ByteQueue {
    shared: Arc<(Mutex<QueueState>, Condvar)>,
}

struct QueueState {
    samples: VecDeque<Sample>,
    bytes: usize,
}

impl ByteQueue {
    fn new() -> Self {
        Self {
            shared: Arc::new((
                Mutex::new(QueueState {
                    samples: VecDeque::new(),
                    bytes: 0,
                }),
                Condvar::new(),
            )),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, QueueState> {
        self.shared.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// zenoh's side: waits while the queue is full.
    fn push(&self, sample: Sample, max_messages: usize, max_bytes: usize) {
        let len = sample.payload().len();
        let mut s = self.lock();
        while !s.samples.is_empty()
            && (s.samples.len() >= max_messages || s.bytes + len > max_bytes)
        {
            s = self.shared.1.wait(s).unwrap_or_else(|p| p.into_inner());
        }
        s.bytes += len;
        s.samples.push_back(sample);
        self.shared.1.notify_all();
    }

    fn pop(s: &mut QueueState) -> Option<Sample> {
        let sample = s.samples.pop_front()?;
        s.bytes -= sample.payload().len();
        Some(sample)
    }

    /// The next sample, waiting up to `timeout`.
    pub(crate) fn recv_timeout(&self, timeout: Duration) -> zenoh::Result<Option<Sample>> {
        let deadline = std::time::Instant::now() + timeout;
        let mut s = self.lock();
        loop {
            if let Some(sample) = Self::pop(&mut s) {
                self.shared.1.notify_all();
                return Ok(Some(sample));
            }
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            s = self
                .shared
                .1
                .wait_timeout(s, left)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }

    /// The next sample if one is queued.
    pub(crate) fn try_recv(&self) -> zenoh::Result<Option<Sample>> {
        let mut s = self.lock();
        let sample = Self::pop(&mut s);
        if sample.is_some() {
            self.shared.1.notify_all();
        }
        Ok(sample)
    }

    /// Payload bytes queued now.
    #[cfg(test)]
    fn bytes(&self) -> usize {
        self.lock().bytes
    }
}

/// A queue and the zenoh callback that fills it.
fn byte_queue(
    max_messages: usize,
    max_bytes: usize,
) -> (impl Fn(Sample) + Send + Sync + 'static, ByteQueue) {
    let q = ByteQueue::new();
    let filler = q.clone();
    (
        move |sample| filler.push(sample, max_messages, max_bytes),
        q,
    )
}

pub(crate) fn declare_subscriber(
    session: &Session,
    key: &str,
    capacity: usize,
    capacity_bytes: usize,
) -> Result<SampleQueue, TransportError> {
    session
        .declare_subscriber(key.to_string())
        .with(byte_queue(capacity, capacity_bytes))
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

/// The payload bytes of a sample and its key expression.
pub(crate) fn with_payload_key<R>(sample: &Sample, f: impl FnOnce(&[u8], &str) -> R) -> R {
    let bytes = sample.payload().to_bytes();
    f(&bytes, sample.key_expr().as_str())
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
        let publisher = declare_publisher(session, key, delivery, fanout, Congestion::ByDelivery)?;
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
                    // Answered with the query's congestion control (zenoh): `Drop` for our
                    // own subscribers' queries (`LatestSubscriber`).
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

    /// Sends the current value again, the same bytes (subscribers see no new value if they
    /// have it already). Returns whether there was one.
    pub(crate) fn republish(&self) -> Result<bool, TransportError> {
        let value = match self.last.lock() {
            Ok(g) => g.clone(),
            Err(p) => p.into_inner().clone(),
        };
        let Some(z) = value else {
            return Ok(false);
        };
        self.publisher
            .put(z)
            .wait()
            .map_err(zenoh_err("put latest"))?;
        Ok(true)
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
                .congestion_control(LATEST_CONGESTION)
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
        .with(byte_queue(1024, 1 << 20))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The queue holds at most its byte bound (one oversized message alone), and a full queue
    /// makes the filler wait until the reader takes something.
    #[test]
    fn the_queue_is_bounded_in_bytes() {
        // Loopback only, no scouting.
        let mut cfg = zenoh::Config::default();
        cfg.insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        cfg.insert_json5("listen/endpoints", r#"["tcp/127.0.0.1:0"]"#)
            .unwrap();
        let session = zenoh::open(cfg).wait().unwrap();
        let sub = session
            .declare_subscriber("fsrl/test/bytequeue")
            .with(byte_queue(1024, 3000))
            .wait()
            .unwrap();
        let publisher = session
            .declare_publisher("fsrl/test/bytequeue")
            .wait()
            .unwrap();
        // A filler thread: 10 messages of 1000 bytes into a 3000-byte queue.
        std::thread::scope(|s| {
            s.spawn(|| {
                for i in 0..10u8 {
                    publisher.put(vec![i; 1000]).wait().unwrap();
                }
            });
            let mut max_seen = 0;
            let mut got = Vec::new();
            while got.len() < 10 {
                std::thread::sleep(Duration::from_millis(20));
                max_seen = max_seen.max(sub.bytes());
                if let Some(sample) = sub.recv_timeout(Duration::from_secs(5)).unwrap() {
                    got.push(sample.payload().to_bytes()[0]);
                }
            }
            assert!(max_seen <= 3000, "queued {max_seen} bytes");
            assert_eq!(got, (0..10).collect::<Vec<u8>>(), "in order, none lost");
        });
        // One message over the bound is still admitted into the empty queue.
        publisher.put(vec![7u8; 5000]).wait().unwrap();
        let big = sub.recv_timeout(Duration::from_secs(5)).unwrap().unwrap();
        assert_eq!(big.payload().len(), 5000);
    }
}
