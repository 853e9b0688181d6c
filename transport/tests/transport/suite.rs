//! The backend-independent suite; `both_backends!` runs each function for zenoh and iceoryx2.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use proto::{
    fixtures, keys, Ack, Header, Member, Message, Metrics, RunId, SenderId, TransitionBatch,
    PROTOCOL_VERSION,
};
use transport::{AliveEvent, AliveWatcher, Transport, TransportError};

use crate::both_backends;
use crate::harness::{Backend, Net, WAIT};

both_backends!(
    transitions_many_to_one,
    reliable_under_backpressure,
    reliable_to_a_subscriber_that_starts_reading_late,
    latest_value_for_late_joiner,
    latest_value_before_publisher,
    acks_reach_only_their_actor,
    telemetry_topics,
    bad_input_is_counted_and_skipped,
    liveliness_join_and_leave,
    crashed_process_is_detected_and_cleaned,
    api_misuse_is_an_error,
    shared_memory_removed_on_shutdown,
);

fn transitions_many_to_one(b: Backend) {
    let mut net = Net::new(b);
    let learner = net.open(SenderId::learner());
    let sub = learner
        .subscriber(&keys::all_transitions(&net.run))
        .expect("subscriber");
    let actors: Vec<Transport> = (0..3).map(|i| net.open(SenderId::actor(i))).collect();
    let pubs: Vec<_> = actors
        .iter()
        .enumerate()
        .map(|(i, a)| {
            a.publisher(&keys::transitions(&net.run, i as u32))
                .expect("publisher")
        })
        .collect();
    for p in &pubs {
        assert!(p.wait_for_subscribers(WAIT).expect("matching"));
    }
    const N: u64 = 40;
    let mut next_episode = [0u64; 3];
    std::thread::scope(|s| {
        for p in &pubs {
            s.spawn(move || {
                for e in 0..N {
                    let seq = p
                        .publish(7, &fixtures::episode(45, 10, e))
                        .expect("publish");
                    assert_eq!(seq, e);
                }
            });
        }
        for _ in 0..3 * N {
            let m = sub
                .recv_timeout(WAIT)
                .expect("recv")
                .expect("message in time");
            let a = m.header.sender.index as usize;
            assert_eq!(m.header.sender, SenderId::actor(a as u32));
            assert_eq!(m.header.policy_version, 7);
            // Ordered per publisher, nothing lost or duplicated.
            assert_eq!(m.header.seq, next_episode[a]);
            assert_eq!(m.body, fixtures::episode(45, 10, next_episode[a]));
            next_episode[a] += 1;
        }
    });
    assert_eq!(next_episode, [N; 3]);
    assert_eq!(sub.try_recv().expect("try_recv"), None);
    assert_eq!(sub.rejected_count(), 0);
}

fn reliable_under_backpressure(b: Backend) {
    let mut net = Net::new(b);
    let mut cfg = net.config(SenderId::learner());
    cfg.subscriber_queue = 4;
    cfg.iceoryx2.subscriber_buffer = 4;
    let learner = net.open_with(cfg);
    let sub = learner
        .subscriber(&keys::all_transitions(&net.run))
        .expect("subscriber");
    let mut cfg = net.config(SenderId::actor(0));
    cfg.iceoryx2.subscriber_buffer = 4;
    let actor = net.open_with(cfg);
    let p = actor
        .publisher(&keys::transitions(&net.run, 0))
        .expect("publisher");
    assert!(p.wait_for_subscribers(WAIT).expect("matching"));
    const N: u64 = 3000;
    let small = fixtures::episode(2, 1, 0);
    std::thread::scope(|s| {
        s.spawn(|| {
            for _ in 0..N {
                p.publish(0, &small).expect("publish never fails or drops");
            }
        });
        for i in 0..N {
            let m = sub.recv_timeout(WAIT).expect("recv").expect("in time");
            assert_eq!(m.header.seq, i, "lost or reordered");
        }
    });
}

