//! Reports that tools read: [`EvalReport`], [`Metrics`], [`Status`].

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::columns::{check_finite_f64, check_max, check_name, check_unit_interval};
use crate::error::ValidationError;
use crate::header::{Body, MessageKind};
use crate::transitions::MAX_SETTING_LEN;

/// Most settings in one evaluation report.
pub const MAX_EVAL_SETTINGS: usize = 64;
/// Most named values in one metrics message.
pub const MAX_METRICS: usize = 512;
/// Longest metric name, in bytes.
pub const MAX_METRIC_NAME_LEN: usize = 96;
/// Longest free-text status detail, in bytes.
pub const MAX_STATUS_DETAIL_LEN: usize = 4096;

/// Evaluation of one weight snapshot (the header's `policy_version`), evaluator → anyone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Learner episodes trained when the snapshot was taken.
    pub trained_episodes: u64,
    /// Whether this is the final snapshot of the run.
    pub final_snapshot: bool,
    /// One entry per setting evaluated.
    pub settings: Vec<SettingReport>,
}

/// The paper's metrics on one setting (§7 of the spec).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SettingReport {
    /// Setting name, e.g. `env3-visible`.
    pub setting: String,
    /// Test episodes run.
    pub episodes: u32,
    /// Fraction of episodes reaching the goal, in [0, 1].
    pub success_rate: f64,
    /// Fraction ending in a collision, in [0, 1].
    pub collision_rate: f64,
    /// Fraction timing out, in [0, 1].
    pub timeout_rate: f64,
    /// Mean navigation time over successful episodes (s); `None` without any success.
    pub nav_time_s: Option<f64>,
    /// Danger steps (closest distance < 0.2 m) / all steps, in [0, 1].
    pub discomfort: f64,
    /// Mean discounted return.
    pub mean_return: f64,
    /// Mean path length (m).
    pub path_length_m: f64,
    /// Mean absolute heading change per step (rad).
    pub smoothness_rad: f64,
    /// Fraction ending in a collision with a wall, in [0, 1]: only in a walled setting.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wall_collision_rate: Option<f64>,
    /// Fraction ending in a collision with a person, in [0, 1]: only in a walled setting.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub people_collision_rate: Option<f64>,
    /// Fraction timing out with the robot frozen, in [0, 1]: only in a walled setting.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frozen_rate: Option<f64>,
}

impl Body for EvalReport {
    const KIND: MessageKind = MessageKind::EvalReport;

    fn validate(&self) -> Result<(), ValidationError> {
        check_max(
            "settings",
            self.settings.len() as u64,
            MAX_EVAL_SETTINGS as u64,
        )?;
        for s in &self.settings {
            check_name("settings.setting", &s.setting, MAX_SETTING_LEN)?;
            check_unit_interval("settings.success_rate", s.success_rate)?;
            check_unit_interval("settings.collision_rate", s.collision_rate)?;
            check_unit_interval("settings.timeout_rate", s.timeout_rate)?;
            check_unit_interval("settings.discomfort", s.discomfort)?;
            if let Some(t) = s.nav_time_s {
                check_finite_f64("settings.nav_time_s", t)?;
            }
            check_finite_f64("settings.mean_return", s.mean_return)?;
            check_finite_f64("settings.path_length_m", s.path_length_m)?;
            check_finite_f64("settings.smoothness_rad", s.smoothness_rad)?;
            for (field, v) in [
                ("settings.wall_collision_rate", s.wall_collision_rate),
                ("settings.people_collision_rate", s.people_collision_rate),
                ("settings.frozen_rate", s.frozen_rate),
            ] {
                if let Some(v) = v {
                    check_unit_interval(field, v)?;
                }
            }
        }
        Ok(())
    }
}

/// Live figures of one process, indexed by environment steps. Encoded with field names, so a
/// Python `msgpack` client reads `msg["body"]["values"]["loss"]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct Metrics {
    /// Environment steps so far (the x axis of every chart).
    pub env_steps: u64,
    /// Episodes so far.
    pub episodes: u64,
    /// Seconds since the process started (wall clock).
    pub wall_time_s: f64,
    /// Named values, e.g. `"loss"`, `"actor_fps"`, `"policy_lag_max"`. Names are
    /// `[a-z0-9_./-]`; values finite.
    pub values: BTreeMap<String, f64>,
}

impl Body for Metrics {
    const KIND: MessageKind = MessageKind::Metrics;

    fn validate(&self) -> Result<(), ValidationError> {
        check_finite_f64("wall_time_s", self.wall_time_s)?;
        check_max("values", self.values.len() as u64, MAX_METRICS as u64)?;
        for (name, v) in &self.values {
            check_name("values.name", name, MAX_METRIC_NAME_LEN)?;
            if !v.is_finite() {
                return Err(ValidationError::InvalidField {
                    field: "values",
                    reason: format!("metric {name:?} is {v}"),
                });
            }
        }
        Ok(())
    }
}

/// Life-cycle state of a process.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ProcessState {
    /// Starting up (loading checkpoints, waiting for weights).
    Starting,
    /// Working.
    Running,
    /// Alive but waiting (no credits, paused run).
    Idle,
    /// Shutting down cleanly.
    Stopping,
    /// Failed; `detail` says why.
    Failed,
}

/// Heartbeat of a process: sent when its state changes, soon after it hits an error, and
/// every few seconds otherwise (`transport::Heartbeat`; learner, actors and evaluator).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Life-cycle state.
    pub state: ProcessState,
    /// Seconds since start (wall clock).
    pub uptime_s: f64,
    /// Environment steps so far.
    pub env_steps: u64,
    /// Episodes so far.
    pub episodes: u64,
    /// Free text (≤ 4096 bytes): the last error the process hit and went on after (a rejected
    /// message, a failed publication, a refused episode, ...), or with [`ProcessState::Failed`]
    /// why it failed; empty while there was none.
    pub detail: String,
}

impl Body for Status {
    const KIND: MessageKind = MessageKind::Status;

    fn validate(&self) -> Result<(), ValidationError> {
        check_finite_f64("uptime_s", self.uptime_s)?;
        check_max(
            "detail",
            self.detail.len() as u64,
            MAX_STATUS_DETAIL_LEN as u64,
        )
    }
}
