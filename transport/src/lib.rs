//! `transport`: typed publish/subscribe of [`proto`] messages, latest-value delivery for
//! weights and control, and liveliness, over zenoh (any number of machines) or iceoryx2
//! (zero-copy shared memory on one machine). The only crate (with the binaries) that opens a
//! zenoh session or an iceoryx2 node.
//!
//! # One interface, two backends
//!
//! [`Transport::open`] takes a [`TransportConfig`]; `data_plane` picks the backend of the
//! *data* topics ([`proto::Plane::Data`]: transitions, weights, control, acks):
//!
//! | | zenoh ([`DataPlane::Zenoh`], default) | iceoryx2 ([`DataPlane::Iceoryx2`]) |
//! |---|---|---|
//! | data topics | zenoh pub/sub | iceoryx2 `[u8]` pub/sub in shared memory (episode batches encoded straight into the sample, others copied in once; read in place) |
//! | telemetry topics (metrics, status, eval) | zenoh | zenoh (loopback) |
//! | liveliness | zenoh liveliness tokens | zenoh liveliness tokens |
//! | latest value (late joiner) | queryable serving the last value + query at subscribe | service history of 1 + join event → `update_connections` |
//! | reliable | `CongestionControl::Block`, reliable links | no overflow, `RetryUntilDelivered` up to `publish_timeout_ms`, then [`TransportError::PublishTimeout`]; a sample that reached no subscriber while one exists (not yet connected) is sent again within the same limit |
//! | best effort | `CongestionControl::Drop`, express | overflow (oldest dropped) |
//! | latest value | `CongestionControl::Drop` (a subscriber that never reads cannot stall the publisher; a newer value supersedes a dropped one, [`LatestPublisher::republish`] repeats the last) | history of 1 |
//! | reliable, superseded and repeated ([`Transport::dropping_publisher`]: acks) | `CongestionControl::Drop`, reliable links (a subscriber that never reads cannot stall the publisher; the next message supersedes a dropped one) | as reliable |
//!
//! Liveliness and telemetry always ride on zenoh, even with the iceoryx2 data plane, so that
//! other tools (Python `eclipse-zenoh`, `z_sub`) see metrics and membership, and because zenoh
//! tokens give immediate join/leave events (a crashed process's TCP link closes). iceoryx2's
//! own crash handling is still used for its resources: [`Transport::cleanup_stale`] (also run
//! automatically when a node is created or a service opened) removes the shared memory and
//! port slots of dead processes.
//!
//! # API
//!
//! * [`Transport::publisher`] / [`Transport::subscriber`]: reliable or best-effort topics
//!   (transitions, acks, eval reports, metrics, status). [`Publisher::publish`] stamps the
//!   header (run, sender, sequence number, policy version), encodes and sends;
//!   [`Subscriber::recv_timeout`] decodes and validates. [`Transport::dropping_publisher`]:
//!   a reliable topic's publisher that drops rather than waits for a subscriber that does not
//!   keep up (acks, which supersede each other and are repeated).
//! * [`Transport::latest_publisher`] / [`Transport::latest_subscriber`]: latest-value topics
//!   (weights, control). [`LatestSubscriber::latest`] is the newest value (a late joiner has
//!   the current one at once); [`LatestSubscriber::next`] waits for a newer one.
//! * [`Transport::declare_alive`] (drop the [`AliveToken`] to leave), [`Transport::watch_alive`]
//!   ([`AliveEvent::Joined`] / [`AliveEvent::Left`], current members first),
//!   [`Transport::alive_members`] (snapshot).
//! * [`Transport::rejected_count`]: malformed, wrong-version or foreign-run messages received
//!   (each logged once per source with `tracing::warn!`, then only counted, and skipped);
//!   [`Transport::last_rejection`], the newest in words.
//! * [`Heartbeat`]: the process's [`proto::Status`] (life-cycle state, last error) on its
//!   status key, on changes and every [`HEARTBEAT_EVERY`].
//! * Every run at once: [`proto::keys::every_run_metrics`] and `…status` subscriptions take a
//!   message only when its header's run is the run of its key; [`Transport::watch_alive_of`]
//!   watches the members of any run.
//!
//! Every call is blocking (bounded by a timeout where it waits); all handles are `Send + Sync`.
//! Roles call them from their own threads (simulation and training never run on an async
//! executor); from async code use `spawn_blocking`. zenoh runs its own runtime internally.

mod config;
mod error;
mod heartbeat;
mod iox;
mod reject;
mod zenoh_impl;

use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::hash::{BuildHasher, Hasher};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use proto::{keys, Body, Delivery, Member, Message, Plane, RunId, SenderId, Topic};
use zenoh::sample::SampleKind;

pub use config::{
    exposed_secret, DataPlane, IceoryxConfig, TransportConfig, ZenohAuth, ZenohConfig, ZenohMode,
    ZenohTls,
};
pub use error::TransportError;
pub use heartbeat::{Heartbeat, ERROR_GAP, HEARTBEAT_EVERY};
pub use iox::StaleCleanup;

use iox::{IoxNode, IoxPublisher, IoxSubscriber};
use reject::{RejectCounter, Rejection, Rejections};

/// An open transport: one zenoh session, plus one iceoryx2 node with the iceoryx2 data plane.
/// Cheap to clone (shared).
#[derive(Clone)]
pub struct Transport {
    inner: Arc<Inner>,
}

