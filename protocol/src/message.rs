//! Messages, one enum per direction: [`ClientMessage`] (client -> server) and
//! [`ServerMessage`] (server -> clients).
//!
//! Both enums, and [`Action`] and [`ShapeSpec`], are *internally tagged*: a message is a map
//! whose `"type"` entry names the variant (`{"type": "input", ...}`), which any MessagePack or
//! JSON library can build and read without knowing Rust's enum layout.

pub use crate::action::{Action, RayHit};
use crate::event::CollisionEvent;
use crate::ids::{ClientId, EntityId, Tick};
pub use crate::shape::ShapeSpec;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Client -> server.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ClientMessage {
    /// Inputs stamped with the tick the client saw when it acted.
    Input(ClientInput),
    /// Several inputs in one message, oldest first: the newest and the unanswered ones before it,
    /// so one lost message loses no input (redundancy). Each `seq` applies once: a repeat of an
    /// accepted one is skipped without an answer.
    Inputs(InputBatch),
    /// A time-sync probe: the server answers at once with a [`ServerMessage::Pong`] naming its
    /// tick, so a client measures its round trip before its first input.
    Ping(TimePing),
    /// Asks for a full frame on the client's state stream at the next frame (after a gap in the
    /// frame numbers, instead of waiting for the periodic one).
    FullFrame(FullFrameRequest),
    /// Game logic opens or closes a world at run time: a query on `client/{id}/world` of the
    /// world in question, answered by [`ServerMessage::World`].
    World(WorldCommand),
}

/// See [`ClientMessage::World`]: what to do with the world the key names.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "command", rename_all = "snake_case")]
pub enum WorldCommand {
    /// Open the world from the scene named `scene`, one the server may open (started with it,
    /// or in its `--scene-dir`): a fresh world at tick 0 under the key's world name.
    Open {
        /// The scene's name (its file name without `.toml`).
        scene: String,
    },
    /// Close the world: every client in it is told ([`ServerMessage::Closed`]), its last events
    /// are confirmed, and it stops.
    Close {
        /// Where its players go next (a match that follows), if anywhere.
        #[serde(default)]
        next: Option<crate::ids::WorldId>,
        /// Why, for the players (at most 256 bytes).
        #[serde(default)]
        reason: String,
    },
}

/// See [`ClientMessage::FullFrame`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FullFrameRequest {
    /// The sender.
    pub client: ClientId,
}

/// Several inputs of one client, oldest first (at most
/// [`MAX_INPUTS_PER_MESSAGE`](crate::limits::MAX_INPUTS_PER_MESSAGE)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputBatch {
    /// The sender; every input in `inputs` names it too.
    pub client: ClientId,
    /// The inputs, by ascending `seq`.
    pub inputs: Vec<ClientInput>,
}

/// A time-sync probe (see [`ClientMessage::Ping`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TimePing {
    /// The sender.
    pub client: ClientId,
    /// The client's number for this probe, echoed in the answer.
    pub id: u32,
}

/// The answer to a [`TimePing`], on the client's `ack` key.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TimePong {
    /// The client.
    pub client: ClientId,
    /// The probe's `id`.
    pub id: u32,
    /// The server's current tick when it handled the probe (the next tick it simulates), as in
    /// [`InputAck::server_tick`]: handled where inputs are, so the round trip it measures is the
    /// one an input sees.
    pub server_tick: Tick,
}

/// One batch of actions a client took at `tick`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClientInput {
    /// Who sent it; must match the `{client}` segment of the key it was published on.
    pub client: ClientId,
    /// Per-client sequence number; a repeated `seq` is a duplicate and is ignored.
    pub seq: u32,
    /// The tick the actions apply at: a past tick (the server rolls back to it), or, for a client
    /// running ahead, the present or a future one (it waits for its tick: no rollback).
    pub tick: Tick,
    /// The tick the client was showing when it acted (the newest server tick it had seen plus the
    /// ticks its clock counted since). Optional: absent means `tick` (a client that stamps what it
    /// sees). The server measures the client's delay from it to recommend a lead, and casts the
    /// input's hitscan rays against the world as it was then (lag compensation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_tick: Option<Tick>,
    /// What to do, in order; at most [`MAX_ACTIONS_PER_INPUT`](crate::limits::MAX_ACTIONS_PER_INPUT).
    pub actions: Vec<Action>,
    /// (Last, so serde's positional form of the fields before it is unchanged.) The tick of the world the player aimed at, when it is not `view_tick`: a client draws
    /// other bodies an interpolation delay behind its view, so it aims at that past. Hitscan
    /// rays are rewound here (within the server's rewind limit); the lead is still measured
    /// from `view_tick`. Optional: absent means `view_tick`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aim_tick: Option<Tick>,
}

