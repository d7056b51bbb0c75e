//! The WebSocket binding's own messages and close reasons (PROTOCOL.md, "WebSocket binding").
//!
//! Every WebSocket message is one binary frame holding one MessagePack message. Browser to
//! gateway: first a [`Hello`], then PROTOCOL.md's client messages (`input`, `inputs`, `ping`,
//! `full_frame`) or a gateway [`Request`]. Gateway to browser: a [`Notice`] `ready` once the
//! hello is accepted, then the server's messages for that player exactly as the server
//! published them (acks, rejects, events, state, pongs, welcome), and a `link_restored` notice
//! when the gateway's own link to the servers came back (what was published meanwhile is lost:
//! PROTOCOL.md, "A lost link"). Whatever ends a connection, the gateway says why in the close
//! frame: a [`Close`] code and a short reason.

use serde::{Deserialize, Serialize};

/// The first message of a connection: who the player is and where it plays.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hello {
    /// The world to join. With a token, the token's (and this may be left out).
    #[serde(default)]
    pub world: Option<String>,
    /// The client id (the users file's `client`). With a token, the token's.
    #[serde(default)]
    pub client: Option<u32>,
    /// A users file's user name, with `password`.
    #[serde(default)]
    pub user: Option<String>,
    /// Its password.
    #[serde(default)]
    pub password: Option<String>,
    /// A signed token from the game's backend, instead of a user and password.
    #[serde(default)]
    pub token: Option<String>,
    /// Whether to relay the player's state stream (default true).
    #[serde(default)]
    pub state: Option<bool>,
}

/// Browser to gateway, besides the hello and the protocol's client messages.
#[derive(Clone, Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Request {
    /// The hello, only as the first message.
    Hello(Hello),
    /// The world's rules and static geometry (`query/scene`), answered by the server's `scene`
    /// message (or a `query_error`).
    Scene,
    /// The confirmed batch of `tick` the player's stream carries, asked again after it was
    /// missed (`query/confirmed` with the player's client id): answered by that `confirmed`
    /// message if the server still keeps the tick, by nothing otherwise.
    Confirmed {
        /// The tick.
        tick: u32,
    },
}

/// Gateway to browser, besides the server's messages.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Notice {
    /// The hello was accepted: relaying as `client` in `world`; the server's `welcome` follows.
    Ready {
        /// The client id relayed.
        client: u32,
        /// The world.
        world: String,
        /// Largest message the gateway reads, in bytes.
        max_message_bytes: u32,
        /// Messages a second the gateway reads from one connection before closing it.
        max_messages_per_s: u32,
    },
    /// The gateway's link to the servers was lost and is back: take the confirmed batches of
    /// the ticks before the server's present as they come (PROTOCOL.md, "A lost link").
    LinkRestored,
}

/// Why the gateway closed a connection: the close frame's code (4000-4999 are the
/// application's, RFC 6455) and its reason text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Close {
    /// The first message was not a hello, or the hello lacked what it needs.
    BadHello,
    /// The user, password or token was refused, or does not allow the client or world asked.
    Unauthorized,
    /// No hello within the time allowed.
    HelloTimeout,
    /// No server runs the world (or none speaking this protocol version).
    NoServer,
    /// The browser read too slowly: its queue filled with messages that cannot be dropped.
    TooSlow,
    /// A message was not a protocol message the gateway relays.
    Malformed,
    /// A message the gateway does not relay for players (world commands).
    NotAllowed,
    /// More messages a second than the gateway reads from one connection.
    Flood,
    /// The same client connected again through this gateway: the newer connection plays.
    Replaced,
    /// The gateway could not reach the servers to relay the player.
    Unavailable,
    /// The gateway is shutting down (1001, going away).
    GoingAway,
    /// A message over the size limit (1009, message too big).
    TooBig,
    /// The browser closed, or the connection broke: nothing to send.
    Gone,
}

impl Close {
    /// The close code.
    pub fn code(self) -> u16 {
        match self {
            Close::BadHello => 4000,
            Close::Unauthorized => 4001,
            Close::HelloTimeout => 4002,
            Close::NoServer => 4004,
            Close::TooSlow => 4008,
            Close::Malformed => 4011,
            Close::NotAllowed => 4012,
            Close::Flood => 4029,
            Close::Replaced => 4030,
            Close::Unavailable => 4503,
            Close::GoingAway => 1001,
            Close::TooBig => 1009,
            Close::Gone => 1000,
        }
    }