struct Inner {
    config: TransportConfig,
    member: Member,
    rejections: Arc<Rejections>,
    // Field order = drop order: iceoryx2 ports live in handles that hold this `Inner`.
    iox: Option<IoxNode>,
    session: zenoh::Session,
}

impl Transport {
    /// Validates the configuration and opens the zenoh session (and the iceoryx2 node).
    pub fn open(config: TransportConfig) -> Result<Self, TransportError> {
        config.validate()?;
        let session = zenoh_impl::open(&config.zenoh, config.max_message_bytes)?;
        let iox = match config.data_plane {
            DataPlane::Zenoh => None,
            DataPlane::Iceoryx2 => Some(IoxNode::open(
                &config.run,
                config.sender,
                &config.iceoryx2,
                config.publish_timeout(),
            )?),
        };
        let member = Member {
            sender: config.sender,
            instance: random_instance(),
        };
        Ok(Self {
            inner: Arc::new(Inner {
                config,
                member,
                rejections: Arc::new(Rejections::default()),
                iox,
                session,
            }),
        })
    }

    /// The run.
    pub fn run(&self) -> &RunId {
        &self.inner.config.run
    }

    /// Who this process is.
    pub fn sender(&self) -> SenderId {
        self.inner.config.sender
    }

    /// This process as a liveliness member (sender + incarnation).
    pub fn member(&self) -> Member {
        self.inner.member
    }

    /// The configuration in force.
    pub fn config(&self) -> &TransportConfig {
        &self.inner.config
    }

    /// Messages rejected on receive by any subscriber of this transport so far.
    pub fn rejected_count(&self) -> u64 {
        self.inner.rejections.total()
    }

    /// The newest of those rejections in words (topic, source, why); empty before the first.
    pub fn last_rejection(&self) -> String {
        self.inner.rejections.last()
    }

    /// Removes the resources of crashed processes (iceoryx2 dead nodes). A no-op on the zenoh
    /// data plane (zenoh closes a dead peer's link itself).
    pub fn cleanup_stale(&self) -> StaleCleanup {
        self.inner
            .iox
            .as_ref()
            .map(IoxNode::cleanup_stale)
            .unwrap_or_default()
    }

    fn iox_for<M>(&self, topic: &Topic<M>) -> Option<&IoxNode> {
        match topic.plane() {
            Plane::Data => self.inner.iox.as_ref(),
            Plane::Telemetry => None,
        }
    }

    /// A publisher for a reliable or best-effort topic (not a wildcard).
    pub fn publisher<M: Body>(&self, topic: &Topic<M>) -> Result<Publisher<M>, TransportError> {
        self.publisher_with(topic, zenoh_impl::Congestion::ByDelivery)
    }

    /// A publisher for a reliable topic whose every message supersedes the previous one and is
    /// repeated by its publisher (acknowledgements: cumulative, and the learner sends every
    /// live actor its acknowledgement again on each metrics tick). Over zenoh a message is
    /// dropped for a subscriber whose queue stays full (congestion control `Drop`) instead of
    /// holding up the publication for the link's `wait_before_close`, so a subscriber that
    /// never reads (a hung or hostile client) cannot stall the publisher; the links stay
    /// reliable, so a subscriber that keeps up loses nothing. With the iceoryx2 data plane the
    /// same as [`Transport::publisher`] (one machine's processes, no router in between).
    pub fn dropping_publisher<M: Body>(
        &self,
        topic: &Topic<M>,
    ) -> Result<Publisher<M>, TransportError> {
        self.publisher_with(topic, zenoh_impl::Congestion::Drop)
    }

    fn publisher_with<M: Body>(
        &self,
        topic: &Topic<M>,
        congestion: zenoh_impl::Congestion,
    ) -> Result<Publisher<M>, TransportError> {
        check_publishable(topic)?;
        if topic.delivery() == Delivery::Latest {
            return Err(wrong_delivery(topic, "Transport::latest_publisher"));
        }
        let backend = match self.iox_for(topic) {
            Some(node) => PubBackend::Iox(node.publisher(
                topic.service_name(),
                topic.key_expr(),
                topic.delivery(),
                topic.fanout(),
            )?),
            None => PubBackend::Zenoh(zenoh_impl::declare_publisher(
                &self.inner.session,
                topic.key_expr(),
                topic.delivery(),
                topic.fanout(),
                congestion,
            )?),
        };
        Ok(Publisher {
            stamp: Stamp::new(self),
            topic: topic.clone(),
            backend,
        })
    }

    /// A subscriber for a reliable or best-effort topic (wildcards allowed on many-to-one
    /// topics).
    pub fn subscriber<M: Body>(&self, topic: &Topic<M>) -> Result<Subscriber<M>, TransportError> {
        if topic.delivery() == Delivery::Latest {
            return Err(wrong_delivery(topic, "Transport::latest_subscriber"));
        }
        let backend = match self.iox_for(topic) {
            Some(node) => {
                let key = (!topic.is_wildcard()).then(|| topic.key_expr());
                SubBackend::Iox(Box::new(node.subscriber(
                    topic.service_name(),
                    key,
                    topic.delivery(),
                    topic.fanout(),
                )?))
            }
            None => SubBackend::Zenoh(zenoh_impl::declare_subscriber(
                &self.inner.session,
                topic.key_expr(),
                self.inner.config.subscriber_queue,
                SUBSCRIBER_QUEUE_BYTES,
            )?),
        };
        Ok(Subscriber {
            rx: Receiver::new(self, topic.key_expr()),
            backend,
            _topic: topic.clone(),
        })
    }

