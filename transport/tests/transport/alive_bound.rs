//! [`transport::AliveWatcher`] is bounded: one sender declaring any number of liveliness tokens
//! under its own id (the router allows it) costs at most `MAX_INSTANCES_PER_SENDER` members,
//! the newest; the displaced ones are announced as left, and every token not tracked is
//! counted.

use std::time::{Duration, Instant};

use proto::{keys, Member, SenderId};
use transport::{AliveEvent, MAX_INSTANCES_PER_SENDER};
use zenoh::Wait;

use crate::harness::{Backend, Net, WAIT};

#[test]
fn one_sender_flooding_tokens_keeps_only_its_newest_instances() {
    let mut net = Net::new(Backend::Zenoh);
    let learner = net.open(SenderId::learner());
    let watcher = learner.watch_alive().expect("watch");
    // A raw peer declaring tokens as actor 0 would, then one of actor 1.
    let mut zc = zenoh::Config::default();
    zc.insert_json5("mode", "\"peer\"").unwrap();
    zc.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zc.insert_json5("listen/endpoints", "[]").unwrap();
    zc.insert_json5("connect/endpoints", &format!("[\"{}\"]", net.endpoint))
        .unwrap();
    let flooder = zenoh::open(zc).wait().expect("session");
    let flood = 4 * MAX_INSTANCES_PER_SENDER + 3;
    let member = |sender, instance| Member { sender, instance };
    let mut tokens = Vec::new();
    for i in 0..flood as u64 {
        let key = keys::alive(&net.run, member(SenderId::actor(0), 0x100 + i));
        tokens.push(flooder.liveliness().declare_token(key).wait().unwrap());
    }
    let other = member(SenderId::actor(1), 7);
    tokens.push(
        flooder
            .liveliness()
            .declare_token(keys::alive(&net.run, other))
            .wait()
            .unwrap(),
    );
    let deadline = Instant::now() + WAIT;
    let mut events = Vec::new();
    while !events.contains(&AliveEvent::Joined(other)) {
        assert!(
            Instant::now() < deadline,
            "actor 1 never joined: {events:?}"
        );
        if let Some(e) = watcher.recv_timeout(Duration::from_millis(100)).unwrap() {
            events.push(e);
        }
    }
    let members = watcher.members().unwrap();
    let newest: Vec<Member> = (flood - MAX_INSTANCES_PER_SENDER..flood)
        .map(|i| member(SenderId::actor(0), 0x100 + i as u64))
        .collect();
    let mut want = newest.clone();
    want.push(other);
    want.sort();
    let mut got = members.clone();
    got.sort();
    assert_eq!(got, want, "the newest instances of actor 0 and actor 1");
    assert_eq!(
        watcher.refused_count().unwrap(),
        (flood - MAX_INSTANCES_PER_SENDER) as u64
    );
    // Every displaced instance was announced as left after it had joined.
    let left = events
        .iter()
        .filter(|e| matches!(e, AliveEvent::Left(m) if m.sender == SenderId::actor(0)))
        .count();
    assert_eq!(left, flood - MAX_INSTANCES_PER_SENDER);
    drop(tokens);
    let _ = flooder.close().wait();
}
