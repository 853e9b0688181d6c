//! A subscriber of the weights, the control or an actor's acknowledgements that never reads
//! (a hung process, a hostile client) cannot stall the publisher: latest-value topics are
//! published with dropping congestion control, and so are acks (`Transport::dropping_publisher`:
//! each supersedes the last and the learner repeats them), so zenoh drops for that subscriber
//! instead of holding up the publication for the link's `wait_before_close`.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use proto::{fixtures, keys, Ack, SenderId};
use zenoh::Wait;

use crate::harness::{Backend, Net, WAIT};

/// How long a blocked reliable publication would wait here before zenoh closes the link:
/// longer than the whole test may take, so a publisher that waits on the stuck subscriber fails.
const BLOCK_MS: u64 = 60_000;

/// The stuck subscriber: a raw zenoh peer whose callbacks never return (until it is dropped),
/// so its session stops reading the link and the socket buffers fill up.
///
/// Its hanging callback holds one thread of zenoh's receive runtime, which every session of
/// the process shares (two threads by default): one stuck subscriber at a time ([`Stuck::new`]
/// holds [`ONE_AT_A_TIME`]), or two would leave no thread to deliver to the healthy ones.
struct Stuck {
    _one: MutexGuard<'static, ()>,
    session: zenoh::Session,
    subs: Vec<zenoh::pubsub::Subscriber<()>>,
    release: Option<mpsc::Sender<()>>,
    /// Callbacks entered (the first one hangs).
    entered: Arc<AtomicUsize>,
}

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

impl Stuck {
    fn new(endpoint: &str, keys: &[String]) -> Self {
        let one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
        let mut zc = zenoh::Config::default();
        zc.insert_json5("mode", "\"peer\"").unwrap();
        zc.insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        zc.insert_json5("listen/endpoints", "[]").unwrap();
        zc.insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
            .unwrap();
        let session = zenoh::open(zc).wait().expect("stuck session");
        let (release, released) = mpsc::channel::<()>();
        let released = Arc::new(Mutex::new(released));
        let entered = Arc::new(AtomicUsize::new(0));
        let mut subs = Vec::new();
        for key in keys {
            let (released, entered) = (Arc::clone(&released), Arc::clone(&entered));
            subs.push(
                session
                    .declare_subscriber(key.clone())
                    .callback(move |_| {
                        entered.fetch_add(1, Ordering::SeqCst);
                        // Blocks until the stuck subscriber is dropped.
                        let _ = released.lock().map(|r| r.recv());
                    })
                    .wait()
                    .expect("stuck subscriber"),
            );
        }
        Self {
            _one: one,
            session,
            subs,
            release: Some(release),
            entered,
        }
    }

    fn hanging(&self) -> bool {
        self.entered.load(Ordering::SeqCst) > 0
    }
}

impl Drop for Stuck {
    fn drop(&mut self) {
        drop(self.release.take());
        self.subs.clear();
        let _ = self.session.close().wait();
    }
}

