//! The serve loop's logic without any IO: inputs (bytes as they arrive, with when they
//! arrived) in, a command and the reason for a stop out. Every safety rule lives here:
//!
//! - a stop (zero command) with a reason whenever there is no usable decision: no odometry,
//!   goal or people yet; odometry or people stale (below); no decision for a period in lockstep
//!   while odometry and people are never stamped alike;
//!   the goal reached (closer than the robot's radius, the simulator's rule); a goal in another
//!   frame than odometry's (refused: there is no TF here); people in another frame; more people
//!   in one message than `max_people` (refused); stamps from another clock or the future
//!   (below); a decision that took longer than its budget; the policy failing; shutdown;
//! - staleness: an odometry or people message is stale `stale_after` after it arrived
//!   ([`DEFAULT_STALE_PERIODS`] periods by default), or earlier, once its stamp is older than
//!   `stale_after` + tolerance on this computer's clock ([`Clock::System`]): old data cannot
//!   drive however late it arrived;
//! - stamps: with [`Clock::System`] every odometry and people stamp must lie within the
//!   tolerance of this computer's clock when it arrives (ahead: refused; behind by more than
//!   `stale_after` + tolerance: refused), a goal must not be stamped ahead of it; with either
//!   clock, people must be stamped within `stale_after` + tolerance of the odometry they are
//!   used with and the goal not after it by more than the tolerance; the episode's step count
//!   is clamped to the model's time limit;
//! - undecodable messages are counted per topic and the last input kept (a stop follows only
//!   when the kept input turns stale); a refused one drops the input it would have replaced
//!   and stops the robot at once, saying why;
//! - speed and turn-rate limits applied to the policy's command;
//! - with a laser scan (`fsrl serve --scan`), the scan is an input like odometry: none yet,
//!   stale, stamped from another clock or out of step with the odometry stops the robot as for
//!   odometry; a scan the checks refuse (angles, one range per beam, more than the allowed
//!   fraction NaN: [`crate::scan::of_msg`]) is counted and stops the robot at once, rather than
//!   letting it drive blind on an older scan; each decision plans among the walls of the latest
//!   scan ([`crate::scan::walls`]), built within the decision's budget.

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use sim::Vec2;

use crate::msg::{self, Odometry, PoseStamped, Time};
use crate::people::{self, PeopleFormat, PeopleObs};
use crate::scan::{ScanOptions, ScanUse};
use crate::served::{Command, Decision, Limits, Observation, RobotObs, ServedPolicy};

/// Why the command is a stop.
#[derive(Debug, Clone, PartialEq)]
pub enum StopReason {
    NoOdometry,
    NoGoal,
    NoPeople,
    StaleOdometry {
        age_s: f64,
    },
    StalePeople {
        age_s: f64,
    },
    GoalReached {
        distance_m: f64,
    },
    GoalFrame {
        goal: String,
        odom: String,
    },
    PeopleFrame {
        people: String,
        odom: String,
    },
    /// `topic`'s stamp is ahead of this computer's clock by more than the tolerance.
    StampAhead {
        topic: &'static str,
        ahead_s: f64,
    },
    /// `topic`'s stamp is older than the staleness limit plus the tolerance on arrival.
    StampBehind {
        topic: &'static str,
        behind_s: f64,
    },
    /// `topic`'s stamp (people, goal) is `offset_s` from the odometry's, beyond what one clock
    /// allows.
    ClocksDisagree {
        topic: &'static str,
        offset_s: f64,
    },
    TooManyPeople {
        count: usize,
        max: usize,
    },
    DecisionTooSlow {
        took_s: f64,
        budget_s: f64,
    },
    /// Lockstep (`--trigger odometry`): fresh inputs but no decision for a period, the people
    /// stamped `offset_s` from the odometry (a decision needs both stamped alike).
    OutOfStep {
        offset_s: f64,
    },
    PolicyFailed(String),
    ModelNotLoaded(String),
    Shutdown,
    /// `--scan`: no scan received yet.
    NoScan,
    /// `--scan`: the scan is stale.
    StaleScan {
        age_s: f64,
    },
    /// `--scan`: the last scan was refused (malformed: angles, length, NaN ranges) or gave no
    /// walls.
    ScanRefused(String),
}

