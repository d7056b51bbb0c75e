//! Every Zenoh key expression impact uses, built in one place under the versioned prefix
//! `impact/v1/{world}`. The patterns in [`PATTERNS`] are the single source: the builders fill
//! them in, and a test checks that `PROTOCOL.md` documents each one.

use crate::error::ProtocolError;
use crate::ids::{ClientId, WorldId};

/// The protocol version segment. Bumped on any incompatible wire change.
pub const VERSION: &str = "v1";

/// A documented key: its name, who publishes it, and its pattern.
#[derive(Clone, Copy, Debug)]
pub struct KeyPattern {
    /// Short name.
    pub name: &'static str,
    /// The pattern, with `{world}` and `{client}` placeholders.
    pub pattern: &'static str,
}

/// Client -> server inputs ([`ClientMessage`](crate::ClientMessage)).
pub const INPUT: KeyPattern = KeyPattern { name: "input", pattern: "impact/v1/{world}/input/{client}" };
/// Per-tick event batches ([`ServerMessage::Events`](crate::ServerMessage::Events)).
pub const EVENTS: KeyPattern = KeyPattern { name: "events", pattern: "impact/v1/{world}/events" };
/// Corrections of published ticks.
pub const CORRECTIONS: KeyPattern = KeyPattern { name: "corrections", pattern: "impact/v1/{world}/corrections" };
/// Confirmed (final) event batches.
pub const CONFIRMED: KeyPattern = KeyPattern { name: "confirmed", pattern: "impact/v1/{world}/confirmed" };
/// Events, corrections and confirmations that involve one client's entities.
pub const CLIENT_EVENTS: KeyPattern =
    KeyPattern { name: "client_events", pattern: "impact/v1/{world}/client/{client}/events" };
/// Acks, rejects, ray results and the welcome for one client.
pub const CLIENT_ACK: KeyPattern = KeyPattern { name: "client_ack", pattern: "impact/v1/{world}/client/{client}/ack" };
/// Server statistics, once a second.
pub const STATS: KeyPattern = KeyPattern { name: "stats", pattern: "impact/v1/{world}/stats" };
/// Liveliness token a client declares while connected.
pub const PRESENCE: KeyPattern = KeyPattern { name: "presence", pattern: "impact/v1/{world}/presence/{client}" };
/// Queryable: world state at a tick (`?tick=T`).
pub const QUERY_STATE: KeyPattern = KeyPattern { name: "query_state", pattern: "impact/v1/{world}/query/state" };
/// Queryable: events of a tick range (`?from=T1;to=T2`).
pub const QUERY_HISTORY: KeyPattern = KeyPattern { name: "query_history", pattern: "impact/v1/{world}/query/history" };
/// Queryable: the confirmed batches of recent ticks (`?from=T1;to=T2`, with `client=C` as that
/// client's stream carries them), one reply per tick the server still keeps: a subscriber that
/// missed a batch gets it again.
pub const QUERY_CONFIRMED: KeyPattern =
    KeyPattern { name: "query_confirmed", pattern: "impact/v1/{world}/query/confirmed" };
/// Queryable: the rules and static world as the core runs them
/// ([`SceneDescription`](crate::SceneDescription)), for a client that predicts.
pub const QUERY_SCENE: KeyPattern = KeyPattern { name: "query_scene", pattern: "impact/v1/{world}/query/scene" };

/// Queryable: game logic opens or closes the world `{world}` at run time
/// ([`ClientMessage::World`](crate::ClientMessage::World), answered by
/// [`ServerMessage::World`](crate::ServerMessage::World)); `{client}` is the logic client.
pub const WORLD_COMMAND: KeyPattern =
    KeyPattern { name: "world_command", pattern: "impact/v1/{world}/client/{client}/world" };

/// The input log, one message per confirmed tick ([`LogTick`](crate::LogTick)).
pub const LOG: KeyPattern = KeyPattern { name: "log", pattern: "impact/v1/{world}/log" };
/// Inputs and server actions admitted but not yet confirmed ([`Admitted`](crate::Admitted)).
pub const LOG_ADMITTED: KeyPattern = KeyPattern { name: "log_admitted", pattern: "impact/v1/{world}/log/admitted" };
/// Liveliness token of the server that owns the world (a standby takes over when it goes).
pub const SERVER: KeyPattern = KeyPattern { name: "server", pattern: "impact/v1/{world}/server" };
/// The world's owner says who it is ([`OwnerNotice`](crate::OwnerNotice)), four times a second:
/// a server that hears a newer epoch than its own stops publishing for the world.
pub const OWNER: KeyPattern = KeyPattern { name: "owner", pattern: "impact/v1/{world}/owner" };
/// Queryable: the complete confirmed state ([`Checkpoint`](crate::Checkpoint)), for a standby.
pub const QUERY_CHECKPOINT: KeyPattern =
    KeyPattern { name: "query_checkpoint", pattern: "impact/v1/{world}/query/checkpoint" };

