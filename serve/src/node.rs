//! `fsrl serve` on zenoh: subscribers for odometry, goal and people, the command publisher,
//! the queryable, rmw_zenoh's liveliness tokens and attachments, and the loop over one closed
//! [`Event`] enum on the calling thread.
//!
//! [`run`] reads top to bottom: check the options, open the node and the command publisher,
//! load the policy ([`load_policy`]), time one decision at the most the options allow
//! ([`check_budget`]), start the queryable's threads, subscribe, then drive ([`Driver`]) until
//! stopped, and sum up.
//!
//! What keeps the loop on time whatever arrives: each input topic has one latest-value slot
//! ([`Inbox`]: a newer message replaces an older one not read yet, nothing queues) and the loop
//! takes every slot at once, so no topic starves another; it takes the deadline (its tick, the
//! instant an input turns stale, or in lockstep a period without a command) before any input,
//! so the staleness check and the stop run every period under any flood; a people message
//! holding more than `max_people` is refused, and a decision with that many cannot take longer
//! than the budget (timed at start-up), so no one step takes long; `cmd_vel` is published with
//! congestion control `Drop` at priority `RealTime` ([`RosNode::command_publisher`]), so a
//! subscriber that does not read cannot block it; queries never reach the loop nor block
//! zenoh's threads ([`crate::queries`]), and behind a router their replies go on a link of
//! their own ([`queries_session`]); and whatever ends the loop, a panic included, its last
//! command is a zero one ([`FinalStop`]).

use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::query::Queryable;
use zenoh::{Session, Wait};

use crate::control::{
    Arrival, Clock, Controller, Intake, Output, Safety, StopKind, StopReason, DEFAULT_MAX_PEOPLE,
    DEFAULT_STALE_PERIODS,
};
use crate::msg::{
    self, AgentStates, LaserScan, Odometry, People, PoseStamped, RosMsg, TrackedPersons, Twist,
    Vector3,
};
use crate::people::PeopleFormat;
use crate::queries::Queries;
pub use crate::queries::{QueryCounts, QUERY_QUEUE, QUERY_QUEUE_BYTES};
use crate::ros2::{check_topic, gid_of, Attachment, Entity, NodeId, Ros2Style};
use crate::served::{Command, Limits, Observation, ServedPolicy};

/// Topic names (ROS 2 names; `/`-rooted or relative, both map to the same key).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    pub odom: String,
    pub goal: String,
    pub people: String,
    pub cmd_vel: String,
    /// The laser scan (`sensor_msgs/LaserScan`), read with `--scan` only.
    pub scan: String,
}

impl Default for Topics {
    fn default() -> Self {
        Self {
            odom: "odom".into(),
            goal: "goal_pose".into(),
            people: "people".into(),
            cmd_vel: "cmd_vel".into(),
            scan: "scan".into(),
        }
    }
}