/// A [`StopReason`]'s variant and topic: see [`StopReason::kind`].
pub type StopKind = (std::mem::Discriminant<StopReason>, &'static str);

impl StopReason {
    /// What kind of stop this is (the variant and its topic), without its changing numbers:
    /// the loop logs a stop when its kind changes, not every period.
    pub fn kind(&self) -> StopKind {
        let topic = match self {
            StopReason::StampAhead { topic, .. }
            | StopReason::StampBehind { topic, .. }
            | StopReason::ClocksDisagree { topic, .. } => topic,
            _ => "",
        };
        (std::mem::discriminant(self), topic)
    }
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
            StopReason::StampAhead { topic, ahead_s } => write!(
                f,
                "{topic} refused: stamped {ahead_s:.3} s ahead of this computer's clock (another clock or the future: synchronise the clocks, or --use-sim-time for a simulator's)"
            ),
            StopReason::StampBehind { topic, behind_s } => write!(
                f,
                "{topic} refused: stamped {behind_s:.3} s before it arrived (another clock, or late: synchronise the clocks, or --use-sim-time for a simulator's)"
            ),
            StopReason::ClocksDisagree { topic, offset_s } => write!(
                f,
                "{topic} stamped {offset_s:+.3} s from the odometry's stamp (not the same clock, or one of them late)"
            ),
            StopReason::TooManyPeople { count, max } => write!(
                f,
                "people refused: {count} in one message, at most {max} (--max-people)"
            ),
            StopReason::DecisionTooSlow { took_s, budget_s } => write!(
                f,
                "decision dropped: it took {:.1} ms, over the budget of {:.1} ms (--decision-budget-s)",
                took_s * 1e3,
                budget_s * 1e3
            ),
            StopReason::OutOfStep { offset_s } => write!(
                f,
                "no decision for a period: people stamped {offset_s:+.3} s from the odometry (--trigger odometry decides when both carry the same stamp)"
            ),
            StopReason::PolicyFailed(e) => write!(f, "the policy failed: {e}"),
            StopReason::ModelNotLoaded(e) => write!(f, "the model did not load: {e}"),
            StopReason::Shutdown => write!(f, "shutting down"),
            StopReason::NoScan => write!(f, "no laser scan received yet"),
            StopReason::StaleScan { age_s } => {
                write!(f, "the laser scan is stale (last {age_s:.2} s ago)")
            }
            StopReason::ScanRefused(e) => write!(
                f,
                "scan refused, not driving blind: {e}"
            ),
        }
    }
}

/// Whose clock the stamps are on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Clock {
    /// This computer's (ROS' default): odometry and people stamps are checked against it on
    /// arrival, within the tolerance.
    #[default]
    System,
    /// The odometry's (`--use-sim-time`: a simulator, a bag): people and goal stamps are checked
    /// against the odometry's only.
    Odometry,
}

/// Settings of the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Safety {
    /// Inputs older than this stop the robot (default [`DEFAULT_STALE_PERIODS`] periods).
    pub stale_after: Duration,
    pub limits: Limits,
    pub clock: Clock,
    /// How far stamps may be from the clock they are checked against.
    pub stamp_tolerance: Duration,
    /// Most people one message may hold (a decision's time grows with them).
    pub max_people: usize,
    /// Longest a decision may take; a slower one is dropped for a stop.
    pub decision_budget: Duration,
}

impl Safety {
    /// The loop's defaults around a staleness limit: limits none, this computer's clock with
    /// 0.5 s of tolerance, [`DEFAULT_MAX_PEOPLE`], a budget of 100 ms.
    pub fn new(stale_after: Duration) -> Self {
        Self {
            stale_after,
            limits: Limits::default(),
            clock: Clock::System,
            stamp_tolerance: Duration::from_millis(500),
            max_people: DEFAULT_MAX_PEOPLE,
            decision_budget: Duration::from_millis(100),
        }
    }
}

/// Periods after which an input is stale by default: the zero command goes out at the stale
/// instant (the loop wakes for it), 1.5 periods after the last input, half a period inside the
/// promise of a zero command within two periods of the inputs stopping.
pub const DEFAULT_STALE_PERIODS: f64 = 1.5;

/// Most people in one message by default: a decision with 64 people takes ~5 ms (against
/// 0.5 ms with 5), far inside a 0.25 s period.
pub const DEFAULT_MAX_PEOPLE: usize = 64;

/// When an input arrived: the monotonic instant (staleness) and this computer's clock in
/// seconds since the Unix epoch (stamps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arrival {
    pub at: Instant,
    pub unix_s: f64,
}

impl Arrival {
    pub fn now() -> Self {
        Self {
            at: Instant::now(),
            unix_s: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64()),
        }
    }
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
    /// Odometry refused for its stamp.
    pub refused_odometry: u64,
    /// People messages refused for their stamp or their count.
    pub refused_people: u64,
    /// Scans accepted (`--scan`).
    pub scans: u64,
    pub undecodable_scans: u64,
    /// Scans refused: malformed (angles, length, NaN ranges) or stamped from another clock.
    pub refused_scans: u64,
    pub decisions: u64,
    pub stops: u64,
    /// Decisions dropped for taking longer than the budget (counted in `stops` too).
    pub too_slow: u64,
}

impl Counters {
    pub fn undecodable(&self) -> u64 {
        self.undecodable_odometry
            + self.undecodable_people
            + self.undecodable_goals
            + self.undecodable_scans
    }
}

