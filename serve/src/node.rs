//! `fsrl serve` on zenoh: subscribers for odometry, goal and people, the command publisher,
//! the queryable, rmw_zenoh's liveliness tokens and attachments, and the loop over one closed
//! [`Event`] enum on the calling thread.
//!
//! What keeps the loop on time whatever arrives: each input topic has one latest-value slot
//! ([`Inbox`]: a newer message replaces an older one not read yet, nothing queues); the loop
//! takes the deadline (its tick, or the instant an input turns stale) before any input, so the
//! staleness check and the stop run every period under any flood; a people message holding
//! more than `max_people` is refused and a decision over its budget dropped, so no one step
//! takes long; `cmd_vel` is published with congestion control `Drop` at priority `RealTime`
//! ([`RosNode::command_publisher`]), so a subscriber that does not read cannot block it; and
//! queries go through a bounded queue ([`QUERY_QUEUE`],
//! refused with a reply beyond, counted) to a worker thread with its own copy of the policy,
//! so neither a query flood nor an asker that does not read its replies reaches the loop.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::query::{Query, Queryable};
use zenoh::{Session, Wait};

use crate::control::{
    Arrival, Clock, Controller, Intake, Output, Safety, StopKind, StopReason, DEFAULT_MAX_PEOPLE,
};
use crate::msg::{
    self, AgentStates, Odometry, People, PoseStamped, RosMsg, TrackedPersons, Twist, Vector3,
};
use crate::people::{PeopleFormat, PersonObs};
use crate::ros2::{check_topic, gid_of, Attachment, Entity, NodeId, Ros2Style};
use crate::served::{Command, Limits, Observation, RobotObs, ServedPolicy};

/// Topic names (ROS 2 names; `/`-rooted or relative, both map to the same key).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    pub odom: String,
    pub goal: String,
    pub people: String,
    pub cmd_vel: String,
}

impl Default for Topics {
    fn default() -> Self {
        Self {
            odom: "odom".into(),
            goal: "goal_pose".into(),
            people: "people".into(),
            cmd_vel: "cmd_vel".into(),
        }
    }
}

impl Topics {
    pub fn check(&self) -> Result<(), String> {
        for t in [&self.odom, &self.goal, &self.people, &self.cmd_vel] {
            check_topic(t)?;
        }
        Ok(())
    }
}

/// When the policy decides.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Trigger {
    /// Every control period (a robot).
    #[default]
    Timer,
    /// On every odometry message, once people of the same stamp are in (a simulator stepping
    /// in lockstep, such as `fsrl sim --as-robot`); the watchdog still stops on stale input.
    Odometry,
}

/// Everything `fsrl serve` needs; [`ServeOptions::check`] says what is wrong with it.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    pub model: PathBuf,
    /// Names the queryable `fsrl/serve/<name>/act` and the ROS 2 node.
    pub name: String,
    pub style: Ros2Style,
    pub topics: Topics,
    pub people_format: PeopleFormat,
    pub trigger: Trigger,
    /// Control period in seconds; default the model's step.
    pub period_s: Option<f64>,
    /// Stale after this many periods (default 2).
    pub stale_periods: f64,
    pub limits: Limits,
    /// Whose clock the stamps are on (default this computer's).
    pub clock: Clock,
    /// How far a stamp may be from the clock it is checked against, in seconds.
    pub stamp_tolerance_s: f64,
    /// Most people in one message (and in one query); beyond: refused, a stop.
    pub max_people: usize,
    /// Longest a decision may take, in seconds; default half the period.
    pub decision_budget_s: Option<f64>,
    pub robot_visible: Option<bool>,
    /// Depth-2 planning over this many best first steps, whatever the model was trained with
    /// (`train.planning_top_k`; 0: the paper's one-step lookahead); default the model's own.
    pub planning_top_k: Option<usize>,
    /// Second steps tried after each planned first step, whatever the model says
    /// (`train.planning_breadth`; 0: every action); default the model's own.
    pub planning_breadth: Option<usize>,
    /// Threads of one decision's network batches (1: the loop's own; more pay with planning).
    pub threads: usize,
    pub zenoh: transport::ZenohConfig,
}

