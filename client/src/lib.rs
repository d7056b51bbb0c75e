//! impact's client library for games (issue 27, in progress): the client's logic as plain state
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
//! - [`netsim`]: a network model (latency, jitter, loss) for testing a game locally.
//!
//! Still to come (issue 27): a time-sync exchange before the first input, inputs that carry the
//! unacknowledged ones before them (redundancy), and prediction of the player's own avatar with
//! the core.

#![warn(missing_docs)]

pub mod clock;
pub mod events;
pub mod inputs;
pub mod netsim;
pub mod remote;