/// A publisher newer than the subscriber fills the subscriber's queue before the subscriber has
/// ever read (with iceoryx2, before the subscriber has opened its side of the connection):
/// the rest waits for room instead of being dropped.
fn reliable_to_a_subscriber_that_starts_reading_late(b: Backend) {
    const BUF: usize = 4;
    const N: u64 = 200;
    let mut net = Net::new(b);
    let mut cfg = net.config(SenderId::learner());
    cfg.subscriber_queue = BUF;
    cfg.iceoryx2.subscriber_buffer = BUF;
    let learner = net.open_with(cfg);
    let sub = learner
        .subscriber(&keys::all_transitions(&net.run))
        .expect("subscriber");
    let mut cfg = net.config(SenderId::actor(0));
    cfg.iceoryx2.subscriber_buffer = BUF;
    let actor = net.open_with(cfg);
    let p = actor
        .publisher(&keys::transitions(&net.run, 0))
        .expect("publisher");
    assert!(p.wait_for_subscribers(WAIT).expect("matching"));
    let small = fixtures::episode(2, 1, 0);
    let (queue_full, done) = (std::sync::mpsc::channel(), std::sync::mpsc::channel());
    std::thread::scope(|s| {
        s.spawn(|| {
            for i in 0..N {
                if i == BUF as u64 {
                    queue_full.0.send(()).expect("signal");
                }
                p.publish(0, &small).expect("publish never fails or drops");
            }
            let _ = done.0.send(());
        });
        // Start reading only when the queue is full and the publisher has either finished
        // (it would have dropped the rest) or has been waiting for room for a while.
        queue_full.1.recv_timeout(WAIT).expect("queue filled");
        let _ = done.1.recv_timeout(Duration::from_millis(300));
        for i in 0..N {
            let m = sub.recv_timeout(WAIT).expect("recv").expect("in time");
            assert_eq!(m.header.seq, i, "lost or reordered");
        }
    });
    assert_eq!(sub.try_recv().expect("try_recv"), None);
}

fn latest_value_for_late_joiner(b: Backend) {
    let mut net = Net::new(b);
    let learner = net.open(SenderId::learner());
    let wp = learner
        .latest_publisher(&keys::weights(&net.run))
        .expect("weights publisher");
    wp.publish(1, &fixtures::sarl_weights(1)).expect("publish");
    wp.publish(2, &fixtures::sarl_weights(2)).expect("publish");

    let actor = net.open(SenderId::actor(0));
    let ws = actor
        .latest_subscriber(&keys::weights(&net.run))
        .expect("weights subscriber");
    let current = ws
        .next(WAIT)
        .expect("next")
        .expect("current weights at once");
    // At once: nothing republishes here, so the value came from the late joiner's query (no
    // bound on the time: a loaded 2-core machine stretches any).
    assert_eq!(current.body.version, 2);
    assert_eq!(current.header.policy_version, 2);
    assert_eq!(current.body, fixtures::sarl_weights(2));
    assert_eq!(
        ws.latest().expect("latest").map(|m| m.body.version),
        Some(2)
    );
    // Nothing newer yet.
    assert!(ws.next(Duration::from_millis(20)).expect("next").is_none());

    wp.publish(3, &fixtures::sarl_weights(3)).expect("publish");
    let newer = ws.next(WAIT).expect("next").expect("update");
    assert_eq!(newer.body.version, 3);

    // Control is latest-value too.
    let cp = learner
        .latest_publisher(&keys::control(&net.run))
        .expect("control publisher");
    cp.publish(3, &fixtures::control()).expect("publish");
    let evaluator = net.open(SenderId::evaluator(0));
    let cs = evaluator
        .latest_subscriber(&keys::control(&net.run))
        .expect("control subscriber");
    let c = cs.next(WAIT).expect("next").expect("control at once");
    assert_eq!(c.body, fixtures::control());
    assert_eq!(ws.rejected_count() + cs.rejected_count(), 0);
}

