//! `fsrl serve` on zenoh: subscribers for odometry, goal and people, the command publisher,
//! the queryable, rmw_zenoh's liveliness tokens and attachments, and the loop over one closed
//! [`Event`] enum on the calling thread.

use std::path::PathBuf;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::CongestionControl;
use zenoh::query::{Query, Queryable};
use zenoh::{Session, Wait};

use crate::control::{Controller, Intake, Output, Safety, StopReason};
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

/// Everything `fsrl serve` needs.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    pub model: PathBuf,
    /// Names the queryable `fsrl/serve/<name>/act` and the ROS 2 node.
    pub name: String,
    pub style: Ros2Style,
    pub topics: Topics,
    pub people_format: PeopleFormat,
    pub trigger: Trigger,
    /// Control period; default the model's step.
    pub period: Option<Duration>,
    /// Stale after this many periods (default 2).
    pub stale_periods: f64,
    pub limits: Limits,
    pub robot_visible: Option<bool>,
    pub zenoh: transport::ZenohConfig,
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

/// What the loop reacts to.
pub enum Event {
    Odometry(Vec<u8>, Instant),
    People(Vec<u8>, Instant),
    Goal(Vec<u8>),
    Query(Query),
    Shutdown,
}

/// The loop's inbox: give the sender to a signal handler to stop it ([`Event::Shutdown`]).
pub fn channel() -> (Sender<Event>, Receiver<Event>) {
    mpsc::channel()
}

/// What a finished run did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Summary {
    pub counters: crate::control::Counters,
    pub queries: u64,
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

    pub fn publisher<M: RosMsg>(&mut self, topic: &str) -> Result<RosPublisher, ServeError> {
        let key = self.style.key::<M>(topic);
        let gid = self.announce::<M>(Entity::Publisher { topic })?;
        let publisher = self
            .session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Block)
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
    tx: Sender<Event>,
) -> Result<Subscriber<()>, ServeError> {
    let f = move |b| {
        let _ = tx.send(Event::People(b, Instant::now()));
    };
    match format {
        PeopleFormat::People => node.subscribe::<People>(topic, f),
        PeopleFormat::Spencer => node.subscribe::<TrackedPersons>(topic, f),
        PeopleFormat::Pedsim => node.subscribe::<AgentStates>(topic, f),
    }
}