/// When an accepted input arrived and when it turns stale.
#[derive(Debug, Clone, Copy)]
struct Fresh {
    at: Instant,
    /// `at` + `stale_after`, or earlier when the stamp was already old on arrival.
    expires: Instant,
    /// How much older than its arrival the stamp was (0 unless on this computer's clock).
    lag_s: f64,
}

impl Fresh {
    /// The input's age at `now`: since it arrived, plus how old its stamp was then.
    fn age_s(&self, now: Instant) -> f64 {
        now.saturating_duration_since(self.at).as_secs_f64() + self.lag_s
    }
}

#[derive(Debug, Clone)]
struct OdomIn {
    frame: String,
    stamp: Time,
    robot: RobotObs,
    fresh: Fresh,
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
    /// Refused (counted): a goal in another frame, a stamp from another clock, too many
    /// people. The input it would have replaced is dropped, the robot stops.
    Refused(StopReason),
}

/// The loop's state.
pub struct Controller {
    safety: Safety,
    format: PeopleFormat,
    odom: Option<OdomIn>,
    people: Option<(PeopleObs, Fresh)>,
    goal: Option<GoalIn>,
    /// Why the goal, the odometry, the people were last refused (until a good one comes).
    refusal: Option<StopReason>,
    odom_refusal: Option<StopReason>,
    people_refusal: Option<StopReason>,
    /// `--scan`: how the scan is read, the latest accepted one, why the last was refused.
    scan_opts: Option<ScanOptions>,
    scan: Option<ScanIn>,
    scan_refusal: Option<StopReason>,
    last_scan_use: ScanUse,
    counters: Counters,
}

#[derive(Debug, Clone)]
struct ScanIn {
    stamp: Time,
    scan: sim::scan::LaserScan,
    fresh: Fresh,
}

