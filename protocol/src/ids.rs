//! Typed identifiers. Each has an explicit integer size on the wire and serialises as its bare
//! value (a MessagePack or JSON integer), so other languages see plain numbers.

use serde::{Deserialize, Serialize};
use std::fmt;

/// A simulation tick. Tick `t` advances the world from time `t * dt` to `(t + 1) * dt`, where
/// `dt = 1 / tick_hz` seconds. `u32` lasts over two years at 64 Hz.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Tick(pub u32);

impl Tick {
    /// The tick after this one, saturating at `u32::MAX`.
    #[must_use]
    pub fn next(self) -> Tick {
        Tick(self.0.saturating_add(1))
    }
}

impl fmt::Display for Tick {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Which ownership of a world a message comes from: a fencing token. A world's first server owns
/// it at epoch 1; a standby that takes over owns it at one more than the newest epoch it has
/// seen. Every message a server publishes or replies carries its epoch as the Zenoh attachment
/// (the 8 bytes of a `u64`, little-endian, first: [`Stamp`]), so a server that finds a newer
/// one stops publishing, and a client drops what an older owner still sends (PROTOCOL.md,
/// "Failover").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Epoch(pub u64);

impl Epoch {
    /// A world's first owner's.
    pub const FIRST: Epoch = Epoch(1);

    /// The epoch after this one (a takeover's).
    #[must_use]
    pub fn next(self) -> Epoch {
        Epoch(self.0.saturating_add(1))
    }

    /// As a Zenoh attachment: 8 bytes, little-endian.
    pub fn attachment(self) -> [u8; 8] {
        self.0.to_le_bytes()
    }

    /// Reads the epoch of an attachment written by [`Epoch::attachment`] or [`Stamp::attachment`]
    /// (`None` for any other length).
    pub fn from_attachment(bytes: &[u8]) -> Option<Epoch> {
        Stamp::from_attachment(bytes).map(|s| s.epoch)
    }
}

/// What a server's message carries as its Zenoh attachment: its owner's [`Epoch`] and, on a
/// message published on a key (not a query's reply), its number on that key: 1 for the first
/// message the owner published on the key, one more for each after. A receiver that sees a
/// number skip knows that messages on the key were lost on the way (PROTOCOL.md, "When things go
/// wrong"). As bytes: the epoch's 8, then the number's 8 when there is one, both `u64`
/// little-endian.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stamp {
    /// The owner's epoch.
    pub epoch: Epoch,
    /// The message's number on its key (`None`: a reply, or a server that does not count).
    pub number: Option<u64>,
}

impl Stamp {
    /// As a Zenoh attachment: 8 bytes, or 16 with a number.
    pub fn attachment(self) -> Vec<u8> {
        let mut out = self.epoch.attachment().to_vec();
        if let Some(n) = self.number {
            out.extend_from_slice(&n.to_le_bytes());
        }
        out
    }

    /// Reads an attachment of 8 or 16 bytes (`None` for any other length).
    pub fn from_attachment(bytes: &[u8]) -> Option<Stamp> {
        let word = |b: &[u8]| <[u8; 8]>::try_from(b).ok().map(u64::from_le_bytes);
        match bytes.len() {
            8 => Some(Stamp { epoch: Epoch(word(bytes)?), number: None }),
            16 => Some(Stamp { epoch: Epoch(word(&bytes[..8])?), number: Some(word(&bytes[8..])?) }),
            _ => None,
        }
    }
}

impl From<Epoch> for Stamp {
    fn from(epoch: Epoch) -> Stamp {
        Stamp { epoch, number: None }
    }
}

impl fmt::Display for Epoch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// A client, unique within a world. Chosen by the client and carried in its key expressions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct ClientId(pub u32);

impl fmt::Display for ClientId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// A body in the world (dynamic, static, terrain). Assigned by the server; never reused within
/// a run, so an event naming an entity is unambiguous.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct EntityId(pub u32);

impl fmt::Display for EntityId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// A world name: the `{world}` segment of every key expression. 1 to 64 characters from
/// `[a-z0-9_-]`, so it can never smuggle a `/` or a wildcard into a key.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct WorldId(String);

impl WorldId {
    /// Checks the name and wraps it.
    pub fn new(name: impl Into<String>) -> Result<WorldId, crate::ProtocolError> {
        let name = name.into();
        let ok_len = !name.is_empty() && name.len() <= crate::limits::MAX_NAME_LEN;
        let ok_chars = name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-');
        if ok_len && ok_chars {
            Ok(WorldId(name))
        } else {
            Err(crate::ProtocolError::OutOfRange {
                field: "world".into(),
                detail: format!(
                    "world name {name:?} must be 1..={} characters of [a-z0-9_-]",
                    crate::limits::MAX_NAME_LEN
                ),
            })
        }
    }

    /// The name as it appears in key expressions.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl TryFrom<String> for WorldId {
    type Error = crate::ProtocolError;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        WorldId::new(s)
    }
}

impl From<WorldId> for String {
    fn from(w: WorldId) -> String {
        w.0
    }
}

impl fmt::Display for WorldId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::{Epoch, Stamp};

    #[test]
    fn a_stamp_reads_back_with_and_without_its_number() {
        let numbered = Stamp { epoch: Epoch(7), number: Some(1 << 40) };
        assert_eq!(numbered.attachment().len(), 16);
        assert_eq!(Stamp::from_attachment(&numbered.attachment()), Some(numbered));
        assert_eq!(Epoch::from_attachment(&numbered.attachment()), Some(Epoch(7)));
        let bare = Stamp::from(Epoch(3));
        assert_eq!(bare.attachment(), Epoch(3).attachment().to_vec());
        assert_eq!(Stamp::from_attachment(&Epoch(3).attachment()), Some(bare));
        for len in [0, 1, 7, 9, 15, 17, 24] {
            assert_eq!(Stamp::from_attachment(&vec![1; len]), None, "{len} bytes");
        }
    }
}