fn latest_value_before_publisher(b: Backend) {
    let mut net = Net::new(b);
    let learner = net.open(SenderId::learner());
    let actor = net.open(SenderId::actor(0));
    let ws = actor
        .latest_subscriber(&keys::weights(&net.run))
        .expect("weights subscriber");
    assert!(ws.latest().expect("latest").is_none());
    assert!(ws.next(Duration::from_millis(10)).expect("next").is_none());
    let wp = learner
        .latest_publisher(&keys::weights(&net.run))
        .expect("weights publisher");
    assert!(wp.wait_for_subscribers(WAIT).expect("matching"));
    for v in 1..=5 {
        wp.publish(v, &fixtures::sarl_weights(v)).expect("publish");
    }
    // Only the newest matters: wait until version 5 is there.
    let deadline = Instant::now() + WAIT;
    let mut version = 0;
    while version < 5 && Instant::now() < deadline {
        if let Some(m) = ws.next(Duration::from_millis(100)).expect("next") {
            assert!(m.body.version > version, "versions go forward");
            version = m.body.version;
        }
    }
    assert_eq!(version, 5);
}

fn acks_reach_only_their_actor(b: Backend) {
    let mut net = Net::new(b);
    let learner = net.open(SenderId::learner());
    let a1 = net.open(SenderId::actor(1));
    let a2 = net.open(SenderId::actor(2));
    let s1 = a1.subscriber(&keys::ack(&net.run, 1)).expect("sub");
    let s2 = a2.subscriber(&keys::ack(&net.run, 2)).expect("sub");
    let p1 = learner.publisher(&keys::ack(&net.run, 1)).expect("pub");
    let p2 = learner.publisher(&keys::ack(&net.run, 2)).expect("pub");
    assert!(p1.wait_for_subscribers(WAIT).expect("matching"));
    assert!(p2.wait_for_subscribers(WAIT).expect("matching"));
    for i in 0..3 {
        let ack = Ack {
            actor: 1,
            acked_below: i,
            episodes: vec![],
            learner: 1,
        };
        p1.publish(0, &ack).expect("publish");
    }
    let ack2 = Ack {
        actor: 2,
        acked_below: 9,
        episodes: vec![11],
        learner: 1,
    };
    p2.publish(0, &ack2).expect("publish");
    for i in 0..3 {
        let m = s1.recv_timeout(WAIT).expect("recv").expect("in time");
        assert_eq!((m.body.actor, m.body.acked_below), (1, i));
    }
    let m = s2.recv_timeout(WAIT).expect("recv").expect("in time");
    assert_eq!(m.body, ack2);
    assert!(s1.try_recv().expect("try").is_none());
    assert!(s2.try_recv().expect("try").is_none());
}

fn telemetry_topics(b: Backend) {
    let mut net = Net::new(b);
    let monitor = net.open(SenderId::monitor(0));
    let metrics = monitor
        .subscriber(&keys::all_metrics(&net.run))
        .expect("sub");
    let evals = monitor
        .subscriber(&keys::all_eval_reports(&net.run))
        .expect("sub");
    let status = monitor
        .subscriber(&keys::all_status(&net.run))
        .expect("sub");
    let actor = net.open(SenderId::actor(4));
    let evaluator = net.open(SenderId::evaluator(0));
    let mp = actor
        .publisher(&keys::metrics(&net.run, actor.sender()))
        .expect("pub");
    let sp = actor
        .publisher(&keys::status(&net.run, actor.sender()))
        .expect("pub");
    let ep = evaluator
        .publisher(&keys::eval_report(&net.run, 0))
        .expect("pub");
    for p in [mp.wait_for_subscribers(WAIT), sp.wait_for_subscribers(WAIT)] {
        assert!(p.expect("matching"));
    }
    assert!(ep.wait_for_subscribers(WAIT).expect("matching"));
    mp.publish(3, &fixtures::metrics()).expect("publish");
    sp.publish(3, &fixtures::status()).expect("publish");
    ep.publish(9, &fixtures::eval_report()).expect("publish");
    let m: Message<Metrics> = metrics.recv_timeout(WAIT).expect("recv").expect("metrics");
    assert_eq!(m.header.sender, SenderId::actor(4));
    assert_eq!(m.body.values.get("loss"), Some(&0.0125));
    let s = status.recv_timeout(WAIT).expect("recv").expect("status");
    assert_eq!(s.body, fixtures::status());
    let e = evals.recv_timeout(WAIT).expect("recv").expect("eval");
    assert_eq!(e.header.policy_version, 9);
    assert_eq!(e.body.settings.len(), 6);
}