#[test]
fn a_subscriber_that_never_reads_cannot_stall_weights_or_control() {
    let mut net = Net::new(Backend::Zenoh);
    let mut cfg = net.config(SenderId::learner());
    cfg.zenoh.block_timeout_ms = BLOCK_MS;
    let learner = net.open_with(cfg);
    let wp = learner
        .latest_publisher(&keys::weights(&net.run))
        .expect("weights publisher");
    let cp = learner
        .latest_publisher(&keys::control(&net.run))
        .expect("control publisher");

    let stuck = Stuck::new(
        &net.endpoint,
        &[
            keys::weights(&net.run).key_expr().to_string(),
            keys::control(&net.run).key_expr().to_string(),
        ],
    );
    // A healthy actor reads on.
    let mut actor_net_cfg = net.config(SenderId::actor(0));
    actor_net_cfg.zenoh.block_timeout_ms = BLOCK_MS;
    let actor = net.open_with(actor_net_cfg);
    let ws = actor
        .latest_subscriber(&keys::weights(&net.run))
        .expect("weights subscriber");
    let cs = actor
        .latest_subscriber(&keys::control(&net.run))
        .expect("control subscriber");
    assert!(wp.wait_for_subscribers(WAIT).expect("matching"));

    // The stuck subscriber has taken its first value and is hanging in its callback.
    let deadline = Instant::now() + WAIT;
    let mut v = 0;
    while !stuck.hanging() {
        assert!(
            Instant::now() < deadline,
            "the stuck subscriber got nothing"
        );
        v += 1;
        wp.publish(v, &fixtures::sarl_weights(v)).expect("publish");
        std::thread::sleep(Duration::from_millis(20));
    }

    // The learner goes on publishing: ~150 weights of ~0.4 MB each (far more than the stuck
    // link's socket buffers hold) and a control with each, none waiting on the stuck one.
    let t0 = Instant::now();
    let last = v + 150;
    for v in v + 1..=last {
        wp.publish(v, &fixtures::sarl_weights(v))
            .expect("publish weights");
        cp.publish(v, &fixtures::control())
            .expect("publish control");
    }
    let took = t0.elapsed();
    assert!(
        took < Duration::from_secs(20),
        "publishing took {took:?}: the stuck subscriber stalled the publisher"
    );

    // The healthy subscriber ends up with the newest value (repeated by the idle publisher in
    // case the burst itself dropped it on the healthy link).
    let deadline = Instant::now() + WAIT;
    let newest = |s: &transport::LatestSubscriber<proto::Weights>| {
        s.latest()
            .expect("latest")
            .map_or(0, |m| m.header.policy_version)
    };
    while newest(&ws) < last {
        assert!(
            Instant::now() < deadline,
            "the healthy subscriber is at {}, not {last}",
            newest(&ws)
        );
        assert!(wp.republish().expect("republish"));
        assert!(cp.republish().expect("republish"));
        std::thread::sleep(Duration::from_millis(100));
    }
    let deadline = Instant::now() + WAIT;
    while cs
        .latest()
        .expect("latest")
        .map_or(0, |m| m.header.policy_version)
        < last
    {
        assert!(Instant::now() < deadline, "control did not arrive");
        assert!(cp.republish().expect("republish"));
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(ws.rejected_count() + cs.rejected_count(), 0);
    drop(stuck);
}

/// Episode indices an ack of the burst lists besides `acked_below` (valid: at most
/// `proto::control::MAX_ACKED_EPISODES`): ~9 KB per ack, so a burst of a few thousand fills
/// the stuck link's buffers as months of the learner's small acks would.
const ACK_EPISODES: u64 = 1000;

fn ack(acked_below: u64) -> Ack {
    Ack {
        actor: 0,
        acked_below,
        episodes: (acked_below + 1..=acked_below + ACK_EPISODES).collect(),
        learner: 7,
    }
}

#[test]
fn a_subscriber_that_never_reads_cannot_stall_acks() {
    let mut net = Net::new(Backend::Zenoh);
    let mut cfg = net.config(SenderId::learner());
    cfg.zenoh.block_timeout_ms = BLOCK_MS;
    let learner = net.open_with(cfg);
    let ap = learner
        .dropping_publisher(&keys::ack(&net.run, 0))
        .expect("ack publisher");
    let stuck = Stuck::new(
        &net.endpoint,
        &[keys::ack(&net.run, 0).key_expr().to_string()],
    );
    // The actor itself reads on.
    let mut actor_cfg = net.config(SenderId::actor(0));
    actor_cfg.zenoh.block_timeout_ms = BLOCK_MS;
    let actor = net.open_with(actor_cfg);
    let acks = actor
        .subscriber(&keys::ack(&net.run, 0))
        .expect("ack subscriber");
    let mut newest = 0;
    let take = |newest: &mut u64| {
        while let Some(m) = acks.try_recv().expect("receive") {
            *newest = (*newest).max(m.body.acked_below);
        }
    };

    // Both subscribers have taken an ack; the stuck one hangs in its callback.
    let deadline = Instant::now() + WAIT;
    let mut below = 0;
    while !stuck.hanging() || newest == 0 {
        assert!(
            Instant::now() < deadline,
            "no ack arrived (stuck: {}, actor: {newest})",
            stuck.hanging()
        );
        below += 1;
        ap.publish(0, &ack(below)).expect("publish");
        std::thread::sleep(Duration::from_millis(20));
        take(&mut newest);
    }

    // The learner goes on acknowledging: 8000 acks of ~9 KB (~70 MB, far more than the stuck
    // link's socket buffers hold), none waiting on the stuck subscriber. The actor reads
    // between them, as its process does.
    let t0 = Instant::now();
    let last = below + 8000;
    for b in below + 1..=last {
        ap.publish(0, &ack(b)).expect("publish ack");
        if b % 64 == 0 {
            take(&mut newest);
        }
    }
    let took = t0.elapsed();
    assert!(
        took < Duration::from_secs(20),
        "acknowledging took {took:?}: the stuck subscriber stalled the publisher"
    );

    // The actor ends up with the newest ack (repeated, as the learner does on every metrics
    // tick, in case the burst dropped it on the actor's link).
    let deadline = Instant::now() + WAIT;
    take(&mut newest);
    while newest < last {
        assert!(
            Instant::now() < deadline,
            "the actor's newest ack is {newest}, not {last}"
        );
        ap.publish(0, &ack(last)).expect("repeat");
        std::thread::sleep(Duration::from_millis(100));
        take(&mut newest);
    }
    assert_eq!(newest, last);
    assert_eq!(acks.rejected_count(), 0);
    drop(stuck);
}
