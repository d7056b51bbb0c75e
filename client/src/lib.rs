//! impact's client library for games (issue 27, in progress): the client's logic as plain state
//! machines, fed with the messages a transport received and the local clock, giving the game
//! plain data each frame. Nothing here does I/O, spawns a thread or reads a clock: a Zenoh
//! transport, a WebSocket one or another language's port drives the same model.
//!
//! - [`remote`]: the remote world, the bodies of a state stream as they are to be drawn at a
//!   render time, interpolated between frames and extrapolated by velocity for a bounded time
//!   when frames are late.
//! - [`events`]: the event view, provisional events with corrections applied by identity, and
//!   each confirmed tick compared with the view.
//! - [`netsim`]: a network model (latency, jitter, loss) for testing a game locally.
//!
//! Still to come (issue 27): the clock and its time-sync exchange, input sequencing with acks and
//! rejects, and prediction of the player's own avatar with the core.

#![warn(missing_docs)]

pub mod events;
pub mod netsim;
pub mod remote;