fn bad_input_is_counted_and_skipped(b: Backend) {
    let mut net = Net::new(b);
    let learner = net.open(SenderId::learner());
    let sub = learner
        .subscriber(&keys::all_transitions(&net.run))
        .expect("sub");
    let actor = net.open(SenderId::actor(0));
    let p = actor
        .publisher(&keys::transitions(&net.run, 0))
        .expect("pub");
    assert!(p.wait_for_subscribers(WAIT).expect("matching"));

    let valid = fixtures::episode(45, 10, 1);
    let header = Header::new::<TransitionBatch>(net.run.clone(), actor.sender(), 0, 1);
    let good = proto::encode(&header, &valid).expect("encode");
    // 1. random garbage
    p.publish_raw(b"\xde\xad\xbe\xef not msgpack".to_vec())
        .expect("raw");
    // 2. truncated
    p.publish_raw(good[..good.len() / 2].to_vec()).expect("raw");
    // 3. another protocol version
    let mut future = header.clone();
    future.protocol_version = PROTOCOL_VERSION + 1;
    let bytes = rmp_serde::to_vec_named(&Message {
        header: future,
        body: valid.clone(),
    })
    .expect("serialise");
    p.publish_raw(bytes).expect("raw");
    // 4. NaN in a state
    let mut nan = valid.clone();
    nan.robot_states[3] = f32::NAN;
    let bytes = rmp_serde::to_vec_named(&Message {
        header: header.clone(),
        body: nan,
    })
    .expect("serialise");
    p.publish_raw(bytes).expect("raw");
    // 5. another run
    let mut other = header.clone();
    other.run = RunId::new("someone-else").expect("run id");
    p.publish_raw(proto::encode(&other, &valid).expect("encode"))
        .expect("raw");
    // then a valid one, which must arrive
    p.publish(1, &valid).expect("publish");

    let m = sub
        .recv_timeout(WAIT)
        .expect("recv")
        .expect("valid message");
    assert_eq!(m.body, valid);
    assert_eq!(sub.rejected_count(), 5);
    assert_eq!(learner.rejected_count(), 5);
    assert_eq!(actor.rejected_count(), 0);
}

/// Waits until all of `want` have been seen, in any order (other events are skipped).
fn expect_events(w: &AliveWatcher, want: &[AliveEvent]) {
    let mut missing: Vec<AliveEvent> = want.to_vec();
    let deadline = Instant::now() + WAIT;
    while !missing.is_empty() && Instant::now() < deadline {
        match w.recv_timeout(deadline - Instant::now()).expect("watch") {
            Some(e) => missing.retain(|m| *m != e),
            None => break,
        }
    }
    assert!(missing.is_empty(), "not seen within {WAIT:?}: {missing:?}");
}

fn expect_event(w: &AliveWatcher, want: AliveEvent) {
    expect_events(w, &[want]);
}

fn liveliness_join_and_leave(b: Backend) {
    let mut net = Net::new(b);
    let learner = net.open(SenderId::learner());
    let _learner_alive = learner.declare_alive().expect("token");
    let actor = net.open(SenderId::actor(0));
    let actor_token = actor.declare_alive().expect("token");
    let watcher = learner.watch_alive().expect("watch");
    // Members alive before watching are reported too.
    expect_events(
        &watcher,
        &[
            AliveEvent::Joined(learner.member()),
            AliveEvent::Joined(actor.member()),
        ],
    );
    let evaluator = net.open(SenderId::evaluator(0));
    let eval_token = evaluator.declare_alive().expect("token");
    expect_event(&watcher, AliveEvent::Joined(evaluator.member()));
    let members = learner.alive_members(WAIT).expect("snapshot");
    for m in [learner.member(), actor.member(), evaluator.member()] {
        assert!(members.contains(&m), "{m} missing from {members:?}");
    }
    assert_eq!(watcher.members().expect("members"), {
        let mut v = vec![learner.member(), actor.member(), evaluator.member()];
        v.sort();
        v
    });
    drop(actor_token);
    expect_event(&watcher, AliveEvent::Left(actor.member()));
    // Closing the whole transport (process exit) also leaves.
    drop(eval_token);
    expect_event(&watcher, AliveEvent::Left(evaluator.member()));
    let evaluator2 = net.open(SenderId::evaluator(0));
    let member2 = evaluator2.member();
    assert_ne!(
        member2,
        evaluator.member(),
        "a new incarnation is a new member"
    );
    let token2 = evaluator2.declare_alive().expect("token");
    expect_event(&watcher, AliveEvent::Joined(member2));
    drop(token2);
    drop(evaluator2);
    expect_event(&watcher, AliveEvent::Left(member2));
}

