//! iceoryx2 data plane: zero-copy `[u8]` publish/subscribe on one machine.
//!
//! Every topic maps to one publish-subscribe service of `[u8]` samples with a `u64` user header
//! (FNV-1a hash of the concrete key expression, so a concrete subscriber of a many-to-one
//! family skips other keys), plus an event service of the same name that publishers notify
//! after each send (stream subscribers poll briefly, then block on it; iceoryx2 makes a notify
//! that finds one still pending free, so a busy stream costs no system call). Latest-value
//! services keep a
//! history of one sample; a new subscriber notifies `<service>/join`, and a thread of the
//! latest-value publisher then calls `update_connections`, which hands the subscriber the
//! current value at once (iceoryx2 delivers history only from the publisher side).

use std::fmt;
use std::mem::MaybeUninit;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use iceoryx2::port::backpressure_strategy::BackpressureStrategy;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo, LoanError, SendError};
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::sample_mut_uninit::SampleMutUninit;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use proto::{Body, Delivery, Fanout, Prepared, RunId, SenderId};

use crate::config::IceoryxConfig;
use crate::error::{iox_err, TransportError};

/// Longest single block on a listener (see [`IoxSubscriber::wait`]).
const MAX_WAIT_SLICE: Duration = Duration::from_millis(10);

/// How long a stream subscriber polls before it blocks (see [`IoxSubscriber::recv_until`]).
const SPIN_BEFORE_WAIT: Duration = Duration::from_micros(50);

/// Thread-safe ports (Send + Sync), so handles can move between threads.
type Svc = ipc_threadsafe::Service;

/// One iceoryx2 node per transport.
pub(crate) struct IoxNode {
    /// Always `Some` until dropped (taken in `Drop` to release it before the final cleanup).
    node: Option<Node<Svc>>,
    config: iceoryx2::config::Config,
    cfg: IceoryxConfig,
    publish_timeout: Duration,
}

/// What the transport's iceoryx2 node cleaned up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StaleCleanup {
    /// Dead nodes whose resources were removed.
    pub cleaned: u64,
    /// Dead nodes that could not be cleaned (permissions, concurrent cleanup).
    pub failed: u64,
}