/// Most threads one decision may use.
pub const MAX_THREADS: usize = 64;
/// Longest control period accepted, in seconds.
pub const MAX_PERIOD_S: f64 = 60.0;
/// Most periods the staleness limit may span.
pub const MAX_STALE_PERIODS: f64 = 1.0e6;
/// Largest stamp tolerance accepted, in seconds.
pub const MAX_STAMP_TOLERANCE_S: f64 = 3600.0;
/// Most queries waiting for the policy; a query beyond is refused at once (counted).
pub const QUERY_QUEUE: usize = 32;
/// Most bytes of queries waiting.
pub const QUERY_QUEUE_BYTES: usize = 4 << 20;

impl ServeOptions {
    /// The defaults of `fsrl serve MODEL`: bridge keys, default topics, people_msgs, the
    /// timer, the model's period, stale after 2 periods, no limits, this computer's clock
    /// with 0.5 s of tolerance, [`DEFAULT_MAX_PEOPLE`], half a period of decision budget,
    /// a peer listening on loopback.
    pub fn new(model: impl Into<PathBuf>) -> Self {
        Self {
            model: model.into(),
            name: "fsrl".into(),
            style: Ros2Style::Bridge { namespace: None },
            topics: Topics::default(),
            people_format: PeopleFormat::People,
            trigger: Trigger::Timer,
            period_s: None,
            stale_periods: 2.0,
            limits: Limits::default(),
            clock: Clock::System,
            stamp_tolerance_s: 0.5,
            max_people: DEFAULT_MAX_PEOPLE,
            decision_budget_s: None,
            robot_visible: None,
            planning_top_k: None,
            planning_breadth: None,
            threads: 1,
            zenoh: transport::ZenohConfig::default(),
        }
    }

    /// Every problem of the limits, periods and names, in one line (nothing is opened or
    /// loaded): negative, zero where it means nothing, NaN and infinite numbers are refused.
    pub fn check(&self) -> Result<(), ServeError> {
        let mut problems = Vec::new();
        let positive = |flag: &str, v: f64, max: f64, problems: &mut Vec<String>| {
            if !(v.is_finite() && v > 0.0 && v <= max) {
                problems.push(format!(
                    "{flag} {v}: must be positive, finite and at most {max}"
                ));
            }
        };
        if let Some(p) = self.period_s {
            positive("--period-s", p, MAX_PERIOD_S, &mut problems);
        }
        positive(
            "--stale-periods",
            self.stale_periods,
            MAX_STALE_PERIODS,
            &mut problems,
        );
        let t = self.stamp_tolerance_s;
        if !(t.is_finite() && (0.0..=MAX_STAMP_TOLERANCE_S).contains(&t)) {
            problems.push(format!(
                "--stamp-tolerance-s {t}: must be finite, at least 0 and at most {MAX_STAMP_TOLERANCE_S}"
            ));
        }
        if let Some(b) = self.decision_budget_s {
            positive("--decision-budget-s", b, MAX_PERIOD_S, &mut problems);
        }
        let max = proto::serve::MAX_HUMANS;
        if !(1..=max).contains(&self.max_people) {
            problems.push(format!(
                "--max-people {}: must be at least 1 and at most {max}",
                self.max_people
            ));
        }
        if !(1..=MAX_THREADS).contains(&self.threads) {
            problems.push(format!(
                "--threads {}: must be at least 1 and at most {MAX_THREADS}",
                self.threads
            ));
        }
        let max = policy::lookahead::MAX_PLANNING_TOP_K;
        for (flag, v) in [
            ("--planning-top-k", self.planning_top_k),
            ("--planning-breadth", self.planning_breadth),
        ] {
            if let Some(v) = v.filter(|&v| v > max) {
                problems.push(format!("{flag} {v}: must be at most {max}"));
            }
        }
        problems.extend(self.limits.check());
        if let Err(e) = self.topics.check() {
            problems.push(e);
        }
        if let Err(e) = proto::keys::serve_act(&self.name) {
            problems.push(format!("--name {:?}: {e}", self.name));
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(ServeError::Config(problems.join("; ")))
        }
    }
}

/// Why serving stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("{0}")]
    Config(String),
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error(transparent)]
    Model(#[from] crate::served::PolicyFailure),
}