    /// The publisher of a latest-value topic (weights, control): subscribers that join later
    /// receive the last published value at once.
    pub fn latest_publisher<M: Body>(
        &self,
        topic: &Topic<M>,
    ) -> Result<LatestPublisher<M>, TransportError> {
        check_publishable(topic)?;
        if topic.delivery() != Delivery::Latest {
            return Err(wrong_delivery(topic, "Transport::publisher"));
        }
        let backend = match self.iox_for(topic) {
            Some(node) => LatestPubBackend::Iox(node.publisher(
                topic.service_name(),
                topic.key_expr(),
                topic.delivery(),
                topic.fanout(),
            )?),
            None => LatestPubBackend::Zenoh(zenoh_impl::LatestPublisher::declare(
                &self.inner.session,
                topic.key_expr(),
                topic.delivery(),
                topic.fanout(),
            )?),
        };
        Ok(LatestPublisher {
            stamp: Stamp::new(self),
            topic: topic.clone(),
            backend,
        })
    }

    /// A subscriber of a latest-value topic; see [`LatestSubscriber`].
    pub fn latest_subscriber<M: Body>(
        &self,
        topic: &Topic<M>,
    ) -> Result<LatestSubscriber<M>, TransportError> {
        if topic.delivery() != Delivery::Latest {
            return Err(wrong_delivery(topic, "Transport::subscriber"));
        }
        let rx = Receiver::new(self, topic.key_expr());
        let slot = Arc::new(Slot::default());
        let backend = match self.iox_for(topic) {
            Some(node) => LatestSubBackend::Iox(Box::new(node.subscriber(
                topic.service_name(),
                Some(topic.key_expr()),
                topic.delivery(),
                topic.fanout(),
            )?)),
            None => {
                let (live_rx, live_slot) = (rx.clone(), Arc::clone(&slot));
                let (init_rx, init_slot) = (rx.clone(), Arc::clone(&slot));
                LatestSubBackend::Zenoh {
                    _subscriber: zenoh_impl::LatestSubscriber::declare(
                        &self.inner.session,
                        topic.key_expr(),
                        move |bytes, source| {
                            if let Some(m) = live_rx.accept::<M>(bytes, source) {
                                live_slot.set(m, true);
                            }
                        },
                        move |bytes, source| {
                            if let Some(m) = init_rx.accept::<M>(bytes, source) {
                                init_slot.set(m, false);
                            }
                        },
                    )?,
                }
            }
        };
        Ok(LatestSubscriber {
            rx,
            slot,
            seen: AtomicU64::new(0),
            backend,
            _topic: topic.clone(),
        })
    }

    /// Declares this process alive (`fsrl/<run>/alive/<role>/<index>/<instance>`) until the
    /// token is dropped.
    pub fn declare_alive(&self) -> Result<AliveToken, TransportError> {
        let key = keys::alive(self.run(), self.inner.member);
        let token = zenoh_impl::declare_token(&self.inner.session, &key)?;
        Ok(AliveToken {
            member: self.inner.member,
            _token: token,
        })
    }

    /// Watches membership: first a `Joined` for every member alive now, then joins and leaves.
    pub fn watch_alive(&self) -> Result<AliveWatcher, TransportError> {
        self.watch_alive_of(self.run())
    }

    /// [`Transport::watch_alive`] for the members of another run (a tool watching several
    /// runs, such as `fsrl dashboard` without `--run`).
    pub fn watch_alive_of(&self, run: &RunId) -> Result<AliveWatcher, TransportError> {
        let queue = zenoh_impl::watch_liveliness(&self.inner.session, &keys::all_alive(run))?;
        Ok(AliveWatcher {
            run: run.clone(),
            queue,
            state: Mutex::new(WatcherState::default()),
            _transport: self.clone(),
        })
    }

    /// The members alive now (a query that waits up to `timeout` for answers).
    pub fn alive_members(&self, timeout: Duration) -> Result<Vec<Member>, TransportError> {
        let keys =
            zenoh_impl::alive_keys(&self.inner.session, &keys::all_alive(self.run()), timeout)?;
        let mut members: Vec<Member> = keys
            .iter()
            .filter_map(|k| keys::parse_alive(self.run(), k).ok())
            .collect();
        members.sort();
        members.dedup();
        Ok(members)
    }
}

/// Payload bytes a zenoh subscriber queues at most (besides `subscriber_queue` messages):
/// 1024 queued 16 MiB messages would be 16 GiB; this keeps a flood to 64 MiB per subscriber.
/// The sender waits meanwhile (reliable topics) or drops (best effort).
pub const SUBSCRIBER_QUEUE_BYTES: usize = 64 << 20;

fn check_publishable<M>(topic: &Topic<M>) -> Result<(), TransportError> {
    if topic.is_wildcard() {
        Err(TransportError::WildcardPublish {
            topic: topic.key_expr().to_string(),
        })
    } else {
        Ok(())
    }
}

