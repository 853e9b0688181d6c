//! One step's consequences as a pure function (SPEC §2 steps 3–4 and §3): the swept closest
//! distance, the outcome and every reward term. The environment's `step` and the policies'
//! one-step lookahead both call [`evaluate_step`], so the reward a policy plans with is the very
//! reward the simulator pays.

use crate::config::{DynamicReading, Semantics, SimConfig};
use crate::geom::{closest_approach, Vec2};
use crate::map::StaticMap;
use crate::robot::{Action, RobotState};
use crate::scenario::HumanState;

/// How an episode stands after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Outcome {
    Running,
    Collision,
    ReachGoal,
    /// The time limit was reached: a truncation, not a failure state of the world.
    Timeout,
}

impl Outcome {
    pub fn is_terminal(self) -> bool {
        self != Outcome::Running
    }

    pub fn name(self) -> &'static str {
        match self {
            Outcome::Running => "running",
            Outcome::Collision => "collision",
            Outcome::ReachGoal => "reach-goal",
            Outcome::Timeout => "timeout",
        }
    }
}

/// The reward of one step, term by term (paper eq. 4–9).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RewardTerms {
    /// R_c: collision, goal and discomfort.
    pub collision_goal: f64,
    /// R_st: foresight penalty for standing humans.
    pub standing: f64,
    /// R_dy: foresight penalty for dynamic humans.
    pub dynamic: f64,
    /// R_t: efficiency term.
    pub time: f64,
    /// The sum of the terms the configuration switches on.
    pub total: f64,
}

/// Everything one step decides, before anything moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepEval {
    pub outcome: Outcome,
    /// Smallest boundary-to-boundary distance to any human over the step (∞ without humans).
    pub closest_m: f64,
    /// A step closer than the comfort distance that neither collides nor reaches the goal.
    pub danger: bool,
    /// The robot touched a wall during the step (a collision, reported apart from people).
    pub wall_contact: bool,
    pub reward: RewardTerms,
    /// The robot at the end of the step.
    pub robot_next: RobotState,
}

/// Evaluates the step that takes the robot from `robot` with `action` while every human `i`
/// moves at `human_velocity[i]` (its new velocity for this step), ending as step number
/// `steps_after` of the episode. The robot moves by `cfg.robot.kinematics`.
///
/// Order under [`Semantics::Spec`] (SPEC §2): collision if the swept closest distance is
/// negative; else reach-goal if the robot's end position is within its radius of the goal; else
/// timeout once `steps_after` reaches the step limit; else running. Under
/// [`Semantics::CrowdNav`] see [`crowdnav_outcome`].
pub fn evaluate_step(
    cfg: &SimConfig,
    robot: &RobotState,
    action: Action,
    humans: &[HumanState],
    human_velocity: &[Vec2],
    steps_after: u32,
) -> StepEval {
    evaluate_step_among(
        cfg,
        None,
        robot,
        action,
        humans,
        human_velocity,
        steps_after,
    )
}

/// [`evaluate_step`] among static obstacles: the robot touching a wall during the step (its
/// swept path closer than its radius to a wall) is a collision, before anything else.
pub fn evaluate_step_among(
    cfg: &SimConfig,
    walls: Option<&StaticMap>,
    robot: &RobotState,
    action: Action,
    humans: &[HumanState],
    human_velocity: &[Vec2],
    steps_after: u32,
) -> StepEval {
    let kinematics = cfg.robot.kinematics;
    let robot_velocity = robot.velocity_for(kinematics, action);
    let robot_next = robot.propagate_with(kinematics, action, cfg.dt_s);
    evaluate_motion(
        cfg,
        walls,
        robot,
        robot_velocity,
        robot_next,
        humans,
        human_velocity,
        steps_after,
    )
}

/// [`evaluate_step`] for a holonomic robot that moves at the world-frame `velocity` directly
/// (CrowdNav's ORCA robot executing ORCA's velocity), whatever `cfg.robot.kinematics` says.
pub fn evaluate_velocity_step(
    cfg: &SimConfig,
    robot: &RobotState,
    velocity: Vec2,
    humans: &[HumanState],
    human_velocity: &[Vec2],
    steps_after: u32,
) -> StepEval {
    evaluate_velocity_step_among(
        cfg,
        None,
        robot,
        velocity,
        humans,
        human_velocity,
        steps_after,
    )
}

