//! [`MessageKind`]: which message a header announces. Below every other module of the
//! protocol (errors name kinds; the header carries one).

use std::fmt;

use serde::{Deserialize, Serialize};

/// Which message a header announces. Serialised as a kebab-case string (`"transition-batch"`),
/// so a tool subscribed to `fsrl/<run>/**` can dispatch on `msg["header"]["kind"]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MessageKind {
    /// [`crate::TransitionBatch`].
    TransitionBatch,
    /// [`crate::Weights`].
    Weights,
    /// [`crate::EvalReport`].
    EvalReport,
    /// [`crate::Metrics`].
    Metrics,
    /// [`crate::Status`].
    Status,
    /// [`crate::Ack`].
    Ack,
    /// [`crate::Control`].
    Control,
}

impl MessageKind {
    /// The wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            MessageKind::TransitionBatch => "transition-batch",
            MessageKind::Weights => "weights",
            MessageKind::EvalReport => "eval-report",
            MessageKind::Metrics => "metrics",
            MessageKind::Status => "status",
            MessageKind::Ack => "ack",
            MessageKind::Control => "control",
        }
    }
}

impl fmt::Display for MessageKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}
