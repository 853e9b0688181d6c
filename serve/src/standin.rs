//! The robot stand-in (`fsrl sim --as-robot`): plays episodes of one setting as a robot would
//! appear to `fsrl serve`: it publishes the goal (once per episode), then per step the people
//! (in any of the three formats, [`people::encode`]: `people_msgs/People` with fsrl's tags
//! (radius, goal, preferred speed, standing), spencer's or pedsim's messages with positions and
//! velocities only) and the odometry (frame `odom`, twist in `base_link`), waits for the
//! `cmd_vel` that answers them and executes it as the nearest action. Or it asks the queryable
//! instead of using topics.
//!
//! Stamps are simulated time (`1000 s` + the steps so far + 1 s between episodes), so the
//! served episode clock counts the simulator's steps.

use std::ops::Range;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use sim::{Env, Outcome, Setting, SimConfig};
use zenoh::Wait;

use crate::msg::{
    self, AgentStates, Header, Odometry, People, Point, Pose, PoseStamped, Quaternion, Time,
    TrackedPersons, Twist,
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

/// Plays `opts.seeds` and returns each episode's outcome, calling `on_episode` as each ends.
pub fn run(
    opts: &RobotOptions,
    reference: Option<Reference<'_>>,
    mut on_episode: impl FnMut(&EpisodeResult),
) -> Result<Vec<EpisodeResult>, ServeError> {
    let mut env = Env::new(opts.sim.clone(), opts.setting, opts.seeds.start)
        .map_err(|e| ServeError::Config(e.to_string()))?;
    let dt = opts.sim.dt_s;
    let deadline = Instant::now() + opts.wait_for_server;
    let mut reference_policy = reference
        .as_ref()
        .map(|r| ServedPolicy::from_model(r.model.clone(), Some(opts.setting.robot_visible)))
        .transpose()?;

    // Either topics or a session for queries.
    let (mut links, session, act_key) = match &opts.link {
        Link::Topics {
            style,
            topics,
            people: people_format,
        } => {
            topics.check().map_err(ServeError::Config)?;
            let mut node = RosNode::open(&opts.zenoh, style.clone(), "fsrl_robot")?;
            let odom = node.publisher::<Odometry>(&topics.odom)?;
            let people = match people_format {
                PeopleFormat::People => node.publisher::<People>(&topics.people)?,
                PeopleFormat::Spencer => node.publisher::<TrackedPersons>(&topics.people)?,
                PeopleFormat::Pedsim => node.publisher::<AgentStates>(&topics.people)?,
            };
            let goal = node.publisher::<PoseStamped>(&topics.goal)?;
            let (tx, cmd) = mpsc::channel();
            let sub = node.subscribe::<Twist>(&topics.cmd_vel, move |b| {
                let _ = tx.send(b);
            })?;
            // `fsrl serve` is there once it subscribes to all three inputs.
            wait_until(deadline, "fsrl serve's subscriptions", || {
                odom.matched() && people.matched() && goal.matched()
            })?;
            (
                Some(Links {
                    node,
                    odom,
                    people,
                    people_format: *people_format,
                    goal,
                    cmd,
                    _sub: sub,
                }),
                None,
                String::new(),
            )
        }
        Link::Queryable { name } => {
            let key =
                proto::keys::serve_act(name).map_err(|e| ServeError::Config(e.to_string()))?;
            let cfg = opts
                .zenoh
                .to_zenoh(msg::MAX_MESSAGE_BYTES)
                .map_err(|e| ServeError::Config(e.to_string()))?;
            let session = zenoh::open(cfg)
                .wait()
                .map_err(|e| ServeError::Zenoh(format!("open session: {e}")))?;
            (None, Some(session), key)
        }
    };
    let ask = |session: &zenoh::Session,
               req: &proto::serve::ActRequest|
     -> Result<Option<proto::serve::ActReply>, ServeError> {
        let replies = session
            .get(act_key.as_str())
            .payload(req.encode())
            .timeout(opts.reply_timeout)
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
    };
    if let Some(s) = &session {
        // The server is there once a query is answered.
        env.reset(opts.seeds.start)
            .map_err(|e| ServeError::Config(e.to_string()))?;
        let probe = request_of(&env);
        let mut answered = false;
        wait_until(deadline, "fsrl serve's queryable", || {
            answered = matches!(ask(s, &probe), Ok(Some(_)));
            answered
        })?;
    }

    let mut t_s = 1000.0;
    let mut results = Vec::new();
    for seed in opts.seeds.clone() {
        env.reset(seed)
            .map_err(|e| ServeError::Config(e.to_string()))?;
        let mut disagreements = 0;
        if let Some(l) = &mut links {
            let g = env.robot().goal;
            l.goal.put(&PoseStamped {
                header: header(t_s),
                pose: Pose {
                    position: Point {
                        x: g.x,
                        y: g.y,
                        z: 0.0,
                    },
                    orientation: Quaternion::default(),
                },
            })?;
        }
        let t0 = t_s;
        while !env.is_done() {
            let t = t0 + env.steps() as f64 * dt;
            // The people message of this step: published below, read back by the reference.
            let people_bytes = links
                .as_ref()
                .map(|l| people_of(&env, t, l.people_format))
                .transpose()?;
            let want = match &mut reference_policy {
                Some(p) => {
                    let mut obs = Observation::of_env(&env);
                    if let (Some(l), Some(b)) = (&links, &people_bytes) {
                        obs.humans = people::decode(l.people_format, b)
                            .map_err(|e| ServeError::Config(e.to_string()))?
                            .people;
                    }
                    Some(p.decide(&obs)?.action)
                }
                None => None,
            };
            let action = match (&mut links, &session) {
                (Some(l), _) => {
                    while l.cmd.try_recv().is_ok() {}
                    if let Some(b) = people_bytes {
                        l.people.put_bytes(b)?;
                    }
                    l.odom.put(&odometry_of(&env, t))?;
                    let bytes = l.cmd.recv_timeout(opts.reply_timeout).map_err(|_| {
                        ServeError::Zenoh(format!(
                            "no command within {:?} (seed {seed}, step {})",
                            opts.reply_timeout,
                            env.steps()
                        ))
                    })?;
                    let tw: Twist = msg::decode(&bytes)
                        .map_err(|e| ServeError::Zenoh(format!("cmd_vel: {e}")))?;
                    let c = Command {
                        linear_x_mps: tw.linear.x,
                        linear_y_mps: tw.linear.y,
                        angular_z_radps: tw.angular.z,
                    };
                    ServedPolicy::action_of(env.action_set(), dt, env.robot().heading_rad, &c)
                }
                (None, Some(s)) => {
                    let reply = ask(s, &request_of(&env))?.ok_or_else(|| {
                        ServeError::Zenoh(format!("no reply (seed {seed}, step {})", env.steps()))
                    })?;
                    if !reply.ok {
                        return Err(ServeError::Zenoh(format!(
                            "the policy refused (seed {seed}): {}",
                            reply.reason
                        )));
                    }
                    reply.action as usize
                }
                _ => unreachable!("one link is set"),
            };
            if want.is_some_and(|w| w != action) {
                disagreements += 1;
            }
            env.step(action)
                .map_err(|e| ServeError::Config(e.to_string()))?;
        }
        t_s = t0 + env.steps() as f64 * dt + 1.0;
        let r = EpisodeResult {
            seed,
            outcome: env.outcome(),
            steps: env.steps(),
            disagreements: reference.as_ref().map(|_| disagreements),
        };
        on_episode(&r);
        results.push(r);
    }
    drop(links.map(|l| l.node));
    Ok(results)
}