fn wrong_delivery<M>(topic: &Topic<M>, use_instead: &'static str) -> TransportError {
    TransportError::WrongDelivery {
        topic: topic.key_expr().to_string(),
        delivery: topic.delivery(),
        use_instead,
    }
}

fn random_instance() -> u64 {
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    h.write_u128(now);
    h.finish()
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Header stamping and encoding shared by publishers.
struct Stamp {
    transport: Transport,
    seq: AtomicU64,
    last_len: AtomicUsize,
    /// Encode buffer reused by the iceoryx2 path for messages without a hand-written codec,
    /// which it copies into shared memory (zenoh takes ownership of a fresh buffer instead).
    scratch: Mutex<Vec<u8>>,
}

impl Stamp {
    fn new(t: &Transport) -> Self {
        Self {
            transport: t.clone(),
            seq: AtomicU64::new(0),
            last_len: AtomicUsize::new(256),
            scratch: Mutex::new(Vec::new()),
        }
    }

    /// The next header: sequence number +1 per call, `policy_version` as given.
    fn header<M: Body>(&self, policy_version: u64) -> proto::Header {
        let seq = self.seq.fetch_add(1, Ordering::Relaxed);
        proto::Header::new::<M>(
            self.transport.run().clone(),
            self.transport.sender(),
            seq,
            policy_version,
        )
    }

    /// Encodes and sends over iceoryx2: straight into the shared-memory sample where the
    /// message has a hand-written codec (episode batches), else into the reused scratch buffer,
    /// which is then copied into the sample.
    fn send_iox<M: Body>(
        &self,
        header: &proto::Header,
        body: &M,
        publisher: &IoxPublisher,
    ) -> Result<usize, TransportError> {
        let limit = self.transport.inner.config.max_message_bytes;
        if let Some(prepared) = proto::prepare(header, body, limit)? {
            return publisher.send_prepared(&prepared);
        }
        let mut buf = lock(&self.scratch);
        proto::encode_into(header, body, &mut buf, limit)?;
        publisher.send(&buf)
    }

    fn encode_header<M: Body>(
        &self,
        header: &proto::Header,
        body: &M,
    ) -> Result<Vec<u8>, TransportError> {
        let mut buf = Vec::with_capacity(self.last_len.load(Ordering::Relaxed) + 64);
        proto::encode_into(
            header,
            body,
            &mut buf,
            self.transport.inner.config.max_message_bytes,
        )?;
        self.last_len.store(buf.len(), Ordering::Relaxed);
        Ok(buf)
    }
}

enum PubBackend {
    Zenoh(zenoh::pubsub::Publisher<'static>),
    Iox(IoxPublisher),
}

/// Publisher of a reliable or best-effort topic; see [`Transport::publisher`].
pub struct Publisher<M> {
    stamp: Stamp,
    topic: Topic<M>,
    backend: PubBackend,
}

impl<M: Body> Publisher<M> {
    /// Stamps a header (sequence number +1 per call, `policy_version` as given), encodes and
    /// sends `body`. Returns the sequence number. On a reliable topic this blocks while a
    /// receiver's queue is full (up to the configured timeout).
    pub fn publish(&self, policy_version: u64, body: &M) -> Result<u64, TransportError> {
        let header = self.stamp.header::<M>(policy_version);
        self.send_encoded(&header, body)?;
        Ok(header.seq)
    }

    /// Sends a message with its own header (e.g. re-sending an unacknowledged episode with its
    /// original sequence number).
    pub fn publish_message(&self, message: &Message<M>) -> Result<(), TransportError> {
        self.send_encoded(&message.header, &message.body)
    }

    fn send_encoded(&self, header: &proto::Header, body: &M) -> Result<(), TransportError> {
        match &self.backend {
            PubBackend::Zenoh(p) => zenoh_impl::put(p, self.stamp.encode_header(header, body)?),
            PubBackend::Iox(p) => self.stamp.send_iox(header, body, p).map(|_| ()),
        }
    }

    /// Sends pre-encoded bytes as they are (no validation). For tests and bridges only.
    #[doc(hidden)]
    pub fn publish_raw(&self, bytes: Vec<u8>) -> Result<(), TransportError> {
        self.send(bytes)
    }

    fn send(&self, bytes: Vec<u8>) -> Result<(), TransportError> {
        match &self.backend {
            PubBackend::Zenoh(p) => zenoh_impl::put(p, bytes),
            PubBackend::Iox(p) => p.send(&bytes).map(|_| ()),
        }
    }

    /// Whether at least one subscriber of this topic is known to exist.
    pub fn has_subscribers(&self) -> Result<bool, TransportError> {
        match &self.backend {
            PubBackend::Zenoh(p) => zenoh_impl::has_subscribers(p),
            PubBackend::Iox(p) => Ok(p.subscriber_count() > 0),
        }
    }

    /// Waits up to `timeout` until a subscriber exists (e.g. an actor waiting for the
    /// learner before publishing). Returns whether one does.
    pub fn wait_for_subscribers(&self, timeout: Duration) -> Result<bool, TransportError> {
        wait_until(timeout, || self.has_subscribers())
    }

    /// The topic.
    pub fn topic(&self) -> &Topic<M> {
        &self.topic
    }
}

/// Decoding + rejection accounting shared by subscribers.
#[derive(Clone)]
struct Receiver {
    /// The run a message must be of: this transport's, or for a subscription to every run
    /// (`fsrl/*/…`, [`keys::every_run_metrics`]) the run of the key it came on.
    run: Option<RunId>,
    limit: usize,
    rejected: RejectCounter,
    /// For a subscription to a family of per-sender keys (`…/transitions/*`,
    /// `…/metrics/**`): the key each sender must publish under.
    sender_keys: Option<SenderKeys>,
    /// A topic only the learner publishes (weights, control, acks): a message whose header
    /// names another role is rejected (a rogue peer or a confused client, whatever its
    /// version: a weights message at version 10⁶ from an actor never reaches the evaluator).
    learner_only: bool,
}

/// Whether `key` is a topic of `run` that only the learner publishes: the weights, the
/// control, an actor's acknowledgements.
fn learner_only(run: &RunId, key: &str) -> bool {
    let ack = keys::ack(run, 0);
    let ack_family = ack.key_expr().strip_suffix('0').unwrap_or(ack.key_expr());
    key == keys::weights(run).key_expr()
        || key == keys::control(run).key_expr()
        || key.starts_with(ack_family)
}

/// The concrete key of a sender within a wildcard family: `<prefix><index>` (`…/*`) or
/// `<prefix><role>/<index>` (`…/**`), as [`proto::keys`] builds them.
#[derive(Clone)]
enum SenderKeys {
    /// `<prefix><index>`, published only by `role` (transitions: actors; eval: evaluators).
    Index(String, Option<proto::Role>),
    RoleIndex(String),
}

impl SenderKeys {
    fn of(key_expr: &str) -> Option<Self> {
        if let Some(prefix) = key_expr.strip_suffix("**") {
            Some(SenderKeys::RoleIndex(prefix.to_string()))
        } else {
            let prefix = key_expr.strip_suffix('*')?;
            let role = if prefix.ends_with("/transitions/") {
                Some(proto::Role::Actor)
            } else if prefix.ends_with("/eval/") {
                Some(proto::Role::Evaluator)
            } else {
                None
            };
            Some(SenderKeys::Index(prefix.to_string(), role))
        }
    }

    fn matches(&self, key: &str, sender: proto::SenderId) -> bool {
        // A subscription to every run: the prefix with the key's own run in place of `*`.
        fn concrete<'a>(p: &'a str, key: &str) -> Option<std::borrow::Cow<'a, str>> {
            let rest = p
                .strip_prefix(keys::ROOT)
                .and_then(|r| r.strip_prefix('/'))
                .and_then(|r| r.strip_prefix(keys::EVERY_RUN))
                .and_then(|r| r.strip_prefix('/'));
            match rest {
                Some(rest) => {
                    keys::run_of_key(key).map(|run| format!("{}/{run}/{rest}", keys::ROOT).into())
                }
                None => Some(p.into()),
            }
        }
        match self {
            SenderKeys::Index(p, role) => {
                concrete(p, key)
                    .is_some_and(|p| key.strip_prefix(&*p) == Some(&*sender.index.to_string()))
                    && role.is_none_or(|r| r == sender.role)
            }
            SenderKeys::RoleIndex(p) => concrete(p, key).is_some_and(|p| {
                key.strip_prefix(&*p)
                    .and_then(|t| t.split_once('/'))
                    .is_some_and(|(role, index)| {
                        role == sender.role.to_string() && index == sender.index.to_string()
                    })
            }),
        }
    }
}

