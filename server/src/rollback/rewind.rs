//! Lag-compensated hitscan without re-simulation. A client running ahead of the server sees the
//! world late (its view tick: the newest tick it has heard of, plus what its clock counted
//! since), so its shot is tested against the world as it was at that view tick, as Source and
//! Overwatch rewind hitboxes for the shot alone; what the shot hits happens at the input's own
//! tick. Nothing is re-simulated for it.
//!
//! The core keeps no history, so the session casts these rays from its history before the
//! input's tick is simulated (and again each time that tick is re-simulated, so a rollback that
//! changed the past world changes the hit too) and hands the hits to the core inside the input.

use crate::query::ray;
use crate::sim::input::{RewoundRay, TickInput};
use crate::sim::World;
use glam::DVec3;
use impact_protocol::{Action, Tick};

/// Fills `rewound` for each input of `tick` whose view tick is in the past: its hitscan rays
/// tested against the world at the start of the view tick. A view tick further back than
/// `max_rewind_ticks` before `tick`, or than `oldest` (the oldest world `past` holds), is
/// clamped to the nearest allowed one and marked. `present` is the world at the start of `tick`.
pub fn rewind_rays<'a>(
    tick: Tick,
    inputs: &mut [TickInput],
    max_rewind_ticks: u32,
    oldest: Tick,
    present: &'a World,
    past: impl Fn(Tick) -> Option<&'a World>,
) {
    for input in inputs {
        input.rewound.clear();
        let Some(requested) = input.view_tick else { continue };
        if requested >= tick || !input.actions.iter().any(|a| matches!(a, Action::FireRay { .. })) {
            continue;
        }
        let floor = Tick(tick.0.saturating_sub(max_rewind_ticks).max(oldest.0).min(tick.0));
        let (view, clamped) = if requested < floor { (floor, true) } else { (requested, false) };
        let world = if view == tick { Some(present) } else { past(view) };
        let Some(world) = world else { continue };
        for (k, a) in input.actions.iter().enumerate() {
            if let Action::FireRay { shooter, origin, direction, max_distance_m } = a {
                let dir = DVec3::from_array(*direction).normalize();
                let hit = ray::cast(world, DVec3::from_array(*origin), dir, *max_distance_m, Some(*shooter));
                input.rewound.push(RewoundRay { action: k as u32, view_tick: view, clamped, hit });
            }
        }
    }
}