fn zerr(what: &'static str) -> impl Fn(zenoh::Error) -> ServeError {
    move |e| ServeError::Zenoh(format!("{what}: {e}"))
}

/// What the loop reacts to, in the order it takes them ([`Inbox::next`]): a stop request,
/// the deadline (the control period's tick or the instant an input turns stale), then the
/// latest odometry, goal and people.
pub enum Event {
    Shutdown,
    Deadline,
    Odometry(Vec<u8>, Arrival),
    Goal(Vec<u8>, Arrival),
    People(Vec<u8>, Arrival),
}

/// The latest input of each topic, waiting for the loop: a newer message replaces an older
/// one not read yet (counted), so nothing queues up behind a slow loop.
#[derive(Default)]
struct Slots {
    odometry: Option<(Vec<u8>, Arrival)>,
    goal: Option<(Vec<u8>, Arrival)>,
    people: Option<(Vec<u8>, Arrival)>,
    shutdown: bool,
    replaced: u64,
}

/// Which slot.
#[derive(Debug, Clone, Copy)]
enum Input {
    Odometry,
    Goal,
    People,
}

/// The loop's inbox: a latest-value slot per input topic and the stop request. The
/// subscribers write into it from zenoh's threads; [`Inbox::next`] hands the loop one event.
#[derive(Clone, Default)]
pub struct Inbox {
    shared: Arc<(Mutex<Slots>, Condvar)>,
}

/// Stops a running [`run`] (from a signal handler, another thread).
#[derive(Clone)]
pub struct Stopper(Inbox);

impl Stopper {
    /// Asks the loop to send a last zero command and return.
    pub fn stop(&self) {
        self.0.lock().shutdown = true;
        self.0.shared.1.notify_all();
    }
}

impl Inbox {
    pub fn new() -> Self {
        Self::default()
    }

    /// A handle that stops the loop reading this inbox.
    pub fn stopper(&self) -> Stopper {
        Stopper(self.clone())
    }

    fn lock(&self) -> MutexGuard<'_, Slots> {
        self.shared.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn put(&self, input: Input, bytes: Vec<u8>, arrival: Arrival) {
        let mut s = self.lock();
        let slot = match input {
            Input::Odometry => &mut s.odometry,
            Input::Goal => &mut s.goal,
            Input::People => &mut s.people,
        };
        let old = slot.replace((bytes, arrival));
        if old.is_some() {
            s.replaced += 1;
        }
        drop(s);
        self.shared.1.notify_all();
        // The replaced bytes are freed here, outside the lock.
        drop(old);
    }

    /// Inputs replaced before the loop read them.
    fn replaced(&self) -> u64 {
        self.lock().replaced
    }