impl Topics {
    pub fn check(&self) -> Result<(), String> {
        for t in [
            &self.odom,
            &self.goal,
            &self.people,
            &self.cmd_vel,
            &self.scan,
        ] {
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
    /// Stale after this many periods (default [`DEFAULT_STALE_PERIODS`]).
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
    /// Static obstacles in the odometry frame (`--map`, parsed and checked before anything
    /// starts): every decision plans among them.
    pub map: Option<sim::map::StaticMap>,
    /// Drive on a laser scan read so (`--scan`): every decision needs a fresh scan and plans
    /// among its walls. Not with `map`.
    pub scan: Option<crate::scan::ScanOptions>,
}

/// Most threads one decision may use.
pub const MAX_THREADS: usize = 64;
/// Longest control period accepted, in seconds.
pub const MAX_PERIOD_S: f64 = 60.0;
/// Most periods the staleness limit may span.
pub const MAX_STALE_PERIODS: f64 = 1.0e6;
/// Largest stamp tolerance accepted, in seconds.
pub const MAX_STAMP_TOLERANCE_S: f64 = 3600.0;

impl ServeOptions {
    /// The defaults of `fsrl serve MODEL`: bridge keys, default topics, people_msgs, the
    /// timer, the model's period, stale after [`DEFAULT_STALE_PERIODS`] periods, no limits, this computer's clock
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
            stale_periods: DEFAULT_STALE_PERIODS,
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
            map: None,
            scan: None,
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
        // As training refuses `train.planning_breadth` without `train.planning_top_k`.
        if let Some(m) = self.planning_breadth.filter(|&m| m > 0) {
            if self.planning_top_k.unwrap_or(0) == 0 {
                problems.push(format!(
                    "--planning-breadth {m} needs --planning-top-k of at least 1 (no planning, no second steps)"
                ));
            }
        }
        problems.extend(self.limits.check());
        if let Some(scan) = &self.scan {
            if self.map.is_some() {
                problems.push(
                    "--map and --scan together: choose one (the walls of a map in the odometry frame, or the walls the scan shows)"
                        .into(),
                );
            }
            problems.extend(scan.check());
        }
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
/// the deadline (the control period's tick, the instant an input turns stale, or in lockstep
/// a period without a command), then every input that came, all at once.
pub enum Event {
    Shutdown,
    Deadline,
    Inputs(Inputs),
}

/// The latest message of each input topic not read yet, with when it arrived.
#[derive(Default)]
pub struct Inputs {
    pub odometry: Option<(Vec<u8>, Arrival)>,
    pub goal: Option<(Vec<u8>, Arrival)>,
    pub people: Option<(Vec<u8>, Arrival)>,
    pub scan: Option<(Vec<u8>, Arrival)>,
}

impl Inputs {
    fn is_empty(&self) -> bool {
        self.odometry.is_none()
            && self.goal.is_none()
            && self.people.is_none()
            && self.scan.is_none()
    }
}

/// The latest input of each topic, waiting for the loop: a newer message replaces an older
/// one not read yet (counted), so nothing queues up behind a slow loop.
#[derive(Default)]
struct Slots {
    inputs: Inputs,
    shutdown: bool,
    replaced: u64,
    /// A test's way to make the loop panic (the final zero command's test).
    #[cfg(test)]
    panic: bool,
}

/// Which slot.
#[derive(Debug, Clone, Copy)]
enum Input {
    Odometry,
    Goal,
    People,
    Scan,
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
            Input::Odometry => &mut s.inputs.odometry,
            Input::Goal => &mut s.inputs.goal,
            Input::People => &mut s.inputs.people,
            Input::Scan => &mut s.inputs.scan,
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
    /// has passed, before any input, however many arrive; else every input waiting, at once
    /// (a flood on one topic cannot hold back the others); else it waits, until `deadline` at
    /// the latest.
    pub fn next(&self, deadline: Instant) -> Event {
        let mut s = self.lock();
        loop {
            #[cfg(test)]
            if s.panic {
                s.panic = false;
                drop(s);
                panic!("a panic in the loop, as a test asked");
            }
            if s.shutdown {
                return Event::Shutdown;
            }
            let now = Instant::now();
            if now >= deadline {
                return Event::Deadline;
            }
            if !s.inputs.is_empty() {
                return Event::Inputs(std::mem::take(&mut s.inputs));
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

/// What a finished run did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Summary {
    pub counters: crate::control::Counters,
    /// Queries answered.
    pub queries: u64,
    /// Queries refused because the queue was full.
    pub refused_queries: u64,
    /// Of those, dropped without a reply (the refusals' own queue full too).
    pub dropped_queries: u64,
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
/// wrong). Calls `on_ready` once, when the model is loaded, a decision at the most the options
/// allow has been timed within the budget, and every subscriber, the command publisher and the
/// queryable are declared (the CLI then prints `ready`, which tests wait for). A model that
/// does not load, or decides too slowly, is reported with a zero command on `cmd_vel` before
/// the error returns, without `on_ready`.
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
    let mut policy = load_policy(opts).or_else(|e| refuse_to_start(&mut cmd, e))?;
    let map_walls = match &opts.map {
        Some(map) => {
            let w = policy
                .walls_of(map.clone())
                .map_err(ServeError::Model)
                .or_else(|e| refuse_to_start(&mut cmd, e))?;
            policy.set_walls(Some(Arc::clone(&w)));
            Some(w)
        }
        None => None,
    };
    let period = match opts.period_s {
        Some(s) => Duration::try_from_secs_f64(s)
            .map_err(|e| ServeError::Config(format!("--period-s {s}: {e}")))?,
        None => Duration::from_secs_f64(policy.period_s()),
    };
    let safety = safety_of(opts, period)?;
    let worst = check_budget(&mut policy, &safety, opts.scan.as_ref())
        .or_else(|e| refuse_to_start(&mut cmd, e))?;

    let mut asked_policy = ServedPolicy::from_model(policy.model().clone(), opts.robot_visible)?
        .with_threads(opts.threads)
        .with_walls(map_walls.clone());
    if opts.scan.is_some() {
        asked_policy = asked_policy.requiring_walls(
            "this server sees walls through its laser scan (--scan), which a query does not carry: ask a server with --map, or none",
        );
    }
    let mut queries =
        Queries::start(asked_policy, opts.limits, opts.max_people).map_err(ServeError::Config)?;
    let subscribers = subscribe_inputs(&mut node, opts, &inbox)?;
    let asked = queries_session(&node, &opts.zenoh)?;
    let queryable = declare_queryable(&asked, &act_key, &queries)?;
    tracing::info!(
        model = %opts.model.display(),
        method = %policy.model().method,
        setting = policy.setting().name(),
        period_s = period.as_secs_f64(),
        stale_after_s = safety.stale_after.as_secs_f64(),
        clock = ?safety.clock,
        max_people = safety.max_people,
        decision_budget_s = safety.decision_budget.as_secs_f64(),
        slowest_decision_ms = worst.as_secs_f64() * 1e3,
        queryable = %act_key,
        walls = match (&opts.map, &opts.scan) {
            (Some(m), _) => format!("a map of {} shapes", m.shapes().len()),
            (None, Some(_)) => format!("the laser scan on {}", opts.topics.scan),
            (None, None) => "none (an open floor)".to_string(),
        },
        "serving"
    );
    if opts.map.is_some() && !policy.setting().env.is_walled() {
        tracing::warn!(
            setting = policy.setting().name(),
            "this model was trained on an open floor: it sees the walls as points it never met in training"
        );
    }
    on_ready();

    let mut control = Controller::new(safety, opts.people_format);
    if let Some(scan) = opts.scan {
        control = control.with_scan(scan);
    }
    let mut driver = Driver::new(control, period, opts.trigger == Trigger::Odometry);
    driver.run(&inbox, &mut policy, &mut cmd);

    drop(queryable);
    drop(subscribers);
    let summary = summarise(&driver.control, &mut queries, &inbox);
    drop(asked);
    drop(node);
    Ok(summary)
}

/// The model with the options' planning and threads.
fn load_policy(opts: &ServeOptions) -> Result<ServedPolicy, ServeError> {
    let mut p = ServedPolicy::load(&opts.model, opts.robot_visible)?;
    if let Some(k) = opts.planning_top_k {
        p = p.with_planning_top_k(k);
    }
    if let Some(m) = opts.planning_breadth {
        p = p.with_planning_breadth(m);
    }
    Ok(p.with_threads(opts.threads))
}

/// Why `fsrl serve` does not start, after a zero command on `cmd_vel` (logged with the reason).
fn refuse_to_start<T>(cmd: &mut RosPublisher, e: ServeError) -> Result<T, ServeError> {
    let reason = match &e {
        ServeError::Model(m) => StopReason::ModelNotLoaded(m.to_string()),
        other => StopReason::PolicyFailed(other.to_string()),
    };
    tracing::error!("zero command: {reason}");
    // Give a subscriber that is connecting a moment to match, so the stop reaches it.
    let deadline = Instant::now() + Duration::from_secs(2);
    while !cmd.matched() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    cmd.put(&Twist::ZERO)?;
    Err(e)
}

/// Times one decision at the most the options allow (`max_people` people, the policy's
/// planning and threads): past the decision budget, every decision with that many people
/// would be dropped for a zero command, after holding the loop that long, so `fsrl serve`
/// refuses to start, saying what it measured. The first decision also sets up the policy's
/// world: a second one is timed when the first is over the budget by less than four times.
fn check_budget(
    policy: &mut ServedPolicy,
    safety: &Safety,
    scan: Option<&crate::scan::ScanOptions>,
) -> Result<Duration, ServeError> {
    let crowd = Observation::crowd(safety.max_people);
    let budget = safety.decision_budget;
    // With a scan, each decision first builds the walls of the scan: a full turn of a 10 m
    // square room around the crowd, at the default lidar's 360 beams.
    let room = scan.map(|opts| {
        let map = sim::map::StaticMap::new(vec![sim::map::Shape::room(
            sim::Vec2::new(-5.0, -3.0),
            sim::Vec2::new(5.0, 7.0),
        )])
        .expect("a valid room");
        let s = sim::scan::simulate(
            &map,
            &[],
            crowd.robot.position,
            crowd.robot.heading_rad,
            &sim::scan::ScanGeometry::default_360(),
        );
        (s, *opts)
    });
    let mut took = Duration::MAX;
    for _ in 0..2 {
        let started = Instant::now();
        if let Some((s, opts)) = &room {
            let (w, _) =
                crate::scan::walls(s, &crowd.robot, &crowd.humans, policy.sim_config(), opts)
                    .map_err(|e| ServeError::Config(e.to_string()))?;
            policy.set_walls(Some(Arc::new(w)));
        }
        policy.decide(&crowd)?;
        took = took.min(started.elapsed());
        if took <= budget || took > 4 * budget {
            break;
        }
    }
    if room.is_some() {
        policy.set_walls(None);
    }
    if took <= budget {
        return Ok(took);
    }
    let train = &policy.model().train;
    Err(ServeError::Config(format!(
        "a decision with {} people (--max-people) and planning top-k {} breadth {} takes {:.1} ms, over the budget of {:.1} ms (--decision-budget-s, default half the period): lower --max-people or --planning-top-k, or raise --threads or the budget",
        safety.max_people,
        train.planning_top_k,
        train.planning_breadth,
        took.as_secs_f64() * 1e3,
        budget.as_secs_f64() * 1e3
    )))
}

/// The input subscribers, each writing into its slot of `inbox`.
fn subscribe_inputs(
    node: &mut RosNode,
    opts: &ServeOptions,
    inbox: &Inbox,
) -> Result<Vec<Subscriber<()>>, ServeError> {
    let i = inbox.clone();
    let odom = node.subscribe::<Odometry>(&opts.topics.odom, move |b| {
        i.put(Input::Odometry, b, Arrival::now())
    })?;
    let i = inbox.clone();
    let goal = node.subscribe::<PoseStamped>(&opts.topics.goal, move |b| {
        i.put(Input::Goal, b, Arrival::now())
    })?;
    let people = subscribe_people(node, &opts.topics.people, opts.people_format, inbox.clone())?;
    let mut subs = vec![odom, goal, people];
    if opts.scan.is_some() {
        let i = inbox.clone();
        subs.push(node.subscribe::<LaserScan>(&opts.topics.scan, move |b| {
            i.put(Input::Scan, b, Arrival::now())
        })?);
    }
    Ok(subs)
}

/// The session the queryable is declared on. Connected to a router (`connect` given), one of
/// its own, opened from the same settings without listening: its own link to the router, so
/// that the replies to askers that do not read, which the router forwards with the askers'
/// congestion control (`Block` by default), stall the router's reading of that link only, not
/// of the link the robot's inputs and `cmd_vel` go on (with one session, the robot received no
/// zero command for seconds). Else the node's own: askers connect directly, each on its own
/// link.
fn queries_session(node: &RosNode, zenoh: &transport::ZenohConfig) -> Result<Session, ServeError> {
    if zenoh.connect.is_empty() {
        return Ok(node.session.clone());
    }
    let own = transport::ZenohConfig {
        listen: Vec::new(),
        ..zenoh.clone()
    };
    let cfg = own
        .to_zenoh(crate::msg::MAX_MESSAGE_BYTES)
        .map_err(|e| ServeError::Config(e.to_string()))?;
    zenoh::open(cfg)
        .wait()
        .map_err(zerr("open the queryable's session"))
}

/// The queryable `act_key` on `session`: each query handed to `queries` at once.
fn declare_queryable(
    session: &Session,
    act_key: &str,
    queries: &Queries,
) -> Result<Queryable<()>, ServeError> {
    let offer = queries.offerer();
    session
        .declare_queryable(act_key.to_string())
        .callback(move |query| offer.offer(query))
        .wait()
        .map_err(zerr("declare queryable"))
}

/// What the run did, logged and returned.
fn summarise(control: &Controller, queries: &mut Queries, inbox: &Inbox) -> Summary {
    let q = queries.close();
    let summary = Summary {
        counters: control.counters(),
        queries: q.answered,
        refused_queries: q.refused,
        dropped_queries: q.dropped,
        replaced_inputs: inbox.replaced(),
    };
    let c = summary.counters;
    tracing::info!(
        decisions = c.decisions,
        stops = c.stops,
        too_slow = c.too_slow,
        undecodable = c.undecodable(),
        refused_goals = c.refused_goals,
        refused_odometry = c.refused_odometry,
        refused_people = c.refused_people,
        scans = c.scans,
        undecodable_scans = c.undecodable_scans,
        refused_scans = c.refused_scans,
        replaced_inputs = summary.replaced_inputs,
        queries = summary.queries,
        refused_queries = summary.refused_queries,
        dropped_queries = summary.dropped_queries,
        "stopped"
    );
    summary
}

/// The command publisher as the loop holds it: whatever ends the loop (a shutdown, a panic),
/// the last command it sends is a zero one.
struct FinalStop<'a> {
    cmd: &'a mut RosPublisher,
    last_was_zero: bool,
}

impl FinalStop<'_> {
    fn put(&mut self, c: &Command) {
        self.last_was_zero = *c == Command::STOP;
        if let Err(e) = self.cmd.put(&twist_of(c)) {
            tracing::warn!("cannot publish the command: {e}");
        }
    }
}

impl Drop for FinalStop<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            tracing::error!("zero command: the loop panicked");
        } else if self.last_was_zero {
            return;
        }
        if let Err(e) = self.cmd.put(&Twist::ZERO) {
            tracing::error!("cannot publish the final zero command: {e}");
        }
    }
}

/// The control loop: one [`Event`] at a time from the inbox, each turned into the commands it
/// calls for.
struct Driver {
    control: Controller,
    period: Duration,
    /// `--trigger odometry`: decide on each odometry once people of its stamp are in; the
    /// tick is only the watchdog.
    lockstep: bool,
    next_tick: Instant,
    /// Stale instants up to this one have been acted on.
    watched: Instant,
    /// Lockstep: when the first input not yet followed by a command arrived.
    undecided_since: Option<Instant>,
    /// The kind of the last command's stop, logged when it changes.
    last_log: Option<Option<StopKind>>,
}

impl Driver {
    fn new(control: Controller, period: Duration, lockstep: bool) -> Self {
        let now = Instant::now();
        Self {
            control,
            period,
            lockstep,
            next_tick: now + period,
            watched: now,
            undecided_since: None,
            last_log: None,
        }
    }

