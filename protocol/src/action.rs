//! What a client can do to the world ([`Action`], with the shapes it may spawn) and where a ray
//! hit ([`RayHit`]): the vocabulary both the messages and the input log are made of.

use crate::ids::EntityId;
use serde::{Deserialize, Serialize};

/// One thing a client can do to the world. Velocities in m/s, positions in metres, world frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Action {
    /// Set the velocity of an entity the client owns.
    SetVelocity {
        /// The owned entity.
        entity: EntityId,
        /// New velocity, m/s.
        velocity: [f64; 3],
    },
    /// Add `impulse / mass` to the velocity of an owned entity.
    ApplyImpulse {
        /// The owned entity.
        entity: EntityId,
        /// Impulse, N*s.
        impulse: [f64; 3],
    },
    /// Spawn a projectile owned by the client.
    SpawnProjectile {
        /// Its shape.
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
    /// Remove an owned entity.
    Despawn {
        /// The owned entity.
        entity: EntityId,
    },
}

/// A shape a client may spawn. Dimensions in metres, all `> 0`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ShapeSpec {
    /// A sphere.
    Sphere {
        /// Radius, metres.
        radius_m: f64,
    },
    /// A capsule along the local y axis.
    Capsule {
        /// Half the length of the segment between the two cap centres, metres.
        half_height_m: f64,
        /// Radius, metres.
        radius_m: f64,
    },
    /// An axis-aligned box (at spawn).
    Cuboid {
        /// Half extents along x, y, z, metres.
        half_extents_m: [f64; 3],
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
