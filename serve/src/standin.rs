//! The robot stand-in (`fsrl sim --as-robot`): plays episodes of one setting as a robot would
//! appear to `fsrl serve`: it publishes the goal (once per episode), then per step the people
//! (in any of the three formats, [`people::encode`]: `people_msgs/People` with fsrl's tags
//! (radius, goal, preferred speed, standing), spencer's or pedsim's messages with positions and
//! velocities only) and the odometry (frame `odom`, twist in `base_link`), waits for the
//! `cmd_vel` that answers them and executes it as the nearest action. Among walls it also
//! publishes, before the odometry, the laser scan the robot's sensor would read
//! (`sensor_msgs/LaserScan`, [`sim::scan::simulate`] of the scene's walls and people from the
//! robot's pose, [`sim::scan::ScanGeometry::default_360`], frame `base_link`), for `fsrl serve
//! --scan`. Or it asks the queryable instead of using topics.
//!
//! Stamps are simulated time (`1000 s` + the steps so far + 1 s between episodes), so the
//! served episode clock counts the simulator's steps.

use std::ops::Range;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use sim::{Env, Outcome, Setting, SimConfig};
use zenoh::Wait;

use crate::msg::{
    self, AgentStates, Header, LaserScan, Odometry, People, Point, Pose, PoseStamped, Quaternion,
    Time, TrackedPersons, Twist,
};
use crate::node::{RosNode, RosPublisher, ServeError, Topics};
use crate::people::{self, PeopleFormat, PersonObs};
use crate::ros2::Ros2Style;
use crate::served::{Command, Observation, ServedPolicy};

/// How the stand-in reaches the policy.
#[derive(Debug, Clone)]
pub enum Link {
    /// ROS 2 topics in `style`, the people in `people`'s message.
    Topics {
        style: Ros2Style,
        topics: Topics,
        people: PeopleFormat,
    },
    /// The queryable `fsrl/serve/<name>/act`.
    Queryable { name: String },
}

/// What the stand-in plays.
#[derive(Debug, Clone)]
pub struct RobotOptions {
    pub setting: Setting,
    pub seeds: Range<u64>,
    /// The world (use the model's `method_sim()` to play the world `fsrl eval` plays).
    pub sim: SimConfig,
    pub link: Link,
    /// How long to wait for `fsrl serve` to appear.
    pub wait_for_server: Duration,
    /// How long to wait for each command.
    pub reply_timeout: Duration,
    pub zenoh: transport::ZenohConfig,
}

/// One episode as played.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeResult {
    pub seed: u64,
    pub outcome: Outcome,
    pub steps: u32,
    /// Steps where the command received was not the action the reference policy (the model,
    /// in-process, on the state the messages convey, see [`Reference`]) chose; `None` without a
    /// reference.
    pub disagreements: Option<u32>,
}

impl EpisodeResult {
    /// `{"seed":…,"outcome":"reach-goal","steps":…,"disagreements":…|null}`.
    pub fn json_line(&self) -> String {
        let d = self
            .disagreements
            .map_or_else(|| "null".to_string(), |d| d.to_string());
        format!(
            r#"{{"seed":{},"outcome":"{}","steps":{},"disagreements":{d}}}"#,
            self.seed,
            self.outcome.name(),
            self.steps
        )
    }
}

/// The in-process decision to compare with: the model deciding as `fsrl serve` and `fsrl eval`
/// do ([`ServedPolicy`], with the played setting's visibility) on the state the robot's messages
/// convey, read back from the bytes it sends: the simulator's exact state through the queryable
/// and `people_msgs/People` with fsrl's tags; the people's positions and velocities only through
/// spencer's and pedsim's messages (the rest as `fsrl serve` fills it in). A disagreement is
/// then the link's doing (the heading's quaternion, the body frame), never what a format
/// cannot say.
pub struct Reference<'a> {
    pub model: &'a learner::model::Model,
}

struct Links {
    node: RosNode,
    odom: RosPublisher,
    people: RosPublisher,
    people_format: PeopleFormat,
    goal: RosPublisher,
    scan: RosPublisher,
    cmd: mpsc::Receiver<Vec<u8>>,
    _sub: zenoh::pubsub::Subscriber<()>,
}

fn header(t_s: f64) -> Header {
    Header {
        stamp: Time::from_secs_f64(t_s),
        frame_id: "odom".into(),
    }
}

