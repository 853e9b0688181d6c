//! [`TransitionBatch`]: one finished episode, or a chunk of one, in a columnar layout.

use serde::{Deserialize, Serialize};

use crate::columns::{check_finite, check_len, check_max, check_name, f32_le};
use crate::error::ValidationError;
use crate::header::Body;

/// Most humans a batch may describe.
pub const MAX_HUMANS: u32 = 256;
/// Most steps one batch (chunk) may hold.
pub const MAX_STEPS_PER_BATCH: u32 = 10_000;
/// Largest action-set size.
pub const MAX_ACTIONS: u16 = 4096;
/// Longest setting name, in bytes.
pub const MAX_SETTING_LEN: usize = 64;

/// Floats per robot state row: `[px_m, py_m, vx_mps, vy_mps, radius_m, gx_m, gy_m, v_pref_mps, theta_rad]`.
pub const ROBOT_STATE_DIM: usize = 9;
/// Floats per human state row: `[px_m, py_m, vx_mps, vy_mps, radius_m]`.
pub const HUMAN_STATE_DIM: usize = 5;
/// Floats per reward row: `[r_c, r_st, r_dy, r_t, total]`.
pub const REWARD_DIM: usize = 5;

/// How an episode ended (state after a step).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Outcome {
    /// Not finished (only in a chunk that is not the last).
    Running,
    /// The robot hit a human.
    Collision,
    /// The robot reached its goal.
    ReachGoal,
    /// Time limit reached.
    Timeout,
}

/// The robot's full state (world frame). Units in the names.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RobotState {
    /// Position x (m).
    pub px_m: f32,
    /// Position y (m).
    pub py_m: f32,
    /// Velocity x (m/s).
    pub vx_mps: f32,
    /// Velocity y (m/s).
    pub vy_mps: f32,
    /// Radius (m).
    pub radius_m: f32,
    /// Goal x (m).
    pub gx_m: f32,
    /// Goal y (m).
    pub gy_m: f32,
    /// Preferred speed (m/s).
    pub v_pref_mps: f32,
    /// Heading (rad).
    pub theta_rad: f32,
}

impl RobotState {
    /// The row layout used in [`TransitionBatch::robot_states`].
    pub fn to_row(&self) -> [f32; ROBOT_STATE_DIM] {
        [
            self.px_m,
            self.py_m,
            self.vx_mps,
            self.vy_mps,
            self.radius_m,
            self.gx_m,
            self.gy_m,
            self.v_pref_mps,
            self.theta_rad,
        ]
    }

    /// Inverse of [`RobotState::to_row`].
    pub fn from_row(r: &[f32; ROBOT_STATE_DIM]) -> Self {
        Self {
            px_m: r[0],
            py_m: r[1],
            vx_mps: r[2],
            vy_mps: r[3],
            radius_m: r[4],
            gx_m: r[5],
            gy_m: r[6],
            v_pref_mps: r[7],
            theta_rad: r[8],
        }
    }
}

/// A human's observable state (world frame).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct HumanState {
    /// Position x (m).
    pub px_m: f32,
    /// Position y (m).
    pub py_m: f32,
    /// Velocity x (m/s).
    pub vx_mps: f32,
    /// Velocity y (m/s).
    pub vy_mps: f32,
    /// Radius (m).
    pub radius_m: f32,
}

impl HumanState {
    /// The row layout used in [`TransitionBatch::human_states`].
    pub fn to_row(&self) -> [f32; HUMAN_STATE_DIM] {
        [
            self.px_m,
            self.py_m,
            self.vx_mps,
            self.vy_mps,
            self.radius_m,
        ]
    }

    /// Inverse of [`HumanState::to_row`].
    pub fn from_row(r: &[f32; HUMAN_STATE_DIM]) -> Self {
        Self {
            px_m: r[0],
            py_m: r[1],
            vx_mps: r[2],
            vy_mps: r[3],
            radius_m: r[4],
        }
    }
}

/// The reward terms of one step (paper eq. 4–9), reported separately for ablations.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RewardTerms {
    /// Collision / goal / discomfort term R_c.
    pub r_c: f32,
    /// Standing-human foresight term R_st.
    pub r_st: f32,
    /// Dynamic-human foresight term R_dy.
    pub r_dy: f32,
    /// Efficiency term R_t.
    pub r_t: f32,
    /// The reward the learner uses (sum of the enabled terms).
    pub total: f32,
}