impl Receiver {
    fn new(t: &Transport, key: &str) -> Self {
        let every_run = key.starts_with(&format!("{}/{}/", keys::ROOT, keys::EVERY_RUN));
        Self {
            run: (!every_run).then(|| t.run().clone()),
            limit: t.inner.config.max_message_bytes,
            rejected: RejectCounter::new(Arc::clone(&t.inner.rejections), key),
            sender_keys: SenderKeys::of(key),
            learner_only: learner_only(t.run(), key),
        }
    }

    /// Decodes and checks one message; `source` (who sent it) is formatted only when the
    /// message is rejected.
    fn accept<M: Body>(&self, bytes: &[u8], source: &dyn fmt::Display) -> Option<Message<M>> {
        self.accept_of(bytes, source, None)
    }

    /// [`Receiver::accept`]; `key`: the zenoh key the message came on, which names the run a
    /// subscription to every run requires (without it such a message is refused).
    fn accept_of<M: Body>(
        &self,
        bytes: &[u8],
        source: &dyn fmt::Display,
        key: Option<&str>,
    ) -> Option<Message<M>> {
        let run_ok = |run: &RunId| match &self.run {
            Some(own) => run == own,
            None => key.and_then(keys::run_of_key).as_ref() == Some(run),
        };
        let why = match proto::decode_with_limit::<M>(bytes, self.limit) {
            Ok(m) if run_ok(&m.header.run) => {
                if self.learner_only && m.header.sender.role != proto::Role::Learner {
                    Rejection::WrongSender(m.header.sender.to_string())
                } else {
                    return Some(m);
                }
            }
            Ok(m) => Rejection::WrongRun(m.header.run.to_string()),
            Err(e) => Rejection::Decode(e),
        };
        self.rejected.reject(source, &why);
        None
    }