    /// Runs until a shutdown; the last command is a zero one, after a panic too.
    fn run(&mut self, inbox: &Inbox, policy: &mut ServedPolicy, cmd: &mut RosPublisher) {
        let mut cmd = FinalStop {
            cmd,
            last_was_zero: false,
        };
        loop {
            let outs = match inbox.next(self.deadline()) {
                Event::Shutdown => {
                    self.publish(&mut cmd, &Output::stop(StopReason::Shutdown));
                    return;
                }
                Event::Deadline => self.on_deadline(policy, Instant::now()),
                Event::Inputs(inputs) => self.on_inputs(policy, inputs),
            };
            for out in &outs {
                self.publish(&mut cmd, out);
            }
        }
    }

    /// The next instant the loop must act at without input: the tick, the instant an input
    /// turns stale (not yet acted on), in lockstep a period after an input no command followed.
    fn deadline(&self) -> Instant {
        let stale = self.control.stale_at().filter(|&t| t > self.watched);
        let undecided = self.undecided_since.map(|t| t + self.period);
        [stale, undecided]
            .into_iter()
            .flatten()
            .fold(self.next_tick, Instant::min)
    }

    fn publish(&mut self, cmd: &mut FinalStop<'_>, out: &Output) {
        log_transition(&mut self.last_log, out);
        cmd.put(&out.command);
        self.undecided_since = None;
    }

