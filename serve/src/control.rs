//! The serve loop's logic without any IO: inputs (bytes as they arrive, with the instant they
//! arrived) in, a command and the reason for a stop out. Every safety rule lives here:
//!
//! - a stop (zero command) with a reason whenever there is no usable decision: no odometry,
//!   goal or people yet; odometry or people older than `stale_after` (two periods by default);
//!   the goal reached (closer than the robot's radius, the simulator's rule); a goal in another
//!   frame than odometry's (refused: there is no TF here); people in another frame; the policy
//!   failing; shutdown;
//! - undecodable messages are counted per topic and the last input kept (a stop follows only
//!   when the kept input turns stale);
//! - speed and turn-rate limits applied to the policy's command.

use std::time::{Duration, Instant};

use sim::Vec2;

use crate::msg::{self, Odometry, PoseStamped, Time};
use crate::people::{self, PeopleFormat, PeopleObs};
use crate::served::{Command, Decision, Limits, Observation, RobotObs, ServedPolicy};

/// Why the command is a stop.
#[derive(Debug, Clone, PartialEq)]
pub enum StopReason {
    NoOdometry,
    NoGoal,
    NoPeople,
    StaleOdometry { age_s: f64 },
    StalePeople { age_s: f64 },
    GoalReached { distance_m: f64 },
    GoalFrame { goal: String, odom: String },
    PeopleFrame { people: String, odom: String },
    PolicyFailed(String),
    ModelNotLoaded(String),
    Shutdown,
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StopReason::NoOdometry => write!(f, "no odometry received yet"),
            StopReason::NoGoal => write!(f, "no goal received yet"),
            StopReason::NoPeople => write!(f, "no people message received yet"),
            StopReason::StaleOdometry { age_s } => {
                write!(f, "odometry is stale (last {age_s:.2} s ago)")
            }
            StopReason::StalePeople { age_s } => {
                write!(f, "people data stopped (last {age_s:.2} s ago)")
            }
            StopReason::GoalReached { distance_m } => {
                write!(f, "goal reached ({distance_m:.2} m away)")
            }
            StopReason::GoalFrame { goal, odom } => write!(
                f,
                "goal refused: it is in frame {goal:?}, odometry in {odom:?} (no TF: send the goal in the odometry frame)"
            ),
            StopReason::PeopleFrame { people, odom } => write!(
                f,
                "people are in frame {people:?}, odometry in {odom:?} (no TF: track people in the odometry frame)"
            ),
            StopReason::PolicyFailed(e) => write!(f, "the policy failed: {e}"),
            StopReason::ModelNotLoaded(e) => write!(f, "the model did not load: {e}"),
            StopReason::Shutdown => write!(f, "shutting down"),
        }
    }
}

/// Settings of the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Safety {
    /// Inputs older than this stop the robot (default two control periods).
    pub stale_after: Duration,
    pub limits: Limits,
}

/// Counters of what arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    pub odometry: u64,
    pub people: u64,
    pub goals: u64,
    pub undecodable_odometry: u64,
    pub undecodable_people: u64,
    pub undecodable_goals: u64,
    pub refused_goals: u64,
    pub decisions: u64,
    pub stops: u64,
}

impl Counters {
    pub fn undecodable(&self) -> u64 {
        self.undecodable_odometry + self.undecodable_people + self.undecodable_goals
    }
}

#[derive(Debug, Clone)]
struct OdomIn {
    frame: String,
    stamp: Time,
    robot: RobotObs,
    at: Instant,
}

#[derive(Debug, Clone)]
struct GoalIn {
    position: Vec2,
    frame: String,
    /// Episode clock origin: the goal's stamp, or the odometry's stamp when the goal came
    /// unstamped (set at the first odometry after it when none had come).
    origin: Option<Time>,
    stamp: Time,
}

/// What one step of the loop produced.
#[derive(Debug, Clone, PartialEq)]
pub struct Output {
    /// The command to publish (after limits; zero on a stop).
    pub command: Command,
    pub decision: Option<Decision>,
    pub stop: Option<StopReason>,
}

impl Output {
    /// A zero command for `reason`.
    pub fn stop(reason: StopReason) -> Output {
        Output {
            command: Command::STOP,
            decision: None,
            stop: Some(reason),
        }
    }
}

/// What happened to one input.
#[derive(Debug, Clone, PartialEq)]
pub enum Intake {
    Accepted,
    /// Could not be decoded (counted); the previous input is kept.
    Undecodable(String),
    /// A goal in another frame (counted; the previous goal is dropped, the robot stops).
    Refused(StopReason),
}

