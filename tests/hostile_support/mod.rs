//! Hostile but well-formed episodes, for `tests/distributed.rs` (a client on the learner's own
//! endpoint, no router) and `tests/hostile_batches.rs` (an actor's credentials through the live
//! router): honest episodes to start from, oversized ones, and publication under any key with
//! any header.
#![allow(dead_code)]

use std::collections::BTreeMap;

use proto::{keys, SenderId, TransitionBatch};
use transport::{Publisher, Transport};

/// The setting of the runs these episodes are made for.
pub const SETTING: &str = "env2-visible";

/// An honest episode of [`SETTING`] (ORCA from seed `seed`) as an actor's episode `episode`.
pub fn honest_batch(episode: u64, seed: u64) -> TransitionBatch {
    let cfg = sim::SimConfig::default();
    let mut env = sim::Env::new(cfg, SETTING.parse().unwrap(), 0).unwrap();
    let ep = policy::rollout::rollout(
        &mut env,
        seed,
        policy::rollout::Behaviour::Orca {
            safety_space_m: 0.0,
        },
    )
    .unwrap();
    policy::wire::to_batch(&ep, episode, env.action_set().len() as u16).unwrap()
}

/// A well-formed episode of [`SETTING`] (it passes `proto`'s validation) whose message is just
/// under the 16 MiB every process accepts (`proto::DEFAULT_MAX_MESSAGE_BYTES`): 3100 steps
/// with 256 humans.
pub fn huge_batch(episode: u64) -> TransitionBatch {
    let mut b = proto::fixtures::episode(3100, 256, episode);
    b.setting = SETTING.into();
    b
}

/// Publishes `batch` on `key_actor`'s transitions key with a header naming `claimed`, through
/// a publisher kept in `publishers` (one per key).
pub fn forge(
    t: &Transport,
    publishers: &mut BTreeMap<u32, Publisher<TransitionBatch>>,
    key_actor: u32,
    claimed: SenderId,
    batch: &TransitionBatch,
) {
    let p = publishers
        .entry(key_actor)
        .or_insert_with(|| t.publisher(&keys::transitions(t.run(), key_actor)).unwrap());
    let header = proto::Header::new::<TransitionBatch>(t.run().clone(), claimed, 0, 1);
    p.publish_raw(proto::encode(&header, batch).unwrap())
        .unwrap();
}