    /// The next event: [`Event::Shutdown`] when asked; [`Event::Deadline`] once `deadline`
    /// has passed, before any input, however many arrive; else the latest odometry, goal or
    /// people; else it waits, until `deadline` at the latest.
    pub fn next(&self, deadline: Instant) -> Event {
        let mut s = self.lock();
        loop {
            if s.shutdown {
                return Event::Shutdown;
            }
            let now = Instant::now();
            if now >= deadline {
                return Event::Deadline;
            }
            if let Some((b, a)) = s.odometry.take() {
                return Event::Odometry(b, a);
            }
            if let Some((b, a)) = s.goal.take() {
                return Event::Goal(b, a);
            }
            if let Some((b, a)) = s.people.take() {
                return Event::People(b, a);
            }
            s = self
                .shared
                .1
                .wait_timeout(s, deadline - now)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
    }
}

/// The queries waiting for the query worker: at most [`QUERY_QUEUE`] of them and
/// [`QUERY_QUEUE_BYTES`] of payload; one more is refused at once, with a reply that says so.
#[derive(Default)]
struct QueryQueue {
    state: Mutex<QueryState>,
    ready: Condvar,
}

#[derive(Default)]
struct QueryState {
    waiting: VecDeque<(Query, Vec<u8>)>,
    bytes: usize,
    refused: u64,
    answered: u64,
    closed: bool,
}

impl QueryQueue {
    fn lock(&self) -> MutexGuard<'_, QueryState> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// From zenoh's callback: queued, or refused with a reply (on the asker's own link).
    fn offer(&self, q: Query) {
        let payload = q
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let mut s = self.lock();
        if s.closed {
            return;
        }
        let full = s.waiting.len() >= QUERY_QUEUE || s.bytes + payload.len() > QUERY_QUEUE_BYTES;
        if !full {
            s.bytes += payload.len();
            s.waiting.push_back((q, payload));
            drop(s);
            self.ready.notify_one();
            return;
        }
        s.refused += 1;
        let (n, waiting) = (s.refused, s.waiting.len());
        drop(s);
        if n.is_power_of_two() {
            tracing::warn!(
                "query refused: {waiting} are waiting, at most {QUERY_QUEUE} (#{n} refused)"
            );
        }
        let reply = proto::serve::ActReply::refused(format!(
            "busy: {waiting} queries are waiting, at most {QUERY_QUEUE}; ask again later"
        ));
        if let Err(e) = q.reply(q.key_expr().clone(), reply.encode()).wait() {
            tracing::debug!("cannot refuse a query: {e}");
        }
    }

    /// For the worker: the next query, or `None` once closed.
    fn take(&self) -> Option<(Query, Vec<u8>)> {
        let mut s = self.lock();
        loop {
            if s.closed {
                return None;
            }
            if let Some((q, payload)) = s.waiting.pop_front() {
                s.bytes -= payload.len();
                return Some((q, payload));
            }
            s = self.ready.wait(s).unwrap_or_else(PoisonError::into_inner);
        }
    }

    fn close(&self) -> (u64, u64) {
        let mut s = self.lock();
        s.closed = true;
        let waiting = std::mem::take(&mut s.waiting);
        let counts = (s.answered, s.refused);
        drop(s);
        self.ready.notify_all();
        // Dropping a query sends its final reply: off the lock, and off the loop (the worker
        // or this thread at shutdown).
        drop(waiting);
        counts
    }
}

/// The query worker: answers the queue's queries with its own copy of the policy, on its own
/// thread, so a query (or an asker that does not read its replies, which blocks a reply) never
/// delays the control loop.
fn answer_queries(
    queue: Arc<QueryQueue>,
    mut policy: ServedPolicy,
    limits: Limits,
    max_people: usize,
) {
    while let Some((q, payload)) = queue.take() {
        let reply = answer(&mut policy, &limits, max_people, &payload);
        if let Err(e) = q.reply(q.key_expr().clone(), reply.encode()).wait() {
            tracing::warn!("cannot reply to a query: {e}");
        }
        queue.lock().answered += 1;
    }
}

/// What a finished run did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Summary {
    pub counters: crate::control::Counters,
    /// Queries answered.
    pub queries: u64,
    /// Queries refused because the queue was full.
    pub refused_queries: u64,
    /// Inputs replaced by a newer one before the loop read them.
    pub replaced_inputs: u64,
}

/// A publisher of one ROS 2 topic, with rmw_zenoh's attachment when that is the style.
pub struct RosPublisher {
    publisher: Publisher<'static>,
    gid: Option<[u8; 16]>,
    seq: i64,
}

impl RosPublisher {
    pub fn put<M: RosMsg>(&mut self, m: &M) -> Result<(), ServeError> {
        let bytes = msg::encode(m).map_err(|e| ServeError::Config(e.to_string()))?;
        self.put_bytes(bytes)
    }

    pub fn put_bytes(&mut self, bytes: Vec<u8>) -> Result<(), ServeError> {
        self.seq += 1;
        let put = self.publisher.put(ZBytes::from(bytes));
        match self.gid {
            Some(gid) => {
                let now_ns = SystemTime::now()
                    .duration_since(UNIX_EPOCH)
                    .map_or(0, |d| d.as_nanos() as i64);
                let a = Attachment {
                    sequence_number: self.seq,
                    source_timestamp_ns: now_ns,
                    source_gid: gid,
                };
                put.attachment(ZBytes::from(a.encode().to_vec())).wait()
            }
            None => put.wait(),
        }
        .map_err(zerr("put"))
    }

