//! `proto`: the fsrl wire protocol — every message that crosses a process, the key
//! expressions, [`PROTOCOL_VERSION`] and the MessagePack codec. Pure: no IO, no zenoh, no tokio.
//!
//! # Messages
//!
//! Every message is a [`Message<B>`]: a [`Header`] (protocol version, [`MessageKind`], run id,
//! sender id, sequence number, policy version that produced it) and a body `B: `[`Body`]:
//!
//! | body | what |
//! |---|---|
//! | [`TransitionBatch`] | one finished episode or a chunk of it: `T+1` raw joint states, `T` actions, reward terms, closest distances, outcome, setting, seed, ε |
//! | [`Weights`] | versioned network parameters, network description, CRC-32 |
//! | [`EvalReport`] | the paper's metrics per setting for one weight snapshot |
//! | [`Metrics`] | live figures of a process, by name, indexed by environment steps |
//! | [`Status`] | heartbeat / life-cycle state |
//! | [`Ack`] | episodes the learner accepted (at-least-once delivery of transitions) |
//! | [`Control`] | run phase, ε, flow-control credits |
//!
//! # Codec
//!
//! [`encode`] / [`decode`]: MessagePack through rmp-serde with **named fields** (struct-map
//! encoding), so other languages read any message by field name (`msgpack.unpackb(b)["body"]`);
//! float columns are little-endian `bin`s (`numpy.frombuffer(b, "<f4")`). Encoding validates the
//! body; decoding enforces a size limit, the protocol version and message kind, rejects trailing
//! bytes and validates dimensions, finiteness, limits and checksums. Every malformed input is a
//! typed [`DecodeError`]; decoding never panics. Episode batches take a hand-written path with
//! the same bytes (see [`codec`]), and [`prepare`] encodes one straight into caller memory.
//!
//! # Topics
//!
//! Key expressions are built only by the functions of [`keys`] (one per topic); `<run>` is a
//! validated [`RunId`], `<actor>`/`<evaluator>`/`<index>` are indices, `<role>` is
//! `learner|actor|evaluator|monitor`. Plane *data* rides on iceoryx2 when the data plane is
//! shared memory and on zenoh otherwise; plane *telemetry* is always zenoh (loopback on one
//! machine), so Python/`z_sub` can watch it. (Also in `proto/TOPICS.md`.)
//!
//! | topic (function) | key expression | publisher | subscribers | message | delivery | plane |
//! |---|---|---|---|---|---|---|
//! | [`keys::transitions`] / [`keys::all_transitions`] | `fsrl/<run>/transitions/<actor>` (`.../*`) | actor | learner | [`TransitionBatch`] | reliable, blocking when full, never dropped silently; at-least-once via [`Ack`] | data |
//! | [`keys::weights`] | `fsrl/<run>/weights` | learner | actors, evaluator | [`Weights`] | latest value: reliable, late joiners get the current weights at once | data |
//! | [`keys::control`] | `fsrl/<run>/control` | learner | actors | [`Control`] | latest value | data |
//! | [`keys::ack`] | `fsrl/<run>/ack/<actor>` | learner | that actor | [`Ack`] | reliable | data |
//! | [`keys::eval_report`] / [`keys::all_eval_reports`] | `fsrl/<run>/eval/<evaluator>` (`.../*`) | evaluator | learner, tools | [`EvalReport`] | reliable | telemetry |
//! | [`keys::metrics`] / [`keys::all_metrics`] | `fsrl/<run>/metrics/<role>/<index>` (`.../**`) | every process | tools | [`Metrics`] | best effort (dropped under congestion) | telemetry |
//! | [`keys::status`] / [`keys::all_status`] | `fsrl/<run>/status/<role>/<index>` (`.../**`) | learner, actors, evaluator (heartbeats: state, last error) | tools | [`Status`] | best effort | telemetry |
//! | [`keys::every_run_metrics`] / [`keys::every_run_status`] | `fsrl/*/metrics/**`, `fsrl/*/status/**` (subscriptions only) | — | tools watching every run (`fsrl dashboard` without `--run`); a message counts only when its header's run is its key's ([`keys::run_of_key`]) | [`Metrics`], [`Status`] | best effort | telemetry |
//! | [`keys::alive`] / [`keys::all_alive`] | `fsrl/<run>/alive/<role>/<index>/<instance>` (`.../**`) | every process (liveliness token, no payload) | learner, tools | — | join/leave events | telemetry |
//! | [`keys::serve_act`] | `fsrl/serve/<name>/act` | `fsrl serve` (queryable) | any program (query) | [`serve::ActRequest`] → [`serve::ActReply`] | one reply per query | — |
//!
//! Sequence numbers count per (sender, topic) from 0. `policy_version` is the weights version
//! the content was produced with (0 = no weights yet, e.g. the ORCA demonstrator); for
//! [`Weights`] it equals `Weights::version`.

pub mod codec;
pub mod columns;
pub mod control;
mod direct;
pub mod error;
pub mod fixtures;
pub mod header;
pub mod ids;
pub mod keys;
mod kind;
pub mod reports;
pub mod serve;
pub mod transitions;
pub mod weights;

pub use codec::{
    decode, decode_with_limit, encode, encode_into, encode_message, prepare,
    probe_protocol_version, Prepared, DEFAULT_MAX_MESSAGE_BYTES,
};
pub use control::{Ack, Control, CreditGrant, RunPhase};
pub use error::{DecodeError, EncodeError, ValidationError};
pub use header::{Body, Header, Message};
pub use ids::{Role, RunId, SenderId};
pub use keys::{Delivery, Fanout, Member, Plane, Topic};
pub use kind::MessageKind;
pub use reports::{EvalReport, Metrics, ProcessState, SettingReport, Status};
pub use transitions::{
    EpisodeMeta, HumanState, Outcome, RewardTerms, RobotState, TransitionBatch,
    TransitionBatchBuilder,
};
pub use weights::{params_crc32, NetworkDesc, NetworkKind, TensorDesc, Weights};

/// Version of this wire protocol. Bump on any incompatible change of a message or key layout;
/// receivers reject other versions with [`DecodeError::WrongProtocolVersion`].
pub const PROTOCOL_VERSION: u16 = 1;