/// Every body's state at `--state-hz`, full frames and deltas ([`StateFrame`](crate::StateFrame)).
pub const STATE: KeyPattern = KeyPattern { name: "state", pattern: "impact/v1/{world}/state" };
/// The bodies near one client's avatar, within its byte budget.
pub const CLIENT_STATE: KeyPattern =
    KeyPattern { name: "client_state", pattern: "impact/v1/{world}/client/{client}/state" };

/// Every key impact uses.
pub const PATTERNS: [KeyPattern; 20] = [
    INPUT,
    EVENTS,
    CORRECTIONS,
    CONFIRMED,
    CLIENT_EVENTS,
    CLIENT_ACK,
    STATS,
    PRESENCE,
    QUERY_STATE,
    QUERY_HISTORY,
    QUERY_CONFIRMED,
    QUERY_SCENE,
    LOG,
    LOG_ADMITTED,
    SERVER,
    OWNER,
    QUERY_CHECKPOINT,
    STATE,
    CLIENT_STATE,
    WORLD_COMMAND,
];

impl KeyPattern {
    /// The key for one world (and, where the pattern has one, one client).
    pub fn key(&self, world: &WorldId, client: Option<ClientId>) -> String {
        let with_world = self.pattern.replace("{world}", world.as_str());
        match client {
            Some(c) => with_world.replace("{client}", &c.0.to_string()),
            None => with_world.replace("{client}", "*"),
        }
    }

    /// The key for one world with `*` for the client: what the server subscribes to.
    pub fn any_client(&self, world: &WorldId) -> String {
        self.key(world, None)
    }

    /// The key with `*` for the world too: what an inspector of every world subscribes to.
    pub fn any_world(&self) -> String {
        self.pattern.replace("{world}", "*").replace("{client}", "*")
    }

    /// Reads `(world, client)` back out of a concrete key of this pattern.
    pub fn parse(&self, key: &str) -> Result<(WorldId, Option<ClientId>), ProtocolError> {
        let bad = || ProtocolError::BadKey { key: key.chars().take(200).collect(), expected: self.pattern };
        let pat: Vec<&str> = self.pattern.split('/').collect();
        let got: Vec<&str> = key.split('/').collect();
        if pat.len() != got.len() {
            return Err(bad());
        }
        let mut world = None;
        let mut client = None;
        for (p, g) in pat.iter().zip(&got) {
            match *p {
                "{world}" => world = Some(WorldId::new(*g).map_err(|_| bad())?),
                "{client}" => client = Some(ClientId(g.parse::<u32>().map_err(|_| bad())?)),
                lit if lit == *g => {}
                _ => return Err(bad()),
            }
        }
        Ok((world.ok_or_else(bad)?, client))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_built_and_parsed_back() {
        let w = WorldId::new("arena").unwrap();
        let k = INPUT.key(&w, Some(ClientId(42)));
        assert_eq!(k, "impact/v1/arena/input/42");
        assert_eq!(INPUT.parse(&k).unwrap(), (w.clone(), Some(ClientId(42))));
        assert_eq!(INPUT.any_client(&w), "impact/v1/arena/input/*");
        assert_eq!(EVENTS.any_world(), "impact/v1/*/events");
        assert!(INPUT.parse("impact/v1/arena/input/x").is_err());
        assert!(INPUT.parse("impact/v1/arena/input/1/2").is_err());
        assert!(INPUT.parse("impact/v2/arena/input/1").is_err());
        assert!(INPUT.parse("impact/v1/Ar*na/input/1").is_err());
    }

    #[test]
    fn every_pattern_is_versioned_and_unique() {
        for (i, p) in PATTERNS.iter().enumerate() {
            assert!(p.pattern.starts_with(&format!("impact/{VERSION}/{{world}}/")), "{}", p.pattern);
            for q in &PATTERNS[i + 1..] {
                assert_ne!(p.pattern, q.pattern);
                assert_ne!(p.name, q.name);
            }
        }
    }
}
