//! The messages of `fsrl serve`'s queryable ([`crate::keys::serve_act`]): an observation in
//! ([`ActRequest`]), the policy's action out ([`ActReply`]), MessagePack with named fields
//! (`msgpack.packb({"robot": {...}, "goal": {...}, "humans": [...]})` from Python).
//!
//! Not a [`crate::Message`]: the asker is any program, not an fsrl process with a run id, and
//! one query gets one reply. World frame, metres, seconds, radians.

use serde::{Deserialize, Serialize};

/// Largest request accepted (a crowd of a few hundred people fits many times over).
pub const MAX_REQUEST_BYTES: usize = 1 << 20;
/// Most humans one request may carry.
pub const MAX_HUMANS: usize = 512;

/// The robot's own state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotObs {
    pub x_m: f64,
    pub y_m: f64,
    /// World-frame velocity.
    pub vx_mps: f64,
    pub vy_mps: f64,
    pub heading_rad: f64,
}

/// A point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalObs {
    pub x_m: f64,
    pub y_m: f64,
}

/// A tracked person. What a tracker does not know is left out and taken from the model's
/// simulator config (radius, preferred speed) or assumed (goal: straight on at the current
/// velocity for one second; walking).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HumanObs {
    pub x_m: f64,
    pub y_m: f64,
    pub vx_mps: f64,
    pub vy_mps: f64,
    #[serde(default)]
    pub radius_m: Option<f64>,
    #[serde(default)]
    pub goal_x_m: Option<f64>,
    #[serde(default)]
    pub goal_y_m: Option<f64>,
    #[serde(default)]
    pub v_pref_mps: Option<f64>,
    #[serde(default)]
    pub standing: Option<bool>,
}

impl HumanObs {
    /// A person seen at (`x_m`, `y_m`) moving at (`vx_mps`, `vy_mps`), nothing else known.
    pub fn walking(x_m: f64, y_m: f64, vx_mps: f64, vy_mps: f64) -> Self {
        Self {
            x_m,
            y_m,
            vx_mps,
            vy_mps,
            radius_m: None,
            goal_x_m: None,
            goal_y_m: None,
            v_pref_mps: None,
            standing: None,
        }
    }
}

/// One observation: what the policy decides from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActRequest {
    pub robot: RobotObs,
    pub goal: GoalObs,
    pub humans: Vec<HumanObs>,
    /// Control periods since the goal was set (the time limit and the time reward count them).
    #[serde(default)]
    pub steps: u32,
}

/// The decision, or why there is none (`ok = false`, `reason` says why; the command fields
/// are then a stop).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActReply {
    pub ok: bool,
    /// Empty when `ok`.
    pub reason: String,
    /// Index into the model's action set (meaningless unless `ok`).
    pub action: u32,
    /// The action: speed and rotation (unicycle: heading change over the step; holonomic: the
    /// world-frame direction of motion).
    pub speed_mps: f64,
    pub rotation_rad: f64,
    /// The velocity command a robot executes for one control period (body frame), after the
    /// served limits.
    pub linear_x_mps: f64,
    pub linear_y_mps: f64,
    pub angular_z_radps: f64,
    /// The lookahead value of the chosen action.
    pub value: f64,
    /// Time the decision took, in microseconds.
    pub decision_us: f64,
}

impl ActReply {
    /// A stop with the reason there is no decision.
    pub fn refused(reason: impl Into<String>) -> Self {
        Self {
            ok: false,
            reason: reason.into(),
            action: 0,
            speed_mps: 0.0,
            rotation_rad: 0.0,
            linear_x_mps: 0.0,
            linear_y_mps: 0.0,
            angular_z_radps: 0.0,
            value: 0.0,
            decision_us: 0.0,
        }
    }
}

/// Why a request was refused before any decision.
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    #[error("request of {0} bytes exceeds the limit of {MAX_REQUEST_BYTES}")]
    TooLarge(usize),
    #[error("not an observation: {0}")]
    Malformed(String),
    #[error("{0}")]
    Invalid(String),
}

