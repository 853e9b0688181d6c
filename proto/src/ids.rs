//! Identities that appear in every header and in key expressions: run ids and sender ids.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::ValidationError;

/// Longest accepted run id, in bytes.
pub const MAX_RUN_ID_LEN: usize = 64;

/// Identifier of one training run; the second chunk of every key expression (`fsrl/<run>/...`).
///
/// Valid run ids are 1..=64 bytes of ASCII letters, digits, `-`, `_` and `.`, not starting with
/// `.`. This excludes everything zenoh treats specially (`*`, `$`, `/`, `#`, `?`), whitespace
/// and the empty string, so a run id is always exactly one literal key-expression chunk.
/// Deserialisation validates too.
#[derive(Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct RunId(String);

impl RunId {
    /// Validates and wraps a run id.
    pub fn new(id: impl Into<String>) -> Result<Self, ValidationError> {
        let id = id.into();
        validate_run_id(&id)?;
        Ok(Self(id))
    }

    /// The run id as a string slice.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

fn validate_run_id(id: &str) -> Result<(), ValidationError> {
    let invalid = |reason: String| ValidationError::InvalidField {
        field: "run_id",
        reason,
    };
    if id.is_empty() {
        return Err(invalid("empty".into()));
    }
    if id.len() > MAX_RUN_ID_LEN {
        return Err(invalid(format!(
            "{} bytes, longer than {MAX_RUN_ID_LEN}",
            id.len()
        )));
    }
    if id.starts_with('.') {
        return Err(invalid("starts with '.'".into()));
    }
    if let Some(c) = id
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.')))
    {
        return Err(invalid(format!(
            "character {c:?} not allowed (use ASCII letters, digits, '-', '_', '.')"
        )));
    }
    Ok(())
}

impl TryFrom<String> for RunId {
    type Error = ValidationError;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        Self::new(s)
    }
}

impl From<RunId> for String {
    fn from(r: RunId) -> Self {
        r.0
    }
}

impl FromStr for RunId {
    type Err = ValidationError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::new(s)
    }
}

impl fmt::Display for RunId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl fmt::Debug for RunId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "RunId({:?})", self.0)
    }
}

/// The role of a process in a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// The single learner: replay, optimisation, weight broadcast.
    Learner,
    /// An actor: simulates episodes and publishes transitions.
    Actor,
    /// The evaluator: scores weight snapshots.
    Evaluator,
    /// A passive tool (monitor, CLI, test harness).
    Monitor,
}

impl Role {
    /// All roles, in a fixed order.
    pub const ALL: [Role; 4] = [Role::Learner, Role::Actor, Role::Evaluator, Role::Monitor];

    /// The lowercase name used on the wire and in key expressions.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Learner => "learner",
            Role::Actor => "actor",
            Role::Evaluator => "evaluator",
            Role::Monitor => "monitor",
        }
    }
}

impl FromStr for Role {
    type Err = ValidationError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Role::ALL
            .into_iter()
            .find(|r| r.as_str() == s)
            .ok_or_else(|| ValidationError::InvalidField {
                field: "role",
                reason: format!("unknown role {s:?}"),
            })
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Who sent a message: a role and an index within the role (`actor-3`, `learner-0`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct SenderId {
    /// The sender's role.
    pub role: Role,
    /// Index within the role, starting at 0.
    pub index: u32,
}

impl SenderId {
    /// A sender id.
    pub const fn new(role: Role, index: u32) -> Self {
        Self { role, index }
    }
    /// `learner-0`.
    pub const fn learner() -> Self {
        Self::new(Role::Learner, 0)
    }
    /// `actor-<index>`.
    pub const fn actor(index: u32) -> Self {
        Self::new(Role::Actor, index)
    }
    /// `evaluator-<index>`.
    pub const fn evaluator(index: u32) -> Self {
        Self::new(Role::Evaluator, index)
    }
    /// `monitor-<index>`.
    pub const fn monitor(index: u32) -> Self {
        Self::new(Role::Monitor, index)
    }
}

impl fmt::Display for SenderId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-{}", self.role, self.index)
    }
}

impl FromStr for SenderId {
    type Err = ValidationError;
    /// Parses the `Display` form, `actor-3`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let invalid = || ValidationError::InvalidField {
            field: "sender",
            reason: format!("{s:?} is not <role>-<index>"),
        };
        let (role, index) = s.rsplit_once('-').ok_or_else(invalid)?;
        let role = role.parse()?;
        let index = index.parse().map_err(|_| invalid())?;
        Ok(Self { role, index })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_ids() {
        for ok in ["r", "run-1", "2026_11_03.fsrl", "A-b_c.9"] {
            assert!(RunId::new(ok).is_ok(), "{ok}");
        }
        let long = "x".repeat(MAX_RUN_ID_LEN + 1);
        for bad in [
            "", "a/b", "a*", "**", "$x", "a#b", "a?b", "a b", ".hidden", "ü", "a\n", &long,
        ] {
            assert!(RunId::new(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn sender_display_round_trip() {
        for s in [
            SenderId::learner(),
            SenderId::actor(17),
            SenderId::evaluator(0),
            SenderId::monitor(2),
        ] {
            assert_eq!(s.to_string().parse::<SenderId>().ok(), Some(s));
        }
        assert!("actor".parse::<SenderId>().is_err());
        assert!("pilot-1".parse::<SenderId>().is_err());
        assert!("actor-x".parse::<SenderId>().is_err());
    }
}