impl ClientInput {
    /// The tick its hitscan rays are rewound to: `aim_tick`, else `view_tick`.
    pub fn rewind_tick(&self) -> Option<Tick> {
        self.aim_tick.or(self.view_tick)
    }
}

/// Server -> clients.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// The events of one tick as first simulated (status `provisional`).
    Events(EventBatch),
    /// What a re-simulation changed in an already published tick.
    Corrections(CorrectionBatch),
    /// The final events of a tick that left the rollback window (status `confirmed`).
    Confirmed(EventBatch),
    /// An input was accepted.
    Ack(InputAck),
    /// An input was refused, with the reason.
    Reject(InputReject),
    /// The answer to a [`Action::FireRay`].
    RayResult(RayResult),
    /// A client joined: its avatar and the world's clock.
    Welcome(Welcome),
    /// The world at a tick (answer to the state query).
    Snapshot(WorldSnapshot),
    /// Events of a tick range (answer to the history query).
    History(EventHistory),
    /// Server figures, once a second.
    Stats(ServerStats),
    /// A query could not be answered.
    QueryError(QueryError),
    /// One confirmed tick of the input log (`log`).
    Log(crate::log::LogTick),
    /// Inputs and server actions admitted in one server tick, not yet confirmed (`log/admitted`).
    Admitted(crate::log::Admitted),
    /// The complete confirmed state (answer to the checkpoint query).
    Checkpoint(crate::log::Checkpoint),
    /// A frame of a state stream (`state`, `client/{id}/state`).
    State(crate::state::StateFrame),
    /// The answer to a time-sync probe ([`ClientMessage::Ping`]).
    Pong(TimePong),
    /// The rules and static world (answer to the scene query).
    Scene(Box<crate::scene::SceneDescription>),
    /// The answer to a [`ClientMessage::World`].
    World(WorldAnswer),
    /// The world closed (game logic ended the match, or the server stopped): sent to each client
    /// in it on its `ack` key, after the world's last events.
    Closed(WorldClosed),
    /// The world's owner and its epoch (`owner`, four times a second; for servers).
    Owner(OwnerNotice),
}

/// See [`ServerMessage::World`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldAnswer {
    /// The world the command named.
    pub world: crate::ids::WorldId,
    /// What became of it.
    pub outcome: WorldOutcome,
}

/// What a [`WorldCommand`] did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum WorldOutcome {
    /// The world runs: clients may join it.
    Opened {
        /// Its scene's hash (as `query/scene` gives it).
        scene_hash: u64,
        /// Its tick rate.
        tick_hz: u32,
    },
    /// The world stopped after this many ticks.
    Closed {
        /// Ticks it ran.
        ticks: u64,
    },
    /// Refused: `not_allowed` (the sender has no game-logic role, or this server opens no
    /// worlds), `out_of_range` (no such scene, the world exists or does not, the server's
    /// world limit), `malformed` (not a world command).
    Refused {
        /// Why.
        reason: RejectReason,
        /// Details.
        detail: String,
    },
}

/// See [`ServerMessage::Owner`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct OwnerNotice {
    /// The owner's epoch (also its attachment).
    pub epoch: crate::ids::Epoch,
    /// The tick it is at.
    pub tick: Tick,
}

/// See [`ServerMessage::Closed`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldClosed {
    /// The world.
    pub world: crate::ids::WorldId,
    /// Its last tick.
    pub tick: Tick,
    /// Where its players go next, if game logic said.
    pub next: Option<crate::ids::WorldId>,
    /// Why, if game logic said.
    pub reason: String,
}

/// The events of one tick.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EventBatch {
    /// The tick.
    pub tick: Tick,
    /// 0 when first published; each correction of this tick increments it.
    pub revision: u32,
    /// The events, in time-of-impact order.
    pub events: Vec<CollisionEvent>,
}

/// The difference between what was published for `tick` and what a re-simulation produced.
/// A client that applies it (remove `retracted`, replace `amended`, insert `added`, matching by
/// [`CollisionEvent::key`]) holds the tick's events at `revision`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorrectionBatch {
    /// The re-simulated tick.
    pub tick: Tick,
    /// The revision this batch brings the tick to (>= 1).
    pub revision: u32,
    /// Events that no longer happen (as they were published).
    pub retracted: Vec<CollisionEvent>,
    /// Events that still happen with changed fields (new values).
    pub amended: Vec<CollisionEvent>,
    /// Events that happen now and were not published before.
    pub added: Vec<CollisionEvent>,
}

