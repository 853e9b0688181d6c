//! Key expressions: one function per topic. Nothing else in the workspace builds key strings.
//!
//! Every key starts with `fsrl/<run>/`. A [`Topic`] carries, besides its zenoh key expression,
//! the message type (type parameter), the delivery guarantee, the plane it travels on and the
//! iceoryx2 service name of its family (one service per family, e.g. all actors publish into
//! `fsrl/<run>/transitions`; the concrete key travels with each sample). See the crate docs or
//! `proto/TOPICS.md` for the table.

use std::fmt;
use std::marker::PhantomData;

use crate::control::{Ack, Control};
use crate::error::ValidationError;
use crate::ids::{Role, RunId, SenderId};
use crate::reports::{EvalReport, Metrics, Status};
use crate::transitions::TransitionBatch;
use crate::weights::Weights;

/// First chunk of every key expression.
pub const ROOT: &str = "fsrl";

/// What a subscriber may rely on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Delivery {
    /// Every message reaches every matching subscriber that exists when it is published, in
    /// order per publisher; a full receiver blocks the publisher (never dropped silently).
    Reliable,
    /// Reliable, and a subscriber that joins late receives the current (last published)
    /// value at once. Older values may be skipped: only the newest matters.
    Latest,
    /// May be dropped under congestion (never blocks the publisher).
    BestEffort,
}

/// Which transport carries a topic when the data plane is shared memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Plane {
    /// Bulk data: iceoryx2 on one machine, zenoh otherwise.
    Data,
    /// Telemetry and membership: always zenoh, so other tools can subscribe.
    Telemetry,
}

/// Who talks to whom on a topic (sizes shared-memory services).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Fanout {
    /// Many publishers (one key each) into few subscribers, usually through a wildcard
    /// (transitions, evaluation reports, telemetry). One iceoryx2 service per family.
    ManyToOne,
    /// One publisher to many subscribers of the same key (weights, control, acks). One
    /// iceoryx2 service per key.
    OneToMany,
}

/// A typed topic: key expression + message type + delivery guarantee.
pub struct Topic<M> {
    key: String,
    service: String,
    delivery: Delivery,
    plane: Plane,
    fanout: Fanout,
    wildcard: bool,
    _message: PhantomData<fn() -> M>,
}

impl<M> Topic<M> {
    fn new(
        family: String,
        tail: Option<String>,
        delivery: Delivery,
        plane: Plane,
        fanout: Fanout,
    ) -> Self {
        let (key, wildcard) = match tail {
            Some(t) => {
                let w = t.contains('*');
                (format!("{family}/{t}"), w)
            }
            None => (family.clone(), false),
        };
        let service = match fanout {
            Fanout::ManyToOne => family,
            Fanout::OneToMany => key.clone(),
        };
        Self {
            key,
            service,
            delivery,
            plane,
            fanout,
            wildcard,
            _message: PhantomData,
        }
    }

    /// Who talks to whom.
    pub fn fanout(&self) -> Fanout {
        self.fanout
    }

    /// The zenoh key expression (may contain wildcards, see [`Topic::is_wildcard`]).
    pub fn key_expr(&self) -> &str {
        &self.key
    }

    /// The iceoryx2 service name: the family for [`Fanout::ManyToOne`] topics (the concrete
    /// key travels with each sample), the key itself for [`Fanout::OneToMany`] topics.
    pub fn service_name(&self) -> &str {
        &self.service
    }

    /// Delivery guarantee.
    pub fn delivery(&self) -> Delivery {
        self.delivery
    }

    /// Plane.
    pub fn plane(&self) -> Plane {
        self.plane
    }

    /// Whether this is a subscription pattern (cannot be published to).
    pub fn is_wildcard(&self) -> bool {
        self.wildcard
    }
}

impl<M> Clone for Topic<M> {
    fn clone(&self) -> Self {
        Self {
            key: self.key.clone(),
            service: self.service.clone(),
            delivery: self.delivery,
            plane: self.plane,
            fanout: self.fanout,
            wildcard: self.wildcard,
            _message: PhantomData,
        }
    }
}

impl<M> fmt::Debug for Topic<M> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Topic")
            .field("key", &self.key)
            .field("delivery", &self.delivery)
            .field("plane", &self.plane)
            .finish()
    }
}

impl<M> fmt::Display for Topic<M> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.key)
    }
}

fn family(run: &RunId, name: &str) -> String {
    format!("{ROOT}/{run}/{name}")
}

fn sender_tail(sender: SenderId) -> String {
    format!("{}/{}", sender.role, sender.index)
}

/// `fsrl/<run>/transitions/<actor>`: [`TransitionBatch`], actor → learner, reliable.
pub fn transitions(run: &RunId, actor: u32) -> Topic<TransitionBatch> {
    Topic::new(
        family(run, "transitions"),
        Some(actor.to_string()),
        Delivery::Reliable,
        Plane::Data,
        Fanout::ManyToOne,
    )
}