    fn on_deadline(&mut self, policy: &mut ServedPolicy, now: Instant) -> Vec<Output> {
        self.watched = now;
        if self.undecided_since.is_some_and(|t| now >= t + self.period) {
            // Lockstep, inputs fresh but no decision for a period: the robot must not keep
            // its last command.
            let reason = match self.control.observation(now) {
                Err(reason) => reason,
                Ok(_) => StopReason::OutOfStep {
                    offset_s: self.control.step_offset_s().unwrap_or(f64::NAN),
                },
            };
            return vec![Output::stop(reason)];
        }
        if now < self.next_tick {
            // An input has just turned stale: the stop goes out now, not at the tick.
            return match self.control.observation(now) {
                Err(
                    reason @ (StopReason::StaleOdometry { .. } | StopReason::StalePeople { .. }),
                ) => vec![Output::stop(reason)],
                _ => Vec::new(),
            };
        }
        self.next_tick += self.period;
        if self.next_tick < now {
            self.next_tick = now + self.period;
        }
        if !self.lockstep {
            return vec![self.control.step(policy, now)];
        }
        // The tick is only the watchdog: inputs missing at the start are not a fault, the
        // simulator has not begun.
        match self.control.observation(now) {
            Err(StopReason::NoOdometry | StopReason::NoGoal | StopReason::NoPeople) | Ok(_) => {
                Vec::new()
            }
            Err(reason) => vec![Output::stop(reason)],
        }
    }

