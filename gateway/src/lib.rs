//! impact for browsers: a WebSocket gateway. A browser cannot open a Zenoh session; the gateway
//! accepts its WebSocket, checks who the player is, and relays that player's messages to and
//! from its world over one Zenoh session, through a router or peer to peer (PROTOCOL.md,
//! "WebSocket binding").
//!
//! A binary of its own rather than a mode of the server: it scales apart from the servers (one
//! gateway in front of many worlds, or one per region), sits at the edge where browsers connect
//! while servers stay behind the router, holds a different credential (a `[[gateway]]` that may
//! act for any player, `impact_protocol::users`), and keeps HTTP and WebSocket code out of the
//! process that steps the world.
//!
//! - [`auth`]: the hello checked against the users file or a signed token; the trust model.
//! - [`token`]: signed, expiring player tokens a game backend issues.
//! - [`wire`]: the binding's own messages (hello, `ready`, `link_restored`) and close reasons.
//! - [`outbox`]: a connection's bounded queue toward its browser, state frames dropped first.
//! - [`relay`]: the Zenoh side, each player's declarations on its own keys, owner epochs.
//! - [`conn`]: one connection from hello to close.
//! - [`gateway`]: the settings, the players relayed, the HTTP routes (`/ws`, `/stats`).
//! - [`page`]: the play page compiled in (`/`, `/play.js`) and guest tokens (`POST /guest`).
//! - [`stats`]: the counters.

pub mod auth;
pub mod conn;
pub mod gateway;
pub mod outbox;
pub mod page;
pub mod relay;
pub mod stats;
pub mod token;
pub mod wire;

pub use gateway::{Config, Gateway};