/// An input was accepted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputAck {
    /// The sender.
    pub client: ClientId,
    /// The input's `seq`.
    pub seq: u32,
    /// The tick the input was stamped with.
    pub tick: Tick,
    /// The tick it was applied at (differs from `tick` only under the clamp policy).
    pub applied_tick: Tick,
    /// The server's current tick when it was accepted (the next tick it simulates).
    pub server_tick: Tick,
    /// How many ticks before its tick the input arrived: `applied_tick - server_tick`. Zero or
    /// more: on time, it waits for its tick and causes no rollback; negative: that many ticks
    /// late, the server rolled back for it.
    #[serde(default)]
    pub margin_ticks: i32,
    /// The lead the server recommends to this client: stamp inputs `view_tick + lead_ticks` so
    /// they arrive just before their tick. From the client's recent delays (`server_tick -
    /// view_tick` at arrival): the largest of the last 32, plus one.
    #[serde(default)]
    pub lead_ticks: u32,
    /// Which of the 64 seqs before `seq` the server has accepted: bit `k` is seq `seq - 1 - k`.
    /// A repeat of an accepted input is skipped without an answer, so an ack lost on the way
    /// would never come again; the next ack says it instead.
    #[serde(default)]
    pub accepted_before: u64,
}

/// Why an input was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RejectReason {
    /// Stamped older than the rollback window (see `oldest_tick`).
    Stale,
    /// Stamped further ahead than the allowed lead (see `newest_tick`).
    Future,
    /// Names an entity the client does not own, or the key's client differs from `client`.
    NotOwner,
    /// Names an entity that does not exist.
    UnknownEntity,
    /// A NaN or infinite number.
    InvalidNumber,
    /// A value outside its range (speed over the class limit, zero ray direction, ...).
    OutOfRange,
    /// More inputs per second than the per-client limit.
    RateLimited,
    /// Payload over the size limit, or too many actions.
    TooLarge,
    /// Not a decodable message.
    Malformed,
    /// The server's ingress queue was full; resend later.
    QueueFull,
    /// The same `(client, seq)` was already accepted.
    Duplicate,
    /// The entity's class does not take this action: a character (a class with `character`
    /// rules) moves by `move` only, so `set_velocity` and `apply_impulse` on it are refused, and
    /// `move` moves characters only.
    NotAllowed,
}

impl RejectReason {
    /// Every reason, in declaration order.
    pub const ALL: [RejectReason; 12] = [
        RejectReason::Stale,
        RejectReason::Future,
        RejectReason::NotOwner,
        RejectReason::UnknownEntity,
        RejectReason::InvalidNumber,
        RejectReason::OutOfRange,
        RejectReason::RateLimited,
        RejectReason::TooLarge,
        RejectReason::Malformed,
        RejectReason::QueueFull,
        RejectReason::Duplicate,
        RejectReason::NotAllowed,
    ];

    /// The snake_case name used on the wire and in stats.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::Stale => "stale",
            RejectReason::Future => "future",
            RejectReason::NotOwner => "not_owner",
            RejectReason::UnknownEntity => "unknown_entity",
            RejectReason::InvalidNumber => "invalid_number",
            RejectReason::OutOfRange => "out_of_range",
            RejectReason::RateLimited => "rate_limited",
            RejectReason::TooLarge => "too_large",
            RejectReason::Malformed => "malformed",
            RejectReason::QueueFull => "queue_full",
            RejectReason::Duplicate => "duplicate",
            RejectReason::NotAllowed => "not_allowed",
        }
    }
}

/// An input was refused. Sent on the client's `ack` key.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputReject {
    /// The sender, as far as it could be read (0 when the payload could not be decoded and the
    /// key named no client).
    pub client: ClientId,
    /// The input's `seq`; nil only when the payload could not be decoded as far as its `client`,
    /// `seq` and `tick` (too large to read, truncated, not a map, ...).
    pub seq: Option<u32>,
    /// The input's tick; nil exactly when `seq` is.
    pub tick: Option<Tick>,
    /// Why.
    pub reason: RejectReason,
    /// Human-readable detail: the field and the bound.
    pub detail: String,
    /// The oldest tick the server accepts now (with `stale`).
    pub oldest_tick: Option<Tick>,
    /// The newest tick the server accepts now (with `future`).
    pub newest_tick: Option<Tick>,
}

