//! One entry point to encode ([`encode`]) and one to decode ([`decode`]).
//!
//! MessagePack (maps with field names, via `rmp-serde`) is the default: compact and
//! self-describing, so `msgpack` in Python or `@msgpack/msgpack` in JavaScript decodes it with
//! no schema. JSON carries the same structure for humans and tools. [`decode`] checks the size
//! limit before reading a byte, rejects trailing bytes, and runs [`Validate`] on the result, so
//! a value that reaches the caller is finite and in range.

use crate::error::ProtocolError;
use crate::limits::MAX_DECODE_DEPTH;
use crate::validate::Validate;
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::fmt;
use std::io::Cursor;
use std::str::FromStr;

/// A wire encoding.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// MessagePack, maps keyed by field name. The default.
    #[default]
    MsgPack,
    /// JSON (UTF-8), the same structure.
    Json,
}

impl Encoding {
    /// The short name used on command lines and in errors: `msgpack` or `json`.
    pub fn name(self) -> &'static str {
        match self {
            Encoding::MsgPack => "msgpack",
            Encoding::Json => "json",
        }
    }

    /// The Zenoh encoding tag set on every sample: `application/msgpack` or
    /// `application/json`.
    pub fn zenoh_tag(self) -> &'static str {
        match self {
            Encoding::MsgPack => "application/msgpack",
            Encoding::Json => "application/json",
        }
    }

    /// The encoding a Zenoh sample's tag names, if it is one of ours. Accepts the tag with an
    /// optional `;schema` suffix.
    pub fn from_zenoh_tag(tag: &str) -> Option<Encoding> {
        let base = tag.split(';').next().unwrap_or(tag);
        match base {
            "application/msgpack" | "application/x-msgpack" => Some(Encoding::MsgPack),
            "application/json" => Some(Encoding::Json),
            _ => None,
        }
    }
}

impl fmt::Display for Encoding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Encoding {
    type Err = ProtocolError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "msgpack" => Ok(Encoding::MsgPack),
            "json" => Ok(Encoding::Json),
            other => Err(ProtocolError::UnknownEncoding(other.to_string())),
        }
    }
}

/// Encodes a message after validating it, so the server can never emit a payload that
/// [`decode`] would refuse (JSON has no representation for NaN, and a client must not have to
/// guess what `null` meant).
pub fn encode<T: Serialize + Validate>(msg: &T, encoding: Encoding) -> Result<Vec<u8>, ProtocolError> {
    msg.validate()?;
    match encoding {
        Encoding::MsgPack => rmp_serde::to_vec_named(msg)
            .map_err(|e| ProtocolError::Malformed { encoding: "msgpack", detail: e.to_string() }),
        Encoding::Json => {
            serde_json::to_vec(msg).map_err(|e| ProtocolError::Malformed { encoding: "json", detail: e.to_string() })
        }
    }
}

/// Decodes and validates a message, refusing payloads over `max_bytes` before reading them.
pub fn decode<T: DeserializeOwned + Validate>(
    bytes: &[u8],
    encoding: Encoding,
    max_bytes: usize,
) -> Result<T, ProtocolError> {
    if bytes.len() > max_bytes {
        return Err(ProtocolError::TooLarge { len: bytes.len(), limit: max_bytes });
    }
    let msg: T = match encoding {
        Encoding::MsgPack => {
            let mut de = rmp_serde::Deserializer::new(Cursor::new(bytes));
            de.set_max_depth(MAX_DECODE_DEPTH);
            let msg = T::deserialize(&mut de)
                .map_err(|e| ProtocolError::Malformed { encoding: "msgpack", detail: e.to_string() })?;
            let used = de.position() as usize;
            if used != bytes.len() {
                return Err(ProtocolError::TrailingBytes { extra: bytes.len() - used });
            }
            msg
        }
        Encoding::Json => {
            let mut stream = serde_json::Deserializer::from_slice(bytes).into_iter::<T>();
            let msg = match stream.next() {
                Some(Ok(msg)) => msg,
                Some(Err(e)) => return Err(ProtocolError::Malformed { encoding: "json", detail: e.to_string() }),
                None => return Err(ProtocolError::Malformed { encoding: "json", detail: "empty payload".into() }),
            };
            let rest = &bytes[stream.byte_offset()..];
            if rest.iter().any(|b| !b.is_ascii_whitespace()) {
                return Err(ProtocolError::TrailingBytes { extra: rest.len() });
            }
            msg
        }
    };
    msg.validate()?;
    Ok(msg)
}