/// The robot's world velocity from odometry: the twist is in the body frame (ROS' convention,
/// `child_frame_id`), rotated by the heading. (The stand-in's reference reads its own odometry
/// back with it, so that it decides on the very pose `fsrl serve` sees.)
pub(crate) fn robot_of(o: &Odometry) -> RobotObs {
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
            odom_refusal: None,
            people_refusal: None,
            scan_opts: None,
            scan: None,
            scan_refusal: None,
            last_scan_use: ScanUse::default(),
            counters: Counters::default(),
        }
    }

    /// Drives on a laser scan read with `opts`: every decision needs a fresh scan and plans
    /// among its walls.
    pub fn with_scan(mut self, opts: ScanOptions) -> Self {
        self.scan_opts = Some(opts);
        self
    }

    /// What the last scan used gave (points kept, points of people, walls).
    pub fn last_scan_use(&self) -> ScanUse {
        self.last_scan_use
    }

    /// A laser scan arrived (ignored without `--scan`).
    pub fn on_scan(&mut self, bytes: &[u8], arrival: Arrival) -> Intake {
        let Some(opts) = self.scan_opts else {
            return Intake::Accepted;
        };
        let m: msg::LaserScan = match msg::decode(bytes) {
            Ok(m) => m,
            Err(e) => {
                self.counters.undecodable_scans += 1;
                return Intake::Undecodable(e.to_string());
            }
        };
        let checked = crate::scan::of_msg(&m, opts.max_nan_fraction)
            .map_err(|e| StopReason::ScanRefused(e.to_string()))
            .and_then(
                |s| match self.check_stamp("scan", m.header.stamp, arrival, false) {
                    Some(reason) => Err(reason),
                    None => Ok(s),
                },
            );
        match checked {
            Ok(scan) => {
                self.counters.scans += 1;
                self.scan_refusal = None;
                self.scan = Some(ScanIn {
                    stamp: m.header.stamp,
                    scan,
                    fresh: self.fresh(m.header.stamp, arrival),
                });
                Intake::Accepted
            }
            Err(reason) => {
                self.counters.refused_scans += 1;
                self.scan = None;
                self.scan_refusal = Some(reason.clone());
                Intake::Refused(reason)
            }
        }
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    pub fn safety(&self) -> &Safety {
        &self.safety
    }

    /// With [`Clock::System`], why a stamp of `topic` arriving at `arrival` is refused: ahead
    /// of this computer's clock by more than the tolerance, or (`old_ok` false) older than
    /// the staleness limit plus the tolerance.
    fn check_stamp(
        &self,
        topic: &'static str,
        stamp: Time,
        arrival: Arrival,
        old_ok: bool,
    ) -> Option<StopReason> {
        if self.safety.clock != Clock::System {
            return None;
        }
        let tolerance_s = self.safety.stamp_tolerance.as_secs_f64();
        let lag_s = arrival.unix_s - stamp.as_secs_f64();
        if lag_s < -tolerance_s {
            return Some(StopReason::StampAhead {
                topic,
                ahead_s: -lag_s,
            });
        }
        if !old_ok && lag_s > self.safety.stale_after.as_secs_f64() + tolerance_s {
            return Some(StopReason::StampBehind {
                topic,
                behind_s: lag_s,
            });
        }
        None
    }

    /// When an input stamped `stamp` arriving at `arrival` turns stale: `stale_after` after
    /// its arrival, or, on this computer's clock, once the stamp is `stale_after` + tolerance
    /// old (a stamp within the tolerance of the clock counts as on time).
    fn fresh(&self, stamp: Time, arrival: Arrival) -> Fresh {
        let stale_s = self.safety.stale_after.as_secs_f64();
        let lag_s = match self.safety.clock {
            Clock::System => (arrival.unix_s - stamp.as_secs_f64()).max(0.0),
            Clock::Odometry => 0.0,
        };
        let by_stamp_s = stale_s + self.safety.stamp_tolerance.as_secs_f64() - lag_s;
        let left_s = stale_s.min(by_stamp_s).max(0.0);
        Fresh {
            at: arrival.at,
            expires: arrival.at + Duration::from_secs_f64(left_s),
            lag_s,
        }
    }

    /// An odometry message arrived.
    pub fn on_odometry(&mut self, bytes: &[u8], arrival: Arrival) -> Intake {
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
        if let Some(reason) = self.check_stamp("odometry", o.header.stamp, arrival, false) {
            self.counters.refused_odometry += 1;
            self.odom = None;
            self.odom_refusal = Some(reason.clone());
            return Intake::Refused(reason);
        }
        self.counters.odometry += 1;
        self.odom_refusal = None;
        if let Some(g) = &mut self.goal {
            if g.origin.is_none() {
                g.origin = Some(o.header.stamp);
            }
        }
        self.odom = Some(OdomIn {
            frame: o.header.frame_id,
            stamp: o.header.stamp,
            robot,
            fresh: self.fresh(o.header.stamp, arrival),
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

    /// A people message arrived.
    pub fn on_people(&mut self, bytes: &[u8], arrival: Arrival) -> Intake {
        let p = match people::decode(self.format, bytes) {
            Ok(p) => p,
            Err(e) => {
                self.counters.undecodable_people += 1;
                return Intake::Undecodable(e.to_string());
            }
        };
        let refused = if p.people.len() > self.safety.max_people {
            Some(StopReason::TooManyPeople {
                count: p.people.len(),
                max: self.safety.max_people,
            })
        } else {
            self.check_stamp("people", p.header.stamp, arrival, false)
        };
        if let Some(reason) = refused {
            self.counters.refused_people += 1;
            self.people = None;
            self.people_refusal = Some(reason.clone());
            return Intake::Refused(reason);
        }
        self.counters.people += 1;
        self.people_refusal = None;
        let fresh = self.fresh(p.header.stamp, arrival);
        self.people = Some((p, fresh));
        Intake::Accepted
    }

    /// A goal arrived. A new goal (another position or stamp) restarts the episode clock.
    pub fn on_goal(&mut self, bytes: &[u8], arrival: Arrival) -> Intake {
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
        // A goal set long ago is a goal; one from the future is another clock's.
        if let Some(reason) = (!g.header.stamp.is_zero())
            .then(|| self.check_stamp("goal", g.header.stamp, arrival, true))
            .flatten()
        {
            self.counters.refused_goals += 1;
            self.goal = None;
            self.refusal = Some(reason.clone());
            return Intake::Refused(reason);
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
        let scan_in = match (&self.scan_opts, &self.scan, &self.odom) {
            (None, _, _) => true,
            (Some(_), Some(s), Some(o)) => s.stamp == o.stamp,
            _ => false,
        };
        scan_in
            && match (&self.odom, &self.people) {
                (Some(o), Some((p, _))) => o.stamp == p.header.stamp,
                _ => false,
            }
    }

    /// The first instant at which an input held now turns stale (the loop wakes then, between
    /// its ticks, to send the stop at once).
    pub fn stale_at(&self) -> Option<Instant> {
        let odom = self.odom.as_ref().map(|o| o.fresh.expires);
        let people = self.people.as_ref().map(|(_, f)| f.expires);
        let scan = self.scan.as_ref().map(|s| s.fresh.expires);
        [odom, people, scan].into_iter().flatten().min()
    }

    /// Lockstep: the people's stamp minus the odometry's, when both are held.
    pub fn step_offset_s(&self) -> Option<f64> {
        match (&self.odom, &self.people) {
            (Some(o), Some((p, _))) => Some(p.header.stamp.as_secs_f64() - o.stamp.as_secs_f64()),
            _ => None,
        }
    }

    /// The observation at `now`, or why there is none.
    pub fn observation(&self, now: Instant) -> Result<Observation, StopReason> {
        let Some(o) = &self.odom else {
            return Err(self.odom_refusal.clone().unwrap_or(StopReason::NoOdometry));
        };
        if now >= o.fresh.expires {
            return Err(StopReason::StaleOdometry {
                age_s: o.fresh.age_s(now),
            });
        }
        let Some(g) = &self.goal else {
            return Err(self.refusal.clone().unwrap_or(StopReason::NoGoal));
        };
        let Some((p, fresh)) = &self.people else {
            return Err(self.people_refusal.clone().unwrap_or(StopReason::NoPeople));
        };
        if now >= fresh.expires {
            return Err(StopReason::StalePeople {
                age_s: fresh.age_s(now),
            });
        }
        if p.header.frame_id != o.frame {
            return Err(StopReason::PeopleFrame {
                people: p.header.frame_id.clone(),
                odom: o.frame.clone(),
            });
        }
        let tolerance_s = self.safety.stamp_tolerance.as_secs_f64();
        let odom_s = o.stamp.as_secs_f64();
        let offset_s = p.header.stamp.as_secs_f64() - odom_s;
        if offset_s.abs() > self.safety.stale_after.as_secs_f64() + tolerance_s {
            return Err(StopReason::ClocksDisagree {
                topic: "people",
                offset_s,
            });
        }
        if let Some(origin) = g.origin {
            let offset_s = origin.as_secs_f64() - odom_s;
            if offset_s > tolerance_s {
                return Err(StopReason::ClocksDisagree {
                    topic: "goal",
                    offset_s,
                });
            }
        }
        if self.scan_opts.is_some() {
            let Some(scan) = &self.scan else {
                return Err(self.scan_refusal.clone().unwrap_or(StopReason::NoScan));
            };
            if now >= scan.fresh.expires {
                return Err(StopReason::StaleScan {
                    age_s: scan.fresh.age_s(now),
                });
            }
            let offset_s = scan.stamp.as_secs_f64() - odom_s;
            if offset_s.abs() > self.safety.stale_after.as_secs_f64() + tolerance_s {
                return Err(StopReason::ClocksDisagree {
                    topic: "scan",
                    offset_s,
                });
            }
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
            Some(StopReason::DecisionTooSlow { .. }) => {
                self.counters.stops += 1;
                self.counters.too_slow += 1;
            }
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
        obs.steps = self.steps(policy.period_s()).min(policy.step_limit());
        let started = Instant::now();
        if let (Some(opts), Some(scan)) = (&self.scan_opts, &self.scan) {
            // The scan was checked on arrival: what can fail here is building RVO2's
            // obstacles, which a checked scan's walls always satisfy.
            match crate::scan::walls(
                &scan.scan,
                &obs.robot,
                &obs.humans,
                policy.sim_config(),
                opts,
            ) {
                Ok((w, used)) => {
                    self.last_scan_use = used;
                    policy.set_walls(Some(Arc::new(w)));
                }
                Err(e) => return Output::stop(StopReason::ScanRefused(e.to_string())),
            }
        }
        let decided = policy.decide(&obs);
        let took = started.elapsed();
        match decided {
            Ok(_) if took > self.safety.decision_budget => {
                Output::stop(StopReason::DecisionTooSlow {
                    took_s: took.as_secs_f64(),
                    budget_s: self.safety.decision_budget.as_secs_f64(),
                })
            }
            Ok(d) => Output {
                command: d.command.limited(&self.safety.limits),
                decision: Some(d),
                stop: None,
            },
            Err(e) => Output::stop(StopReason::PolicyFailed(e.to_string())),
        }
    }

    /// Control periods since the goal: (odometry stamp − goal origin) / period, rounded, at
    /// most `u32::MAX` (the policy clamps it further to the model's time limit).
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
    use crate::fixtures::{goal, header, odometry_at as odom, shipped_model};
    use crate::msg::{encode, People};
    use crate::people::{person_with_tags, PersonObs};

    fn policy() -> ServedPolicy {
        ServedPolicy::load(&shipped_model(), None).unwrap()
    }

    /// One person in `frame` stamped `t_s`, at (2, 0) walking at (−0.5, 0).
    fn people(frame: &str, t_s: f64) -> Vec<u8> {
        crate::fixtures::people(frame, t_s, 1)
    }

    /// On the odometry's clock (the stamps here are a simulator's).
    fn controller() -> Controller {
        Controller::new(
            Safety {
                clock: Clock::Odometry,
                ..Safety::new(Duration::from_millis(500))
            },
            PeopleFormat::People,
        )
    }

    /// Arrived at `at` (this computer's clock unused on the odometry's).
    fn arr(at: Instant) -> Arrival {
        Arrival { at, unix_s: 0.0 }
    }

    #[test]
    fn it_drives_only_with_fresh_inputs_and_says_why_it_stops() {
        let mut pol = policy();
        let mut c = controller();
        let t0 = Instant::now();
        assert_eq!(c.step(&mut pol, t0).stop, Some(StopReason::NoOdometry));
        assert_eq!(c.on_goal(&goal("odom", 10.0), arr(t0)), Intake::Accepted);
        c.on_odometry(&odom("odom", 10.0, -4.0), arr(t0));
        assert_eq!(c.step(&mut pol, t0).stop, Some(StopReason::NoPeople));
        c.on_people(&people("odom", 10.0), arr(t0));
        assert!(c.synced());
        let out = c.step(&mut pol, t0);
        assert_eq!(out.stop, None);
        assert!(out.command.linear_x_mps > 0.0);

        // Odometry stops: a stop once it is older than two periods.
        let later = t0 + Duration::from_millis(600);
        c.on_people(&people("odom", 10.5), arr(later));
        let out = c.step(&mut pol, later);
        assert!(
            matches!(out.stop, Some(StopReason::StaleOdometry { .. })),
            "{out:?}"
        );
        assert_eq!(out.command, Command::STOP);
        // People stop: the same.
        c.on_odometry(
            &odom("odom", 10.6, -3.9),
            arr(later + Duration::from_millis(400)),
        );
        let out = c.step(&mut pol, later + Duration::from_millis(400));
        assert_eq!(out.stop, None);
        c.on_odometry(
            &odom("odom", 11.0, -3.8),
            arr(later + Duration::from_millis(700)),
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
        c.on_goal(&goal("odom", 1.0), arr(t0));
        c.on_odometry(&odom("odom", 1.0, -4.0), arr(t0));
        c.on_people(&people("odom", 1.0), arr(t0));
        assert!(matches!(
            c.on_odometry(b"garbage", arr(t0)),
            Intake::Undecodable(_)
        ));
        assert!(matches!(
            c.on_people(&[0, 1, 0, 0, 9], arr(t0)),
            Intake::Undecodable(_)
        ));
        assert!(matches!(c.on_goal(&[], arr(t0)), Intake::Undecodable(_)));
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
        c.on_odometry(b"more garbage", arr(t0 + Duration::from_secs(1)));
        assert!(c.step(&mut pol, t0 + Duration::from_secs(1)).stop.is_some());
    }

    #[test]
    fn a_goal_in_another_frame_is_refused_and_the_goal_reached_stops() {
        let mut pol = policy();
        let mut c = controller();
        let t0 = Instant::now();
        c.on_odometry(&odom("odom", 1.0, -4.0), arr(t0));
        c.on_people(&people("odom", 1.0), arr(t0));
        assert!(matches!(
            c.on_goal(&goal("map", 1.0), arr(t0)),
            Intake::Refused(StopReason::GoalFrame { .. })
        ));
        let out = c.step(&mut pol, t0);
        assert!(
            matches!(out.stop, Some(StopReason::GoalFrame { .. })),
            "{out:?}"
        );
        assert!(out.stop.unwrap().to_string().contains("no TF"));
        assert_eq!(c.counters().refused_goals, 1);
        c.on_goal(&goal("odom", 1.0), arr(t0));
        assert_eq!(c.step(&mut pol, t0).stop, None);
        c.on_odometry(&odom("odom", 2.0, 3.9), arr(t0));
        c.on_people(&people("odom", 2.0), arr(t0));
        assert!(matches!(
            c.step(&mut pol, t0).stop,
            Some(StopReason::GoalReached { .. })
        ));
        // People in another frame: a stop, said why.
        c.on_odometry(&odom("odom", 2.25, 0.0), arr(t0));
        c.on_people(&people("base_link", 2.25), arr(t0));
        assert!(matches!(
            c.step(&mut pol, t0).stop,
            Some(StopReason::PeopleFrame { .. })
        ));
    }

    #[test]
    fn the_episode_clock_counts_periods_since_the_goal() {
        let mut c = controller();
        let t0 = Instant::now();
        c.on_goal(&goal("odom", 100.0), arr(t0));
        c.on_odometry(&odom("odom", 100.0 + 7.0 * 0.25, -4.0), arr(t0));
        assert_eq!(c.steps(0.25), 7);
        // An unstamped goal starts the clock at the odometry's stamp.
        let mut c = controller();
        c.on_odometry(&odom("odom", 50.0, -4.0), arr(t0));
        c.on_goal(&goal("odom", 0.0), arr(t0));
        c.on_odometry(&odom("odom", 51.0, -4.0), arr(t0));
        assert_eq!(c.steps(0.25), 4);
    }

    /// On this computer's clock, at most `max_people` in a message.
    fn on_system_clock(max_people: usize) -> Controller {
        Controller::new(
            Safety {
                max_people,
                ..Safety::new(Duration::from_millis(500))
            },
            PeopleFormat::People,
        )
    }

    /// On this computer's clock at `now_s`, arriving now: a goal set a minute ago, people
    /// stamped `now_s` and odometry stamped `odometry_s` accepted and a decision made; the
    /// policy, the controller and what the inputs arrived with.
    fn driving_at(now_s: f64, odometry_s: f64) -> (ServedPolicy, Controller, Arrival) {
        let mut pol = policy();
        let mut c = on_system_clock(DEFAULT_MAX_PEOPLE);
        let at = Arrival {
            at: Instant::now(),
            unix_s: now_s,
        };
        c.on_goal(&goal("odom", now_s - 60.0), at);
        c.on_people(&people("odom", now_s), at);
        assert_eq!(
            c.on_odometry(&odom("odom", odometry_s, -4.0), at),
            Intake::Accepted
        );
        assert_eq!(c.step(&mut pol, at.at).stop, None);
        (pol, c, at)
    }

    #[test]
    fn stamps_from_another_clock_or_the_future_are_refused_with_their_reason() {
        let now_s = 1.7e9;
        let (mut pol, mut c, at) = driving_at(now_s, now_s);
        let t0 = at.at;
        // Odometry an hour ahead (another clock, or the future): refused, the robot stops
        // at once and says why.
        let r = c.on_odometry(&odom("odom", now_s + 3600.0, -4.0), at);
        assert!(
            matches!(r, Intake::Refused(StopReason::StampAhead { topic: "odometry", ahead_s }) if ahead_s > 3599.0),
            "{r:?}"
        );
        let stop = c.step(&mut pol, t0).stop.unwrap();
        assert!(
            stop.to_string().contains("ahead of this computer's clock"),
            "{stop}"
        );
        // Odometry on a simulator's clock (stamped near 0): refused as too old.
        let r = c.on_odometry(&odom("odom", 100.0, -4.0), at);
        assert!(
            matches!(r, Intake::Refused(StopReason::StampBehind { .. })),
            "{r:?}"
        );
        assert!(c
            .step(&mut pol, t0)
            .stop
            .unwrap()
            .to_string()
            .contains("before it arrived"));
        // Within the tolerance (0.3 s ahead, 0.8 s behind with 0.5 s stale + 0.5 s): fine.
        assert_eq!(
            c.on_odometry(&odom("odom", now_s + 0.3, -4.0), at),
            Intake::Accepted
        );
        assert_eq!(
            c.on_odometry(&odom("odom", now_s - 0.8, -4.0), at),
            Intake::Accepted
        );
        assert_eq!(c.step(&mut pol, t0).stop, None);
        // People from the future, a goal from the future: refused the same way.
        let r = c.on_people(&people("odom", now_s + 10.0), at);
        assert!(matches!(
            r,
            Intake::Refused(StopReason::StampAhead {
                topic: "people",
                ..
            })
        ));
        assert!(matches!(
            c.step(&mut pol, t0).stop,
            Some(StopReason::StampAhead {
                topic: "people",
                ..
            })
        ));
        c.on_people(&people("odom", now_s), at);
        let r = c.on_goal(&goal("odom", now_s + 10.0), at);
        assert!(matches!(
            r,
            Intake::Refused(StopReason::StampAhead { topic: "goal", .. })
        ));
        assert!(matches!(
            c.step(&mut pol, t0).stop,
            Some(StopReason::StampAhead { topic: "goal", .. })
        ));
        let n = c.counters();
        assert_eq!(
            (n.refused_odometry, n.refused_people, n.refused_goals),
            (2, 1, 1)
        );
        // A goal set an hour ago is a goal.
        assert_eq!(
            c.on_goal(&goal("odom", now_s - 3600.0), at),
            Intake::Accepted
        );
        assert_eq!(c.step(&mut pol, t0).stop, None);
    }

    #[test]
    fn an_input_stamped_long_before_it_arrived_turns_stale_by_its_stamp() {
        let now_s = 1.7e9;
        // Stamped 0.8 s before it arrived: accepted (0.5 s stale + 0.5 s of tolerance), and
        // stale 0.2 s later, when its stamp is 1.0 s old, not 0.5 s after its arrival.
        let (mut pol, mut c, at) = driving_at(now_s, now_s - 0.8);
        let t0 = at.at;
        // (1.7e9 s in f64 and a stamp's nanoseconds: within a microsecond)
        let stale_in = c.stale_at().unwrap() - t0;
        assert!(
            stale_in.abs_diff(Duration::from_millis(200)) < Duration::from_micros(1),
            "{stale_in:?}"
        );
        let later = t0 + Duration::from_millis(250);
        let stop = c.step(&mut pol, later).stop;
        assert!(
            matches!(stop, Some(StopReason::StaleOdometry { age_s }) if (age_s - 1.05).abs() < 1e-5),
            "{stop:?}"
        );
        // Stamped on time: stale 0.5 s after it arrived.
        c.on_odometry(&odom("odom", now_s, -4.0), at);
        assert_eq!(c.step(&mut pol, later).stop, None);
        assert_eq!(c.stale_at(), Some(t0 + Duration::from_millis(500)));
    }

    #[test]
    fn on_the_odometrys_clock_people_and_goal_must_keep_to_it() {
        let mut pol = policy();
        let mut c = controller();
        let t0 = Instant::now();
        c.on_goal(&goal("odom", 1000.0), arr(t0));
        c.on_odometry(&odom("odom", 1000.0, -4.0), arr(t0));
        // People stamped on another clock than the odometry's.
        c.on_people(&people("odom", 10.0), arr(t0));
        let stop = c.step(&mut pol, t0).stop.unwrap();
        assert!(
            matches!(stop, StopReason::ClocksDisagree { topic: "people", offset_s } if offset_s < -989.0),
            "{stop:?}"
        );
        assert!(stop.to_string().contains("from the odometry's stamp"));
        c.on_people(&people("odom", 1000.0), arr(t0));
        assert_eq!(c.step(&mut pol, t0).stop, None);
        // A goal stamped after the odometry by more than the tolerance.
        c.on_goal(&goal("odom", 2000.0), arr(t0));
        assert!(matches!(
            c.step(&mut pol, t0).stop,
            Some(StopReason::ClocksDisagree { topic: "goal", .. })
        ));
    }

    #[test]
    fn too_many_people_are_refused_and_a_slow_decision_is_dropped() {
        let mut pol = policy();
        let mut c = controller();
        c.safety.max_people = 3;
        let t0 = Instant::now();
        c.on_goal(&goal("odom", 1.0), arr(t0));
        c.on_odometry(&odom("odom", 1.0, -4.0), arr(t0));
        c.on_people(&people("odom", 1.0), arr(t0));
        assert_eq!(c.step(&mut pol, t0).stop, None);
        let p = PersonObs::tracked(Vec2::new(2.0, 0.0), Vec2::new(-0.5, 0.0));
        let crowd = encode(&People {
            header: header("odom", 1.0),
            people: (0..4)
                .map(|i| person_with_tags(i.to_string(), &p))
                .collect(),
        })
        .unwrap();
        let r = c.on_people(&crowd, arr(t0));
        assert_eq!(
            r,
            Intake::Refused(StopReason::TooManyPeople { count: 4, max: 3 })
        );
        let stop = c.step(&mut pol, t0).stop.unwrap();
        assert!(
            stop.to_string().contains("4 in one message, at most 3"),
            "{stop}"
        );
        assert_eq!(c.counters().refused_people, 1);
        // A decision over its budget is not sent.
        c.on_people(&people("odom", 1.0), arr(t0));
        c.safety.decision_budget = Duration::from_nanos(1);
        let out = c.step(&mut pol, t0);
        assert!(
            matches!(out.stop, Some(StopReason::DecisionTooSlow { .. })),
            "{out:?}"
        );
        assert_eq!(out.command, Command::STOP);
        assert_eq!(c.counters().too_slow, 1);
    }

    #[test]
    fn the_stale_instant_is_the_oldest_inputs_and_staleness_starts_there() {
        let mut c = controller();
        let t0 = Instant::now();
        assert_eq!(c.stale_at(), None);
        c.on_odometry(
            &odom("odom", 1.0, -4.0),
            arr(t0 + Duration::from_millis(100)),
        );
        c.on_people(&people("odom", 1.0), arr(t0));
        assert_eq!(c.stale_at(), Some(t0 + Duration::from_millis(500)));
        c.on_goal(&goal("odom", 1.0), arr(t0));
        let at = c.stale_at().unwrap();
        assert!(matches!(
            c.observation(at),
            Err(StopReason::StalePeople { .. })
        ));
        assert!(c.observation(at - Duration::from_millis(1)).is_ok());
    }

    #[test]
    fn a_step_count_from_a_goal_on_another_clock_is_clamped() {
        let mut pol = policy();
        let mut c = controller();
        let t0 = Instant::now();
        // The goal stamped at the epoch's first nanosecond, the odometry at i32::MAX s: the
        // step count would be 8.6e9 periods.
        c.on_goal(&goal("odom", 1e-9), arr(t0));
        c.on_odometry(&odom("odom", i32::MAX as f64, -4.0), arr(t0));
        c.on_people(&people("odom", i32::MAX as f64), arr(t0));
        assert_eq!(c.steps(pol.period_s()), u32::MAX);
        let out = c.step(&mut pol, t0);
        assert_eq!(out.stop, None);
        assert_eq!(pol.step_limit(), 100);
    }
}