/// [`evaluate_velocity_step`] among static obstacles (see [`evaluate_step_among`]).
pub fn evaluate_velocity_step_among(
    cfg: &SimConfig,
    walls: Option<&StaticMap>,
    robot: &RobotState,
    velocity: Vec2,
    humans: &[HumanState],
    human_velocity: &[Vec2],
    steps_after: u32,
) -> StepEval {
    let robot_next = robot.move_with_velocity(velocity, cfg.dt_s);
    evaluate_motion(
        cfg,
        walls,
        robot,
        velocity,
        robot_next,
        humans,
        human_velocity,
        steps_after,
    )
}

/// CrowdNav's `point_to_segment_dist(x1, y1, x2, y2, 0, 0)`: the distance from the origin to
/// the segment from `a` to `b`, with its arithmetic in its order.
pub fn crowdnav_origin_to_segment(a: Vec2, b: Vec2) -> f64 {
    let px = b.x - a.x;
    let py = b.y - a.y;
    if px == 0.0 && py == 0.0 {
        return norm2(0.0 - a.x, 0.0 - a.y);
    }
    let u = ((0.0 - a.x) * px + (0.0 - a.y) * py) / (px * px + py * py);
    // CrowdNav clamps with `if u > 1 ... elif u < 0`; the same for every u, NaN included.
    let u = u.clamp(0.0, 1.0);
    let x = a.x + u * px;
    let y = a.y + u * py;
    norm2(x, y)
}

/// `sqrt(x² + y²)` as numpy's `norm` of a 2-vector computes it (no `hypot` scaling).
#[inline]
fn norm2(x: f64, y: f64) -> f64 {
    (x * x + y * y).sqrt()
}

/// CrowdNav's collision scan (`crowdnav-facts.md` §1.6 step 2): for each human in order, the
/// distance from the origin to the relative segment from q = p_h − p_r to q + (v_h − v_r)·dt,
/// where v_h is the human's *current* velocity (the one it took last step) and v_r the robot's
/// commanded velocity, minus both radii. Returns (collision, closest): the scan stops at the
/// first negative distance, which is then the closest; otherwise the minimum (∞ without humans).
pub fn crowdnav_closest(
    robot: &RobotState,
    robot_velocity: Vec2,
    humans: &[HumanState],
    dt_s: f64,
) -> (bool, f64) {
    let mut closest_m = f64::INFINITY;
    for h in humans {
        let px = h.position.x - robot.position.x;
        let py = h.position.y - robot.position.y;
        let vx = h.velocity.x - robot_velocity.x;
        let vy = h.velocity.y - robot_velocity.y;
        let ex = px + vx * dt_s;
        let ey = py + vy * dt_s;
        let d = crowdnav_origin_to_segment(Vec2::new(px, py), Vec2::new(ex, ey))
            - h.radius_m
            - robot.radius_m;
        if d < 0.0 {
            return (true, d);
        }
        if d < closest_m {
            closest_m = d;
        }
    }
    (false, closest_m)
}

/// CrowdNav's outcome of a step (`CrowdSim.step`, `crowdnav-facts.md` §1.6 step 5), first match
/// wins: timeout when the time at the start of the step, (steps_after − 1)·dt, is
/// ≥ time_limit − 1 s; collision; reach-goal; running.
pub fn crowdnav_outcome(
    cfg: &SimConfig,
    collision: bool,
    reaching_goal: bool,
    steps_after: u32,
) -> Outcome {
    let time_at_start_s = steps_after.saturating_sub(1) as f64 * cfg.dt_s;
    if time_at_start_s >= cfg.time_limit_s - 1.0 {
        Outcome::Timeout
    } else if collision {
        Outcome::Collision
    } else if reaching_goal {
        Outcome::ReachGoal
    } else {
        Outcome::Running
    }
}

