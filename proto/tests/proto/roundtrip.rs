//! One round-trip test per message.

use proto::fixtures;
use proto::{decode, encode, Body, Message, SenderId};

fn round_trip<B: Body + PartialEq>(body: B) {
    let header = fixtures::header::<B>(SenderId::actor(4), 17, 9);
    let bytes = encode(&header, &body).expect("encode");
    let back: Message<B> = decode(&bytes).expect("decode");
    assert_eq!(back.header, header);
    assert_eq!(back.body, body);
}

#[test]
fn transition_batch() {
    round_trip(fixtures::episode(45, 10, 7));
    round_trip(fixtures::episode(1, 0, 0));
    round_trip(fixtures::episode(100, 10, u64::MAX));
}

#[test]
fn transition_batch_chunks() {
    let full = fixtures::episode(45, 10, 3);
    let chunks = full.clone().into_chunks(20).expect("valid");
    assert_eq!(chunks.len(), 3);
    assert_eq!(
        chunks.iter().map(|c| c.n_steps).collect::<Vec<_>>(),
        [20, 20, 5]
    );
    assert!(chunks[..2].iter().all(|c| !c.last_chunk));
    assert!(chunks[2].last_chunk);
    assert_eq!(chunks[2].outcome, full.outcome);
    assert_eq!(chunks[1].first_step, 20);
    // Chunk boundaries share the state between them.
    assert_eq!(chunks[0].robot_state(20), chunks[1].robot_state(0));
    assert_eq!(chunks[1].robot_state(0), full.robot_state(20));
    assert_eq!(chunks[2].human_state(5, 9), full.human_state(45, 9));
    for c in chunks {
        round_trip(c);
    }
}

#[test]
fn accessors() {
    let b = fixtures::episode(45, 10, 3);
    assert_eq!(b.robot_state(0).map(|r| r.py_m), Some(-4.0));
    assert!(b.robot_state(46).is_none());
    assert!(b.human_state(0, 10).is_none());
    assert_eq!(b.reward(44).map(|r| r.total), Some(-0.03));
    assert!(b.reward(45).is_none());
}

#[test]
fn weights() {
    let w = fixtures::sarl_weights(12);
    assert_eq!(w.params.len(), 96_502);
    round_trip(w);
}

#[test]
fn eval_report() {
    round_trip(fixtures::eval_report());
}

#[test]
fn metrics() {
    round_trip(fixtures::metrics());
}

#[test]
fn status() {
    round_trip(fixtures::status());
}

#[test]
fn ack() {
    let a = fixtures::ack();
    assert!(a.covers(39) && a.covers(42) && !a.covers(40));
    round_trip(a);
}

#[test]
fn control() {
    let c = fixtures::control();
    assert_eq!(c.budget_for(1), Some(48));
    assert_eq!(c.budget_for(2), None);
    round_trip(c);
}

#[test]
fn encoded_sizes_are_compact() {
    let header = fixtures::header::<proto::TransitionBatch>(SenderId::actor(0), 0, 0);
    let b = fixtures::episode(45, 10, 0);
    let raw_floats = 4 * (46 * 9 + 46 * 10 * 5 + 45 * 5 + 45);
    let n = encode(&header, &b).expect("encode").len();
    assert!(
        n < raw_floats + 600,
        "{n} bytes for {raw_floats} bytes of floats"
    );
    let w = fixtures::sarl_weights(1);
    let header = fixtures::header::<proto::Weights>(SenderId::learner(), 0, 1);
    let n = encode(&header, &w).expect("encode").len();
    assert!(n < 96_502 * 4 + 2048, "{n}");
}