    /// Every input that came, goal first, then people, the scan, then odometry (in lockstep a
    /// decision follows once all are stamped alike).
    fn on_inputs(&mut self, policy: &mut ServedPolicy, inputs: Inputs) -> Vec<Output> {
        let mut outs = Vec::new();
        if let Some((b, at)) = inputs.goal {
            let r = self.control.on_goal(&b, at);
            self.intake(Input::Goal, r, at, &mut outs);
        }
        let mut fresh = false;
        if let Some((b, at)) = inputs.people {
            let r = self.control.on_people(&b, at);
            fresh |= self.intake(Input::People, r, at, &mut outs);
        }
        if let Some((b, at)) = inputs.scan {
            let r = self.control.on_scan(&b, at);
            fresh |= self.intake(Input::Scan, r, at, &mut outs);
        }
        if let Some((b, at)) = inputs.odometry {
            let r = self.control.on_odometry(&b, at);
            fresh |= self.intake(Input::Odometry, r, at, &mut outs);
        }
        if self.lockstep && fresh && self.control.synced() {
            outs.push(self.control.step(policy, Instant::now()));
        }
        outs
    }

    /// One input's intake: whether it was accepted; a refusal's stop into `outs`, an
    /// undecodable message logged. In lockstep an accepted input starts the wait for the
    /// command that must follow within a period.
    fn intake(&mut self, input: Input, r: Intake, at: Arrival, outs: &mut Vec<Output>) -> bool {
        match r {
            Intake::Accepted => {
                if self.lockstep && !matches!(input, Input::Goal) {
                    self.undecided_since.get_or_insert(at.at);
                }
                true
            }
            Intake::Undecodable(e) => {
                let c = self.control.counters();
                let (topic, n) = match input {
                    Input::Odometry => ("odometry", c.undecodable_odometry),
                    Input::Goal => ("goal", c.undecodable_goals),
                    Input::People => ("people", c.undecodable_people),
                    Input::Scan => ("scan", c.undecodable_scans),
                };
                log_count(topic, n, &e);
                false
            }
            Intake::Refused(reason) => {
                if let Input::Scan = input {
                    let n = self.control.counters().refused_scans;
                    if n.is_power_of_two() {
                        tracing::warn!("refused scan (#{n}, the robot stops): {reason}");
                    }
                }
                outs.push(Output::stop(reason));
                false
            }
        }
    }
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