// ---- multi-process: a child that crashes --------------------------------------------------

const CHILD_ENV: &str = "FSRL_TRANSPORT_TEST_CHILD";

/// Not a test of its own: the body of the child process of
/// `crashed_process_is_detected_and_cleaned` (re-executes this test binary).
#[test]
fn child_process() {
    let Ok(spec) = std::env::var(CHILD_ENV) else {
        return;
    };
    // spec = backend;run;prefix;endpoint
    let parts: Vec<&str> = spec.split(';').collect();
    let backend = if parts[0] == "iceoryx2" {
        Backend::Iceoryx2
    } else {
        Backend::Zenoh
    };
    let mut net = Net::new(backend);
    net.run = RunId::new(parts[1]).expect("run");
    net.prefix = parts[2].to_string();
    let mut cfg = net.config(SenderId::actor(9));
    cfg.iceoryx2.max_processes = 2;
    cfg.zenoh.connect = vec![parts[3].to_string()];
    let t = Transport::open(cfg).expect("child transport");
    let _token = t.declare_alive().expect("token");
    let p = t
        .publisher(&keys::transitions(&net.run, 9))
        .expect("child publisher");
    p.publish(0, &fixtures::episode(3, 2, 0)).expect("publish");
    println!("CHILD-READY {}", t.member().instance);
    // Wait to be killed (bounded, in case the parent dies).
    let mut line = String::new();
    let _ = std::io::stdin().read_line(&mut line);
}

struct KillOnDrop(Child);
impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn crashed_process_is_detected_and_cleaned(b: Backend) {
    let mut net = Net::new(b);
    let mut cfg = net.config(SenderId::learner());
    cfg.iceoryx2.max_processes = 2;
    let learner = net.open_with(cfg.clone());
    let watcher = learner.watch_alive().expect("watch");
    let sub = learner
        .subscriber(&keys::all_transitions(&net.run))
        .expect("sub");
    let own = learner
        .publisher(&keys::transitions(&net.run, 0))
        .expect("learner-side publisher takes the second slot");

    let spec = format!(
        "{};{};{};{}",
        if b == Backend::Iceoryx2 {
            "iceoryx2"
        } else {
            "zenoh"
        },
        net.run,
        net.prefix,
        net.endpoint
    );
    let exe = std::env::current_exe().expect("test binary");
    let child = Command::new(exe)
        .args([
            "suite::child_process",
            "--exact",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, spec)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn child");
    let mut child = KillOnDrop(child);
    // Read the child's output on a thread, so that waiting for "ready" is bounded.
    let stdout = child.0.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { return };
            if let Some(pos) = line.find("CHILD-READY ") {
                let _ = tx.send(line[pos + "CHILD-READY ".len()..].trim().to_string());
            }
        }
    });
    let instance = rx
        .recv_timeout(WAIT)
        .ok()
        .and_then(|i| i.parse::<u64>().ok());
    let member = Member {
        sender: SenderId::actor(9),
        instance: instance.expect("child became ready"),
    };
    expect_event(&watcher, AliveEvent::Joined(member));
    let m = sub
        .recv_timeout(WAIT)
        .expect("recv")
        .expect("child's batch");
    assert_eq!(m.header.sender, SenderId::actor(9));

    // Crash: SIGKILL, and reap it (a zombie would still look alive to iceoryx2).
    child.0.kill().expect("kill");
    child.0.wait().expect("reap");
    expect_event(&watcher, AliveEvent::Left(member));

    if b == Backend::Iceoryx2 {
        let cleaned = learner.cleanup_stale();
        assert!(cleaned.cleaned >= 1, "{cleaned:?}");
        // The dead publisher's slot is free again (the service allows 2 publishers).
        let late = net.open_with({
            let mut c = cfg.clone();
            c.sender = SenderId::actor(1);
            c
        });
        let p = late
            .publisher(&keys::transitions(&net.run, 1))
            .expect("slot of the crashed publisher reclaimed");
        p.publish(0, &fixtures::episode(3, 2, 1)).expect("publish");
        let m = sub.recv_timeout(WAIT).expect("recv").expect("batch");
        assert_eq!(m.header.sender, SenderId::actor(1));
        drop(p);
        drop(late);
    }
    drop(own);
    drop(sub);
    drop(watcher);
    drop(learner);
    if b == Backend::Iceoryx2 {
        let left = net.shm_entries();
        assert!(left.is_empty(), "shared memory left behind: {left:?}");
    }
}