impl RewardTerms {
    /// Row layout used in [`TransitionBatch::rewards`].
    pub fn to_row(&self) -> [f32; REWARD_DIM] {
        [self.r_c, self.r_st, self.r_dy, self.r_t, self.total]
    }

    /// Inverse of [`RewardTerms::to_row`].
    pub fn from_row(r: &[f32; REWARD_DIM]) -> Self {
        Self {
            r_c: r[0],
            r_st: r[1],
            r_dy: r[2],
            r_t: r[3],
            total: r[4],
        }
    }
}

/// One finished episode or a chunk of one, actor → learner.
///
/// Dimensions are explicit: with `T = n_steps` and `H = n_humans`, a batch holds the `T + 1`
/// joint states `s_0 .. s_T` of its steps (`s_T` is the state after the last step, also the
/// first state of the next chunk), the `T` actions taken in `s_0 .. s_{T-1}`, and per step the
/// reward terms and the closest boundary distance. Rows are row-major:
/// `robot_states[t * 9 + k]`, `human_states[(t * H + i) * 5 + k]`, `rewards[t * 5 + k]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransitionBatch {
    /// Setting name, e.g. `env1-invisible`.
    pub setting: String,
    /// Episode seed (the episode is a pure function of setting, seed and policy).
    pub seed: u64,
    /// Episode index of this actor (monotonic per actor; acknowledged by [`crate::Ack`]).
    pub episode: u64,
    /// Chunk index within the episode (0 for a whole episode).
    pub chunk: u32,
    /// Whether this chunk ends the episode.
    pub last_chunk: bool,
    /// Index within the episode of this chunk's first step.
    pub first_step: u32,
    /// Number of steps `T` in this chunk (≥ 1).
    pub n_steps: u32,
    /// Number of humans `H`.
    pub n_humans: u32,
    /// Size of the action set the actions index into.
    pub n_actions: u16,
    /// Exploration rate ε used for this episode, in [0, 1].
    pub epsilon: f32,
    /// Per human, whether it is standing (never moves) during the episode. Length `H`.
    pub human_standing: Vec<bool>,
    /// Robot full states, `(T + 1) × 9`, see [`RobotState`].
    #[serde(with = "f32_le")]
    pub robot_states: Vec<f32>,
    /// Human observable states, `(T + 1) × H × 5`, see [`HumanState`].
    #[serde(with = "f32_le")]
    pub human_states: Vec<f32>,
    /// Action index taken at each step, `T`, each `< n_actions`.
    pub actions: Vec<u16>,
    /// Reward terms per step, `T × 5`, see [`RewardTerms`].
    #[serde(with = "f32_le")]
    pub rewards: Vec<f32>,
    /// Closest boundary distance to any human during each step (m), `T`. May be `+inf` only
    /// when `H = 0`.
    #[serde(with = "f32_le")]
    pub closest_dist_m: Vec<f32>,
    /// Outcome after the last step of this chunk: `Running` unless `last_chunk`.
    pub outcome: Outcome,
}

impl TransitionBatch {
    /// Starts a batch at state `s_0`. Episode-level fields come from `meta`.
    pub fn builder(
        meta: EpisodeMeta,
        robot: RobotState,
        humans: &[HumanState],
    ) -> TransitionBatchBuilder {
        TransitionBatchBuilder::new(meta, robot, humans)
    }

    /// Robot state `s_t`, `t` in `0..=n_steps`.
    pub fn robot_state(&self, t: usize) -> Option<RobotState> {
        let row = self
            .robot_states
            .get(t * ROBOT_STATE_DIM..(t + 1) * ROBOT_STATE_DIM)?;
        Some(RobotState::from_row(row.try_into().ok()?))
    }

    /// State of human `i` in `s_t`.
    pub fn human_state(&self, t: usize, i: usize) -> Option<HumanState> {
        let h = self.n_humans as usize;
        if i >= h {
            return None;
        }
        let start = (t * h + i) * HUMAN_STATE_DIM;
        let row = self.human_states.get(start..start + HUMAN_STATE_DIM)?;
        Some(HumanState::from_row(row.try_into().ok()?))
    }