    /// Whether a subscriber matches (someone listens).
    pub fn matched(&self) -> bool {
        self.publisher
            .matching_status()
            .wait()
            .is_ok_and(|s| s.matching())
    }
}

/// A ROS 2 participant on zenoh: its session, node identity and liveliness tokens.
pub struct RosNode {
    pub session: Session,
    style: Ros2Style,
    node: NodeId,
    next_id: u32,
    tokens: Vec<LivelinessToken>,
}

impl RosNode {
    pub fn open(
        zenoh: &transport::ZenohConfig,
        style: Ros2Style,
        name: &str,
    ) -> Result<Self, ServeError> {
        let cfg = zenoh
            .to_zenoh(crate::msg::MAX_MESSAGE_BYTES)
            .map_err(|e| ServeError::Config(e.to_string()))?;
        let session = zenoh::open(cfg).wait().map_err(zerr("open session"))?;
        let node = NodeId {
            zid: session.zid().to_string(),
            nid: 0,
            namespace: "/".into(),
            name: name.replace('-', "_"),
            enclave: "/".into(),
        };
        let mut n = Self {
            session,
            style,
            node,
            next_id: 1,
            tokens: Vec::new(),
        };
        if let Ros2Style::RmwZenoh { domain, distro } = n.style {
            let key = n.node.liveliness::<Twist>(domain, distro, 0, Entity::Node);
            n.token(key)?;
        }
        Ok(n)
    }

    fn token(&mut self, key: String) -> Result<(), ServeError> {
        let t = self
            .session
            .liveliness()
            .declare_token(key)
            .wait()
            .map_err(zerr("declare liveliness token"))?;
        self.tokens.push(t);
        Ok(())
    }

    /// Announces an entity under rmw_zenoh (nothing otherwise); its GID.
    fn announce<M: RosMsg>(&mut self, entity: Entity<'_>) -> Result<Option<[u8; 16]>, ServeError> {
        let Ros2Style::RmwZenoh { domain, distro } = self.style else {
            return Ok(None);
        };
        let id = self.next_id;
        self.next_id += 1;
        let key = self.node.liveliness::<M>(domain, distro, id, entity);
        let gid = gid_of(&key);
        self.token(key)?;
        Ok(Some(gid))
    }

    /// A publisher that waits when the link is congested (the stand-in's inputs, whose
    /// loss would stall a lockstep episode), at zenoh's default priority.
    pub fn publisher<M: RosMsg>(&mut self, topic: &str) -> Result<RosPublisher, ServeError> {
        self.publisher_with::<M>(topic, CongestionControl::Block, Priority::DEFAULT)
    }

    /// The velocity command's publisher: a message a congested link cannot take is dropped
    /// (`Drop`, after zenoh's `wait_before_drop`, 1 ms) instead of waited for, and it goes at
    /// priority `RealTime`, whose queue no `Block` message shares: a query's replies (sent with
    /// the asker's congestion control, `Block` by default, at its priority, `Data` by default)
    /// to an asker that does not read hold the `Data` queue of that link while they wait.
    pub fn command_publisher<M: RosMsg>(
        &mut self,
        topic: &str,
    ) -> Result<RosPublisher, ServeError> {
        self.publisher_with::<M>(topic, CongestionControl::Drop, Priority::RealTime)
    }

    fn publisher_with<M: RosMsg>(
        &mut self,
        topic: &str,
        cc: CongestionControl,
        priority: Priority,
    ) -> Result<RosPublisher, ServeError> {
        let key = self.style.key::<M>(topic);
        let gid = self.announce::<M>(Entity::Publisher { topic })?;
        let publisher = self
            .session
            .declare_publisher(key)
            .congestion_control(cc)
            .priority(priority)
            .wait()
            .map_err(zerr("declare publisher"))?;
        Ok(RosPublisher {
            publisher,
            gid,
            seq: 0,
        })
    }