/// `fsrl/<run>/transitions/*`: every actor's transitions (the learner's subscription).
pub fn all_transitions(run: &RunId) -> Topic<TransitionBatch> {
    Topic::new(
        family(run, "transitions"),
        Some("*".into()),
        Delivery::Reliable,
        Plane::Data,
        Fanout::ManyToOne,
    )
}

/// `fsrl/<run>/weights`: [`Weights`], learner → actors + evaluator, latest value.
pub fn weights(run: &RunId) -> Topic<Weights> {
    Topic::new(
        family(run, "weights"),
        None,
        Delivery::Latest,
        Plane::Data,
        Fanout::OneToMany,
    )
}

/// `fsrl/<run>/control`: [`Control`], learner → actors, latest value.
pub fn control(run: &RunId) -> Topic<Control> {
    Topic::new(
        family(run, "control"),
        None,
        Delivery::Latest,
        Plane::Data,
        Fanout::OneToMany,
    )
}

/// `fsrl/<run>/ack/<actor>`: [`Ack`], learner → one actor, reliable.
pub fn ack(run: &RunId, actor: u32) -> Topic<Ack> {
    Topic::new(
        family(run, "ack"),
        Some(actor.to_string()),
        Delivery::Reliable,
        Plane::Data,
        Fanout::OneToMany,
    )
}

