//! A subscriber of the weights or the control that never reads (a hung process, a hostile
//! client) cannot stall the publisher: latest-value topics are published with dropping
//! congestion control, so zenoh drops for that subscriber instead of holding up the
//! publication for the link's `wait_before_close`.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use proto::{fixtures, keys, SenderId};
use zenoh::Wait;

use crate::harness::{Backend, Net, WAIT};

/// How long a blocked reliable publication would wait here before zenoh closes the link:
/// longer than the whole test may take, so a publisher that waits on the stuck subscriber fails.
const BLOCK_MS: u64 = 60_000;

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

    // The stuck subscriber: a raw zenoh peer whose callback never returns (until the test
    // ends), so its session stops reading the link and the socket buffers fill up.
    let mut zc = zenoh::Config::default();
    zc.insert_json5("mode", "\"peer\"").unwrap();
    zc.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zc.insert_json5("listen/endpoints", "[]").unwrap();
    zc.insert_json5("connect/endpoints", &format!("[\"{}\"]", net.endpoint))
        .unwrap();
    let stuck = zenoh::open(zc).wait().expect("stuck session");
    let (release, released) = mpsc::channel::<()>();
    let released = Arc::new(Mutex::new(released));
    let entered = Arc::new(AtomicUsize::new(0));
    let mut subs = Vec::new();
    for key in [
        keys::weights(&net.run).key_expr().to_string(),
        keys::control(&net.run).key_expr().to_string(),
    ] {
        let (released, entered) = (Arc::clone(&released), Arc::clone(&entered));
        subs.push(
            stuck
                .declare_subscriber(key)
                .callback(move |_| {
                    entered.fetch_add(1, Ordering::SeqCst);
                    // Blocks until the test drops `release`.
                    let _ = released.lock().map(|r| r.recv());
                })
                .wait()
                .expect("stuck subscriber"),
        );
    }
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
    while entered.load(Ordering::SeqCst) == 0 {
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
    drop(release);
    drop(subs);
    let _ = stuck.close().wait();
}