    pub fn subscribe<M: RosMsg>(
        &mut self,
        topic: &str,
        f: impl Fn(Vec<u8>) + Send + Sync + 'static,
    ) -> Result<Subscriber<()>, ServeError> {
        let key = self.style.key::<M>(topic);
        self.announce::<M>(Entity::Subscription { topic })?;
        self.session
            .declare_subscriber(key)
            .callback(move |s| f(s.payload().to_bytes().into_owned()))
            .wait()
            .map_err(zerr("declare subscriber"))
    }
}

fn twist_of(c: &Command) -> Twist {
    Twist {
        linear: Vector3 {
            x: c.linear_x_mps,
            y: c.linear_y_mps,
            z: 0.0,
        },
        angular: Vector3 {
            x: 0.0,
            y: 0.0,
            z: c.angular_z_radps,
        },
    }
}

fn subscribe_people(
    node: &mut RosNode,
    topic: &str,
    format: PeopleFormat,
    inbox: Inbox,
) -> Result<Subscriber<()>, ServeError> {
    let f = move |b| inbox.put(Input::People, b, Arrival::now());
    match format {
        PeopleFormat::People => node.subscribe::<People>(topic, f),
        PeopleFormat::Spencer => node.subscribe::<TrackedPersons>(topic, f),
        PeopleFormat::Pedsim => node.subscribe::<AgentStates>(topic, f),
    }
}

/// The reply to one query: refused when it does not decode, holds more than `max_people`
/// humans, or the policy refuses its values (out of the simulator's range); its step count is
/// clamped to the model's time limit.
fn answer(
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

/// Logs a stop when its kind changes (not every period, not when only its numbers change).
fn log_transition(last: &mut Option<Option<StopKind>>, out: &Output) {
    let now = out.stop.as_ref().map(StopReason::kind);
    if Some(now) != *last {
        match &out.stop {
            Some(r) => tracing::warn!("zero command: {r}"),
            None => tracing::info!("driving"),
        }
        *last = Some(now);
    }
}

/// The loop's settings once the model has given the period.
fn safety_of(opts: &ServeOptions, period: Duration) -> Result<Safety, ServeError> {
    let secs = |what: &str, s: f64| {
        Duration::try_from_secs_f64(s).map_err(|e| ServeError::Config(format!("{what}: {e}")))
    };
    let budget_s = opts.decision_budget_s.unwrap_or(period.as_secs_f64() / 2.0);
    Ok(Safety {
        stale_after: secs(
            "the staleness limit",
            period.as_secs_f64() * opts.stale_periods,
        )?,
        limits: opts.limits,
        clock: opts.clock,
        stamp_tolerance: secs("--stamp-tolerance-s", opts.stamp_tolerance_s)?,
        max_people: opts.max_people,
        decision_budget: secs("--decision-budget-s", budget_s)?,
    })
}

/// Runs `fsrl serve` until its [`Stopper`] is called (give [`Inbox::stopper`] to a signal
/// handler). Checks `opts` first ([`ServeOptions::check`]: nothing is opened if they are
/// wrong). Calls `on_ready` once, when the model is loaded and every subscriber, the command
/// publisher and the queryable are declared (the CLI then prints `ready`, which tests wait
/// for). A model that does not load is reported with a zero command on `cmd_vel` before the
/// error returns, without `on_ready`.
pub fn run(
    opts: &ServeOptions,
    inbox: Inbox,
    on_ready: impl FnOnce(),
) -> Result<Summary, ServeError> {
    opts.check()?;
    let act_key =
        proto::keys::serve_act(&opts.name).map_err(|e| ServeError::Config(e.to_string()))?;
    let mut node = RosNode::open(&opts.zenoh, opts.style.clone(), &opts.name)?;
    let mut cmd = node.command_publisher::<Twist>(&opts.topics.cmd_vel)?;
    let mut policy = match ServedPolicy::load(&opts.model, opts.robot_visible) {
        Ok(p) => {
            let p = match opts.planning_top_k {
                Some(k) => p.with_planning_top_k(k),
                None => p,
            };
            match opts.planning_breadth {
                Some(m) => p.with_planning_breadth(m),
                None => p,
            }
            .with_threads(opts.threads)
        }
        Err(e) => {
            let reason = StopReason::ModelNotLoaded(e.to_string());
            tracing::error!("zero command: {reason}");
            // Give a subscriber that is connecting a moment to match, so the stop reaches it.
            let deadline = Instant::now() + Duration::from_secs(2);
            while !cmd.matched() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(20));
            }
            cmd.put(&Twist::ZERO)?;
            return Err(e.into());
        }
    };
    let period = match opts.period_s {
        Some(s) => Duration::try_from_secs_f64(s)
            .map_err(|e| ServeError::Config(format!("--period-s {s}: {e}")))?,
        None => Duration::from_secs_f64(policy.period_s()),
    };
    let safety = safety_of(opts, period)?;
    let mut control = Controller::new(safety, opts.people_format);

