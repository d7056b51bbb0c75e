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

/// A hitscan ray of an input, to be cast against the world of its view tick.
#[derive(Clone, Copy, Debug)]
pub struct Shot {
    /// The tick whose world (at its start) it is tested against.
    pub view: Tick,
    /// The requested view tick was further back than allowed.
    pub clamped: bool,
    /// The input (index among the tick's inputs) and its `FireRay` action.
    pub input: usize,
    /// The action's index in the input.
    pub action: u32,
    /// The ray.
    pub ray: Ray,
}

/// The rewound rays of `tick`'s inputs: each input whose view tick is in the past, its hitscan
/// rays with the view tick they are tested at. A shot keeps the view tick it was first cast at
/// (its `rewound` entries say which); a shot cast for the first time looks at its view tick, or,
/// further back than `max_rewind_ticks` before `tick` or than `oldest` (the oldest world held),
/// at the nearest allowed one, marked clamped. Sorted by view tick, then input, then action.
/// Inputs from the log are skipped (their hits are used as logged).
pub fn shots(tick: Tick, inputs: &[TickInput], max_rewind_ticks: u32, oldest: Tick) -> Vec<Shot> {
    let mut shots = Vec::new();
    for (n, input) in inputs.iter().enumerate() {
        if input.logged {
            continue;
        }
        let Some(requested) = input.view_tick else { continue };
        if requested >= tick {
            continue;
        }
        let (view, clamped) = match input.rewound.first() {
            Some(r) => (r.view_tick, r.clamped),
            None => {
                let floor = Tick(tick.0.saturating_sub(max_rewind_ticks).max(oldest.0).min(tick.0));
                if requested < floor {
                    (floor, true)
                } else {
                    (requested, false)
                }
            }
        };
        for (k, a) in input.actions.iter().enumerate() {
            if let Action::FireRay { shooter, origin, direction, max_distance_m } = a {
                let ray = Ray {
                    origin: DVec3::from_array(*origin),
                    dir: DVec3::from_array(*direction).normalize(),
                    max_m: *max_distance_m,
                    exclude: Some(*shooter),
                };
                shots.push(Shot { view, clamped, input: n, action: k as u32, ray });
            }
        }
    }
    shots.sort_by_key(|s| (s.view, s.input, s.action));
    shots
}

/// Fills `rewound` for each input of `tick` whose view tick is in the past: its hitscan rays
/// ([`shots`]) tested against the world at the start of the view tick. `present` is the world at
/// the start of `tick`. A re-simulation from tick `from` passes `unchanged_through: Some(from)`:
/// the worlds up to the start of `from` are as they were, so a shot cast before at one of them
/// keeps its hit; one looking later is cast again at the same view tick, against the world the
/// re-simulation left there. A shot's view tick never moves once cast, so its hit does not
/// depend on when, or whether, its tick is re-simulated.
///
/// The rays that look at the same past tick are cast together through that world's index
/// (`past` gives it, built once per past world: [`ray_index::cast_many_indexed`]), so a shot
/// tests the bodies along its path, not every body.
pub fn rewind_rays<'a>(
    tick: Tick,
    inputs: &mut [TickInput],
    max_rewind_ticks: u32,
    oldest: Tick,
    unchanged_through: Option<Tick>,
    present: &'a World,
    past: impl Fn(Tick) -> Option<(&'a World, &'a RayIndex)>,
) {
    let kept = |i: &TickInput| i.rewound.first().is_some_and(|r| unchanged_through.is_some_and(|u| r.view_tick <= u));
    let mut shots = shots(tick, inputs, max_rewind_ticks, oldest);
    shots.retain(|s| !kept(&inputs[s.input]));
    for input in inputs.iter_mut().filter(|i| !i.logged && !kept(i)) {
        input.rewound.clear();
    }
    let mut rays = Vec::new();
    let mut hits = Vec::new();
    for group in shots.chunk_by(|a, b| a.view == b.view) {
        let view = group[0].view;
        rays.clear();
        rays.extend(group.iter().map(|s| s.ray));
        if view == tick {
            ray::cast_many(present, &rays, &mut hits);
        } else if let Some((world, index)) = past(view) {
            ray_index::cast_many_indexed(world, index, &rays, &mut hits);
        } else {
            continue;
        }
        for (s, hit) in group.iter().zip(hits.drain(..)) {
            inputs[s.input].rewound.push(RewoundRay { action: s.action, view_tick: view, clamped: s.clamped, hit });
        }
    }
}
