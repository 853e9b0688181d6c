//! The queryable `fsrl/serve/<name>/act` (MessagePack, `proto::serve`), kept off the control
//! loop and off zenoh's callback threads.
//!
//! zenoh calls [`Offer::offer`] on the thread that reads the asker's link, which may be the
//! very link the robot's inputs come on (behind a router, every peer's traffic to a session
//! shares one link; the queryable has a session of its own there, `node::queries_session`).
//! A reply goes with the asker's congestion control (zenoh 1.10 ignores a reply's own), `Block`
//! by default: to an asker that does not read, it waits until the link takes it (up to zenoh's
//! `wait_before_close`, 5 s), and so does the final "no more replies" that dropping a query
//! sends. So the callback never replies and never drops a query while there is room: a query
//! waits in the answer queue ([`QUERY_QUEUE`], [`QUERY_QUEUE_BYTES`]) for the worker, which
//! answers with its own copy of the policy; beyond it, in the refusal queue ([`REFUSAL_QUEUE`])
//! for the refuser, which replies `busy: ...`. Only past both (the refuser stuck that long on a
//! link that does not read) is a query dropped where it arrived, counted.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::Instant;

use zenoh::query::Query;
use zenoh::Wait;

use crate::people::PersonObs;
use crate::served::{Limits, Observation, RobotObs, ServedPolicy};

/// Most queries waiting for the policy; a query beyond is refused (counted).
pub const QUERY_QUEUE: usize = 32;
/// Most bytes of queries waiting.
pub const QUERY_QUEUE_BYTES: usize = 4 << 20;
/// Most refused queries waiting for their reply; beyond, a query is dropped where it arrived.
pub const REFUSAL_QUEUE: usize = 1024;

#[derive(Default)]
struct State {
    waiting: VecDeque<(Query, Vec<u8>)>,
    bytes: usize,
    /// Refused queries and how many were waiting when each came.
    refusing: VecDeque<(Query, usize)>,
    refused: u64,
    dropped: u64,
    answered: u64,
    closed: bool,
}

#[derive(Default)]
struct Shared {
    state: Mutex<State>,
    /// A query to answer, or closed.
    ready: Condvar,
    /// A query to refuse, or closed.
    refusal: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Waits for the next item `pick` takes from the state, or `None` once closed.
    fn take<T>(&self, cv: &Condvar, pick: impl Fn(&mut State) -> Option<T>) -> Option<T> {
        let mut s = self.lock();
        loop {
            if s.closed {
                return None;
            }
            if let Some(t) = pick(&mut s) {
                return Some(t);
            }
            s = cv.wait(s).unwrap_or_else(PoisonError::into_inner);
        }
    }
}

/// What the queryable did over a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct QueryCounts {
    pub answered: u64,
    /// Refused because the answer queue was full.
    pub refused: u64,
    /// Of those, dropped without a reply because the refusal queue was full too.
    pub dropped: u64,
}

/// The queryable's two queues and the two threads that empty them; closed on drop.
pub struct Queries {
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

impl Queries {
    /// Starts the worker (answering with `policy`) and the refuser; why not.
    pub fn start(
        mut policy: ServedPolicy,
        limits: Limits,
        max_people: usize,
    ) -> Result<Self, String> {
        let shared = Arc::new(Shared::default());
        let spawn = |name: &str, f: Box<dyn FnOnce() + Send>| {
            std::thread::Builder::new()
                .name(name.into())
                .spawn(f)
                .map_err(|e| format!("cannot start {name}: {e}"))
        };
        let s = shared.clone();
        let worker = spawn(
            "fsrl-serve-queries",
            Box::new(move || {
                while let Some((q, payload)) = s.take(&s.ready, |st| {
                    let (q, p) = st.waiting.pop_front()?;
                    st.bytes -= p.len();
                    Some((q, p))
                }) {
                    let reply = answer(&mut policy, &limits, max_people, &payload);
                    if let Err(e) = q.reply(q.key_expr().clone(), reply.encode()).wait() {
                        tracing::warn!("cannot reply to a query: {e}");
                    }
                    s.lock().answered += 1;
                }
            }),
        )?;
        let s = shared.clone();
        let refuser = spawn(
            "fsrl-serve-refusals",
            Box::new(move || {
                while let Some((q, waiting)) = s.take(&s.refusal, |st| st.refusing.pop_front()) {
                    let reply = proto::serve::ActReply::refused(format!(
                        "busy: {waiting} queries are waiting, at most {QUERY_QUEUE}; ask again later"
                    ));
                    if let Err(e) = q.reply(q.key_expr().clone(), reply.encode()).wait() {
                        tracing::debug!("cannot refuse a query: {e}");
                    }
                }
            }),
        );
        let refuser = match refuser {
            Ok(t) => t,
            Err(e) => {
                Self::close_shared(&shared);
                return Err(e);
            }
        };
        Ok(Self {
            shared,
            threads: vec![worker, refuser],
        })
    }

    /// What zenoh's callback holds: [`Offer::offer`].
    pub fn offerer(&self) -> Offer {
        Offer(self.shared.clone())
    }

    fn close_shared(shared: &Shared) -> (State, QueryCounts) {
        let mut s = shared.lock();
        s.closed = true;
        let counts = QueryCounts {
            answered: s.answered,
            refused: s.refused,
            dropped: s.dropped,
        };
        let left = State {
            waiting: std::mem::take(&mut s.waiting),
            refusing: std::mem::take(&mut s.refusing),
            ..State::default()
        };
        drop(s);
        shared.ready.notify_all();
        shared.refusal.notify_all();
        (left, counts)
    }