pub(crate) fn key_hash(key: &str) -> u64 {
    // FNV-1a, 64 bit.
    key.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

fn service_name(name: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(name).map_err(iox_err("service name"))
}

impl IoxNode {
    pub(crate) fn open(
        run: &RunId,
        sender: SenderId,
        cfg: &IceoryxConfig,
        publish_timeout: Duration,
    ) -> Result<Self, TransportError> {
        let mut config = iceoryx2::config::Config::default();
        let prefix = cfg
            .prefix
            .clone()
            .unwrap_or_else(|| format!("fsrl_{}_", run.as_str().replace('.', "_")));
        config.global.prefix = FileName::new(prefix.as_bytes()).map_err(iox_err("prefix"))?;
        if let Some(root) = &cfg.root_path {
            let root = Path::new(root.as_bytes()).map_err(iox_err("root path"))?;
            config.global.set_root_path(&root);
        }
        let name = NodeName::new(&sender.to_string()).map_err(iox_err("node name"))?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Svc>()
            .map_err(iox_err("create node"))?;
        Ok(Self {
            node: Some(node),
            config,
            cfg: cfg.clone(),
            publish_timeout,
        })
    }

    fn node(&self) -> Result<&Node<Svc>, TransportError> {
        self.node.as_ref().ok_or(TransportError::Iceoryx {
            op: "use node",
            detail: "node already released".into(),
        })
    }

    /// Removes the resources of dead nodes (crashed processes) of this run.
    pub(crate) fn cleanup_stale(&self) -> StaleCleanup {
        let Some(node) = &self.node else {
            return StaleCleanup::default();
        };
        let s = node.try_cleanup_dead_nodes();
        StaleCleanup {
            cleaned: s.cleanups,
            failed: s.failed_cleanups,
        }
    }

    fn pubsub(
        &self,
        name: &str,
        delivery: Delivery,
        fanout: Fanout,
    ) -> Result<publish_subscribe::PortFactory<Svc, [u8], u64>, TransportError> {
        let c = &self.cfg;
        let (max_pubs, max_subs) = match fanout {
            Fanout::ManyToOne => (c.max_processes, c.max_collectors),
            Fanout::OneToMany => (2, c.max_processes),
        };
        let (buffer, history, overflow) = match delivery {
            Delivery::Reliable => (c.subscriber_buffer, 0, false),
            Delivery::Latest => (2, 1, true),
            Delivery::BestEffort => (c.subscriber_buffer, 0, true),
        };
        self.node()?
            .service_builder(&service_name(name)?)
            .publish_subscribe::<[u8]>()
            .user_header::<u64>()
            .max_publishers(max_pubs)
            .max_subscribers(max_subs)
            .max_nodes(c.max_processes)
            .subscriber_max_buffer_size(buffer)
            .subscriber_max_borrowed_samples(2)
            .history_size(history)
            .enable_safe_overflow(overflow)
            .open_or_create()
            .map_err(iox_err("open publish-subscribe service"))
    }

    fn events(&self, name: &str) -> Result<event::PortFactory<Svc>, TransportError> {
        let n = self.cfg.max_processes;
        self.node()?
            .service_builder(&service_name(name)?)
            .event()
            .max_notifiers(n)
            .max_listeners(n)
            .max_nodes(n)
            .open_or_create()
            .map_err(iox_err("open event service"))
    }

    pub(crate) fn publisher(
        &self,
        service: &str,
        key: &str,
        delivery: Delivery,
        fanout: Fanout,
    ) -> Result<IoxPublisher, TransportError> {
        let factory = self.pubsub(service, delivery, fanout)?;
        let events = self.events(service)?;
        let builder = factory.publisher_builder().max_loaned_samples(2);
        let builder = match delivery {
            Delivery::Latest => builder
                .initial_max_slice_len(self.cfg.latest_sample_bytes)
                .allocation_strategy(AllocationStrategy::Static),
            Delivery::Reliable | Delivery::BestEffort => builder
                .initial_max_slice_len(self.cfg.initial_sample_bytes)
                .allocation_strategy(AllocationStrategy::PowerOfTwo),
        };
        let builder = match delivery {
            Delivery::Reliable => {
                let timeout = self.publish_timeout;
                builder
                    .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
                    .set_backpressure_handler(move |info: &BackpressureInfo| {
                        backpressure(info, timeout)
                    })
            }
            Delivery::Latest | Delivery::BestEffort => {
                builder.backpressure_strategy(BackpressureStrategy::DiscardData)
            }
        };
        let publisher = Arc::new(builder.create().map_err(iox_err("create publisher"))?);
        let notifier = Arc::new(
            events
                .notifier_builder()
                .create()
                .map_err(iox_err("create notifier"))?,
        );
        // Wake the subscribers, so that they open their side of the connection to this new
        // publisher now rather than at their next receive (see `IoxPublisher::send_with`).
        notifier.notify().map_err(iox_err("notify"))?;
        let joiner = match delivery {
            Delivery::Latest => Some(JoinWatcher::start(
                self.events(&join_service(service))?,
                Arc::clone(&publisher),
                Arc::clone(&notifier),
            )?),
            _ => None,
        };
        Ok(IoxPublisher {
            publisher,
            notifier,
            key_hash: key_hash(key),
            key: key.to_string(),
            reliable: delivery == Delivery::Reliable,
            timeout: self.publish_timeout,
            joiner,
            factory,
            _events: events,
        })
    }

    pub(crate) fn subscriber(
        &self,
        service: &str,
        key: Option<&str>,
        delivery: Delivery,
        fanout: Fanout,
    ) -> Result<IoxSubscriber, TransportError> {
        let factory = self.pubsub(service, delivery, fanout)?;
        let events = self.events(service)?;
        let listener = events
            .listener_builder()
            .create()
            .map_err(iox_err("create listener"))?;
        let builder = match delivery {
            Delivery::Latest => factory
                .subscriber_builder()
                .buffer_size(2)
                .history_request(1),
            Delivery::Reliable | Delivery::BestEffort => factory
                .subscriber_builder()
                .buffer_size(self.cfg.subscriber_buffer),
        };
        let subscriber = builder.create().map_err(iox_err("create subscriber"))?;
        if delivery == Delivery::Latest {
            // Ask the publisher (if any) to hand us its current value now.
            let join = self.events(&join_service(service))?;
            let notifier = join
                .notifier_builder()
                .create()
                .map_err(iox_err("create join notifier"))?;
            notifier.notify().map_err(iox_err("notify join"))?;
        }
        Ok(IoxSubscriber {
            subscriber,
            listener,
            filter: key.map(key_hash),
            _factory: factory,
            _events: events,
        })
    }
}

impl Drop for IoxNode {
    fn drop(&mut self) {
        // Release our node (and with it every service segment we were the last user of).
        drop(self.node.take());
        // iceoryx2 keeps one tiny per-domain segment (`<prefix>…_node.<version>.global_mgmt`,
        // a node-id counter) on purpose. Our domain is per run: when no node of it is left on
        // this machine, remove it too, so shutting down leaves no shared memory behind.
        let mut others = 0usize;
        let listed = Node::<Svc>::list(&self.config, |_| {
            others += 1;
            CallbackProgression::Continue
        });
        if listed.is_ok() && others == 0 {
            // SAFETY: no node of this domain (prefix) exists any more, so no process uses the
            // segment; a process starting concurrently just recreates it (node ids also embed
            // the pid and creation time, so a reset counter cannot make them collide).
            let removed =
                unsafe { iceoryx2::testing::remove_global_mgmt_segment::<Svc>(&self.config) };
            if let Err(e) = removed {
                tracing::debug!(error = ?e, "could not remove the iceoryx2 management segment");
            }
        }
    }
}

fn join_service(service: &str) -> String {
    format!("{service}/join")
}

fn backpressure(info: &BackpressureInfo, timeout: Duration) -> BackpressureAction {
    if info.elapsed_time >= timeout {
        return BackpressureAction::DiscardDataAndFail;
    }
    back_off(info.retries);
    BackpressureAction::Retry
}

/// Waits before the next attempt to deliver: yields the CPU for the first tries, then sleeps
/// briefly while the receiver drains or connects.
fn back_off(retries: u64) {
    if retries > 64 {
        std::thread::sleep(Duration::from_micros(50));
    } else {
        std::thread::yield_now();
    }
}

/// A loaned, not yet written sample of a publisher.
type Loaned = SampleMutUninit<Svc, [MaybeUninit<u8>], u64>;

/// Publisher side of one topic.
pub(crate) struct IoxPublisher {
    publisher: Arc<Publisher<Svc, [u8], u64>>,
    notifier: Arc<Notifier<Svc>>,
    key_hash: u64,
    key: String,
    reliable: bool,
    timeout: Duration,
    joiner: Option<JoinWatcher>,
    factory: publish_subscribe::PortFactory<Svc, [u8], u64>,
    _events: event::PortFactory<Svc>,
}

impl IoxPublisher {
    /// Copies `bytes` into a shared-memory sample, sends it and wakes the subscribers.
    pub(crate) fn send(&self, bytes: &[u8]) -> Result<usize, TransportError> {
        self.send_with(bytes.len(), |sample| Ok(sample.write_from_slice(bytes)))
    }

    /// Encodes `message` straight into a shared-memory sample of its exact size (no encode
    /// buffer, no copy), sends it and wakes the subscribers.
    pub(crate) fn send_prepared<B: Body>(
        &self,
        message: &Prepared<'_, B>,
    ) -> Result<usize, TransportError> {
        self.send_with(message.encoded_len(), |mut sample| {
            message.write(sample.payload_mut())?;
            // SAFETY: `write` succeeded, which means it initialised every byte of the payload.
            Ok(unsafe { sample.assume_init() })
        })
    }

    /// Loans a sample of `len` bytes, lets `fill` initialise it (or fail, and the sample is
    /// returned unsent), sends it and wakes the subscribers; returns how many received it.
    ///
    /// iceoryx2 delivers a sample to a subscriber whose side of the connection to this
    /// publisher is not open yet (a subscriber opens it at its next receive) only while that
    /// connection's queue has room, and drops it silently once the queue is full. On a
    /// reliable topic a sample that reached nobody while subscribers exist is therefore sent
    /// again, with the same back-off and time limit as a full queue.
    fn send_with(
        &self,
        len: usize,
        mut fill: impl FnMut(Loaned) -> Result<SampleMut<Svc, [u8], u64>, TransportError>,
    ) -> Result<usize, TransportError> {
        let start = Instant::now();
        let mut retries = 0u64;
        loop {
            let sample = fill(self.loan(len)?)?;
            let delivered = sample.send().map_err(|e| match e {
                // Our backpressure handler gave up after the publish timeout.
                SendError::UnableToDeliver => self.timed_out(),
                other => iox_err("send")(other),
            })?;
            self.notifier.notify().map_err(iox_err("notify"))?;
            if delivered > 0 || !self.reliable || self.subscriber_count() == 0 {
                return Ok(delivered);
            }
            if start.elapsed() >= self.timeout {
                return Err(self.timed_out());
            }
            retries += 1;
            back_off(retries);
        }
    }

    fn timed_out(&self) -> TransportError {
        TransportError::PublishTimeout {
            topic: self.key.clone(),
            timeout_ms: self.timeout.as_millis() as u64,
        }
    }

    fn loan(&self, len: usize) -> Result<Loaned, TransportError> {
        let mut sample = self.publisher.loan_slice_uninit(len).map_err(|e| match e {
            LoanError::ExceedsMaxLoanSize => TransportError::Iceoryx {
                op: "loan sample",
                detail: format!(
                    "{len} bytes exceed the fixed sample size of {} (raise \
                     iceoryx2.latest_sample_bytes)",
                    self.publisher.initial_max_slice_len()
                ),
            },
            other => iox_err("loan sample")(other),
        })?;
        *sample.user_header_mut() = self.key_hash;
        Ok(sample)
    }
}

impl IoxPublisher {
    /// Subscribers currently attached to the service.
    pub(crate) fn subscriber_count(&self) -> usize {
        self.factory.dynamic_config().number_of_subscribers()
    }
}

impl Drop for IoxPublisher {
    fn drop(&mut self) {
        if let Some(j) = self.joiner.take() {
            j.stop();
        }
    }
}

/// Thread that serves late subscribers of a latest-value topic (see module docs).
struct JoinWatcher {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    _events: event::PortFactory<Svc>,
}

impl JoinWatcher {
    fn start(
        events: event::PortFactory<Svc>,
        publisher: Arc<Publisher<Svc, [u8], u64>>,
        notifier: Arc<Notifier<Svc>>,
    ) -> Result<Self, TransportError> {
        let listener = events
            .listener_builder()
            .create()
            .map_err(iox_err("create join listener"))?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("iox2-latest-join".into())
            .spawn(move || {
                while !stop2.load(Ordering::Relaxed) {
                    let mut joined = false;
                    if let Err(e) =
                        listener.timed_wait(|_| joined = true, Duration::from_millis(20))
                    {
                        tracing::warn!(error = ?e, "iceoryx2 join listener failed");
                        return;
                    }
                    if joined {
                        // Delivers the history sample to the new subscriber, then wakes it.
                        if let Err(e) = publisher.update_connections() {
                            tracing::warn!(error = ?e, "iceoryx2 update_connections failed");
                        }
                        if let Err(e) = notifier.notify() {
                            tracing::warn!(error = ?e, "iceoryx2 notify failed");
                        }
                    }
                }
            })
            .map_err(|e| TransportError::Iceoryx {
                op: "spawn join thread",
                detail: e.to_string(),
            })?;
        Ok(Self {
            stop,
            thread: Some(thread),
            _events: events,
        })
    }

    fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Subscriber side of one topic.
pub(crate) struct IoxSubscriber {
    subscriber: Subscriber<Svc, [u8], u64>,
    listener: Listener<Svc>,
    filter: Option<u64>,
    _factory: publish_subscribe::PortFactory<Svc, [u8], u64>,
    _events: event::PortFactory<Svc>,
}

impl IoxSubscriber {
    /// Takes the next sample of our key, if any, and hands its bytes to `f` (zero-copy, while
    /// the sample is borrowed from shared memory). Returns whether a sample was handed over.
    pub(crate) fn try_take<R>(
        &self,
        mut f: impl FnMut(&[u8], &dyn fmt::Display) -> R,
    ) -> Result<Option<R>, TransportError> {
        loop {
            let Some(sample) = self.subscriber.receive().map_err(iox_err("receive"))? else {
                return Ok(None);
            };
            if let Some(h) = self.filter {
                if *sample.user_header() != h {
                    continue;
                }
            }
            // Formatted only if the message is rejected (not once per message).
            let source = Origin(sample.origin());
            return Ok(Some(f(sample.payload(), &source)));
        }
    }

    /// Blocks until a publisher signals new data or `timeout` passes. Waits at most
    /// [`MAX_WAIT_SLICE`] at a time: callers re-check for samples after every wake-up, so a
    /// missed notification costs at most one slice of latency, never a stall.
    pub(crate) fn wait(&self, timeout: Duration) -> Result<(), TransportError> {
        self.listener
            .timed_wait(|_| {}, timeout.min(MAX_WAIT_SLICE))
            .map_err(iox_err("wait"))?;
        Ok(())
    }

    /// Repeats `try_take` until `f` accepts a sample (returns `Some`) or the deadline passes.
    ///
    /// Polls for up to [`SPIN_BEFORE_WAIT`] (yielding the CPU between polls) before it blocks
    /// on the listener: the next sample of a stream usually follows within microseconds, and
    /// while the subscriber does not block, the publishers' notifications stay pending in
    /// iceoryx2, so a send costs no system call and the receive no wake-up.
    pub(crate) fn recv_until<T>(
        &self,
        deadline: Instant,
        mut f: impl FnMut(&[u8], &dyn fmt::Display) -> Option<T>,
    ) -> Result<Option<T>, TransportError> {
        let mut spin_end = None;
        loop {
            while let Some(r) = self.try_take(&mut f)? {
                if r.is_some() {
                    return Ok(r);
                }
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            if now < *spin_end.get_or_insert(now + SPIN_BEFORE_WAIT) {
                std::thread::yield_now();
                continue;
            }
            self.wait(deadline - now)?;
        }
    }
}

/// The publisher of a received sample, as rejection logs name it.
struct Origin<T>(T);

impl<T: fmt::Debug> fmt::Display for Origin<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "iceoryx2 publisher {:?}", self.0)
    }
}
