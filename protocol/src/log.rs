//! The input log: what a world applied, tick by tick, so that anyone holding the scene can
//! reproduce it bit for bit.
//!
//! The server publishes one [`LogTick`] per confirmed tick on `impact/v1/{world}/log` (and writes
//! the same to disk with `--record`): the inputs and server actions applied at the tick, in the
//! order they were applied, and the state hash after it. A standby follows it to keep an identical
//! world; `impact-server --offline --replay FILE` re-simulates a recording and checks every hash.
//!
//! The confirmed log trails the present by the rollback window. What the server admitted since
//! (acked but not yet confirmed) goes out once per tick as [`Admitted`] on
//! `impact/v1/{world}/log/admitted`, so a standby that takes over re-applies every acked input.
//! A standby that joins late starts from a [`Checkpoint`] (`impact/v1/{world}/query/checkpoint`):
//! the complete confirmed state, not the summary a state query returns.

use crate::action::{Action, RayHit};
use crate::ids::{ClientId, EntityId, Tick};
use crate::shape::ShapeSpec;
use serde::{Deserialize, Serialize};

/// One input as the server applied it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoggedInput {
    /// The sender.
    pub client: ClientId,
    /// Its sequence number.
    pub seq: u32,
    /// The tick it was applied at (its own, or the oldest in the window when clamped).
    pub tick: Tick,
    /// The tick the client was looking at, for rewound rays.
    pub view_tick: Option<Tick>,
    /// The actions, in order.
    pub actions: Vec<Action>,
    /// Its hitscan rays as the server finally cast them against the world at their view tick
    /// (lag compensation reads a history a follower may not hold: the outcome is logged).
    #[serde(default)]
    pub rewound: Vec<LoggedRay>,
    /// Sent by a game-logic client: its actions act on any body (see `Action::Teleport`).
    #[serde(default)]
    pub logic: bool,
}

/// A rewound hitscan ray of a logged input.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoggedRay {
    /// Index of the `fire_ray` action in the input.
    pub action: u32,
    /// The tick whose world it was tested against.
    pub view_tick: Tick,
    /// The requested view tick was clamped.
    pub clamped: bool,
    /// What it hit.
    pub hit: Option<RayHit>,
}

/// An action of the server's own: avatars joining and leaving.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum LoggedSystem {
    /// Spawn `client`'s avatar (class and shape: the scene's `[avatar]`).
    SpawnAvatar {
        /// The owner.
        client: ClientId,
        /// Centre, world frame, metres.
        position: [f64; 3],
    },
    /// Remove a body (an avatar whose client left).
    Remove {
        /// The body.
        entity: EntityId,
    },
}

/// One confirmed tick of the log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LogTick {
    /// The tick.
    pub tick: Tick,
    /// Server actions, applied first, in order.
    pub system: Vec<LoggedSystem>,
    /// Client inputs, in the order they were applied.
    pub inputs: Vec<LoggedInput>,
    /// The state hash of the world after the tick (as in [`WorldSnapshot`](crate::WorldSnapshot)).
    pub state_hash: u64,
}

/// What the server admitted during one of its ticks: inputs it acked (for ticks not yet
/// confirmed) and the server actions it queued for `tick`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Admitted {
    /// The server's tick: `system` applies at it, and `inputs` were acked just before it.
    pub tick: Tick,
    /// Server actions for `tick`.
    pub system: Vec<LoggedSystem>,
    /// Inputs acked, each with the tick it applies at.
    pub inputs: Vec<LoggedInput>,
}

/// A dynamic body, complete.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointBody {
    /// Its id.
    pub entity: EntityId,
    /// Class index in the scene's class table.
    pub class: u16,
    /// Shape.
    pub shape: ShapeSpec,
    /// Centre, m.
    pub position: [f64; 3],
    /// Velocity, m/s.
    pub velocity: [f64; 3],
    /// Orientation quaternion `[x, y, z, w]`.
    pub rotation: [f64; 4],
    /// Inverse mass, 1/kg.
    pub inv_mass: f64,
    /// Owner.
    pub owner: Option<ClientId>,
    /// Asleep.
    pub asleep: bool,
    /// Ticks it has been slower than the sleep speed.
    pub still_ticks: u16,
    /// Its game state (absent: none).
    #[serde(default, skip_serializing_if = "crate::GameState::is_empty")]
    pub game: crate::GameState,
    /// The tick of its last teleport (absent: never).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub teleported: Option<Tick>,
}

/// A resting contact carried from one tick to the next.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointTouch {
    /// Lower id.
    pub a: EntityId,
    /// Higher id.
    pub b: EntityId,
    /// Normal from `a` to `b`.
    pub normal: [f64; 3],
    /// Overlap, m.
    pub depth: f64,
    /// Normal impulse, N s.
    pub impulse: f64,
    /// Friction impulse, N s.
    pub friction_impulse: [f64; 3],
}

/// A client the server remembers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointClient {
    /// The client.
    pub client: ClientId,
    /// Its avatar.
    pub avatar: Option<EntityId>,
    /// Seqs accepted: the highest (none yet: `None`) and the bitmap of the replay window.
    pub highest_seq: Option<u32>,
    /// The replay window's bits (see `PROTOCOL.md`, Replay protection).
    pub seq_bits: Vec<u64>,
}

/// The complete world at the start of `tick` (the state after the last confirmed tick), for a
/// standby that joins late. Static geometry and settings come from the scene file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// The next tick to simulate: the log continues at this tick.
    pub tick: Tick,
    /// The id the next spawned body gets.
    pub next_entity: u32,
    /// Bodies by ascending id.
    pub bodies: Vec<CheckpointBody>,
    /// Resting contacts, sorted by `(a, b)`.
    pub touching: Vec<CheckpointTouch>,
    /// Clients the server remembers.
    pub clients: Vec<CheckpointClient>,
    /// State hash of this world: a restore is checked against it.
    pub state_hash: u64,
    /// The settings the world runs with (tick rate, gravity, the resolved `[world]` values and
    /// the class rules), as `(name, value)` text: a server restoring the checkpoint refuses one
    /// whose settings differ from its own, naming them (a standby of a build with other
    /// defaults). Empty from a primary that predates it: not checked.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub settings: Vec<(String, String)>,
}