/// The result of a hitscan ray.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RayResult {
    /// The shooter's client.
    pub client: ClientId,
    /// The input's `seq`.
    pub seq: u32,
    /// The input's tick: where the hit's consequences (event, destroy) happen.
    pub tick: Tick,
    /// The tick whose world the ray was tested against: the input's `view_tick` (or `tick`),
    /// clamped (lag compensation).
    #[serde(default)]
    pub view_tick: Tick,
    /// The requested view tick was further back than the server rewinds (`max_rewind_ms`, or
    /// the history window), so the ray was tested at the oldest tick allowed instead.
    #[serde(default)]
    pub clamped: bool,
    /// The entity that fired.
    pub shooter: EntityId,
    /// The first thing hit, if any.
    pub hit: Option<RayHit>,
}

/// Sent to a client when its presence appears and its avatar is spawned.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Welcome {
    /// The client.
    pub client: ClientId,
    /// Its avatar, if the scene spawns one.
    pub avatar: Option<EntityId>,
    /// The server's tick when the avatar was spawned.
    pub tick: Tick,
    /// Ticks per second.
    pub tick_hz: u32,
    /// Ticks of history the server keeps (inputs older than `tick - window` are stale).
    pub window_ticks: u32,
    /// How far ahead of the server an input may be stamped, ticks (further is `future`).
    #[serde(default)]
    pub input_lead_ticks: u32,
    /// How far back a hitscan ray is rewound at most, ticks (the scene's `max_rewind_ms`).
    #[serde(default)]
    pub max_rewind_ticks: u32,
    /// The lowest `seq` the server will accept from this client: 0 for a new client, one past the
    /// highest accepted for a client that reconnects within the grace period (seqs are never
    /// reused while the server remembers the client; see Replay protection in `PROTOCOL.md`).
    #[serde(default)]
    pub next_seq: u32,
    /// A hash of what a client needs to predict with the core: the static world and the rules
    /// (`impact_core::sim::World::scene_hash`). A client that built its world from `query/scene`
    /// or loaded the scene itself compares it with its own (0: not sent).
    #[serde(default)]
    pub scene_hash: u64,
}

/// One body in a snapshot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BodyState {
    /// The body.
    pub entity: EntityId,
    /// Its class name from the scene.
    pub class: String,
    /// Owning client, if any.
    pub owner: Option<ClientId>,
    /// Centre, world frame, metres.
    pub position: [f64; 3],
    /// Velocity, m/s.
    pub velocity: [f64; 3],
}

/// The world at the end of `tick`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldSnapshot {
    /// The tick.
    pub tick: Tick,
    /// The deterministic state hash of the world at that tick (64 bits, over the exact bits of the state).
    pub state_hash: u64,
    /// Every body, by ascending entity id.
    pub bodies: Vec<BodyState>,
}

/// Events of ticks `from..=to`, in tick order, as they stand now.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EventHistory {
    /// First tick.
    pub from: Tick,
    /// Last tick.
    pub to: Tick,
    /// The events.
    pub events: Vec<CollisionEvent>,
}

/// A query the server could not answer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct QueryError {
    /// Why (e.g. the tick left the history window).
    pub detail: String,
}

/// Server figures over the last reporting period (one second).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ServerStats {
    /// The current tick.
    pub tick: Tick,
    /// Tick duration median, milliseconds.
    pub tick_ms_p50: f64,
    /// Tick duration 99th percentile, milliseconds.
    pub tick_ms_p99: f64,
    /// Longest tick, milliseconds.
    pub tick_ms_max: f64,
    /// Ticks that missed their deadline, since start.
    pub overruns: u64,
    /// Bodies in the world.
    pub bodies: u32,
    /// Narrowphase pairs tested in the last tick.
    pub pairs_tested: u32,
    /// Rollbacks in the period.
    pub rollbacks: u32,
    /// Deepest rollback in the period, ticks.
    pub rollback_depth_max: u32,
    /// Inputs accepted since start.
    pub inputs_accepted: u64,
    /// Inputs rejected since start, by reason (snake_case reason name -> count).
    pub inputs_rejected: BTreeMap<String, u64>,
    /// Inputs skipped since start because their `seq` was already accepted: the redundant
    /// copies an [`InputBatch`] carries, and resends. Neither accepted nor rejected.
    #[serde(default)]
    pub inputs_repeated: u64,
    /// Events published per second.
    pub events_per_s: f64,
    /// Deepest the ingress queue got in the period.
    pub queue_depth_max: u32,
    /// Every tick's duration in the period, ms, in tick order: a tool that gathers them has
    /// the exact distribution over any span (`impact-sim` reports its whole run from them).
    #[serde(default)]
    pub tick_ms: Vec<f32>,
    /// Mean time per core step of each stage in the period, ms, in tick order
    /// (`[["broadphase", 0.12], ...]`); re-simulations count as steps.
    #[serde(default)]
    pub stage_ms: Vec<(String, f64)>,
    /// Clients present.
    #[serde(default)]
    pub clients: u32,
}