    /// [`Receiver::accept`] for a message that arrived on zenoh key `key`: within a family of
    /// per-sender keys the header's sender must be the key's (the router's access control
    /// binds keys to credentials, so the header cannot claim another sender).
    fn accept_keyed<M: Body>(&self, bytes: &[u8], key: &str) -> Option<Message<M>> {
        let m = self.accept_of::<M>(bytes, &key, Some(key))?;
        match &self.sender_keys {
            Some(k) if !k.matches(key, m.header.sender) => {
                self.rejected
                    .reject(&key, &Rejection::WrongSender(m.header.sender.to_string()));
                None
            }
            _ => Some(m),
        }
    }
}

enum SubBackend {
    Zenoh(zenoh_impl::SampleQueue),
    Iox(Box<IoxSubscriber>),
}

/// Subscriber of a reliable or best-effort topic; see [`Transport::subscriber`].
pub struct Subscriber<M> {
    rx: Receiver,
    backend: SubBackend,
    _topic: Topic<M>,
}

impl<M: Body> Subscriber<M> {
    /// The next valid message, waiting up to `timeout`. Invalid messages are counted and
    /// skipped.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Option<Message<M>>, TransportError> {
        let deadline = Instant::now() + timeout;
        match &self.backend {
            SubBackend::Zenoh(q) => loop {
                let remaining = deadline.saturating_duration_since(Instant::now());
                let sample = q
                    .recv_timeout(remaining)
                    .map_err(error::zenoh_err("receive"))?;
                let Some(sample) = sample else {
                    return Ok(None);
                };
                if let Some(m) =
                    zenoh_impl::with_payload_key(&sample, |b, k| self.rx.accept_keyed(b, k))
                {
                    return Ok(Some(m));
                }
            },
            SubBackend::Iox(s) => s.recv_until(deadline, |b, src| self.rx.accept(b, src)),
        }
    }

    /// The next valid message if one is queued, without waiting.
    pub fn try_recv(&self) -> Result<Option<Message<M>>, TransportError> {
        match &self.backend {
            SubBackend::Zenoh(q) => {
                while let Some(sample) = q.try_recv().map_err(error::zenoh_err("receive"))? {
                    if let Some(m) =
                        zenoh_impl::with_payload_key(&sample, |b, k| self.rx.accept_keyed(b, k))
                    {
                        return Ok(Some(m));
                    }
                }
                Ok(None)
            }
            SubBackend::Iox(s) => {
                while let Some(r) = s.try_take(|b, src| self.rx.accept(b, src))? {
                    if r.is_some() {
                        return Ok(r);
                    }
                }
                Ok(None)
            }
        }
    }

    /// Hands the next message's raw bytes to `f` without decoding (zero-copy from shared
    /// memory with iceoryx2). For benchmarks and bridges only.
    #[doc(hidden)]
    pub fn recv_bytes_timeout<R>(
        &self,
        timeout: Duration,
        mut f: impl FnMut(&[u8]) -> R,
    ) -> Result<Option<R>, TransportError> {
        let deadline = Instant::now() + timeout;
        match &self.backend {
            SubBackend::Zenoh(q) => {
                let remaining = deadline.saturating_duration_since(Instant::now());
                let sample = q
                    .recv_timeout(remaining)
                    .map_err(error::zenoh_err("receive"))?;
                Ok(sample.map(|s| zenoh_impl::with_payload(&s, |b, _| f(b))))
            }
            SubBackend::Iox(s) => s.recv_until(deadline, |b, _| Some(f(b))),
        }
    }

    /// Messages this subscriber rejected (malformed, other protocol version, other run).
    pub fn rejected_count(&self) -> u64 {
        self.rx.rejected.count()
    }
}

enum LatestPubBackend {
    Zenoh(zenoh_impl::LatestPublisher),
    Iox(IoxPublisher),
}

/// Publisher of a latest-value topic; see [`Transport::latest_publisher`].
pub struct LatestPublisher<M> {
    stamp: Stamp,
    topic: Topic<M>,
    backend: LatestPubBackend,
}

impl<M: Body> LatestPublisher<M> {
    /// Publishes a new current value; returns its sequence number.
    pub fn publish(&self, policy_version: u64, body: &M) -> Result<u64, TransportError> {
        let header = self.stamp.header::<M>(policy_version);
        match &self.backend {
            LatestPubBackend::Zenoh(p) => p.put(self.stamp.encode_header(&header, body)?)?,
            LatestPubBackend::Iox(p) => {
                self.stamp.send_iox(&header, body, p)?;
            }
        }
        Ok(header.seq)
    }

    /// Sends the current value again, byte for byte (same header: a subscriber that has it
    /// sees nothing new). Over zenoh a value is dropped for a subscriber that does not keep up
    /// (congestion control `Drop`, so that one that never reads cannot stall the publisher); a
    /// publisher that has nothing newer to send repeats its current value now and then so that
    /// the last one reaches everyone. Nothing to do with iceoryx2 (no drops; the service keeps
    /// the last value). Returns whether a value was sent.
    pub fn republish(&self) -> Result<bool, TransportError> {
        match &self.backend {
            LatestPubBackend::Zenoh(p) => p.republish(),
            LatestPubBackend::Iox(_) => Ok(false),
        }
    }