    use std::sync::mpsc;

    use crate::msg::{Header, Quaternion, Time};
    use crate::people::{person_with_tags, PersonObs};

    fn header(t_s: f64) -> Header {
        Header {
            stamp: Time::from_secs_f64(t_s),
            frame_id: "odom".into(),
        }
    }

    /// `fsrl serve` of the shipped model in lockstep on the odometry's clock, never stale, on a
    /// thread (its result joined at the end); its inbox; a robot peer receiving `cmd_vel`.
    fn lockstep_server() -> (
        std::thread::JoinHandle<Result<Summary, ServeError>>,
        Inbox,
        Session,
        mpsc::Receiver<Twist>,
    ) {
        let endpoint = format!("tcp/127.0.0.1:{}", testkit::free_port());
        let opts = ServeOptions {
            name: "node-test".into(),
            trigger: Trigger::Odometry,
            clock: Clock::Odometry,
            stale_periods: MAX_STALE_PERIODS,
            zenoh: transport::ZenohConfig::peer(vec![endpoint.clone()], vec![]),
            ..ServeOptions::new(crate::fixtures::shipped_model())
        };
        let inbox = Inbox::new();
        let (ready_tx, ready) = mpsc::channel();
        let server = {
            let inbox = inbox.clone();
            std::thread::spawn(move || {
                run(&opts, inbox, move || {
                    let _ = ready_tx.send(());
                })
            })
        };
        ready
            .recv_timeout(Duration::from_secs(60))
            .expect("fsrl serve is ready");
        let cfg = transport::ZenohConfig::peer(vec![], vec![endpoint])
            .to_zenoh(1 << 20)
            .unwrap();
        let robot = zenoh::open(cfg).wait().unwrap();
        let (tx, cmd) = mpsc::channel();
        robot
            .declare_subscriber("cmd_vel")
            .callback(move |s| {
                let _ = tx.send(msg::decode::<Twist>(&s.payload().to_bytes()).unwrap());
            })
            .background()
            .wait()
            .unwrap();
        (server, inbox, robot, cmd)
    }