    /// Reward terms of step `t`, `t` in `0..n_steps`.
    pub fn reward(&self, t: usize) -> Option<RewardTerms> {
        let row = self.rewards.get(t * REWARD_DIM..(t + 1) * REWARD_DIM)?;
        Some(RewardTerms::from_row(row.try_into().ok()?))
    }

    /// Approximate encoded size in bytes (for sizing buffers).
    pub fn approx_encoded_len(&self) -> usize {
        512 + 4
            * (self.robot_states.len()
                + self.human_states.len()
                + self.rewards.len()
                + self.closest_dist_m.len())
            + 3 * self.actions.len()
            + self.human_standing.len()
    }
}

impl TransitionBatch {
    /// [`Body::validate`] of a batch (its `Body` impl is in `direct.rs`, beside the
    /// hand-written encoding it selects).
    pub(crate) fn check(&self) -> Result<(), ValidationError> {
        check_name("setting", &self.setting, MAX_SETTING_LEN)?;
        check_max("n_humans", self.n_humans.into(), MAX_HUMANS.into())?;
        check_max("n_steps", self.n_steps.into(), MAX_STEPS_PER_BATCH.into())?;
        check_max("n_actions", self.n_actions.into(), MAX_ACTIONS.into())?;
        if self.n_steps == 0 {
            return Err(ValidationError::InvalidField {
                field: "n_steps",
                reason: "a batch holds at least one step".into(),
            });
        }
        if self.n_actions == 0 {
            return Err(ValidationError::InvalidField {
                field: "n_actions",
                reason: "empty action set".into(),
            });
        }
        if !(self.epsilon.is_finite() && (0.0..=1.0).contains(&self.epsilon)) {
            return Err(ValidationError::InvalidField {
                field: "epsilon",
                reason: format!("{} is not in [0, 1]", self.epsilon),
            });
        }
        let t = self.n_steps as usize;
        let h = self.n_humans as usize;
        check_len("human_standing", self.human_standing.len(), h)?;
        check_len(
            "robot_states",
            self.robot_states.len(),
            (t + 1) * ROBOT_STATE_DIM,
        )?;
        check_len(
            "human_states",
            self.human_states.len(),
            (t + 1) * h * HUMAN_STATE_DIM,
        )?;
        check_len("actions", self.actions.len(), t)?;
        check_len("rewards", self.rewards.len(), t * REWARD_DIM)?;
        check_len("closest_dist_m", self.closest_dist_m.len(), t)?;
        check_finite("robot_states", &self.robot_states)?;
        check_finite("human_states", &self.human_states)?;
        check_finite("rewards", &self.rewards)?;
        if let Some(index) = self
            .closest_dist_m
            .iter()
            .position(|d| !(d.is_finite() || (h == 0 && *d == f32::INFINITY)))
        {
            return Err(ValidationError::NonFinite {
                field: "closest_dist_m",
                index,
            });
        }
        if let Some(a) = self.actions.iter().find(|a| **a >= self.n_actions) {
            return Err(ValidationError::InvalidField {
                field: "actions",
                reason: format!("action {a} out of range for {} actions", self.n_actions),
            });
        }
        let running = self.outcome == Outcome::Running;
        if self.last_chunk == running {
            return Err(ValidationError::InvalidField {
                field: "outcome",
                reason: format!(
                    "{:?} with last_chunk = {} (only non-last chunks are Running)",
                    self.outcome, self.last_chunk
                ),
            });
        }
        if self.first_step.checked_add(self.n_steps).is_none() {
            return Err(ValidationError::InvalidField {
                field: "first_step",
                reason: "first_step + n_steps overflows".into(),
            });
        }
        Ok(())
    }
}

/// Episode-level fields of a [`TransitionBatch`].
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeMeta {
    /// Setting name, e.g. `env1-invisible`.
    pub setting: String,
    /// Episode seed.
    pub seed: u64,
    /// Episode index of the actor.
    pub episode: u64,
    /// Size of the action set.
    pub n_actions: u16,
    /// Exploration rate used.
    pub epsilon: f32,
    /// Per human, standing or not.
    pub human_standing: Vec<bool>,
}

/// Appends steps to a [`TransitionBatch`]; see [`TransitionBatch::builder`].
#[derive(Clone, Debug)]
pub struct TransitionBatchBuilder {
    batch: TransitionBatch,
}