fn odometry_of(env: &Env, t_s: f64) -> Odometry {
    let r = env.robot();
    let (s, c) = r.heading_rad.sin_cos();
    let mut o = Odometry {
        header: header(t_s),
        child_frame_id: "base_link".into(),
        ..Odometry::default()
    };
    o.pose.pose = Pose {
        position: Point {
            x: r.position.x,
            y: r.position.y,
            z: 0.0,
        },
        orientation: Quaternion::from_yaw(r.heading_rad),
    };
    // Body frame: the world velocity rotated by −heading.
    o.twist.twist.linear = Point {
        x: r.velocity.x * c + r.velocity.y * s,
        y: -r.velocity.x * s + r.velocity.y * c,
        z: 0.0,
    };
    o
}

/// The laser scan the robot's sensor reads among the env's walls and people (None on an open
/// floor), stamped `t_s` in the robot's frame `base_link`.
pub fn scan_of(env: &Env, t_s: f64) -> Option<LaserScan> {
    let walls = env.walls()?;
    let r = env.robot();
    let people: Vec<(sim::Vec2, f64)> = env
        .humans()
        .iter()
        .map(|h| (h.position, h.radius_m))
        .collect();
    let s = sim::scan::simulate(
        walls.map(),
        &people,
        r.position,
        r.heading_rad,
        &sim::scan::ScanGeometry::default_360(),
    );
    Some(crate::scan::to_msg(
        &s,
        Header {
            stamp: Time::from_secs_f64(t_s),
            frame_id: "base_link".into(),
        },
    ))
}

/// The people message of `format` for the env's humans (what a perfect tracker sees).
fn people_of(env: &Env, t_s: f64, format: PeopleFormat) -> Result<Vec<u8>, ServeError> {
    let humans: Vec<PersonObs> = env.humans().iter().map(PersonObs::of_human).collect();
    people::encode(format, &header(t_s), &humans).map_err(|e| ServeError::Config(e.to_string()))
}

/// The queryable's request for the env's exact state.
pub fn request_of(env: &Env) -> proto::serve::ActRequest {
    use proto::serve::{ActRequest, GoalObs, HumanObs, RobotObs};
    let r = env.robot();
    ActRequest {
        robot: RobotObs {
            x_m: r.position.x,
            y_m: r.position.y,
            vx_mps: r.velocity.x,
            vy_mps: r.velocity.y,
            heading_rad: r.heading_rad,
        },
        goal: GoalObs {
            x_m: r.goal.x,
            y_m: r.goal.y,
        },
        humans: env
            .humans()
            .iter()
            .map(|h| HumanObs {
                x_m: h.position.x,
                y_m: h.position.y,
                vx_mps: h.velocity.x,
                vy_mps: h.velocity.y,
                radius_m: Some(h.radius_m),
                goal_x_m: Some(h.goal.x),
                goal_y_m: Some(h.goal.y),
                v_pref_mps: Some(h.v_pref_mps),
                standing: Some(h.standing),
            })
            .collect(),
        steps: env.steps(),
    }
}

