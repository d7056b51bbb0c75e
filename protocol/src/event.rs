//! The collision event: what the server tells clients happened.

use crate::ids::{EntityId, Tick};
use serde::{Deserialize, Serialize};

/// Whether a contact began, ended, or (for a hitscan ray) happened in an instant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// The pair started touching during this tick.
    Begin,
    /// The pair stopped touching during this tick (separated, or one of them was destroyed).
    End,
    /// A hitscan ray hit `b`; `a` is the shooter. Instantaneous: no matching `end`.
    Hit,
}

/// The response the server applied, chosen by the scene's table for the two classes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Response {
    /// Velocities reflected along the normal with restitution and the two masses.
    Bounce,
    /// The moving body keeps its tangential motion for the rest of the step (players on walls).
    Slide,
    /// The moving body stops at the contact.
    Stop,
    /// One or both bodies were removed (see the class table); the event is their last.
    Destroy,
    /// No velocity change: the event is the whole effect (pickups, zones, hitscan).
    Trigger,
}

/// Where an event stands in its life: first published, changed by a re-simulation, or final.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventStatus {
    /// Published at the tick it happened; a late input may still change it.
    Provisional,
    /// Re-published by a correction after a rollback.
    Corrected,
    /// Its tick has left the rollback window: it will never change again.
    Confirmed,
}

/// One collision (or ray hit) the server resolved.
///
/// Identity: two events are the same event when `(tick, a, b, phase)` are equal; corrections
/// refer to events by that key. All vectors are in the world frame, metres and m/s.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CollisionEvent {
    /// The tick during which it happened.
    pub tick: Tick,
    /// Time of impact as a fraction of the tick, in `[0, 1]`: the contact happened at
    /// `(tick + toi) * dt` seconds of world time. `0` for pairs already overlapping at the
    /// start of the tick.
    pub toi: f64,
    /// The entity with the lower id (for [`Phase::Hit`], the shooter).
    pub a: EntityId,
    /// The other entity (for [`Phase::Hit`], the entity hit).
    pub b: EntityId,
    /// Contact point in world coordinates, metres.
    pub point: [f64; 3],
    /// Unit contact normal in the world frame, pointing from `a` towards `b` (for a ray hit:
    /// the surface normal of `b`, facing the shooter).
    pub normal: [f64; 3],
    /// Penetration depth at the reported pose, metres (`>= 0`; about 0 when the time of impact
    /// was found by bisection).
    pub depth_m: f64,
    /// Speed at which the two approached along the normal just before the response, m/s
    /// (`>= 0` for approaching pairs).
    pub closing_speed_mps: f64,
    /// Begin, end or hit.
    pub phase: Phase,
    /// The response the server applied.
    pub response: Response,
    /// Provisional, corrected or confirmed.
    pub status: EventStatus,
}

/// An event's identity: `(tick, a, b, phase)`.
pub type EventKey = (Tick, EntityId, EntityId, Phase);

impl CollisionEvent {
    /// The identity corrections use: `(tick, a, b, phase)`.
    pub fn key(&self) -> EventKey {
        (self.tick, self.a, self.b, self.phase)
    }
}