    /// Its name, the first word of the reason text.
    pub fn name(self) -> &'static str {
        match self {
            Close::BadHello => "bad_hello",
            Close::Unauthorized => "unauthorized",
            Close::HelloTimeout => "hello_timeout",
            Close::NoServer => "no_server",
            Close::TooSlow => "too_slow",
            Close::Malformed => "malformed",
            Close::NotAllowed => "not_allowed",
            Close::Flood => "flood",
            Close::Replaced => "replaced",
            Close::Unavailable => "unavailable",
            Close::GoingAway => "going_away",
            Close::TooBig => "too_big",
            Close::Gone => "gone",
        }
    }

    /// Every reason, for the documentation and the metrics.
    pub const ALL: [Close; 13] = [
        Close::BadHello,
        Close::Unauthorized,
        Close::HelloTimeout,
        Close::NoServer,
        Close::TooSlow,
        Close::Malformed,
        Close::NotAllowed,
        Close::Flood,
        Close::Replaced,
        Close::Unavailable,
        Close::GoingAway,
        Close::TooBig,
        Close::Gone,
    ];
}

/// A close reason's text: the name, and a detail cut to fit a close frame (123 bytes).
pub fn close_reason(why: Close, detail: &str) -> String {
    let mut text = if detail.is_empty() { why.name().to_string() } else { format!("{}: {detail}", why.name()) };
    if text.len() > 123 {
        let mut end = 123;
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        text.truncate(end);
    }
    text
}

/// A gateway notice as a binary frame.
pub fn encode_notice(n: &Notice) -> Vec<u8> {
    rmp_serde::to_vec_named(n).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_and_names_are_distinct() {
        let codes: std::collections::BTreeSet<u16> = Close::ALL.iter().map(|c| c.code()).collect();
        let names: std::collections::BTreeSet<&str> = Close::ALL.iter().map(|c| c.name()).collect();
        assert_eq!((codes.len(), names.len()), (Close::ALL.len(), Close::ALL.len()));
    }

    #[test]
    fn a_reason_fits_a_close_frame() {
        assert_eq!(close_reason(Close::Flood, ""), "flood");
        assert_eq!(close_reason(Close::Unauthorized, "token expired"), "unauthorized: token expired");
        let long = close_reason(Close::Malformed, &"é".repeat(100));
        assert!(long.len() <= 123 && long.starts_with("malformed: "));
    }

    /// The hello and the requests read as PROTOCOL.md writes them; the notices write so.
    #[test]
    fn the_binding_reads_and_writes_its_messages() {
        #[derive(Serialize)]
        struct H<'a> {
            r#type: &'a str,
            world: &'a str,
            client: u32,
            user: &'a str,
            password: &'a str,
        }
        let bytes =
            rmp_serde::to_vec_named(&H { r#type: "hello", world: "arena", client: 7, user: "u", password: "p" })
                .unwrap();
        let Request::Hello(h) = rmp_serde::from_slice(&bytes).unwrap() else { panic!("a hello") };
        assert_eq!((h.world.as_deref(), h.client, h.token), (Some("arena"), Some(7), None));
        let scene = rmp_serde::to_vec_named(&serde_json::json!({"type": "scene"})).unwrap();
        assert!(matches!(rmp_serde::from_slice(&scene).unwrap(), Request::Scene));
        let ready = encode_notice(&Notice::LinkRestored);
        let v: serde_json::Value = rmp_serde::from_slice(&ready).unwrap();
        assert_eq!(v, serde_json::json!({"type": "link_restored"}));
    }

    /// PROTOCOL.md's examples of the binding's own messages: each hello reads as one, and the
    /// `ready` is what the gateway writes with the default limits.
    #[test]
    fn the_documented_examples_are_the_binding() {
        // cargo runs a test in its package's directory (a path built in would name the clone it was built in)
        let doc = std::fs::read_to_string("../PROTOCOL.md").unwrap();
        let section = doc.split("## WebSocket binding").nth(1).unwrap().split("\n## ").next().unwrap();
        let lines: Vec<serde_json::Value> = section
            .split("```text\n")
            .skip(1)
            .flat_map(|b| b.split("```").next().unwrap().lines().map(|l| serde_json::from_str(l).unwrap()))
            .collect();
        let hellos: Vec<&serde_json::Value> = lines.iter().filter(|v| v["type"] == "hello").collect();
        assert_eq!(hellos.len(), 2);
        for h in hellos {
            let bytes = rmp_serde::to_vec_named(h).unwrap();
            assert!(matches!(rmp_serde::from_slice(&bytes), Ok(Request::Hello(_))), "{h}");
        }
        let ready = lines.iter().find(|v| v["type"] == "ready").unwrap();
        let c = crate::Config::default();
        let ours = Notice::Ready {
            client: 7,
            world: "arena".into(),
            max_message_bytes: c.max_message_bytes as u32,
            max_messages_per_s: c.max_messages_per_s,
        };
        assert_eq!(&serde_json::to_value(&ours).unwrap(), ready);
    }
}