    /// Closes both queues; what was done. The threads end after their current reply (they are
    /// not waited for: a reply to an asker that does not read may hold one until zenoh closes
    /// that link).
    pub fn close(&mut self) -> QueryCounts {
        let (left, counts) = Self::close_shared(&self.shared);
        // Dropping a query sends its final reply: off the lock, off the loop.
        drop(left);
        self.threads.clear();
        counts
    }
}

/// Hands zenoh's queries to [`Queries`] from its callback.
pub struct Offer(Arc<Shared>);

impl Offer {
    /// Queued for the worker, or for the refuser: never a reply, never a query dropped here
    /// while the refusal queue has room.
    pub fn offer(&self, q: Query) {
        let payload = q
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let mut s = self.0.lock();
        if s.closed {
            return;
        }
        let full = s.waiting.len() >= QUERY_QUEUE || s.bytes + payload.len() > QUERY_QUEUE_BYTES;
        if !full {
            s.bytes += payload.len();
            s.waiting.push_back((q, payload));
            drop(s);
            self.0.ready.notify_one();
            return;
        }
        s.refused += 1;
        let (n, waiting) = (s.refused, s.waiting.len());
        let overflow = if s.refusing.len() < REFUSAL_QUEUE {
            s.refusing.push_back((q, waiting));
            None
        } else {
            s.dropped += 1;
            Some(q)
        };
        drop(s);
        self.0.refusal.notify_one();
        if n.is_power_of_two() {
            tracing::warn!(
                "query refused: {waiting} are waiting, at most {QUERY_QUEUE} (#{n} refused)"
            );
        }
        // The last resort: the refuser has been stuck for REFUSAL_QUEUE queries.
        drop(overflow);
    }
}

impl Drop for Queries {
    fn drop(&mut self) {
        self.close();
    }
}

/// The reply to one query: refused when it does not decode, holds more than `max_people`
/// humans, or the policy refuses its values (out of the simulator's range); its step count is
/// clamped to the model's time limit.
pub(crate) fn answer(
    policy: &mut ServedPolicy,
    limits: &Limits,
    max_people: usize,
    payload: &[u8],
) -> proto::serve::ActReply {
    use proto::serve::{ActReply, ActRequest};
    let req = match ActRequest::decode(payload) {
        Ok(r) => r,
        Err(e) => return ActReply::refused(e.to_string()),
    };
    if req.humans.len() > max_people {
        return ActReply::refused(format!(
            "{} humans, at most {max_people} (--max-people)",
            req.humans.len()
        ));
    }
    let obs = Observation {
        robot: RobotObs {
            position: sim::Vec2::new(req.robot.x_m, req.robot.y_m),
            velocity: sim::Vec2::new(req.robot.vx_mps, req.robot.vy_mps),
            heading_rad: req.robot.heading_rad,
        },
        goal: sim::Vec2::new(req.goal.x_m, req.goal.y_m),
        humans: req
            .humans
            .iter()
            .map(|h| PersonObs {
                position: sim::Vec2::new(h.x_m, h.y_m),
                velocity: sim::Vec2::new(h.vx_mps, h.vy_mps),
                radius_m: h.radius_m,
                goal: h
                    .goal_x_m
                    .zip(h.goal_y_m)
                    .map(|(x, y)| sim::Vec2::new(x, y)),
                v_pref_mps: h.v_pref_mps,
                standing: h.standing,
            })
            .collect(),
        steps: req.steps,
    };
    let t = Instant::now();
    match policy.decide(&obs) {
        Ok(d) => {
            let c = d.command.limited(limits);
            ActReply {
                ok: true,
                reason: String::new(),
                action: d.action as u32,
                speed_mps: d.speed_mps,
                rotation_rad: d.rotation_rad,
                linear_x_mps: c.linear_x_mps,
                linear_y_mps: c.linear_y_mps,
                angular_z_radps: c.angular_z_radps,
                value: d.value,
                decision_us: t.elapsed().as_secs_f64() * 1e6,
            }
        }
        Err(e) => ActReply::refused(e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::serve::{ActReply, ActRequest};

    fn policy() -> ServedPolicy {
        ServedPolicy::load(&crate::fixtures::shipped_model(), None).unwrap()
    }

    /// The robot at (0, −4), its goal (0, 4), `humans` people ahead.
    fn request(humans: usize) -> ActRequest {
        ActRequest::example(humans)
    }

    fn ask(pol: &mut ServedPolicy, r: &ActRequest) -> ActReply {
        answer(pol, &Limits::default(), 8, &r.encode())
    }

    #[test]
    fn the_queryable_checks_its_fields() {
        let mut pol = policy();
        assert!(ask(&mut pol, &request(3)).ok);
        let many = ask(&mut pol, &request(9));
        assert!(
            !many.ok && many.reason.contains("9 humans, at most 8"),
            "{many:?}"
        );
        let mut far = request(3);
        far.robot.x_m = 1e9;
        let r = ask(&mut pol, &far);
        assert!(!r.ok && r.reason.contains("farther than"), "{r:?}");
        let mut fast = request(3);
        fast.humans[1].vx_mps = 1e4;
        assert!(!ask(&mut pol, &fast).ok);
        // A step count past the time limit plans as the limit.
        let mut late = request(3);
        late.steps = pol.step_limit();
        let at_limit = ask(&mut pol, &late);
        late.steps = u32::MAX;
        let beyond = ask(&mut pol, &late);
        assert!(beyond.ok);
        assert_eq!(
            (beyond.action, beyond.value),
            (at_limit.action, at_limit.value)
        );
        assert!(!answer(&mut pol, &Limits::default(), 8, b"\xc1").ok);
    }
}