/// `fsrl/<run>/eval/<evaluator>`: [`EvalReport`], evaluator → anyone, reliable, always zenoh.
pub fn eval_report(run: &RunId, evaluator: u32) -> Topic<EvalReport> {
    Topic::new(
        family(run, "eval"),
        Some(evaluator.to_string()),
        Delivery::Reliable,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// `fsrl/<run>/eval/*`: every evaluator's reports.
pub fn all_eval_reports(run: &RunId) -> Topic<EvalReport> {
    Topic::new(
        family(run, "eval"),
        Some("*".into()),
        Delivery::Reliable,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// `fsrl/<run>/metrics/<role>/<index>`: [`Metrics`], any process → tools, best effort.
pub fn metrics(run: &RunId, sender: SenderId) -> Topic<Metrics> {
    Topic::new(
        family(run, "metrics"),
        Some(sender_tail(sender)),
        Delivery::BestEffort,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// `fsrl/<run>/metrics/**`: everybody's metrics.
pub fn all_metrics(run: &RunId) -> Topic<Metrics> {
    Topic::new(
        family(run, "metrics"),
        Some("**".into()),
        Delivery::BestEffort,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// `fsrl/<run>/status/<role>/<index>`: [`Status`] heartbeats, any process → tools, best effort.
pub fn status(run: &RunId, sender: SenderId) -> Topic<Status> {
    Topic::new(
        family(run, "status"),
        Some(sender_tail(sender)),
        Delivery::BestEffort,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// `fsrl/<run>/status/**`: everybody's heartbeats.
pub fn all_status(run: &RunId) -> Topic<Status> {
    Topic::new(
        family(run, "status"),
        Some("**".into()),
        Delivery::BestEffort,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// The run chunk of a key expression that stands for every run (`fsrl/*/…`): a [`RunId`] is
/// never `*`, so no run's own key starts with it.
pub const EVERY_RUN: &str = "*";

fn every_run_family(name: &str) -> String {
    format!("{ROOT}/{EVERY_RUN}/{name}")
}

/// `fsrl/*/metrics/**`: the metrics of every run (a tool watching whatever runs it sees, such
/// as `fsrl dashboard` without `--run`). A message is taken only when its header names the run
/// of the key it came on ([`run_of_key`]).
pub fn every_run_metrics() -> Topic<Metrics> {
    Topic::new(
        every_run_family("metrics"),
        Some("**".into()),
        Delivery::BestEffort,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// `fsrl/*/status/**`: the heartbeats of every run (as [`every_run_metrics`]).
pub fn every_run_status() -> Topic<Status> {
    Topic::new(
        every_run_family("status"),
        Some("**".into()),
        Delivery::BestEffort,
        Plane::Telemetry,
        Fanout::ManyToOne,
    )
}

/// The run of a concrete key this module built (`fsrl/<run>/…`); `None` for anything else
/// (another root, a wildcard or invalid run chunk).
pub fn run_of_key(key: &str) -> Option<RunId> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix('/')?;
    let (run, _) = rest.split_once('/')?;
    RunId::new(run).ok()
}

/// Whether `topic` stands for every run (`fsrl/*/…`, [`every_run_metrics`],
/// [`every_run_status`]).
pub fn is_every_run<M>(topic: &Topic<M>) -> bool {
    topic
        .key_expr()
        .strip_prefix(ROOT)
        .and_then(|r| r.strip_prefix('/'))
        .is_some_and(|r| r.starts_with(&format!("{EVERY_RUN}/")))
}

/// `fsrl/<run>/**`: everything of a run (for tools such as `z_sub -k`).
pub fn run_prefix(run: &RunId) -> String {
    format!("{ROOT}/{run}/**")
}

/// One live process: who it is and which incarnation (a random number per process start, so
/// a restarted actor is a new member and two tokens never share a key).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Member {
    /// Role and index.
    pub sender: SenderId,
    /// Incarnation.
    pub instance: u64,
}

impl fmt::Display for Member {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}#{:016x}", self.sender, self.instance)
    }
}

/// `fsrl/<run>/alive/<role>/<index>/<instance as 16 hex digits>`: liveliness token of a
/// process (no payload).
pub fn alive(run: &RunId, member: Member) -> String {
    format!(
        "{}/{}/{:016x}",
        family(run, "alive"),
        sender_tail(member.sender),
        member.instance
    )
}

/// `fsrl/<run>/alive/**`: every liveliness token of the run.
pub fn all_alive(run: &RunId) -> String {
    format!("{}/**", family(run, "alive"))
}

/// `fsrl/serve/<name>/act`: the queryable of `fsrl serve` (an [`crate::serve::ActRequest`]
/// in, an [`crate::serve::ActReply`] out). `name` is 1–64 of `A–Z a–z 0–9 - _`.
pub fn serve_act(name: &str) -> Result<String, ValidationError> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    if !ok {
        return Err(ValidationError::InvalidField {
            field: "serve name",
            reason: format!("{name:?}: 1-64 of A-Z a-z 0-9 - _"),
        });
    }
    Ok(format!("{ROOT}/serve/{name}/act"))
}

/// Parses a key produced by [`alive`] for `run`.
pub fn parse_alive(run: &RunId, key: &str) -> Result<Member, ValidationError> {
    let invalid = || ValidationError::InvalidField {
        field: "alive key",
        reason: format!(
            "{key:?} is not {}/<role>/<index>/<instance>",
            family(run, "alive")
        ),
    };
    let prefix = format!("{}/", family(run, "alive"));
    let rest = key.strip_prefix(&prefix).ok_or_else(invalid)?;
    let mut parts = rest.split('/');
    let (Some(role), Some(index), Some(instance), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(invalid());
    };
    let role: Role = role.parse()?;
    let index: u32 = index.parse().map_err(|_| invalid())?;
    let instance = u64::from_str_radix(instance, 16).map_err(|_| invalid())?;
    Ok(Member {
        sender: SenderId::new(role, index),
        instance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run() -> RunId {
        RunId::new("r1").expect("valid")
    }

    #[test]
    fn keys() {
        let r = run();
        assert_eq!(transitions(&r, 3).key_expr(), "fsrl/r1/transitions/3");
        assert_eq!(transitions(&r, 3).service_name(), "fsrl/r1/transitions");
        assert!(all_transitions(&r).is_wildcard());
        assert!(!transitions(&r, 3).is_wildcard());
        assert_eq!(weights(&r).key_expr(), "fsrl/r1/weights");
        assert_eq!(weights(&r).delivery(), Delivery::Latest);
        assert_eq!(
            metrics(&r, SenderId::actor(2)).key_expr(),
            "fsrl/r1/metrics/actor/2"
        );
        assert_eq!(all_metrics(&r).key_expr(), "fsrl/r1/metrics/**");
        assert_eq!(ack(&r, 7).key_expr(), "fsrl/r1/ack/7");
        assert_eq!(ack(&r, 7).service_name(), "fsrl/r1/ack/7");
        assert_eq!(weights(&r).fanout(), Fanout::OneToMany);
        assert_eq!(run_prefix(&r), "fsrl/r1/**");
        assert_eq!(every_run_metrics().key_expr(), "fsrl/*/metrics/**");
        assert_eq!(every_run_status().key_expr(), "fsrl/*/status/**");
        assert!(every_run_metrics().is_wildcard() && is_every_run(&every_run_status()));
        assert!(!is_every_run(&all_metrics(&r)));
        assert_eq!(every_run_metrics().plane(), Plane::Telemetry);
        let key = metrics(&r, SenderId::actor(2));
        assert_eq!(run_of_key(key.key_expr()), Some(r.clone()));
        assert_eq!(run_of_key(every_run_metrics().key_expr()), None);
        assert_eq!(run_of_key("other/r1/metrics"), None);
        assert_eq!(run_of_key("fsrl/r1"), None);
    }

    #[test]
    fn alive_round_trip() {
        let r = run();
        let m = Member {
            sender: SenderId::evaluator(1),
            instance: 0xdead_beef,
        };
        let k = alive(&r, m);
        assert_eq!(k, "fsrl/r1/alive/evaluator/1/00000000deadbeef");
        assert_eq!(parse_alive(&r, &k), Ok(m));
        assert!(parse_alive(&r, "fsrl/r2/alive/actor/1/00").is_err());
        assert!(parse_alive(&r, "fsrl/r1/alive/actor/1").is_err());
        assert!(parse_alive(&r, "fsrl/r1/alive/actor/1/zz").is_err());
        assert!(parse_alive(&r, "fsrl/r1/alive/actor/1/00/x").is_err());
    }
}
