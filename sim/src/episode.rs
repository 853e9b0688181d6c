//! Running whole episodes and summarising them (paper §IV.B metrics).

use crate::env::{Env, EnvError, RobotCommand, StepInfo};
use crate::geom::{wrap_angle, Vec2};
use crate::reward::Outcome;
use crate::robot::RobotState;

/// Where everyone was at one instant (for pictures).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub time_s: f64,
    pub robot: RobotState,
    pub humans: Vec<Vec2>,
}

/// A whole episode: every step's record and, when asked for, every frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Episode {
    pub steps: Vec<StepInfo>,
    /// Frames at t = 0 and after every step (empty unless recorded).
    pub frames: Vec<Frame>,
    pub summary: EpisodeSummary,
}

/// The numbers of one episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeSummary {
    pub outcome: Outcome,
    pub steps: u32,
    pub time_s: f64,
    pub danger_steps: u32,
    /// Distance the robot travelled.
    pub path_length_m: f64,
    /// Sum over steps of |Δθ|, the heading change.
    pub total_abs_rotation_rad: f64,
    /// Undiscounted sum of the total rewards.
    pub return_sum: f64,
    /// Smallest closest distance over the episode.
    pub min_closest_m: f64,
    /// Smallest closest distance over the danger steps (∞ without one): CrowdNav's
    /// `min_danger_dist` of one episode.
    pub min_danger_m: f64,
    /// The episode ended in a collision with a wall (its outcome is `Collision`).
    pub wall_collision: bool,
    /// The robot froze: the episode timed out and the robot moved less than
    /// [`FROZEN_DISTANCE_M`] over its last [`FROZEN_WINDOW_S`] ([`is_frozen`]).
    pub frozen: bool,
}

/// A timed-out robot that moved less than this over the last [`FROZEN_WINDOW_S`] froze.
pub const FROZEN_DISTANCE_M: f64 = 0.5;
/// The window over which [`FROZEN_DISTANCE_M`] is measured, in simulated time.
pub const FROZEN_WINDOW_S: f64 = 5.0;

/// Whether an episode with `outcome`, whose robot went through `positions` (one per step, the
/// start included), froze: it timed out and the robot ended less than [`FROZEN_DISTANCE_M`]
/// from where it was [`FROZEN_WINDOW_S`] earlier (the "freezing robot problem").
pub fn is_frozen(outcome: Outcome, positions: &[Vec2], dt_s: f64) -> bool {
    if outcome != Outcome::Timeout || positions.is_empty() {
        return false;
    }
    let window = (FROZEN_WINDOW_S / dt_s).round() as usize;
    let last = positions[positions.len() - 1];
    let then = positions[positions.len().saturating_sub(window + 1)];
    (last - then).norm() < FROZEN_DISTANCE_M
}

impl EpisodeSummary {
    /// Mean |Δθ| per step (smoothness).
    pub fn mean_abs_rotation_rad(&self) -> f64 {
        if self.steps == 0 {
            0.0
        } else {
            self.total_abs_rotation_rad / self.steps as f64
        }
    }
}

fn frame(env: &Env) -> Frame {
    Frame {
        time_s: env.time_s(),
        robot: *env.robot(),
        humans: env.humans().iter().map(|h| h.position).collect(),
    }
}

/// Runs the episode in `env` to its end, asking `policy` for an action index at every step.
pub fn run_episode<P>(
    env: &mut Env,
    mut policy: P,
    record_frames: bool,
) -> Result<Episode, EnvError>
where
    P: FnMut(&mut Env) -> usize,
{
    run_episode_with(env, |env| RobotCommand::Action(policy(env)), record_frames)
}

/// Runs the episode in `env` to its end, asking `policy` for a [`RobotCommand`] at every step
/// (e.g. [`Env::orca_robot_command`], which drives a holonomic robot at ORCA's velocity).
pub fn run_episode_with<P>(
    env: &mut Env,
    mut policy: P,
    record_frames: bool,
) -> Result<Episode, EnvError>
where
    P: FnMut(&mut Env) -> RobotCommand,
{
    let mut steps = Vec::with_capacity(env.config().max_steps() as usize);
    let mut frames = Vec::new();
    if record_frames {
        frames.push(frame(env));
    }
    let mut summary = EpisodeSummary {
        outcome: Outcome::Running,
        steps: 0,
        time_s: 0.0,
        danger_steps: 0,
        path_length_m: 0.0,
        total_abs_rotation_rad: 0.0,
        return_sum: 0.0,
        min_closest_m: f64::INFINITY,
        min_danger_m: f64::INFINITY,
        wall_collision: false,
        frozen: false,
    };
    let mut positions = Vec::with_capacity(env.config().max_steps() as usize + 1);
    positions.push(env.robot().position);
    while !env.is_done() {
        let before = *env.robot();
        let command = policy(env);
        let info = env.step_command(command)?;
        let after = env.robot();
        summary.path_length_m += (after.position - before.position).norm();
        summary.total_abs_rotation_rad += wrap_angle(after.heading_rad - before.heading_rad).abs();
        summary.return_sum += info.eval.reward.total;
        summary.min_closest_m = summary.min_closest_m.min(info.eval.closest_m);
        if info.eval.danger {
            summary.danger_steps += 1;
            summary.min_danger_m = summary.min_danger_m.min(info.eval.closest_m);
        }
        summary.wall_collision = info.eval.wall_contact;
        positions.push(env.robot().position);
        steps.push(info);
        if record_frames {
            frames.push(frame(env));
        }
    }
    summary.outcome = env.outcome();
    summary.frozen = is_frozen(summary.outcome, &positions, env.config().dt_s);
    summary.steps = env.steps();
    summary.time_s = env.time_s();
    Ok(Episode {
        steps,
        frames,
        summary,
    })
}

