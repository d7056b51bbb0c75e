//! The impact wire protocol: what crosses the network between the authoritative server and
//! its clients. Types, key expressions, the codec and the limits; no I/O and no async, so a
//! client, a test or a tool can use it without pulling in a runtime.
//!
//! - [`ids`]: typed identifiers with explicit sizes on the wire (`u32`, never `usize`).
//! - [`serial`]: the counters that wrap (input seqs, frame numbers), ordered as serial numbers.
//! - [`message`]: one enum per direction, [`ClientMessage`] and [`ServerMessage`].
//! - [`action`]: what a client can do ([`Action`]) and where a ray hit ([`RayHit`]).
//! - [`event`]: the [`CollisionEvent`] the server publishes.
//! - [`scene`]: [`SceneDescription`], the rules and static world as the core runs them
//!   (`query/scene`), so a client predicts without the scene file.
//! - [`shape`]: [`ShapeSpec`], a collision shape as data: scene files, spawns and checkpoints.
//! - [`state`]: the state streams' frames ([`StateFrame`]) for drawing and interpolation.
//! - [`keys`]: every Zenoh key expression, built in one place under `impact/v1/{world}`.
//! - [`codec`]: [`encode`] and [`decode`], MessagePack by default, JSON on request.
//! - [`limits`]: the hard bounds every decoded message is checked against.
//! - [`log`]: the input log a standby follows and a recording replays.
//! - [`users`]: the users file, who may be which client, and the access rules it implies.
//! - [`validate`]: the value checks every decoded message passes ([`Validate`]).
//! - [`error`]: [`ProtocolError`], why a payload was refused.
//!
//! `PROTOCOL.md` at the repository root documents all of it for a client in another language.

pub mod action;
pub mod codec;
pub mod error;
pub mod event;
pub mod ids;
pub mod keys;
pub mod limits;
pub mod log;
pub mod message;
pub mod scene;
pub mod serial;
pub mod shape;
pub mod state;
pub mod users;
pub mod validate;

pub use codec::{decode, decode_unchecked, encode, encode_into, input_header, Encoding};
pub use error::ProtocolError;
pub use event::{CollisionEvent, EventKey, EventStatus, Phase, Response};
pub use ids::{ClientId, EntityId, Epoch, Stamp, Tick, WorldId};
pub use log::{Admitted, Checkpoint, LogTick, LoggedInput, LoggedSystem};
pub use message::{
    Action, BodyState, ClientInput, ClientMessage, CorrectionBatch, EventBatch, EventHistory, FullFrameRequest,
    InputAck, InputBatch, InputReject, OwnerNotice, QueryError, RayHit, RayResult, RejectReason, ServerMessage,
    ServerStats, ShapeSpec, TimePing, TimePong, Welcome, WorldAnswer, WorldClosed, WorldCommand, WorldOutcome,
    WorldSnapshot,
};
pub use scene::SceneDescription;
pub use state::{AvatarState, AvatarTouch, BodyInfo, BodyMotion, BodyShape, GameState, StateFrame};
pub use validate::Validate;
