//! Typed errors of the codec and of message validation.

use thiserror::Error;

use crate::kind::MessageKind;

/// A message that decoded structurally but breaks an invariant (also checked before encoding).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ValidationError {
    /// A float that must be finite is NaN or infinite.
    #[error("non-finite value in `{field}` at index {index}")]
    NonFinite {
        /// Field name.
        field: &'static str,
        /// Index of the first offending element (0 for scalars).
        index: usize,
    },
    /// A column's length does not match the declared dimensions.
    #[error("`{field}` has {found} elements, the declared dimensions need {expected}")]
    LengthMismatch {
        /// Field name.
        field: &'static str,
        /// Length implied by the dimensions.
        expected: usize,
        /// Actual length.
        found: usize,
    },
    /// A dimension or count is outside the accepted range.
    #[error("`{field}` = {value} is outside the accepted range (max {limit})")]
    LimitExceeded {
        /// Field name.
        field: &'static str,
        /// Value found.
        value: u64,
        /// Largest accepted value.
        limit: u64,
    },
    /// The weight checksum does not match the parameter bytes.
    #[error(
        "checksum mismatch: message says {expected:#010x}, parameters hash to {computed:#010x}"
    )]
    ChecksumMismatch {
        /// Checksum carried by the message.
        expected: u32,
        /// CRC-32 of the parameter bytes.
        computed: u32,
    },
    /// Any other invalid field (bad names, out-of-range rates, inconsistent flags).
    #[error("invalid `{field}`: {reason}")]
    InvalidField {
        /// Field name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// Why bytes could not be turned into a message. Every malformed input maps to one of these;
/// decoding never panics.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DecodeError {
    /// The input is larger than the decode limit.
    #[error("message of {len} bytes exceeds the limit of {limit} bytes")]
    Oversized {
        /// Input length.
        len: usize,
        /// Limit in force.
        limit: usize,
    },
    /// The input ends in the middle of a value.
    #[error("message truncated")]
    Truncated,
    /// The input is not a MessagePack encoding of the expected message.
    #[error("malformed message: {0}")]
    Malformed(String),
    /// Bytes follow a complete message.
    #[error("{0} trailing bytes after the message")]
    TrailingBytes(usize),
    /// The sender speaks another protocol version.
    #[error("protocol version {found}, this build speaks {expected}")]
    WrongProtocolVersion {
        /// Version in the message header.
        found: u16,
        /// `PROTOCOL_VERSION`.
        expected: u16,
    },
    /// The header announces another message kind than the one expected on this topic.
    #[error("expected a {expected} message, header says {found}")]
    WrongKind {
        /// Kind expected by the caller.
        expected: MessageKind,
        /// Kind in the header.
        found: MessageKind,
    },
    /// The message decoded but is invalid.
    #[error(transparent)]
    Invalid(#[from] ValidationError),
}

/// Why a message could not be encoded.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum EncodeError {
    /// The message is invalid and would be rejected by every receiver.
    #[error(transparent)]
    Invalid(#[from] ValidationError),
    /// The encoding is larger than the limit.
    #[error("encoded message of {len} bytes exceeds the limit of {limit} bytes")]
    Oversized {
        /// Encoded length.
        len: usize,
        /// Limit in force.
        limit: usize,
    },
    /// The serialiser failed (should not happen for proto types).
    #[error("serialisation failed: {0}")]
    Serialize(String),
}
