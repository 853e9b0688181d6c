//! The robot stand-in (`fsrl sim --as-robot`): plays episodes of one setting as a robot would
//! appear to `fsrl serve`: it publishes the goal (once per episode), then per step the people
//! (`people_msgs/People`, with fsrl's tags: radius, goal, preferred speed, standing) and the
//! odometry (frame `odom`, twist in `base_link`), waits for the `cmd_vel` that answers them and
//! executes it as the nearest action. Or it asks the queryable instead of using topics.
//!
//! Stamps are simulated time (`1000 s` + the steps so far + 1 s between episodes), so the
//! served episode clock counts the simulator's steps.

use std::ops::Range;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use policy::lookahead::Lookahead;
use sim::{Env, Outcome, Setting, SimConfig};
use zenoh::Wait;

use crate::msg::{
    self, Header, Odometry, People, Point, Pose, PoseStamped, Quaternion, Time, Twist,
};
use crate::node::{RosNode, ServeError, Topics};
use crate::people::{person_with_tags, PersonObs};
use crate::ros2::Ros2Style;
use crate::served::{Command, ServedPolicy};

/// How the stand-in reaches the policy.
#[derive(Debug, Clone)]
pub enum Link {
    /// ROS 2 topics (People format) in `style`.
    Topics { style: Ros2Style, topics: Topics },
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
    /// in-process, on the simulator's exact state) chose; `None` without a reference.
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

/// The in-process decision to compare with (a model's policy on the exact state).
pub struct Reference<'a> {
    pub model: &'a learner::model::Model,
}

struct Links {
    node: RosNode,
    odom: crate::node::RosPublisher,
    people: crate::node::RosPublisher,
    goal: crate::node::RosPublisher,
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

fn people_of(env: &Env, t_s: f64) -> People {
    People {
        header: header(t_s),
        people: env
            .humans()
            .iter()
            .enumerate()
            .map(|(i, h)| person_with_tags(i.to_string(), &PersonObs::of_human(h)))
            .collect(),
    }
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
    let mut lookahead = reference.as_ref().map(|r| {
        Lookahead::new(
            r.model.train.gamma,
            r.model.train.human_model.into(),
            r.model.method.human_order(),
        )
        .with_terminal_previews(r.model.train.terminal_previews)
    });

    // Either topics or a session for queries.
    let (mut links, session, act_key) = match &opts.link {
        Link::Topics { style, topics } => {
            topics.check().map_err(ServeError::Config)?;
            let mut node = RosNode::open(&opts.zenoh, style.clone(), "fsrl_robot")?;
            let odom = node.publisher::<Odometry>(&topics.odom)?;
            let people = node.publisher::<People>(&topics.people)?;
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
            let want = match (&mut lookahead, &reference) {
                (Some(la), Some(r)) => Some(
                    la.decide(&mut env, &r.model.net)
                        .map_err(|e| ServeError::Config(e.to_string()))?
                        .action,
                ),
                _ => None,
            };
            let action = match (&mut links, &session) {
                (Some(l), _) => {
                    while l.cmd.try_recv().is_ok() {}
                    l.people.put(&people_of(&env, t))?;
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