fn wait_until(
    deadline: Instant,
    what: &str,
    mut ok: impl FnMut() -> bool,
) -> Result<(), ServeError> {
    while !ok() {
        if Instant::now() > deadline {
            return Err(ServeError::Zenoh(format!("timed out waiting for {what}")));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

/// Plays `opts.seeds` and returns each episode's outcome, calling `on_episode` as each ends:
/// connect (topics or the queryable) and wait for `fsrl serve`, then play each seed.
pub fn run(
    opts: &RobotOptions,
    reference: Option<Reference<'_>>,
    mut on_episode: impl FnMut(&EpisodeResult),
) -> Result<Vec<EpisodeResult>, ServeError> {
    let mut env = Env::new(opts.sim.clone(), opts.setting, opts.seeds.start).map_err(config)?;
    let deadline = Instant::now() + opts.wait_for_server;
    let mut reference_policy = reference
        .as_ref()
        .map(|r| ServedPolicy::from_model(r.model.clone(), Some(opts.setting.robot_visible)))
        .transpose()?;
    let mut link = match &opts.link {
        Link::Topics {
            style,
            topics,
            people,
        } => Connected::Topics(Box::new(Links::open(
            opts, style, topics, *people, deadline,
        )?)),
        Link::Queryable { name } => {
            let asker = Asker::open(opts, name)?;
            asker.wait_for_server(&mut env, opts.seeds.start, deadline)?;
            Connected::Asker(asker)
        }
    };
    let mut t_s = 1000.0;
    let mut results = Vec::new();
    for seed in opts.seeds.clone() {
        let disagreements = play(
            &mut env,
            seed,
            &mut t_s,
            &mut link,
            reference_policy.as_mut(),
            opts.reply_timeout,
        )?;
        let r = EpisodeResult {
            seed,
            outcome: env.outcome(),
            steps: env.steps(),
            disagreements: reference.as_ref().map(|_| disagreements),
        };
        on_episode(&r);
        results.push(r);
    }
    if let Connected::Topics(l) = link {
        drop(l.node);
    }
    Ok(results)
}

fn config(e: impl std::fmt::Display) -> ServeError {
    ServeError::Config(e.to_string())
}

/// The stand-in's link to `fsrl serve`, connected.
enum Connected {
    Topics(Box<Links>),
    Asker(Asker),
}

impl Links {
    /// Publishers of the inputs and a subscriber of the commands; `fsrl serve` is there once
    /// it subscribes to all three inputs.
    fn open(
        opts: &RobotOptions,
        style: &Ros2Style,
        topics: &Topics,
        people_format: PeopleFormat,
        deadline: Instant,
    ) -> Result<Self, ServeError> {
        topics.check().map_err(ServeError::Config)?;
        let mut node = RosNode::open(&opts.zenoh, style.clone(), "fsrl_robot")?;
        let odom = node.publisher::<Odometry>(&topics.odom)?;
        let people = match people_format {
            PeopleFormat::People => node.publisher::<People>(&topics.people)?,
            PeopleFormat::Spencer => node.publisher::<TrackedPersons>(&topics.people)?,
            PeopleFormat::Pedsim => node.publisher::<AgentStates>(&topics.people)?,
        };
        let goal = node.publisher::<PoseStamped>(&topics.goal)?;
        let scan = node.publisher::<LaserScan>(&topics.scan)?;
        let (tx, cmd) = mpsc::channel();
        let sub = node.subscribe::<Twist>(&topics.cmd_vel, move |b| {
            let _ = tx.send(b);
        })?;
        wait_until(deadline, "fsrl serve's subscriptions", || {
            odom.matched() && people.matched() && goal.matched()
        })?;
        Ok(Links {
            node,
            odom,
            people,
            people_format,
            goal,
            scan,
            cmd,
            _sub: sub,
        })
    }

    /// The episode's goal, stamped `t_s`.
    fn put_goal(&mut self, env: &Env, t_s: f64) -> Result<(), ServeError> {
        let g = env.robot().goal;
        self.goal.put(&PoseStamped {
            header: header(t_s),
            pose: Pose {
                position: Point {
                    x: g.x,
                    y: g.y,
                    z: 0.0,
                },
                orientation: Quaternion::default(),
            },
        })
    }

    /// Publishes this step's people (`people_bytes`) and odometry stamped `t`, and waits for
    /// the command; the action it stands for.
    fn step(
        &mut self,
        env: &Env,
        people_bytes: Vec<u8>,
        odometry: &Odometry,
        t: f64,
        timeout: Duration,
        seed: u64,
    ) -> Result<usize, ServeError> {
        while self.cmd.try_recv().is_ok() {}
        self.people.put_bytes(people_bytes)?;
        if let Some(s) = scan_of(env, t) {
            self.scan.put(&s)?;
        }
        self.odom.put(odometry)?;
        let bytes = self.cmd.recv_timeout(timeout).map_err(|_| {
            ServeError::Zenoh(format!(
                "no command within {timeout:?} (seed {seed}, step {})",
                env.steps()
            ))
        })?;
        let tw: Twist =
            msg::decode(&bytes).map_err(|e| ServeError::Zenoh(format!("cmd_vel: {e}")))?;
        let c = Command {
            linear_x_mps: tw.linear.x,
            linear_y_mps: tw.linear.y,
            angular_z_radps: tw.angular.z,
        };
        let dt = env.config().dt_s;
        Ok(ServedPolicy::action_of(
            env.action_set(),
            dt,
            env.robot().heading_rad,
            &c,
        ))
    }
}

/// A session asking the queryable `fsrl/serve/<name>/act`.
struct Asker {
    session: zenoh::Session,
    key: String,
    timeout: Duration,
}

impl Asker {
    fn open(opts: &RobotOptions, name: &str) -> Result<Self, ServeError> {
        let key = proto::keys::serve_act(name).map_err(config)?;
        let cfg = opts
            .zenoh
            .to_zenoh(msg::MAX_MESSAGE_BYTES)
            .map_err(config)?;
        let session = zenoh::open(cfg)
            .wait()
            .map_err(|e| ServeError::Zenoh(format!("open session: {e}")))?;
        Ok(Self {
            session,
            key,
            timeout: opts.reply_timeout,
        })
    }

    /// The first reply to `req`, or `None` within the timeout.
    fn ask(
        &self,
        req: &proto::serve::ActRequest,
    ) -> Result<Option<proto::serve::ActReply>, ServeError> {
        let replies = self
            .session
            .get(self.key.as_str())
            .payload(req.encode())
            .timeout(self.timeout)
            .wait()
            .map_err(|e| ServeError::Zenoh(format!("query: {e}")))?;
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result() {
                let r = proto::serve::ActReply::decode(&sample.payload().to_bytes())
                    .map_err(|e| ServeError::Zenoh(format!("reply: {e}")))?;
                return Ok(Some(r));
            }
        }
        Ok(None)
    }

    /// The server is there once a query (seed `seed`'s first state) is answered.
    fn wait_for_server(
        &self,
        env: &mut Env,
        seed: u64,
        deadline: Instant,
    ) -> Result<(), ServeError> {
        env.reset(seed).map_err(config)?;
        let probe = request_of(env);
        wait_until(deadline, "fsrl serve's queryable", || {
            matches!(self.ask(&probe), Ok(Some(_)))
        })
    }

    /// The action the queryable gives for `env`'s state.
    fn step(&self, env: &Env, seed: u64) -> Result<usize, ServeError> {
        let reply = self.ask(&request_of(env))?.ok_or_else(|| {
            ServeError::Zenoh(format!("no reply (seed {seed}, step {})", env.steps()))
        })?;
        if !reply.ok {
            return Err(ServeError::Zenoh(format!(
                "the policy refused (seed {seed}): {}",
                reply.reason
            )));
        }
        Ok(reply.action as usize)
    }
}

/// Plays seed `seed` from stamp `t_s` (moved on past the episode, plus 1 s); the steps whose
/// command was not the reference's decision.
fn play(
    env: &mut Env,
    seed: u64,
    t_s: &mut f64,
    link: &mut Connected,
    mut reference: Option<&mut ServedPolicy>,
    timeout: Duration,
) -> Result<u32, ServeError> {
    env.reset(seed).map_err(config)?;
    let dt = env.config().dt_s;
    if let Connected::Topics(l) = link {
        l.put_goal(env, *t_s)?;
    }
    let t0 = *t_s;
    let mut disagreements = 0;
    while !env.is_done() {
        let t = t0 + env.steps() as f64 * dt;
        // The people and odometry messages of this step: published below, read back by the
        // reference.
        let messages = match link {
            Connected::Topics(l) => {
                Some((people_of(env, t, l.people_format)?, odometry_of(env, t)))
            }
            Connected::Asker(_) => None,
        };
        let want = match reference.as_deref_mut() {
            Some(p) => {
                // The reference decides among the scene's own walls (what `--map` gives).
                p.set_walls(env.walls().cloned());
                let mut obs = Observation::of_env(env);
                if let (Connected::Topics(l), Some((b, odometry))) = (&*link, &messages) {
                    // What `fsrl serve` reads: the people's bytes and the odometry's round
                    // trips (the quaternion, the body-frame twist), each a rounding away from
                    // the simulator's state and enough to flip a near tie among walls.
                    obs.humans = people::decode(l.people_format, b).map_err(config)?.people;
                    obs.robot = crate::control::robot_of(odometry);
                }
                Some(p.decide(&obs)?.action)
            }
            None => None,
        };
        let action = match link {
            Connected::Topics(l) => {
                let (b, odometry) = messages.unwrap_or_default();
                l.step(env, b, &odometry, t, timeout, seed)?
            }
            Connected::Asker(a) => a.step(env, seed)?,
        };
        if want.is_some_and(|w| w != action) {
            disagreements += 1;
        }
        env.step(action).map_err(config)?;
    }
    *t_s = t0 + env.steps() as f64 * dt + 1.0;
    Ok(disagreements)
}