    let queries = Arc::new(QueryQueue::default());
    let worker_policy = ServedPolicy::from_model(policy.model().clone(), opts.robot_visible)?
        .with_threads(opts.threads);
    let worker = {
        let queries = queries.clone();
        let (limits, max_people) = (opts.limits, opts.max_people);
        std::thread::Builder::new()
            .name("fsrl-serve-queries".into())
            .spawn(move || answer_queries(queries, worker_policy, limits, max_people))
            .map_err(|e| ServeError::Config(format!("cannot start the query worker: {e}")))?
    };

    let i = inbox.clone();
    let _odom = node.subscribe::<Odometry>(&opts.topics.odom, move |b| {
        i.put(Input::Odometry, b, Arrival::now())
    })?;
    let i = inbox.clone();
    let _goal = node.subscribe::<PoseStamped>(&opts.topics.goal, move |b| {
        i.put(Input::Goal, b, Arrival::now())
    })?;
    let _people = subscribe_people(
        &mut node,
        &opts.topics.people,
        opts.people_format,
        inbox.clone(),
    )?;
    let q = queries.clone();
    let queryable: Queryable<()> = node
        .session
        .declare_queryable(act_key.clone())
        .callback(move |query| q.offer(query))
        .wait()
        .map_err(zerr("declare queryable"))?;
    tracing::info!(
        model = %opts.model.display(),
        method = %policy.model().method,
        setting = policy.setting().name(),
        period_s = period.as_secs_f64(),
        stale_after_s = safety.stale_after.as_secs_f64(),
        clock = ?safety.clock,
        max_people = safety.max_people,
        decision_budget_s = safety.decision_budget.as_secs_f64(),
        queryable = %act_key,
        "serving"
    );
    on_ready();

    let mut summary = Summary::default();
    let mut last_log = None;
    let mut next_tick = Instant::now() + period;
    // Stale instants up to this one have been acted on.
    let mut watched = Instant::now();
    let publish = |cmd: &mut RosPublisher, out: &Output, last: &mut _| {
        log_transition(last, out);
        if let Err(e) = cmd.put(&twist_of(&out.command)) {
            tracing::warn!("cannot publish the command: {e}");
        }
    };
    let lockstep = opts.trigger == Trigger::Odometry;
    loop {
        let stale = control.stale_at().filter(|&t| t > watched);
        let deadline = stale.map_or(next_tick, |t| t.min(next_tick));
        let ev = inbox.next(deadline);
        let out = match ev {
            Event::Shutdown => {
                let out = Output::stop(StopReason::Shutdown);
                publish(&mut cmd, &out, &mut last_log);
                break;
            }
            Event::Deadline => {
                let now = Instant::now();
                watched = now;
                if now >= next_tick {
                    next_tick += period;
                    if next_tick < now {
                        next_tick = now + period;
                    }
                    if lockstep {
                        // The tick is only the watchdog: inputs missing at the start are
                        // not a fault, the simulator has not begun.
                        match control.observation(now) {
                            Err(reason)
                                if !matches!(
                                    reason,
                                    StopReason::NoOdometry
                                        | StopReason::NoGoal
                                        | StopReason::NoPeople
                                ) =>
                            {
                                Some(Output::stop(reason))
                            }
                            _ => None,
                        }
                    } else {
                        Some(control.step(&mut policy, now))
                    }
                } else {
                    // An input has just turned stale: the stop goes out now, not at the tick.
                    match control.observation(now) {
                        Err(
                            reason @ (StopReason::StaleOdometry { .. }
                            | StopReason::StalePeople { .. }),
                        ) => Some(Output::stop(reason)),
                        _ => None,
                    }
                }
            }
            Event::Odometry(b, at) => match control.on_odometry(&b, at) {
                Intake::Undecodable(e) => {
                    log_count("odometry", control.counters().undecodable_odometry, &e);
                    None
                }
                Intake::Refused(r) => Some(Output::stop(r)),
                Intake::Accepted => (lockstep && control.synced())
                    .then(|| control.step(&mut policy, Instant::now())),
            },
            Event::People(b, at) => match control.on_people(&b, at) {
                Intake::Undecodable(e) => {
                    log_count("people", control.counters().undecodable_people, &e);
                    None
                }
                Intake::Refused(r) => Some(Output::stop(r)),
                Intake::Accepted => (lockstep && control.synced())
                    .then(|| control.step(&mut policy, Instant::now())),
            },
            Event::Goal(b, at) => match control.on_goal(&b, at) {
                Intake::Undecodable(e) => {
                    log_count("goal", control.counters().undecodable_goals, &e);
                    None
                }
                Intake::Refused(r) => Some(Output::stop(r)),
                Intake::Accepted => None,
            },
        };
        if let Some(out) = out {
            publish(&mut cmd, &out, &mut last_log);
        }
    }
    drop(queryable);
    (summary.queries, summary.refused_queries) = queries.close();
    // The worker ends after its current reply (it is not waited for: a reply to an asker
    // that does not read may block it until zenoh closes that link).
    drop(worker);
    summary.counters = control.counters();
    summary.replaced_inputs = inbox.replaced();
    let c = summary.counters;
    tracing::info!(
        decisions = c.decisions,
        stops = c.stops,
        too_slow = c.too_slow,
        undecodable = c.undecodable(),
        refused_goals = c.refused_goals,
        refused_odometry = c.refused_odometry,
        refused_people = c.refused_people,
        replaced_inputs = summary.replaced_inputs,
        queries = summary.queries,
        refused_queries = summary.refused_queries,
        "stopped"
    );
    drop(node);
    Ok(summary)
}