/// Aggregate metrics over many episodes of one setting (paper §IV.B, SPEC §7).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Aggregate {
    pub episodes: u32,
    pub successes: u32,
    pub collisions: u32,
    pub timeouts: u32,
    /// Sum of the nav times of successful episodes.
    pub success_time_s: f64,
    /// Sum of the path lengths of successful episodes.
    pub success_path_m: f64,
    pub danger_steps: u64,
    pub steps: u64,
    /// Steps of the episodes that timed out (included in `steps`).
    pub timeout_steps: u64,
    pub abs_rotation_rad: f64,
    pub return_sum: f64,
    /// Collisions with a wall (included in `collisions`).
    pub wall_collisions: u32,
    /// Timed-out episodes whose robot froze (included in `timeouts`).
    pub frozen: u32,
}

impl Aggregate {
    pub fn add(&mut self, s: &EpisodeSummary) {
        self.episodes += 1;
        match s.outcome {
            Outcome::ReachGoal => {
                self.successes += 1;
                self.success_time_s += s.time_s;
                self.success_path_m += s.path_length_m;
            }
            Outcome::Collision => {
                self.collisions += 1;
                self.wall_collisions += u32::from(s.wall_collision);
            }
            Outcome::Timeout => {
                self.timeouts += 1;
                self.timeout_steps += s.steps as u64;
                self.frozen += u32::from(s.frozen);
            }
            Outcome::Running => {}
        }
        self.danger_steps += s.danger_steps as u64;
        self.steps += s.steps as u64;
        self.abs_rotation_rad += s.total_abs_rotation_rad;
        self.return_sum += s.return_sum;
    }

    /// Merges another aggregate (e.g. from another worker).
    pub fn merge(&mut self, o: &Aggregate) {
        self.episodes += o.episodes;
        self.successes += o.successes;
        self.collisions += o.collisions;
        self.timeouts += o.timeouts;
        self.success_time_s += o.success_time_s;
        self.success_path_m += o.success_path_m;
        self.danger_steps += o.danger_steps;
        self.steps += o.steps;
        self.timeout_steps += o.timeout_steps;
        self.abs_rotation_rad += o.abs_rotation_rad;
        self.return_sum += o.return_sum;
        self.wall_collisions += o.wall_collisions;
        self.frozen += o.frozen;
    }

    fn rate(&self, n: u32) -> f64 {
        if self.episodes == 0 {
            0.0
        } else {
            n as f64 / self.episodes as f64
        }
    }
    pub fn success_rate(&self) -> f64 {
        self.rate(self.successes)
    }
    pub fn collision_rate(&self) -> f64 {
        self.rate(self.collisions)
    }
    pub fn timeout_rate(&self) -> f64 {
        self.rate(self.timeouts)
    }
    /// Collisions with a wall, over all episodes.
    pub fn wall_collision_rate(&self) -> f64 {
        self.rate(self.wall_collisions)
    }
    /// Collisions with people, over all episodes.
    pub fn people_collision_rate(&self) -> f64 {
        self.rate(self.collisions - self.wall_collisions)
    }
    /// Frozen robots (timeouts without progress), over all episodes.
    pub fn frozen_rate(&self) -> f64 {
        self.rate(self.frozen)
    }
    /// Mean nav time over successful episodes; `None` without a success.
    pub fn nav_time_s(&self) -> Option<f64> {
        (self.successes > 0).then(|| self.success_time_s / self.successes as f64)
    }
    /// Mean path length over successful episodes; `None` without a success.
    pub fn path_length_m(&self) -> Option<f64> {
        (self.successes > 0).then(|| self.success_path_m / self.successes as f64)
    }
    /// Disc.: danger steps over all steps.
    pub fn discomfort(&self) -> f64 {
        if self.steps == 0 {
            0.0
        } else {
            self.danger_steps as f64 / self.steps as f64
        }
    }
    /// CrowdNav's "frequency of being in danger" (`crowdnav-facts.md` §7): danger steps over
    /// (steps of the episodes that did not time out + `time_limit_steps` per timeout). CrowdNav
    /// books a timeout as the whole time limit (25 s = 100 steps) although it simulates only
    /// 97 steps. Under SPEC semantics a timeout takes exactly the time limit, so with
    /// `time_limit_steps = cfg.max_steps()` this equals [`Aggregate::discomfort`].
    pub fn danger_frequency(&self, time_limit_steps: u32) -> f64 {
        let denominator =
            self.steps - self.timeout_steps + self.timeouts as u64 * time_limit_steps as u64;
        if denominator == 0 {
            0.0
        } else {
            self.danger_steps as f64 / denominator as f64
        }
    }
    /// Mean |Δθ| per step over all steps (smoothness).
    pub fn mean_abs_rotation_rad(&self) -> f64 {
        if self.steps == 0 {
            0.0
        } else {
            self.abs_rotation_rad / self.steps as f64
        }
    }
    pub fn mean_return(&self) -> f64 {
        if self.episodes == 0 {
            0.0
        } else {
            self.return_sum / self.episodes as f64
        }
    }
}