/// The loop's state.
pub struct Controller {
    safety: Safety,
    format: PeopleFormat,
    odom: Option<OdomIn>,
    people: Option<(PeopleObs, Instant)>,
    goal: Option<GoalIn>,
    refusal: Option<StopReason>,
    counters: Counters,
}

/// The robot's world velocity from odometry: the twist is in the body frame (ROS' convention,
/// `child_frame_id`), rotated by the heading.
fn robot_of(o: &Odometry) -> RobotObs {
    let heading = o.pose.pose.orientation.yaw();
    let (s, c) = heading.sin_cos();
    let t = &o.twist.twist.linear;
    RobotObs {
        position: Vec2::new(o.pose.pose.position.x, o.pose.pose.position.y),
        velocity: Vec2::new(t.x * c - t.y * s, t.x * s + t.y * c),
        heading_rad: heading,
    }
}

impl Controller {
    pub fn new(safety: Safety, format: PeopleFormat) -> Self {
        Self {
            safety,
            format,
            odom: None,
            people: None,
            goal: None,
            refusal: None,
            counters: Counters::default(),
        }
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// An odometry message arrived at `at`.
    pub fn on_odometry(&mut self, bytes: &[u8], at: Instant) -> Intake {
        let o: Odometry = match msg::decode(bytes) {
            Ok(o) => o,
            Err(e) => {
                self.counters.undecodable_odometry += 1;
                return Intake::Undecodable(e.to_string());
            }
        };
        let robot = robot_of(&o);
        let ok = [
            robot.position.x,
            robot.position.y,
            robot.velocity.x,
            robot.velocity.y,
            robot.heading_rad,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !ok {
            self.counters.undecodable_odometry += 1;
            return Intake::Undecodable("odometry with values that are not finite".into());
        }
        self.counters.odometry += 1;
        if let Some(g) = &mut self.goal {
            if g.origin.is_none() {
                g.origin = Some(o.header.stamp);
            }
        }
        self.odom = Some(OdomIn {
            frame: o.header.frame_id,
            stamp: o.header.stamp,
            robot,
            at,
        });
        self.check_goal_frame()
    }

    fn check_goal_frame(&mut self) -> Intake {
        if let (Some(g), Some(o)) = (&self.goal, &self.odom) {
            if g.frame != o.frame {
                let reason = StopReason::GoalFrame {
                    goal: g.frame.clone(),
                    odom: o.frame.clone(),
                };
                self.goal = None;
                self.counters.refused_goals += 1;
                self.refusal = Some(reason.clone());
                return Intake::Refused(reason);
            }
        }
        Intake::Accepted
    }

    /// A people message arrived at `at`.
    pub fn on_people(&mut self, bytes: &[u8], at: Instant) -> Intake {
        match people::decode(self.format, bytes) {
            Ok(p) => {
                self.counters.people += 1;
                self.people = Some((p, at));
                Intake::Accepted
            }
            Err(e) => {
                self.counters.undecodable_people += 1;
                Intake::Undecodable(e.to_string())
            }
        }
    }

    /// A goal arrived. A new goal (another position or stamp) restarts the episode clock.
    pub fn on_goal(&mut self, bytes: &[u8]) -> Intake {
        let g: PoseStamped = match msg::decode(bytes) {
            Ok(g) => g,
            Err(e) => {
                self.counters.undecodable_goals += 1;
                return Intake::Undecodable(e.to_string());
            }
        };
        let p = g.pose.position;
        if !(p.x.is_finite() && p.y.is_finite()) {
            self.counters.undecodable_goals += 1;
            return Intake::Undecodable("goal with values that are not finite".into());
        }
        self.counters.goals += 1;
        let position = Vec2::new(p.x, p.y);
        let same = self
            .goal
            .as_ref()
            .is_some_and(|old| old.position == position && old.stamp == g.header.stamp);
        if !same {
            let origin = if g.header.stamp.is_zero() {
                self.odom.as_ref().map(|o| o.stamp)
            } else {
                Some(g.header.stamp)
            };
            self.goal = Some(GoalIn {
                position,
                frame: g.header.frame_id,
                origin,
                stamp: g.header.stamp,
            });
            self.refusal = None;
        }
        self.check_goal_frame()
    }

    /// Whether a decision for the latest odometry can be made now in lockstep: people of the
    /// same stamp are in.
    pub fn synced(&self) -> bool {
        match (&self.odom, &self.people) {
            (Some(o), Some((p, _))) => o.stamp == p.header.stamp,
            _ => false,
        }
    }

    /// The observation at `now`, or why there is none.
    pub fn observation(&self, now: Instant) -> Result<Observation, StopReason> {
        let Some(o) = &self.odom else {
            return Err(StopReason::NoOdometry);
        };
        let age = now.saturating_duration_since(o.at);
        if age > self.safety.stale_after {
            return Err(StopReason::StaleOdometry {
                age_s: age.as_secs_f64(),
            });
        }
        let Some(g) = &self.goal else {
            return Err(self.refusal.clone().unwrap_or(StopReason::NoGoal));
        };
        let Some((p, at)) = &self.people else {
            return Err(StopReason::NoPeople);
        };
        let age = now.saturating_duration_since(*at);
        if age > self.safety.stale_after {
            return Err(StopReason::StalePeople {
                age_s: age.as_secs_f64(),
            });
        }
        if p.header.frame_id != o.frame {
            return Err(StopReason::PeopleFrame {
                people: p.header.frame_id.clone(),
                odom: o.frame.clone(),
            });
        }
        Ok(Observation {
            robot: o.robot,
            goal: g.position,
            humans: p.people.clone(),
            steps: 0,
        })
    }

    /// One step of the loop at `now`: a decision, or a stop with its reason.
    pub fn step(&mut self, policy: &mut ServedPolicy, now: Instant) -> Output {
        let out = self.decide(policy, now);
        match &out.stop {
            Some(_) => self.counters.stops += 1,
            None => self.counters.decisions += 1,
        }
        out
    }

    fn decide(&mut self, policy: &mut ServedPolicy, now: Instant) -> Output {
        let mut obs = match self.observation(now) {
            Ok(o) => o,
            Err(reason) => return Output::stop(reason),
        };
        let distance_m = (obs.goal - obs.robot.position).norm();
        if distance_m < policy.sim_config().robot.radius_m {
            return Output::stop(StopReason::GoalReached { distance_m });
        }
        obs.steps = self.steps(policy.period_s());
        match policy.decide(&obs) {
            Ok(d) => Output {
                command: d.command.limited(&self.safety.limits),
                decision: Some(d),
                stop: None,
            },
            Err(e) => Output::stop(StopReason::PolicyFailed(e.to_string())),
        }
    }

    /// Control periods since the goal: (odometry stamp − goal origin) / period, rounded.
    fn steps(&self, period_s: f64) -> u32 {
        let (Some(o), Some(g)) = (&self.odom, &self.goal) else {
            return 0;
        };
        let Some(origin) = g.origin else { return 0 };
        let dt = o.stamp.as_secs_f64() - origin.as_secs_f64();
        if dt <= 0.0 || !dt.is_finite() {
            0
        } else {
            (dt / period_s).round().min(u32::MAX as f64) as u32
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::{encode, Header, People, Point, Pose, Quaternion};
    use crate::people::{person_with_tags, PersonObs};

    fn policy() -> ServedPolicy {
        ServedPolicy::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../models/fsrl-env1-invisible-s0.fsrlm"),
            None,
        )
        .unwrap()
    }

    fn header(frame: &str, t_s: f64) -> Header {
        Header {
            stamp: Time::from_secs_f64(t_s),
            frame_id: frame.into(),
        }
    }

    fn odom(frame: &str, t_s: f64, y: f64) -> Vec<u8> {
        let mut o = Odometry {
            header: header(frame, t_s),
            child_frame_id: "base_link".into(),
            ..Odometry::default()
        };
        o.pose.pose.position.y = y;
        o.pose.pose.orientation = Quaternion::from_yaw(std::f64::consts::FRAC_PI_2);
        encode(&o).unwrap()
    }

    fn goal(frame: &str, t_s: f64) -> Vec<u8> {
        encode(&PoseStamped {
            header: header(frame, t_s),
            pose: Pose {
                position: Point {
                    x: 0.0,
                    y: 4.0,
                    z: 0.0,
                },
                ..Pose::default()
            },
        })
        .unwrap()
    }

    fn people(frame: &str, t_s: f64) -> Vec<u8> {
        let p = PersonObs::tracked(Vec2::new(2.0, 0.0), Vec2::new(-0.5, 0.0));
        encode(&People {
            header: header(frame, t_s),
            people: vec![person_with_tags("a".into(), &p)],
        })
        .unwrap()
    }

    fn controller() -> Controller {
        Controller::new(
            Safety {
                stale_after: Duration::from_millis(500),
                limits: Limits::default(),
            },
            PeopleFormat::People,
        )
    }

    #[test]
    fn it_drives_only_with_fresh_inputs_and_says_why_it_stops() {
        let mut pol = policy();
        let mut c = controller();
        let t0 = Instant::now();
        assert_eq!(c.step(&mut pol, t0).stop, Some(StopReason::NoOdometry));
        assert_eq!(c.on_goal(&goal("odom", 10.0)), Intake::Accepted);
        c.on_odometry(&odom("odom", 10.0, -4.0), t0);
        assert_eq!(c.step(&mut pol, t0).stop, Some(StopReason::NoPeople));
        c.on_people(&people("odom", 10.0), t0);
        assert!(c.synced());
        let out = c.step(&mut pol, t0);
        assert_eq!(out.stop, None);
        assert!(out.command.linear_x_mps > 0.0);

        // Odometry stops: a stop once it is older than two periods.
        let later = t0 + Duration::from_millis(600);
        c.on_people(&people("odom", 10.5), later);
        let out = c.step(&mut pol, later);
        assert!(
            matches!(out.stop, Some(StopReason::StaleOdometry { .. })),
            "{out:?}"
        );
        assert_eq!(out.command, Command::STOP);
        // People stop: the same.
        c.on_odometry(
            &odom("odom", 10.6, -3.9),
            later + Duration::from_millis(400),
        );
        let out = c.step(&mut pol, later + Duration::from_millis(400));
        assert_eq!(out.stop, None);
        c.on_odometry(
            &odom("odom", 11.0, -3.8),
            later + Duration::from_millis(700),
        );
        let out = c.step(&mut pol, later + Duration::from_millis(700));
        assert!(
            matches!(out.stop, Some(StopReason::StalePeople { .. })),
            "{out:?}"
        );
    }

    #[test]
    fn undecodable_bytes_are_counted_and_the_last_input_kept() {
        let mut pol = policy();
        let mut c = controller();
        let t0 = Instant::now();
        c.on_goal(&goal("odom", 1.0));
        c.on_odometry(&odom("odom", 1.0, -4.0), t0);
        c.on_people(&people("odom", 1.0), t0);
        assert!(matches!(
            c.on_odometry(b"garbage", t0),
            Intake::Undecodable(_)
        ));
        assert!(matches!(
            c.on_people(&[0, 1, 0, 0, 9], t0),
            Intake::Undecodable(_)
        ));
        assert!(matches!(c.on_goal(&[]), Intake::Undecodable(_)));
        let n = c.counters();
        assert_eq!(
            (
                n.undecodable_odometry,
                n.undecodable_people,
                n.undecodable_goals
            ),
            (1, 1, 1)
        );
        assert_eq!(c.step(&mut pol, t0).stop, None);
        // Garbage alone keeps nothing fresh: a stop when the kept input turns stale.
        c.on_odometry(b"more garbage", t0 + Duration::from_secs(1));
        assert!(c.step(&mut pol, t0 + Duration::from_secs(1)).stop.is_some());
    }

    #[test]
    fn a_goal_in_another_frame_is_refused_and_the_goal_reached_stops() {
        let mut pol = policy();
        let mut c = controller();
        let t0 = Instant::now();
        c.on_odometry(&odom("odom", 1.0, -4.0), t0);
        c.on_people(&people("odom", 1.0), t0);
        assert!(matches!(
            c.on_goal(&goal("map", 1.0)),
            Intake::Refused(StopReason::GoalFrame { .. })
        ));
        let out = c.step(&mut pol, t0);
        assert!(
            matches!(out.stop, Some(StopReason::GoalFrame { .. })),
            "{out:?}"
        );
        assert!(out.stop.unwrap().to_string().contains("no TF"));
        assert_eq!(c.counters().refused_goals, 1);
        c.on_goal(&goal("odom", 1.0));
        assert_eq!(c.step(&mut pol, t0).stop, None);
        c.on_odometry(&odom("odom", 2.0, 3.9), t0);
        c.on_people(&people("odom", 2.0), t0);
        assert!(matches!(
            c.step(&mut pol, t0).stop,
            Some(StopReason::GoalReached { .. })
        ));
        // People in another frame: a stop, said why.
        c.on_odometry(&odom("odom", 2.25, 0.0), t0);
        c.on_people(&people("base_link", 2.25), t0);
        assert!(matches!(
            c.step(&mut pol, t0).stop,
            Some(StopReason::PeopleFrame { .. })
        ));
    }

    #[test]
    fn the_episode_clock_counts_periods_since_the_goal() {
        let mut c = controller();
        let t0 = Instant::now();
        c.on_goal(&goal("odom", 100.0));
        c.on_odometry(&odom("odom", 100.0 + 7.0 * 0.25, -4.0), t0);
        assert_eq!(c.steps(0.25), 7);
        // An unstamped goal starts the clock at the odometry's stamp.
        let mut c = controller();
        c.on_odometry(&odom("odom", 50.0, -4.0), t0);
        c.on_goal(&goal("odom", 0.0));
        c.on_odometry(&odom("odom", 51.0, -4.0), t0);
        assert_eq!(c.steps(0.25), 4);
    }
}
