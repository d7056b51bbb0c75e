//! What a tick produced besides the new state: the types the input and step stages both write,
//! kept apart from either so that neither has to import the other for them.

use impact_protocol::{ClientId, CollisionEvent, EntityId, RayResult, RejectReason, Tick};

/// What one tick produced besides the new state.
#[derive(Clone, Debug, Default)]
pub struct TickOutput {
    /// Collision events in `(toi, a, b, phase)` order.
    pub events: Vec<CollisionEvent>,
    /// Results of the tick's hitscan rays, in input order.
    pub rays: Vec<RayResult>,
    /// Inputs (or actions) that could not apply, with why: `(client, seq, reason)`.
    pub skipped: Vec<Skipped>,
    /// Avatars spawned by system actions this tick: `(owner, entity)`.
    pub spawned: Vec<(ClientId, EntityId)>,
}

/// An input that did not apply.
#[derive(Clone, Debug, PartialEq)]
pub struct Skipped {
    /// The sender.
    pub client: ClientId,
    /// Its sequence number.
    pub seq: u32,
    /// The tick it was to apply at.
    pub tick: Tick,
    /// Why.
    pub reason: RejectReason,
    /// Detail for humans.
    pub detail: String,
}
