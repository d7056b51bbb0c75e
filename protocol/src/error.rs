//! The protocol crate's one error type. Every variant names what was wrong so the server can
//! turn it into a [`RejectReason`] the client receives.

use crate::message::RejectReason;

/// Why a payload, a key or a value was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtocolError {
    /// The payload exceeds the size limit; nothing was decoded.
    #[error("payload of {len} bytes exceeds the {limit}-byte limit")]
    TooLarge {
        /// Payload length in bytes.
        len: usize,
        /// The limit it broke, in bytes.
        limit: usize,
    },
    /// The payload is not a valid message in the named encoding (truncated, wrong type,
    /// unknown variant, missing field...).
    #[error("malformed {encoding} payload: {detail}")]
    Malformed {
        /// Encoding name (`msgpack` or `json`).
        encoding: &'static str,
        /// The decoder's explanation.
        detail: String,
    },
    /// An input carries more actions than [`MAX_ACTIONS_PER_INPUT`](crate::limits::MAX_ACTIONS_PER_INPUT).
    #[error("input carries {count} actions, at most {limit} are allowed")]
    TooManyActions {
        /// Actions in the input.
        count: usize,
        /// The limit.
        limit: usize,
    },
    /// A whole message was decoded but bytes were left over.
    #[error("{extra} trailing bytes after a complete message")]
    TrailingBytes {
        /// How many bytes were left.
        extra: usize,
    },
    /// A float field holds NaN or an infinity.
    #[error("field `{field}` is not a finite number")]
    NonFinite {
        /// Path of the field, e.g. `actions[1].velocity[2]`.
        field: String,
    },
    /// A value is outside its documented range.
    #[error("field `{field}` out of range: {detail}")]
    OutOfRange {
        /// Path of the field.
        field: String,
        /// What the range is.
        detail: String,
    },
    /// An encoding name that is neither `msgpack` nor `json`.
    #[error("unknown encoding {0:?} (expected msgpack or json)")]
    UnknownEncoding(String),
    /// A key expression that does not match the expected shape.
    #[error("key expression {key:?} is not {expected}")]
    BadKey {
        /// The key that was received.
        key: String,
        /// What was expected.
        expected: &'static str,
    },
}

impl ProtocolError {
    /// The reason sent to a client whose input failed with this error.
    pub fn reject_reason(&self) -> RejectReason {
        match self {
            ProtocolError::TooLarge { .. } | ProtocolError::TooManyActions { .. } => RejectReason::TooLarge,
            ProtocolError::NonFinite { .. } => RejectReason::InvalidNumber,
            ProtocolError::OutOfRange { .. } => RejectReason::OutOfRange,
            ProtocolError::Malformed { .. }
            | ProtocolError::TrailingBytes { .. }
            | ProtocolError::UnknownEncoding(_)
            | ProtocolError::BadKey { .. } => RejectReason::Malformed,
        }
    }
}
