//! impact's client library for games: the client's logic as plain state
//! machines, fed with the messages a transport received and the local clock, giving the game
//! plain data each frame. Nothing here does I/O, spawns a thread or reads a clock: a Zenoh
//! transport, a WebSocket one or another language's port drives the same model.
//!
//! - [`inputs`]: the input outbox, sequence numbers and the inputs awaiting an answer, matched
//!   by `seq` to acks and rejects.
//! - [`remote`]: the remote world, the bodies of a state stream as they are to be drawn at a
//!   render time, interpolated between frames and extrapolated by velocity for a bounded time
//!   when frames are late.
//! - [`clock`]: the client's estimate of the server's tick, and the tick to stamp an input with
//!   (behind, or ahead by the lead the acks recommend, moved by time dilation).
//! - [`events`]: the event view, provisional events with corrections applied by identity, and
//!   each confirmed tick compared with the view.
//! - [`netsim`]: a network model (latency, jitter, loss, stalls) for testing a game locally.
//!
//! - [`predict`]: the player's own avatar stepped with the server's core, checked against every
//!   state the server streams, corrected by replay and eased.
//! - [`session`]: all of the above as one state machine, a client's whole side of the protocol:
//!   join and welcome, the time-sync exchange, inputs with redundancy, the three views.
//! - [`transport`] (feature `zenoh`, on by default): the session over Zenoh, the only I/O here.
//! - [`report`] (feature `zenoh`): how a game played, its drawing checked against the server's
//!   record, and the one-line summary the examples print; [`bot`]: a scripted player for them.
//!
//! A game, in a few lines (`examples/play.rs` is a whole one):
//!
//! ```no_run
//! use impact_client::transport::{ConnectOptions, Connection};
//! use impact_client::{Outcome, Session, SessionConfig, Status};
//! use impact_protocol::{Action, ClientId, WorldId};
//! use std::time::Instant;
//!
//! let me = ClientId(1);
//! let world = WorldId::new("arena")?;
//! let conn = Connection::open(&ConnectOptions::new(vec!["tcp/127.0.0.1:7447".into()], world, me))?;
//! let mut game = Session::new(SessionConfig::new(me));
//! let mut drawn = Vec::new();
//! loop {
//!     let now = Instant::now();
//!     conn.pump(&mut game, now)?; // what arrived in, what is due out
//!     if let (Status::Playing, Some(avatar)) = (game.status(), game.avatar()) {
//!         game.input(vec![Action::SetVelocity { entity: avatar, velocity: [2.0, 0.0, 0.0] }], now)?;
//!     }
//!     let _me_at = game.draw_avatar(now); // the own avatar, predicted
//!     game.draw_remote(now, &mut drawn); // the remote world at render time: draw it
//!     for ray in game.take_ray_results() { /* hits */ }
//!     for answer in game.take_answers() { // each input accepted, or refused and why
//!         if let Outcome::Rejected(why) = answer.outcome {
//!             eprintln!("input {} refused: {why:?}", answer.seq);
//!         }
//!     }
//!     let _confirmed_ok = game.events().matched; // the event view
//!     # break;
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The transport asks the server for its rules and static world (`query/scene`) as it
//! connects; the session predicts the own avatar with them once they come
//! ([`Session::prediction_problem`] says why it does not). A game that ships its levels may give
//! its own predictor instead ([`Session::predict_with`]).

#![warn(missing_docs)]

pub mod bot;
pub mod clock;
pub mod events;
pub mod inputs;
pub mod netsim;
pub mod predict;
pub mod remote;
#[cfg(feature = "zenoh")]
pub mod report;
pub mod session;
#[cfg(feature = "zenoh")]
pub mod transport;

pub use session::{Answer, EventNews, InputError, Outcome, Session, SessionConfig, SessionStats, Status};
