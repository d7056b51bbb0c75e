//! Lag-compensated hitscan without re-simulation. A client running ahead of the server sees the
//! world late (its view tick: the newest tick it has heard of, plus what its clock counted
//! since), so its shot is tested against the world as it was at that view tick, as Source and
//! Overwatch rewind hitboxes for the shot alone; what the shot hits happens at the input's own
//! tick. Nothing is re-simulated for it.
//!
//! The core keeps no history, so the session casts these rays from its history before the
//! input's tick is simulated (and again each time that tick is re-simulated, so a rollback that
//! changed the past world changes the hit too) and hands the hits to the core inside the input.

use glam::DVec3;
use impact_core::sim::input::{RewoundRay, TickInput};
use impact_core::sim::ray::{self, Ray};
use impact_core::sim::ray_index::{self, RayIndex};
use impact_core::sim::World;
use impact_protocol::{Action, Tick};

/// Fills `rewound` for each input of `tick` whose view tick is in the past: its hitscan rays
/// tested against the world at the start of the view tick. A view tick further back than
/// `max_rewind_ticks` before `tick`, or than `oldest` (the oldest world `past` holds), is
/// clamped to the nearest allowed one and marked. `present` is the world at the start of `tick`.
///
/// The rays that look at the same past tick are cast together through that world's index
/// (`past` gives it, built once per past world: [`ray_index::cast_many_indexed`]), so a shot
/// tests the bodies along its path, not every body.
pub fn rewind_rays<'a>(
    tick: Tick,
    inputs: &mut [TickInput],
    max_rewind_ticks: u32,
    oldest: Tick,
    present: &'a World,
    past: impl Fn(Tick) -> Option<(&'a World, &'a RayIndex)>,
) {
    // (view tick, clamped, input, action, ray), grouped by view tick below.
    let mut shots: Vec<(Tick, bool, usize, u32, Ray)> = Vec::new();
    for (n, input) in inputs.iter_mut().enumerate() {
        if input.logged {
            continue;
        }
        input.rewound.clear();
        let Some(requested) = input.view_tick else { continue };
        if requested >= tick {
            continue;
        }
        let floor = Tick(tick.0.saturating_sub(max_rewind_ticks).max(oldest.0).min(tick.0));
        let (view, clamped) = if requested < floor { (floor, true) } else { (requested, false) };
        for (k, a) in input.actions.iter().enumerate() {
            if let Action::FireRay { shooter, origin, direction, max_distance_m } = a {
                let ray = Ray {
                    origin: DVec3::from_array(*origin),
                    dir: DVec3::from_array(*direction).normalize(),
                    max_m: *max_distance_m,
                    exclude: Some(*shooter),
                };
                shots.push((view, clamped, n, k as u32, ray));
            }
        }
    }
    if shots.is_empty() {
        return;
    }
    shots.sort_by_key(|s| (s.0, s.2, s.3));
    let mut rays = Vec::new();
    let mut hits = Vec::new();
    for group in shots.chunk_by(|a, b| a.0 == b.0) {
        let view = group[0].0;
        rays.clear();
        rays.extend(group.iter().map(|s| s.4));
        if view == tick {
            ray::cast_many(present, &rays, &mut hits);
        } else if let Some((world, index)) = past(view) {
            ray_index::cast_many_indexed(world, index, &rays, &mut hits);
        } else {
            continue;
        }
        for (s, hit) in group.iter().zip(hits.drain(..)) {
            inputs[s.2].rewound.push(RewoundRay { action: s.3, view_tick: view, clamped: s.1, hit });
        }
    }
}