fn api_misuse_is_an_error(b: Backend) {
    let mut net = Net::new(b);
    let t = net.open(SenderId::learner());
    assert!(matches!(
        t.publisher(&keys::all_transitions(&net.run)),
        Err(TransportError::WildcardPublish { .. })
    ));
    assert!(matches!(
        t.publisher(&keys::weights(&net.run)),
        Err(TransportError::WrongDelivery { .. })
    ));
    assert!(matches!(
        t.latest_subscriber(&keys::all_transitions(&net.run)),
        Err(TransportError::WrongDelivery { .. })
    ));
    // Invalid bodies are refused at the source.
    let p = t.publisher(&keys::transitions(&net.run, 0)).expect("pub");
    let mut bad = fixtures::episode(3, 2, 0);
    bad.rewards[0] = f32::INFINITY;
    assert!(matches!(
        p.publish(0, &bad),
        Err(TransportError::Encode(proto::EncodeError::Invalid(_)))
    ));
    // Oversized messages too.
    let mut cfg = net.config(SenderId::actor(0));
    cfg.max_message_bytes = 4096;
    cfg.iceoryx2.latest_sample_bytes = 4096;
    let small = net.open_with(cfg);
    let p = small
        .publisher(&keys::transitions(&net.run, 0))
        .expect("pub");
    assert!(matches!(
        p.publish(0, &fixtures::episode(45, 10, 0)),
        Err(TransportError::Encode(proto::EncodeError::Oversized { .. }))
    ));
    // Configuration problems are all reported at once.
    let mut cfg = net.config(SenderId::actor(1));
    cfg.subscriber_queue = 0;
    cfg.iceoryx2.max_processes = 1;
    match Transport::open(cfg) {
        Err(TransportError::Config(msg)) => {
            assert!(
                msg.contains("subscriber_queue") && msg.contains("max_processes"),
                "{msg}"
            )
        }
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("invalid config accepted"),
    }
}

fn shared_memory_removed_on_shutdown(b: Backend) {
    let mut net = Net::new(b);
    {
        let learner = net.open(SenderId::learner());
        let actor = net.open(SenderId::actor(0));
        let sub = learner
            .subscriber(&keys::all_transitions(&net.run))
            .expect("sub");
        let p = actor
            .publisher(&keys::transitions(&net.run, 0))
            .expect("pub");
        let wp = learner
            .latest_publisher(&keys::weights(&net.run))
            .expect("pub");
        wp.publish(1, &fixtures::sarl_weights(1)).expect("publish");
        let ws = actor
            .latest_subscriber(&keys::weights(&net.run))
            .expect("sub");
        assert!(p.wait_for_subscribers(WAIT).expect("matching"));
        p.publish(1, &fixtures::episode(45, 10, 0))
            .expect("publish");
        assert!(sub.recv_timeout(WAIT).expect("recv").is_some());
        assert_eq!(
            ws.next(WAIT).expect("next").map(|m| m.body.version),
            Some(1)
        );
        if b == Backend::Iceoryx2 {
            assert!(!net.shm_entries().is_empty(), "iceoryx2 uses shared memory");
        }
    }
    let left = net.shm_entries();
    assert!(left.is_empty(), "shared memory left behind: {left:?}");
}

