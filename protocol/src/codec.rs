//! One entry point to encode ([`encode`]) and one to decode ([`decode`]).
//!
//! MessagePack (maps with field names, via `rmp-serde`) is the default: compact and
//! self-describing, so `msgpack` in Python or `@msgpack/msgpack` in JavaScript decodes it with
//! no schema. JSON carries the same structure for humans and tools. [`decode`] checks the size
//! limit before reading a byte, rejects trailing bytes, and runs [`Validate`] on the result, so
//! a value that reaches the caller is finite and in range.

use crate::error::ProtocolError;
use crate::ids::{ClientId, Tick};
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
    let mut out = Vec::new();
    encode_into(msg, encoding, &mut out)?;
    Ok(out)
}

/// [`encode`] onto the end of `out`: a caller that knows about how large the message is gives
/// the room ahead (the server's state frames, each bounded by its budget's estimate), so the
/// bytes are not grown and copied as they are written. On an error `out` may hold part of it.
pub fn encode_into<T: Serialize + Validate>(
    msg: &T,
    encoding: Encoding,
    out: &mut Vec<u8>,
) -> Result<(), ProtocolError> {
    msg.validate()?;
    match encoding {
        Encoding::MsgPack => rmp_serde::encode::write_named(out, msg)
            .map_err(|e| ProtocolError::Malformed { encoding: "msgpack", detail: e.to_string() }),
        Encoding::Json => serde_json::to_writer(out, msg)
            .map_err(|e| ProtocolError::Malformed { encoding: "json", detail: e.to_string() }),
    }
}

/// Decodes and validates a message, refusing payloads over `max_bytes` before reading them.
pub fn decode<T: DeserializeOwned + Validate>(
    bytes: &[u8],
    encoding: Encoding,
    max_bytes: usize,
) -> Result<T, ProtocolError> {
    let msg: T = decode_unchecked(bytes, encoding, max_bytes)?;
    msg.validate()?;
    Ok(msg)
}

/// Decodes a message's structure without checking its values: the size limit, the depth limit,
/// every field present with its type, no trailing bytes. The caller must [`Validate`] the result
/// before it trusts a number in it; the server does so after reading the input's `seq` and
/// `tick`, so a refused value is answered with them.
pub fn decode_unchecked<T: DeserializeOwned>(
    bytes: &[u8],
    encoding: Encoding,
    max_bytes: usize,
) -> Result<T, ProtocolError> {
    let (msg, used) = decode_prefix(bytes, encoding, max_bytes)?;
    let rest = &bytes[used..];
    let trailing = match encoding {
        Encoding::MsgPack => !rest.is_empty(),
        Encoding::Json => rest.iter().any(|b| !b.is_ascii_whitespace()),
    };
    if trailing {
        return Err(ProtocolError::TrailingBytes { extra: rest.len() });
    }
    Ok(msg)
}

/// The first message in `bytes` and the bytes it took.
fn decode_prefix<T: DeserializeOwned>(
    bytes: &[u8],
    encoding: Encoding,
    max_bytes: usize,
) -> Result<(T, usize), ProtocolError> {
    if bytes.len() > max_bytes {
        return Err(ProtocolError::TooLarge { len: bytes.len(), limit: max_bytes });
    }
    match encoding {
        Encoding::MsgPack => {
            let mut de = rmp_serde::Deserializer::new(Cursor::new(bytes));
            de.set_max_depth(MAX_DECODE_DEPTH);
            let msg = T::deserialize(&mut de)
                .map_err(|e| ProtocolError::Malformed { encoding: "msgpack", detail: e.to_string() })?;
            Ok((msg, de.position() as usize))
        }
        Encoding::Json => {
            let mut stream = serde_json::Deserializer::from_slice(bytes).into_iter::<T>();
            match stream.next() {
                Some(Ok(msg)) => Ok((msg, stream.byte_offset())),
                Some(Err(e)) => Err(ProtocolError::Malformed { encoding: "json", detail: e.to_string() }),
                None => Err(ProtocolError::Malformed { encoding: "json", detail: "empty payload".into() }),
            }
        }
    }
}

/// The `client`, `seq` and `tick` of an input whose whole could not be decoded (an unknown
/// action type, a field of the wrong type further in): every other field is skipped unread, so
/// a malformed input is still answered with its own `seq` and `tick`. `None` when even these
/// cannot be read (too large, truncated, not a map). Bytes after the message are ignored here.
pub fn input_header(bytes: &[u8], encoding: Encoding, max_bytes: usize) -> Option<(ClientId, u32, Tick)> {
    // The same tagging as `ClientMessage`, so whatever form decodes as an input (a map, or
    // serde's positional array) also yields its header; the fields after `tick` are skipped.
    #[derive(serde::Deserialize)]
    #[serde(tag = "type", rename_all = "snake_case")]
    enum Message {
        Input(Header),
    }
    #[derive(serde::Deserialize)]
    struct Header {
        client: ClientId,
        seq: u32,
        tick: Tick,
        #[serde(default)]
        #[allow(dead_code)]
        view_tick: serde::de::IgnoredAny,
        #[serde(default)]
        #[allow(dead_code)]
        actions: serde::de::IgnoredAny,
    }
    let (Message::Input(h), _): (Message, usize) = decode_prefix(bytes, encoding, max_bytes).ok()?;
    Some((h.client, h.seq, h.tick))
}