    /// Whether at least one subscriber of this topic is known to exist.
    pub fn has_subscribers(&self) -> Result<bool, TransportError> {
        match &self.backend {
            LatestPubBackend::Zenoh(p) => p.has_subscribers(),
            LatestPubBackend::Iox(p) => Ok(p.subscriber_count() > 0),
        }
    }

    /// Waits up to `timeout` until a subscriber exists. Returns whether one does.
    pub fn wait_for_subscribers(&self, timeout: Duration) -> Result<bool, TransportError> {
        wait_until(timeout, || self.has_subscribers())
    }

    /// The topic.
    pub fn topic(&self) -> &Topic<M> {
        &self.topic
    }
}

/// Polls `cond` every millisecond until it holds or `timeout` passes.
fn wait_until(
    timeout: Duration,
    mut cond: impl FnMut() -> Result<bool, TransportError>,
) -> Result<bool, TransportError> {
    let deadline = Instant::now() + timeout;
    loop {
        if cond()? {
            return Ok(true);
        }
        if Instant::now() >= deadline {
            return Ok(false);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[derive(Default)]
struct SlotState<M> {
    current: Option<Arc<Message<M>>>,
    generation: u64,
    live_seen: bool,
}

struct Slot<M> {
    state: Mutex<SlotState<M>>,
    changed: Condvar,
}

impl<M> Default for Slot<M> {
    fn default() -> Self {
        Self {
            state: Mutex::new(SlotState {
                current: None,
                generation: 0,
                live_seen: false,
            }),
            changed: Condvar::new(),
        }
    }
}

impl<M> Slot<M> {
    /// A live sample always wins; the initial (queried) value only if nothing live arrived.
    fn set(&self, m: Message<M>, live: bool) {
        let mut s = lock(&self.state);
        if !live && s.live_seen {
            return;
        }
        // The same message twice (queried and live, or queried twice) is one update.
        if s.current.as_ref().is_some_and(|c| c.header == m.header) {
            s.live_seen |= live;
            return;
        }
        s.live_seen |= live;
        s.current = Some(Arc::new(m));
        s.generation += 1;
        self.changed.notify_all();
    }
}

enum LatestSubBackend {
    /// The zenoh callbacks fill the slot; the handle only keeps them declared.
    Zenoh {
        _subscriber: zenoh_impl::LatestSubscriber,
    },
    Iox(Box<IoxSubscriber>),
}

/// Subscriber of a latest-value topic (weights, control). Keeps only the newest value; a
/// subscriber created after the value was published gets it at once.
pub struct LatestSubscriber<M> {
    rx: Receiver,
    slot: Arc<Slot<M>>,
    seen: AtomicU64,
    backend: LatestSubBackend,
    _topic: Topic<M>,
}

impl<M: Body> LatestSubscriber<M> {
    fn pump(&self) -> Result<(), TransportError> {
        if let LatestSubBackend::Iox(s) = &self.backend {
            while let Some(r) = s.try_take(|b, src| self.rx.accept::<M>(b, src))? {
                if let Some(m) = r {
                    self.slot.set(m, true);
                }
            }
        }
        Ok(())
    }

    /// The newest value received so far, without waiting.
    pub fn latest(&self) -> Result<Option<Arc<Message<M>>>, TransportError> {
        self.pump()?;
        Ok(lock(&self.slot.state).current.clone())
    }

    /// Waits up to `timeout` for a value newer than the last one returned by `next` (the
    /// first call returns the current value at once if there is one). Intermediate values
    /// may be skipped.
    pub fn next(&self, timeout: Duration) -> Result<Option<Arc<Message<M>>>, TransportError> {
        let deadline = Instant::now() + timeout;
        loop {
            self.pump()?;
            let s = lock(&self.slot.state);
            if s.generation > self.seen.load(Ordering::Relaxed) {
                self.seen.store(s.generation, Ordering::Relaxed);
                return Ok(s.current.clone());
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            match &self.backend {
                LatestSubBackend::Zenoh { .. } => {
                    // Woken by the zenoh callback that fills the slot.
                    let _ = self.slot.changed.wait_timeout(s, remaining);
                }
                LatestSubBackend::Iox(sub) => {
                    drop(s);
                    sub.wait(remaining)?;
                }
            }
        }
    }

    /// Messages this subscriber rejected.
    pub fn rejected_count(&self) -> u64 {
        self.rx.rejected.count()
    }
}

/// Keeps this process listed as alive; dropping it announces the leave.
pub struct AliveToken {
    member: Member,
    _token: zenoh::liveliness::LivelinessToken,
}

impl AliveToken {
    /// The member announced.
    pub fn member(&self) -> Member {
        self.member
    }
}

/// A membership change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AliveEvent {
    /// A process declared itself alive (or was alive when watching started).
    Joined(Member),
    /// A process left (dropped its token, exited or crashed).
    Left(Member),
}

/// Most instances of one sender (role and index) an [`AliveWatcher`] tracks at once: a
/// process restarted before its old token expired, a second process started by mistake. A
/// further instance displaces the oldest one (the newest wins: a `Left` for the old one, a
/// `Joined` for the new), so one client that declares any number of tokens under its own id
/// (the router allows it) costs at most this many members.
pub const MAX_INSTANCES_PER_SENDER: usize = 4;

/// Most distinct senders an [`AliveWatcher`] tracks; tokens of further senders are refused
/// (counted, [`AliveWatcher::refused_count`], and logged at powers of two). Room for every actor
/// id a learner serves ([`proto::control::MAX_CREDIT_GRANTS`]) and as many others.
pub const MAX_ALIVE_SENDERS: usize = 2 * proto::control::MAX_CREDIT_GRANTS;

#[derive(Default)]
struct WatcherState {
    /// Instances alive per sender, oldest first (at most [`MAX_INSTANCES_PER_SENDER`]; at most
    /// [`MAX_ALIVE_SENDERS`] senders).
    members: BTreeMap<SenderId, VecDeque<u64>>,
    pending: VecDeque<AliveEvent>,
    /// Tokens not tracked: of a sender beyond [`MAX_ALIVE_SENDERS`], or an instance displaced
    /// by a newer one of the same sender.
    refused: u64,
}

impl WatcherState {
    fn refuse(&mut self, what: std::fmt::Arguments<'_>) {
        self.refused += 1;
        if self.refused.is_power_of_two() {
            tracing::warn!(
                refused = self.refused,
                "{what} (liveliness tokens not tracked; logged at powers of two of the count)"
            );
        }
    }

    /// A token appeared: the events it causes (none if known or refused).
    fn put(&mut self, member: Member) {
        let (sender, instance) = (member.sender, member.instance);
        if self
            .members
            .get(&sender)
            .is_some_and(|q| q.contains(&instance))
        {
            return;
        }
        if !self.members.contains_key(&sender) && self.members.len() >= MAX_ALIVE_SENDERS {
            self.refuse(format_args!(
                "ignoring {member}: {MAX_ALIVE_SENDERS} senders are alive"
            ));
            return;
        }
        let q = self.members.entry(sender).or_default();
        let displaced = if q.len() >= MAX_INSTANCES_PER_SENDER {
            q.pop_front()
        } else {
            None
        };
        q.push_back(instance);
        if let Some(old) = displaced {
            let old = Member {
                sender,
                instance: old,
            };
            self.pending.push_back(AliveEvent::Left(old));
            self.refuse(format_args!(
                "{member} displaces {old}: at most {MAX_INSTANCES_PER_SENDER} instances of {sender} are tracked, the newest"
            ));
        }
        self.pending.push_back(AliveEvent::Joined(member));
    }

    /// A token went away: a `Left` if it was tracked.
    fn delete(&mut self, member: Member) {
        let Some(q) = self.members.get_mut(&member.sender) else {
            return;
        };
        let Some(at) = q.iter().position(|i| *i == member.instance) else {
            return;
        };
        q.remove(at);
        if q.is_empty() {
            self.members.remove(&member.sender);
        }
        self.pending.push_back(AliveEvent::Left(member));
    }
}

/// Stream of [`AliveEvent`]s; see [`Transport::watch_alive`].
pub struct AliveWatcher {
    run: RunId,
    queue: zenoh_impl::SampleQueue,
    state: Mutex<WatcherState>,
    _transport: Transport,
}

impl AliveWatcher {
    fn absorb(&self, sample: zenoh::sample::Sample, state: &mut WatcherState) {
        let key = sample.key_expr().as_str();
        let member = match keys::parse_alive(&self.run, key) {
            Ok(m) => m,
            Err(e) => {
                tracing::debug!(key, error = %e, "ignoring foreign liveliness token");
                return;
            }
        };
        match sample.kind() {
            SampleKind::Put => state.put(member),
            SampleKind::Delete => state.delete(member),
        }
    }

    fn drain(&self, state: &mut WatcherState) -> Result<(), TransportError> {
        while let Some(s) = self
            .queue
            .try_recv()
            .map_err(error::zenoh_err("liveliness receive"))?
        {
            self.absorb(s, state);
        }
        Ok(())
    }

    /// The next membership change, waiting up to `timeout`.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Option<AliveEvent>, TransportError> {
        let deadline = Instant::now() + timeout;
        loop {
            {
                let mut st = lock(&self.state);
                self.drain(&mut st)?;
                if let Some(e) = st.pending.pop_front() {
                    return Ok(Some(e));
                }
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            let sample = self
                .queue
                .recv_timeout(remaining)
                .map_err(error::zenoh_err("liveliness receive"))?;
            if let Some(s) = sample {
                self.absorb(s, &mut lock(&self.state));
            }
        }
    }

    /// Members alive according to the events received so far (pending events are absorbed
    /// and stay queued for [`AliveWatcher::recv_timeout`]).
    pub fn members(&self) -> Result<Vec<Member>, TransportError> {
        let mut st = lock(&self.state);
        self.drain(&mut st)?;
        Ok(st
            .members
            .iter()
            .flat_map(|(&sender, q)| q.iter().map(move |&instance| Member { sender, instance }))
            .collect())
    }

    /// Liveliness tokens not tracked so far: of a sender beyond [`MAX_ALIVE_SENDERS`], or an
    /// instance displaced by a newer one of its sender ([`MAX_INSTANCES_PER_SENDER`]).
    pub fn refused_count(&self) -> Result<u64, TransportError> {
        let mut st = lock(&self.state);
        self.drain(&mut st)?;
        Ok(st.refused)
    }
}