/// Over zenoh (where the router binds keys to credentials) a message whose header names
/// another sender than its key is rejected and counted: an actor cannot pass its episodes off
/// as another actor's. iceoryx2 stays on one machine, within one trust domain.
#[test]
fn a_header_naming_another_sender_than_its_key_is_rejected() {
    let mut net = Net::new(Backend::Zenoh);
    let learner = net.open(SenderId::learner());
    let sub = learner
        .subscriber(&keys::all_transitions(&net.run))
        .expect("sub");
    let metrics_sub = learner
        .subscriber(&keys::all_metrics(&net.run))
        .expect("metrics sub");
    let actor = net.open(SenderId::actor(0));
    let p = actor
        .publisher(&keys::transitions(&net.run, 0))
        .expect("pub");
    let m = actor
        .publisher(&keys::metrics(&net.run, SenderId::actor(0)))
        .expect("metrics pub");
    assert!(p.wait_for_subscribers(WAIT).expect("matching"));
    assert!(m.wait_for_subscribers(WAIT).expect("matching"));
    let valid = fixtures::episode(45, 10, 0);
    for claimed in [SenderId::actor(1), SenderId::learner()] {
        let header = Header::new::<TransitionBatch>(net.run.clone(), claimed, 0, 1);
        p.publish_raw(proto::encode(&header, &valid).expect("encode"))
            .expect("raw");
    }
    p.publish(1, &valid).expect("publish");
    let got = sub
        .recv_timeout(WAIT)
        .expect("recv")
        .expect("the honest one");
    assert_eq!(got.header.sender, SenderId::actor(0), "{:?}", got.header);
    assert_eq!(sub.rejected_count(), 2);
    // Metrics are best effort (a loaded machine may drop some): forged and honest ones in
    // rounds until an honest one arrived and two forged ones were rejected; no forged one is
    // ever delivered.
    let deadline = Instant::now() + WAIT;
    let mut honest = 0;
    while (honest == 0 || metrics_sub.rejected_count() < 2) && Instant::now() < deadline {
        for claimed in [SenderId::actor(1), SenderId::learner()] {
            let header = Header::new::<Metrics>(net.run.clone(), claimed, 0, 1);
            m.publish_raw(proto::encode(&header, &Metrics::default()).expect("encode"))
                .expect("raw");
        }
        m.publish(1, &Metrics::default()).expect("publish");
        while let Some(got) = metrics_sub
            .recv_timeout(Duration::from_millis(100))
            .expect("recv")
        {
            assert_eq!(got.header.sender, SenderId::actor(0));
            honest += 1;
        }
    }
    assert!(honest > 0, "no honest metrics arrived");
    assert!(metrics_sub.rejected_count() >= 2);
    assert_eq!(sub.try_recv().expect("try_recv"), None);
}

