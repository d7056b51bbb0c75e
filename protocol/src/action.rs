//! What a client can do to the world ([`Action`]) and where a ray hit ([`RayHit`]): the
//! vocabulary both the messages and the input log are made of.

use crate::ids::EntityId;
use crate::shape::ShapeSpec;
use serde::{Deserialize, Serialize};

/// One thing a client can do to the world. Velocities in m/s, positions in metres, world frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Action {
    /// Set the velocity of an entity the client owns (game logic: any dynamic body).
    SetVelocity {
        /// The owned entity.
        entity: EntityId,
        /// New velocity, m/s.
        velocity: [f64; 3],
    },
    /// Add `impulse / mass` to the velocity of an owned entity (game logic: any dynamic body,
    /// characters too: a knock-back).
    ApplyImpulse {
        /// The owned entity.
        entity: EntityId,
        /// Impulse, N*s.
        impulse: [f64; 3],
    },
    /// Spawn a projectile owned by the client.
    SpawnProjectile {
        /// Its shape: a sphere, a capsule or a cuboid ([`ShapeSpec::spawnable`]).
        shape: ShapeSpec,
        /// Centre at the input's tick, metres.
        position: [f64; 3],
        /// Velocity, m/s.
        velocity: [f64; 3],
    },
    /// Fire a hitscan ray, tested against the world as it was at the input's `view_tick` (or its
    /// tick), clamped to the scene's `max_rewind_ms` and the history window; what it hits happens
    /// at the input's tick.
    FireRay {
        /// The owned entity that fires (it is never hit by its own ray).
        shooter: EntityId,
        /// Ray origin, metres.
        origin: [f64; 3],
        /// Ray direction; any non-zero length, normalised by the server.
        direction: [f64; 3],
        /// Longest distance tested, metres.
        max_distance_m: f64,
    },
    /// Walk, run or jump an owned character (a body of a class with `character` rules): the
    /// server moves it with its class's controller, so no client sets a character's velocity.
    /// The intent holds until the next `move` (a held key), because the character keeps its
    /// velocity: on the ground it walks along the surface at that speed, in the air it keeps
    /// its momentum and steers by the class's `air_control`.
    Move {
        /// The owned character.
        entity: EntityId,
        /// Where to go, world frame: only the part across gravity counts (up is opposite
        /// gravity, or +y in a world without). Its length is the fraction of the class's walk
        /// speed, at most 1 (longer is taken as 1); zero stands still.
        direction: [f64; 3],
        /// Jump, if standing on walkable ground (ignored in the air): up at the speed that
        /// reaches the class's jump height.
        #[serde(default)]
        jump: bool,
    },
    /// Game logic only: put any body at `position` (and set its velocity, if given): a respawn,
    /// a teleporter, a reset.
    Teleport {
        /// Any dynamic body.
        entity: EntityId,
        /// Where, metres.
        position: [f64; 3],
        /// Its velocity from then on, m/s (`None`: kept).
        #[serde(default)]
        velocity: Option<[f64; 3]>,
    },
    /// Game logic only: spawn a body of any dynamic class: a pickup, a crate, a player's new
    /// body.
    Spawn {
        /// The class, by its name in the scene.
        class: String,
        /// Its shape.
        shape: ShapeSpec,
        /// Centre, metres.
        position: [f64; 3],
        /// Velocity, m/s.
        velocity: [f64; 3],
        /// The client that owns it (`None`: nobody; the logic acts on it).
        #[serde(default)]
        owner: Option<crate::ids::ClientId>,
    },
    /// Game logic only: change a body's class (a player becomes a ghost, a pickup is taken).
    SetClass {
        /// Any dynamic body.
        entity: EntityId,
        /// The new class, by name: a dynamic one.
        class: String,
    },
    /// Game logic only: set named numbers of a body's game state (health, team, score); names
    /// not given keep their values. The state streams carry it to the players near the body.
    SetState {
        /// Any dynamic body.
        entity: EntityId,
        /// The values to set, by name: at most 8 names of at most 16 bytes on the body in all,
        /// finite numbers.
        values: crate::state::GameState,
    },
    /// Remove an owned entity (game logic: any dynamic body).
    Despawn {
        /// The owned entity.
        entity: EntityId,
    },
}

/// Where a ray hit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RayHit {
    /// The entity hit.
    pub entity: EntityId,
    /// Hit point, world frame, metres.
    pub point: [f64; 3],
    /// Unit surface normal at the hit, world frame, facing the ray origin.
    pub normal: [f64; 3],
    /// Distance from the origin, metres.
    pub distance_m: f64,
}
