//! One step's consequences as a pure function (SPEC §2 steps 3–4 and §3): the swept closest
//! distance, the outcome and every reward term. The environment's `step` and the policies'
//! one-step lookahead both call [`evaluate_step`], so the reward a policy plans with is the very
//! reward the simulator pays.

use crate::config::SimConfig;
use crate::geom::{closest_approach, Vec2};
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
    pub reward: RewardTerms,
    /// The robot at the end of the step.
    pub robot_next: RobotState,
}

/// Evaluates the step that takes the robot from `robot` with `action` while every human `i`
/// moves at `human_velocity[i]` (its new velocity for this step), ending as step number
/// `steps_after` of the episode.
///
/// Order (SPEC §2): collision if the swept closest distance is negative; else reach-goal if the
/// robot's end position is within its radius of the goal; else timeout once `steps_after`
/// reaches the step limit; else running.
pub fn evaluate_step(
    cfg: &SimConfig,
    robot: &RobotState,
    action: Action,
    humans: &[HumanState],
    human_velocity: &[Vec2],
    steps_after: u32,
) -> StepEval {
    debug_assert_eq!(humans.len(), human_velocity.len());
    let dt = cfg.dt_s;
    let robot_velocity = robot.commanded_velocity(action);
    let robot_next = robot.propagate(action, dt);

    let mut closest_m = f64::INFINITY;
    for (h, v) in humans.iter().zip(human_velocity) {
        let d = closest_approach(h.position - robot.position, v - robot_velocity, dt)
            - h.radius_m
            - robot.radius_m;
        closest_m = closest_m.min(d);
    }

    let w = &cfg.reward;
    let outcome = if closest_m < 0.0 {
        Outcome::Collision
    } else if (robot_next.position - robot.goal).norm() < robot.radius_m {
        Outcome::ReachGoal
    } else if steps_after >= cfg.max_steps() {
        Outcome::Timeout
    } else {
        Outcome::Running
    };

    let collision_goal = match outcome {
        Outcome::Collision => w.collision_penalty,
        Outcome::ReachGoal => w.success_reward,
        _ if closest_m < w.comfort_dist_m => {
            w.discomfort_slope_per_m * (closest_m - w.comfort_dist_m)
        }
        _ => 0.0,
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
        danger: closest_m < w.comfort_dist_m
            && !matches!(outcome, Outcome::Collision | Outcome::ReachGoal),
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

/// R_dy = β·(d − r_c) when d < r_c, where d is the smallest boundary distance after ΔT_dy to the
/// dynamic humans within r_e, the robot holding `robot_velocity` and the humans their current
/// velocities.
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
        let human_future = h.position + h.velocity * horizon;
        d = d.min((human_future - robot_future).norm() - h.radius_m - robot.radius_m);
    }
    if d < w.comfort_dist_m {
        w.dynamic_beta * (d - w.comfort_dist_m)
    } else {
        0.0
    }
}