/// Undecodable input: logged at powers of two of its count (1, 2, 4, ...).
fn log_count(topic: &str, count: u64, error: &str) {
    if count.is_power_of_two() {
        tracing::warn!("undecodable {topic} message (#{count}, kept the last good one): {error}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::serve::{ActReply, ActRequest, GoalObs, HumanObs, RobotObs as RobotIn};

    fn policy() -> ServedPolicy {
        ServedPolicy::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../models/fsrl-env1-invisible-s0.fsrlm"),
            None,
        )
        .unwrap()
    }

    fn request(humans: usize) -> ActRequest {
        ActRequest {
            robot: RobotIn {
                x_m: 0.0,
                y_m: -4.0,
                vx_mps: 0.0,
                vy_mps: 0.0,
                heading_rad: 1.5,
            },
            goal: GoalObs { x_m: 0.0, y_m: 4.0 },
            humans: (0..humans)
                .map(|i| HumanObs {
                    x_m: 1.0 + i as f64,
                    y_m: 0.0,
                    vx_mps: -0.5,
                    vy_mps: 0.0,
                    radius_m: None,
                    goal_x_m: None,
                    goal_y_m: None,
                    v_pref_mps: None,
                    standing: None,
                })
                .collect(),
            steps: 0,
        }
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

    #[test]
    fn options_are_checked_all_at_once_in_one_line() {
        let mut o = ServeOptions::new("model.fsrlm");
        assert!(o.check().is_ok());
        o.stale_periods = f64::INFINITY;
        o.period_s = Some(-0.25);
        o.limits.max_turn_rate_radps = Some(f64::NAN);
        o.max_people = 0;
        o.planning_top_k = Some(policy::lookahead::MAX_PLANNING_TOP_K + 1);
        o.planning_breadth = Some(policy::lookahead::MAX_PLANNING_TOP_K + 2);
        o.threads = 0;
        let e = o.check().unwrap_err().to_string();
        for flag in [
            "--stale-periods inf",
            "--period-s -0.25",
            "--max-turn-rate-radps NaN",
            "--max-people 0",
            "--planning-top-k 82",
            "--planning-breadth 83",
            "--threads 0",
        ] {
            assert!(e.contains(flag), "{flag}: {e}");
        }
        assert!(!e.contains('\n'));
    }
}