/// A subscription to every run (`fsrl/*/metrics/**`): each run's messages arrive with their
/// run; a message whose header names another run than its key's is rejected, and the newest
/// rejection is there in words.
#[test]
fn every_run_subscription_takes_each_run_on_its_own_keys() {
    let mut net = Net::new(Backend::Zenoh);
    let monitor = net.open(SenderId::monitor(0));
    let metrics = monitor.subscriber(&keys::every_run_metrics()).expect("sub");
    let other = RunId::new(format!("{}-b", net.run)).expect("run id");
    let mut cfg = net.config(SenderId::learner());
    cfg.run = other.clone();
    let b = net.open_with(cfg);
    let a = net.open(SenderId::actor(1));
    let pa = a
        .publisher(&keys::metrics(&net.run, a.sender()))
        .expect("pub");
    let pb = b
        .publisher(&keys::metrics(&other, b.sender()))
        .expect("pub");
    for p in [&pa, &pb] {
        assert!(p.wait_for_subscribers(WAIT).expect("matching"));
    }
    pa.publish(1, &fixtures::metrics()).expect("publish");
    pb.publish(2, &fixtures::metrics()).expect("publish");
    let mut runs = Vec::new();
    for _ in 0..2 {
        let m: Message<Metrics> = metrics.recv_timeout(WAIT).expect("recv").expect("metrics");
        runs.push((m.header.run.to_string(), m.header.sender));
    }
    runs.sort();
    assert_eq!(
        runs,
        [
            (net.run.to_string(), SenderId::actor(1)),
            (other.to_string(), SenderId::learner())
        ]
    );
    // Run b's learner message on run a's learner key: the key's run is not the header's.
    let header = Header::new::<Metrics>(other.clone(), SenderId::learner(), 9, 0);
    let forged = proto::encode(&header, &fixtures::metrics()).expect("encode");
    let wrong = a
        .publisher(&keys::metrics(&net.run, SenderId::learner()))
        .expect("pub");
    assert!(wrong.wait_for_subscribers(WAIT).expect("matching"));
    wrong.publish_raw(forged).expect("raw");
    let deadline = Instant::now() + WAIT;
    while metrics.rejected_count() == 0 {
        assert!(metrics.try_recv().expect("recv").is_none(), "accepted");
        assert!(Instant::now() < deadline, "not rejected");
        std::thread::sleep(Duration::from_millis(10));
    }
    let why = monitor.last_rejection();
    assert!(
        why.contains(other.as_str()) && why.contains("fsrl/*/metrics/**"),
        "{why}"
    );
    // A sender on another's key within its run is refused too, as on one run's subscription.
    let header = Header::new::<Metrics>(net.run.clone(), SenderId::actor(2), 0, 0);
    pa.publish_raw(proto::encode(&header, &fixtures::metrics()).expect("encode"))
        .expect("raw");
    let deadline = Instant::now() + WAIT;
    while metrics.rejected_count() < 2 {
        assert!(metrics.try_recv().expect("recv").is_none(), "accepted");
        assert!(Instant::now() < deadline, "not rejected");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A process's heartbeats: the state at once when it changes, its last error soon after, a
/// rejected message as an error, and why it failed.
#[test]
fn heartbeats_carry_the_state_and_the_last_error() {
    use proto::{ProcessState, Status};
    let mut net = Net::new(Backend::Zenoh);
    let monitor = net.open(SenderId::monitor(0));
    let status = monitor
        .subscriber(&keys::all_status(&net.run))
        .expect("sub");
    let actor = net.open(SenderId::actor(3));
    // The subscription is matched before the first heartbeat goes.
    let probe = actor
        .publisher(&keys::status(&net.run, actor.sender()))
        .expect("pub");
    assert!(probe.wait_for_subscribers(WAIT).expect("matching"));
    let hb = transport::Heartbeat::new(&actor).expect("heartbeat");
    // The next heartbeat, beating as a process's loop does.
    let next = |what: &str| -> Status {
        let deadline = Instant::now() + WAIT;
        loop {
            hb.beat();
            if let Some(m) = status
                .recv_timeout(Duration::from_millis(20))
                .expect("recv")
            {
                assert_eq!(m.header.sender, SenderId::actor(3));
                return m.body;
            }
            assert!(Instant::now() < deadline, "no heartbeat: {what}");
        }
    };
    assert_eq!(next("start").state, ProcessState::Starting);
    hb.set_state(ProcessState::Running);
    let s = next("running");
    assert_eq!((s.state, s.detail.as_str()), (ProcessState::Running, ""));
    let t0 = Instant::now();
    hb.error("publishing control failed: no route");
    let s = next("error");
    assert_eq!(s.detail, "publishing control failed: no route");
    assert!(
        t0.elapsed() < transport::HEARTBEAT_EVERY,
        "sent as a new error, not as a beat"
    );
    // Garbage on the actor's ack key: rejected by its subscriber, the heartbeat's last error.
    let acks = actor.subscriber(&keys::ack(&net.run, 3)).expect("sub");
    let evil = monitor.publisher(&keys::ack(&net.run, 3)).expect("pub");
    assert!(evil.wait_for_subscribers(WAIT).expect("matching"));
    evil.publish_raw(b"not a message".to_vec()).expect("raw");
    let deadline = Instant::now() + WAIT;
    while actor.rejected_count() == 0 {
        assert!(acks.try_recv().expect("recv").is_none());
        assert!(Instant::now() < deadline, "not rejected");
        std::thread::sleep(Duration::from_millis(10));
    }
    let s = loop {
        let s = next("the rejection");
        if s.detail.contains("rejected a message") {
            break s;
        }
    };
    assert!(
        s.detail.contains(&keys::ack(&net.run, 3).to_string()),
        "{}",
        s.detail
    );
    hb.fail("the run directory is locked by process 12");
    let s = loop {
        let s = next("failed");
        if s.state == ProcessState::Failed {
            break s;
        }
    };
    assert_eq!(s.detail, "the run directory is locked by process 12");
}