#[allow(clippy::too_many_arguments)]
fn evaluate_motion(
    cfg: &SimConfig,
    walls: Option<&StaticMap>,
    robot: &RobotState,
    robot_velocity: Vec2,
    robot_next: RobotState,
    humans: &[HumanState],
    human_velocity: &[Vec2],
    steps_after: u32,
) -> StepEval {
    debug_assert_eq!(humans.len(), human_velocity.len());
    let dt = cfg.dt_s;
    let w = &cfg.reward;
    let reaching_goal = (robot_next.position - robot.goal).norm() < robot.radius_m;
    let wall_contact = walls.is_some_and(|map| {
        map.swept_clearance_m(robot.position, robot_next.position) < robot.radius_m
    });

    let (outcome, closest_m) = match cfg.semantics {
        Semantics::Spec => {
            let mut closest_m = f64::INFINITY;
            for (h, v) in humans.iter().zip(human_velocity) {
                let d = closest_approach(h.position - robot.position, v - robot_velocity, dt)
                    - h.radius_m
                    - robot.radius_m;
                closest_m = closest_m.min(d);
            }
            let outcome = if closest_m < 0.0 {
                Outcome::Collision
            } else if reaching_goal {
                Outcome::ReachGoal
            } else if steps_after >= cfg.max_steps() {
                Outcome::Timeout
            } else {
                Outcome::Running
            };
            (outcome, closest_m)
        }
        Semantics::CrowdNav => {
            let (collision, closest_m) = crowdnav_closest(robot, robot_velocity, humans, dt);
            (
                crowdnav_outcome(cfg, collision, reaching_goal, steps_after),
                closest_m,
            )
        }
    };
    let outcome = if wall_contact {
        Outcome::Collision
    } else {
        outcome
    };

    let collision_goal = match (cfg.semantics, outcome) {
        (Semantics::CrowdNav, Outcome::Timeout) => 0.0,
        (_, Outcome::Collision) => w.collision_penalty,
        (_, Outcome::ReachGoal) => w.success_reward,
        _ if closest_m < w.comfort_dist_m => {
            w.discomfort_slope_per_m * (closest_m - w.comfort_dist_m)
        }
        _ => 0.0,
    };
    let danger = closest_m < w.comfort_dist_m
        && match cfg.semantics {
            Semantics::Spec => !matches!(outcome, Outcome::Collision | Outcome::ReachGoal),
            Semantics::CrowdNav => outcome == Outcome::Running,
        };
    let standing = standing_penalty(cfg, robot, robot_velocity, humans);
    let dynamic = dynamic_penalty(cfg, robot, robot_velocity, humans);
    let time = match outcome {
        Outcome::ReachGoal => -w.time_goal_factor * (steps_after as f64 * dt) / cfg.time_limit_s,
        Outcome::Timeout => w.timeout_penalty,
        _ => 0.0,
    };
    let mut total = collision_goal;
    if w.foresight {
        total += standing + dynamic;
    }
    if w.efficiency {
        total += time;
    }
    StepEval {
        outcome,
        closest_m,
        danger,
        wall_contact,
        reward: RewardTerms {
            collision_goal,
            standing,
            dynamic,
            time,
            total,
        },
        robot_next,
    }
}

/// R_st = −α·N_col/N_static over standing humans within r_e (centre distance) of the robot;
/// N_col counts those the robot would hit within ΔT_st holding `robot_velocity`.
pub fn standing_penalty(
    cfg: &SimConfig,
    robot: &RobotState,
    robot_velocity: Vec2,
    humans: &[HumanState],
) -> f64 {
    let w = &cfg.reward;
    let mut n_static = 0usize;
    let mut n_col = 0usize;
    for h in humans.iter().filter(|h| h.standing) {
        let rel = h.position - robot.position;
        if rel.norm() > w.effective_range_m {
            continue;
        }
        n_static += 1;
        let d = closest_approach(rel, -robot_velocity, w.standing_horizon_s);
        if d < h.radius_m + robot.radius_m {
            n_col += 1;
        }
    }
    if n_static == 0 {
        0.0
    } else {
        -w.standing_alpha * n_col as f64 / n_static as f64
    }
}

/// R_dy = β·(d − r_c) when d < r_c, where d is the smallest boundary distance to the dynamic
/// humans within r_e, the robot holding `robot_velocity` and the humans their current velocities:
/// at exactly t + ΔT_dy ([`DynamicReading::After`]) or swept over [t, t + ΔT_dy]
/// ([`DynamicReading::Within`]).
pub fn dynamic_penalty(
    cfg: &SimConfig,
    robot: &RobotState,
    robot_velocity: Vec2,
    humans: &[HumanState],
) -> f64 {
    let w = &cfg.reward;
    let horizon = w.dynamic_horizon_s;
    let robot_future = robot.position + robot_velocity * horizon;
    let mut d = f64::INFINITY;
    for h in humans.iter().filter(|h| !h.standing) {
        if (h.position - robot.position).norm() > w.effective_range_m {
            continue;
        }
        let centre_m = match w.dynamic_reading {
            DynamicReading::After => (h.position + h.velocity * horizon - robot_future).norm(),
            DynamicReading::Within => closest_approach(
                h.position - robot.position,
                h.velocity - robot_velocity,
                horizon,
            ),
        };
        d = d.min(centre_m - h.radius_m - robot.radius_m);
    }
    if d < w.comfort_dist_m {
        w.dynamic_beta * (d - w.comfort_dist_m)
    } else {
        0.0
    }
}