impl TransitionBatchBuilder {
    fn new(meta: EpisodeMeta, robot: RobotState, humans: &[HumanState]) -> Self {
        let n_humans = u32::try_from(humans.len()).unwrap_or(u32::MAX);
        let mut batch = TransitionBatch {
            setting: meta.setting,
            seed: meta.seed,
            episode: meta.episode,
            chunk: 0,
            last_chunk: true,
            first_step: 0,
            n_steps: 0,
            n_humans,
            n_actions: meta.n_actions,
            epsilon: meta.epsilon,
            human_standing: meta.human_standing,
            robot_states: Vec::with_capacity(101 * ROBOT_STATE_DIM),
            human_states: Vec::with_capacity(101 * humans.len() * HUMAN_STATE_DIM),
            actions: Vec::with_capacity(100),
            rewards: Vec::with_capacity(100 * REWARD_DIM),
            closest_dist_m: Vec::with_capacity(100),
            outcome: Outcome::Running,
        };
        push_state(&mut batch, &robot, humans);
        Self { batch }
    }

    /// Records one step: the action taken, its rewards and closest distance (m), and the state
    /// reached. `next_humans` must have as many humans as the initial state (checked by
    /// [`TransitionBatchBuilder::finish`]).
    pub fn push_step(
        &mut self,
        action: u16,
        reward: RewardTerms,
        closest_dist_m: f32,
        next_robot: &RobotState,
        next_humans: &[HumanState],
    ) {
        let b = &mut self.batch;
        b.actions.push(action);
        b.rewards.extend_from_slice(&reward.to_row());
        b.closest_dist_m.push(closest_dist_m);
        b.n_steps = b.n_steps.saturating_add(1);
        push_state(b, next_robot, next_humans);
    }

    /// Number of steps recorded so far.
    pub fn n_steps(&self) -> u32 {
        self.batch.n_steps
    }

    /// Finishes a whole episode with its outcome and validates it.
    pub fn finish(mut self, outcome: Outcome) -> Result<TransitionBatch, ValidationError> {
        self.batch.outcome = outcome;
        self.batch.last_chunk = outcome != Outcome::Running;
        self.batch.validate()?;
        Ok(self.batch)
    }
}

fn push_state(b: &mut TransitionBatch, robot: &RobotState, humans: &[HumanState]) {
    b.robot_states.extend_from_slice(&robot.to_row());
    for h in humans {
        b.human_states.extend_from_slice(&h.to_row());
    }
}

impl TransitionBatch {
    /// Splits a batch into chunks of at most `max_steps` steps each (the last chunk keeps the
    /// outcome, earlier ones are `Running`). Returns the batch unchanged when it fits.
    /// Validates the batch first.
    pub fn into_chunks(self, max_steps: u32) -> Result<Vec<TransitionBatch>, ValidationError> {
        self.validate()?;
        let max_steps = max_steps.max(1);
        if self.n_steps <= max_steps {
            return Ok(vec![self]);
        }
        let h = self.n_humans as usize;
        let mut out = Vec::new();
        let mut start = 0u32;
        let mut chunk = self.chunk;
        while start < self.n_steps {
            let n = max_steps.min(self.n_steps - start);
            let (s, e) = (start as usize, (start + n) as usize);
            let last = start + n == self.n_steps;
            out.push(TransitionBatch {
                setting: self.setting.clone(),
                seed: self.seed,
                episode: self.episode,
                chunk,
                last_chunk: last && self.last_chunk,
                first_step: self.first_step + start,
                n_steps: n,
                n_humans: self.n_humans,
                n_actions: self.n_actions,
                epsilon: self.epsilon,
                human_standing: self.human_standing.clone(),
                robot_states: self.robot_states[s * ROBOT_STATE_DIM..(e + 1) * ROBOT_STATE_DIM]
                    .to_vec(),
                human_states: self.human_states
                    [s * h * HUMAN_STATE_DIM..(e + 1) * h * HUMAN_STATE_DIM]
                    .to_vec(),
                actions: self.actions[s..e].to_vec(),
                rewards: self.rewards[s * REWARD_DIM..e * REWARD_DIM].to_vec(),
                closest_dist_m: self.closest_dist_m[s..e].to_vec(),
                outcome: if last { self.outcome } else { Outcome::Running },
            });
            start += n;
            chunk += 1;
        }
        Ok(out)
    }
}
