//! Transport errors.

use proto::{Delivery, EncodeError};
use thiserror::Error;

/// Why a transport operation failed. Malformed messages received from the wire are not errors
/// (they are counted and skipped, see [`crate::Transport::rejected_count`]).
#[derive(Debug, Error)]
pub enum TransportError {
    /// Invalid configuration (every problem listed).
    #[error("invalid transport configuration: {0}")]
    Config(String),
    /// zenoh failed.
    #[error("zenoh {op}: {detail}")]
    Zenoh {
        /// What was being done.
        op: &'static str,
        /// zenoh's message.
        detail: String,
    },
    /// iceoryx2 failed.
    #[error("iceoryx2 {op}: {detail}")]
    Iceoryx {
        /// What was being done.
        op: &'static str,
        /// iceoryx2's message.
        detail: String,
    },
    /// The message could not be encoded (invalid or oversized).
    #[error(transparent)]
    Encode(#[from] EncodeError),
    /// Wildcard topics are for subscribing only.
    #[error("{topic} is a subscription pattern and cannot be published to")]
    WildcardPublish {
        /// Key expression.
        topic: String,
    },
    /// The topic's delivery guarantee needs the other kind of publisher/subscriber.
    #[error("{topic} has delivery {delivery:?}: use {use_instead}")]
    WrongDelivery {
        /// Key expression.
        topic: String,
        /// The topic's delivery.
        delivery: Delivery,
        /// What to call instead.
        use_instead: &'static str,
    },
    /// A reliable publication waited too long for a receiver with a full queue.
    #[error("publishing on {topic} timed out after {timeout_ms} ms: a subscriber is not draining")]
    PublishTimeout {
        /// Key expression.
        topic: String,
        /// Timeout in force.
        timeout_ms: u64,
    },
    /// iceoryx2 topics support no wildcard subscription of this kind.
    #[error("{topic}: {reason}")]
    Unsupported {
        /// Key expression.
        topic: String,
        /// Why.
        reason: &'static str,
    },
}

pub(crate) fn zenoh_err(op: &'static str) -> impl FnOnce(zenoh::Error) -> TransportError {
    move |e| TransportError::Zenoh {
        op,
        detail: e.to_string(),
    }
}

pub(crate) fn iox_err<E: std::fmt::Debug>(op: &'static str) -> impl FnOnce(E) -> TransportError {
    move |e| TransportError::Iceoryx {
        op,
        detail: format!("{e:?}"),
    }
}