impl ActRequest {
    /// Test support: the robot at rest at (0, −4) heading 1.5 rad, its goal (0, 4), `humans`
    /// people (person `i` at (1 + i, 0) walking at (−0.5, 0)), no steps yet.
    #[doc(hidden)]
    pub fn example(humans: usize) -> Self {
        Self {
            robot: RobotObs {
                x_m: 0.0,
                y_m: -4.0,
                vx_mps: 0.0,
                vy_mps: 0.0,
                heading_rad: 1.5,
            },
            goal: GoalObs { x_m: 0.0, y_m: 4.0 },
            humans: (0..humans)
                .map(|i| HumanObs::walking(1.0 + i as f64, 0.0, -0.5, 0.0))
                .collect(),
            steps: 0,
        }
    }

    /// Decodes and checks a request: finite numbers, positive radii and speeds, at most
    /// [`MAX_HUMANS`] humans, a goal given whole.
    pub fn decode(bytes: &[u8]) -> Result<Self, RequestError> {
        if bytes.len() > MAX_REQUEST_BYTES {
            return Err(RequestError::TooLarge(bytes.len()));
        }
        let r: Self =
            rmp_serde::from_slice(bytes).map_err(|e| RequestError::Malformed(e.to_string()))?;
        r.check().map_err(RequestError::Invalid)?;
        Ok(r)
    }

    pub fn encode(&self) -> Vec<u8> {
        rmp_serde::to_vec_named(self).unwrap_or_default()
    }

    fn check(&self) -> Result<(), String> {
        let finite = [
            self.robot.x_m,
            self.robot.y_m,
            self.robot.vx_mps,
            self.robot.vy_mps,
            self.robot.heading_rad,
            self.goal.x_m,
            self.goal.y_m,
        ];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err("robot and goal values must be finite".into());
        }
        if self.humans.len() > MAX_HUMANS {
            return Err(format!(
                "{} humans, at most {MAX_HUMANS}",
                self.humans.len()
            ));
        }
        for (i, h) in self.humans.iter().enumerate() {
            let values = [h.x_m, h.y_m, h.vx_mps, h.vy_mps];
            let optional = [h.radius_m, h.goal_x_m, h.goal_y_m, h.v_pref_mps];
            if values.iter().any(|v| !v.is_finite())
                || optional.iter().flatten().any(|v| !v.is_finite())
            {
                return Err(format!("human {i}: values must be finite"));
            }
            if h.radius_m.is_some_and(|r| r <= 0.0) || h.v_pref_mps.is_some_and(|v| v <= 0.0) {
                return Err(format!("human {i}: radius and v_pref must be positive"));
            }
            if h.goal_x_m.is_some() != h.goal_y_m.is_some() {
                return Err(format!("human {i}: goal_x_m and goal_y_m go together"));
            }
        }
        Ok(())
    }
}

impl ActReply {
    pub fn encode(&self) -> Vec<u8> {
        rmp_serde::to_vec_named(self).unwrap_or_default()
    }

    pub fn decode(bytes: &[u8]) -> Result<Self, RequestError> {
        rmp_serde::from_slice(bytes).map_err(|e| RequestError::Malformed(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One person, of radius 0.3 m, 3 steps after the goal was set.
    fn request() -> ActRequest {
        let mut r = ActRequest {
            steps: 3,
            ..ActRequest::example(1)
        };
        r.humans[0].radius_m = Some(0.3);
        r
    }

    #[test]
    fn requests_round_trip_and_bad_ones_are_refused() {
        let r = request();
        assert_eq!(ActRequest::decode(&r.encode()).unwrap(), r);
        let mut bad = r.clone();
        bad.humans[0].x_m = f64::NAN;
        assert!(matches!(
            ActRequest::decode(&bad.encode()),
            Err(RequestError::Invalid(_))
        ));
        let mut bad = r.clone();
        bad.humans[0].goal_x_m = Some(1.0);
        assert!(ActRequest::decode(&bad.encode()).is_err());
        assert!(matches!(
            ActRequest::decode(b"\xc1garbage"),
            Err(RequestError::Malformed(_))
        ));
        assert!(ActRequest::decode(&[]).is_err());
        let reply = ActReply::refused("no goal");
        assert_eq!(ActReply::decode(&reply.encode()).unwrap(), reply);
    }
}