    /// Steps the robot in lockstep (goal, people and odometry stamped alike) until a command
    /// that moves it comes.
    fn drive(robot: &Session, cmd: &mpsc::Receiver<Twist>) {
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut t_s = 1000.0;
        while Instant::now() < deadline {
            t_s += 0.25;
            let goal = PoseStamped {
                header: header(1000.0),
                pose: crate::msg::Pose {
                    position: crate::msg::Point {
                        x: 0.0,
                        y: 4.0,
                        z: 0.0,
                    },
                    ..Default::default()
                },
            };
            let p = PersonObs::tracked(sim::Vec2::new(2.0, 0.0), sim::Vec2::new(-0.5, 0.0));
            let people = People {
                header: header(t_s),
                people: vec![person_with_tags("a".into(), &p)],
            };
            let mut odom = Odometry {
                header: header(t_s),
                child_frame_id: "base_link".into(),
                ..Odometry::default()
            };
            odom.pose.pose.position.y = -4.0;
            odom.pose.pose.orientation = Quaternion::from_yaw(std::f64::consts::FRAC_PI_2);
            for (key, bytes) in [
                ("goal_pose", msg::encode(&goal)),
                ("people", msg::encode(&people)),
                ("odom", msg::encode(&odom)),
            ] {
                robot.put(key, bytes.unwrap()).wait().unwrap();
            }
            if let Ok(t) = cmd.recv_timeout(Duration::from_millis(100)) {
                if t != Twist::ZERO {
                    return;
                }
            }
        }
        panic!("no command that moves the robot");
    }

    #[test]
    fn a_flood_on_one_input_does_not_hold_back_the_others() {
        let inbox = Inbox::new();
        let far = Instant::now() + Duration::from_secs(60);
        let now = Arrival::now();
        inbox.put(Input::Goal, b"goal".to_vec(), now);
        inbox.put(Input::People, b"people".to_vec(), now);
        let mut seen = (false, false);
        // Odometry is there again each time the loop looks.
        for _ in 0..10 {
            inbox.put(Input::Odometry, b"odom".to_vec(), now);
            let Event::Inputs(i) = inbox.next(far) else {
                panic!("not inputs");
            };
            assert!(i.odometry.is_some());
            seen.0 |= i.goal.is_some();
            seen.1 |= i.people.is_some();
        }
        assert_eq!(seen, (true, true), "(goal, people) never taken");
        // A deadline passed comes before any input.
        inbox.put(Input::Odometry, b"odom".to_vec(), now);
        assert!(matches!(inbox.next(Instant::now()), Event::Deadline));
    }

    #[test]
    fn a_panic_in_the_loop_still_sends_a_last_zero_command() {
        let (server, inbox, robot, cmd) = lockstep_server();
        drive(&robot, &cmd);
        while cmd.try_recv().is_ok() {}
        // Nothing else sends a command now: lockstep, no input, never stale.
        inbox.lock().panic = true;
        inbox.shared.1.notify_all();
        let last = cmd.recv_timeout(Duration::from_secs(5));
        assert_eq!(last, Ok(Twist::ZERO), "no zero command after the panic");
        assert!(server.join().is_err(), "the loop did not panic");
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
        let mut breadth_alone = ServeOptions::new("model.fsrlm");
        breadth_alone.planning_breadth = Some(8);
        let b = breadth_alone.check().unwrap_err().to_string();
        assert!(
            b.contains("--planning-breadth 8 needs --planning-top-k"),
            "{b}"
        );
        breadth_alone.planning_top_k = Some(3);
        assert!(breadth_alone.check().is_ok());
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