/// The reply to one query.
fn answer(policy: &mut ServedPolicy, limits: &Limits, payload: &[u8]) -> proto::serve::ActReply {
    use proto::serve::{ActReply, ActRequest};
    let req = match ActRequest::decode(payload) {
        Ok(r) => r,
        Err(e) => return ActReply::refused(e.to_string()),
    };
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

/// Logs a stop when its kind changes (not every period).
fn log_transition(last: &mut Option<String>, out: &Output) {
    let now = out.stop.as_ref().map(|r| {
        let s = r.to_string();
        // One log line per kind of stop, not per changing age.
        s.split(" (").next().unwrap_or(&s).to_string()
    });
    if now != *last {
        match &out.stop {
            Some(r) => tracing::warn!("zero command: {r}"),
            None => tracing::info!("driving"),
        }
        *last = now;
    }
}

/// Runs `fsrl serve` until [`Event::Shutdown`] arrives on `events` (its sender side was given to
/// a signal handler, see [`channel`]). Calls `on_ready` once, when the model is loaded and every
/// subscriber, the command publisher and the queryable are declared (the CLI then prints
/// `ready`, which tests wait for). A model that does not load is reported with a zero command on
/// `cmd_vel` before the error returns, without `on_ready`.
pub fn run(
    opts: &ServeOptions,
    events: (Sender<Event>, Receiver<Event>),
    on_ready: impl FnOnce(),
) -> Result<Summary, ServeError> {
    opts.topics.check().map_err(ServeError::Config)?;
    let act_key =
        proto::keys::serve_act(&opts.name).map_err(|e| ServeError::Config(e.to_string()))?;
    let (tx, rx) = events;
    let mut node = RosNode::open(&opts.zenoh, opts.style.clone(), &opts.name)?;
    let mut cmd = node.publisher::<Twist>(&opts.topics.cmd_vel)?;
    let mut policy = match ServedPolicy::load(&opts.model, opts.robot_visible) {
        Ok(p) => p,
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
    let period = opts
        .period
        .unwrap_or_else(|| Duration::from_secs_f64(policy.period_s()));
    if period.is_zero() || opts.stale_periods.is_nan() || opts.stale_periods <= 0.0 {
        return Err(ServeError::Config(
            "the period and the staleness limit must be positive".into(),
        ));
    }
    let safety = Safety {
        stale_after: period.mul_f64(opts.stale_periods),
        limits: opts.limits,
    };
    let mut control = Controller::new(safety, opts.people_format);

    let t = tx.clone();
    let _odom = node.subscribe::<Odometry>(&opts.topics.odom, move |b| {
        let _ = t.send(Event::Odometry(b, Instant::now()));
    })?;
    let t = tx.clone();
    let _goal = node.subscribe::<PoseStamped>(&opts.topics.goal, move |b| {
        let _ = t.send(Event::Goal(b));
    })?;
    let _people = subscribe_people(
        &mut node,
        &opts.topics.people,
        opts.people_format,
        tx.clone(),
    )?;
    let t = tx.clone();
    let _queryable: Queryable<()> = node
        .session
        .declare_queryable(act_key.clone())
        .callback(move |q| {
            let _ = t.send(Event::Query(q));
        })
        .wait()
        .map_err(zerr("declare queryable"))?;
    drop(tx);
    tracing::info!(
        model = %opts.model.display(),
        method = %policy.model().method,
        setting = policy.setting().name(),
        period_s = period.as_secs_f64(),
        queryable = %act_key,
        "serving"
    );
    on_ready();

    let mut summary = Summary::default();
    let mut last_log: Option<String> = None;
    let mut next_tick = Instant::now() + period;
    let publish = |cmd: &mut RosPublisher, out: &Output, last: &mut Option<String>| {
        log_transition(last, out);
        if let Err(e) = cmd.put(&twist_of(&out.command)) {
            tracing::warn!("cannot publish the command: {e}");
        }
    };
    loop {
        let wait = next_tick.saturating_duration_since(Instant::now());
        let ev = match rx.recv_timeout(wait) {
            Ok(ev) => Some(ev),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => Some(Event::Shutdown),
        };
        match ev {
            None => {
                next_tick += period;
                let now = Instant::now();
                if next_tick < now {
                    next_tick = now + period;
                }
                let out = match opts.trigger {
                    Trigger::Timer => Some(control.step(&mut policy, now)),
                    // Lockstep: the tick is only the watchdog.
                    Trigger::Odometry => match control.observation(now) {
                        Err(reason)
                            if !matches!(
                                reason,
                                StopReason::NoOdometry | StopReason::NoGoal | StopReason::NoPeople
                            ) =>
                        {
                            Some(Output::stop(reason))
                        }
                        _ => None,
                    },
                };
                if let Some(out) = out {
                    publish(&mut cmd, &out, &mut last_log);
                }
            }
            Some(Event::Odometry(b, at)) => match control.on_odometry(&b, at) {
                Intake::Undecodable(e) => {
                    log_count("odometry", control.counters().undecodable_odometry, &e)
                }
                Intake::Refused(r) => {
                    tracing::error!("{r}");
                    let out = Output::stop(r);
                    publish(&mut cmd, &out, &mut last_log);
                }
                Intake::Accepted => {
                    if opts.trigger == Trigger::Odometry && control.synced() {
                        let out = control.step(&mut policy, Instant::now());
                        publish(&mut cmd, &out, &mut last_log);
                    }
                }
            },
            Some(Event::People(b, at)) => match control.on_people(&b, at) {
                Intake::Undecodable(e) => {
                    log_count("people", control.counters().undecodable_people, &e)
                }
                _ => {
                    if opts.trigger == Trigger::Odometry && control.synced() {
                        let out = control.step(&mut policy, Instant::now());
                        publish(&mut cmd, &out, &mut last_log);
                    }
                }
            },
            Some(Event::Goal(b)) => match control.on_goal(&b) {
                Intake::Undecodable(e) => {
                    log_count("goal", control.counters().undecodable_goals, &e)
                }
                Intake::Refused(r) => {
                    tracing::error!("{r}");
                    let out = Output::stop(r);
                    publish(&mut cmd, &out, &mut last_log);
                }
                Intake::Accepted => {}
            },
            Some(Event::Query(q)) => {
                summary.queries += 1;
                let payload = q
                    .payload()
                    .map(|p| p.to_bytes().into_owned())
                    .unwrap_or_default();
                let reply = answer(&mut policy, &opts.limits, &payload);
                if let Err(e) = q.reply(q.key_expr().clone(), reply.encode()).wait() {
                    tracing::warn!("cannot reply to a query: {e}");
                }
            }
            Some(Event::Shutdown) => {
                let out = Output::stop(StopReason::Shutdown);
                publish(&mut cmd, &out, &mut last_log);
                break;
            }
        }
    }
    summary.counters = control.counters();
    let c = summary.counters;
    tracing::info!(
        decisions = c.decisions,
        stops = c.stops,
        undecodable = c.undecodable(),
        refused_goals = c.refused_goals,
        queries = summary.queries,
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
