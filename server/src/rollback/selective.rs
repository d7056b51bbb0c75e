//! Selective re-simulation: re-simulate only the bodies a late input can reach.
//!
//! The reach set `R` starts with the entities the late inputs name. It grows, to a fixpoint,
//! with every body whose path box (kept per tick in the history) overlapped the path box of a
//! body in `R` at the same tick, and with the entities of any other input of the interval that
//! names a body in `R` (a ray adds every body whose box its segment crosses). `R` is then
//! re-simulated alone, with the static world, in a sub-world; the new paths are checked against
//! the old path boxes of everything outside `R`, and any overlap grows `R` and starts again.
//!
//! At the fixpoint no body outside `R` came near a body in `R` in the old run or the new one, so
//! bodies outside `R` follow exactly their recorded history and bodies in `R` exactly what a full
//! re-simulation would give them: impacts resolve in (time, body, partner) order, and slot order
//! is id order in the world and in the sub-world alike. What cannot be shown that way falls back
//! to a full re-simulation: a spawn in the interval (entity ids are global), a reach set that is
//! not small, a tick that hit (or could hit) the per-tick resolution cap, or a re-simulation that
//! destroys a different set of bodies than before. `tests/selective.rs` checks equality with a
//! full re-simulation on random scenes and late inputs.

use super::{Advance, Session};
use crate::rollback::history::Frame;
use glam::DVec3;
use impact_core::broadphase::sorted::SortedBoxes;
use impact_core::geometry::Aabb;
use impact_core::sim::{Stepper, TickInput, TickOutput, World};
use impact_protocol::{Action, CollisionEvent, EntityId, RayResult, Tick};
use std::collections::BTreeSet;

/// The entities an input acts on; a ray also reaches every body whose path box its segment
/// crosses at that tick.
fn entities(input: &TickInput, frame: &Frame, out: &mut BTreeSet<EntityId>) {
    for a in &input.actions {
        match a {
            Action::SetVelocity { entity, .. }
            | Action::ApplyImpulse { entity, .. }
            | Action::Move { entity, .. }
            | Action::Despawn { entity } => {
                out.insert(*entity);
            }
            Action::FireRay { shooter, origin, direction, max_distance_m } => {
                out.insert(*shooter);
                let o = DVec3::from_array(*origin);
                let end = o + DVec3::from_array(*direction).normalize_or_zero() * *max_distance_m;
                let ray = Aabb { min: o.min(end), max: o.max(end) };
                for (slot, p) in frame.paths.iter().enumerate() {
                    if p.overlaps(&ray) {
                        out.insert(frame.state.bodies.id[slot]);
                    }
                }
            }
            // Inputs with these take the full re-simulation (see below).
            Action::SpawnProjectile { .. }
            | Action::Spawn { .. }
            | Action::Teleport { .. }
            | Action::SetClass { .. }
            | Action::SetState { .. } => {}
        }
    }
}

/// Grows `reach` with the old run's neighbours and inputs, to a fixpoint. Gives up (false) as
/// soon as it holds more than `limit` bodies: the full re-simulation is then cheaper than
/// growing on.
fn grow(s: &Session, from: Tick, now: Tick, reach: &mut BTreeSet<EntityId>, limit: usize) -> bool {
    let mut scratch = BTreeSet::new();
    loop {
        let before = reach.len();
        for k in from.0..now.0 {
            let f = s.history.get(Tick(k)).expect("held");
            for input in &f.inputs {
                scratch.clear();
                entities(input, f, &mut scratch);
                if scratch.iter().any(|e| reach.contains(e)) {
                    reach.extend(scratch.iter().copied());
                }
            }
            let boxes: Vec<Aabb> =
                reach.iter().filter_map(|id| f.state.bodies.slot(*id)).map(|slot| f.paths[slot]).collect();
            let Some(hull) = boxes.iter().copied().reduce(|a, b| a.union(&b)) else { continue };
            let set = SortedBoxes::new(boxes);
            for (slot, p) in f.paths.iter().enumerate() {
                if p.overlaps(&hull) && set.hits(p) {
                    reach.insert(f.state.bodies.id[slot]);
                }
            }
            if reach.len() > limit {
                return false;
            }
        }
        if reach.len() == before {
            return true;
        }
    }
}

/// Rounds of grow, re-simulate, check before giving up for a full re-simulation: each round
/// re-simulates the whole interval, so a reach set that keeps finding new bodies costs more than
/// the full run it was meant to save.
const MAX_ROUNDS: usize = 3;

/// `w` with only the dynamic bodies in `keep` (and contacts among them or with static
/// geometry).
fn subset(w: &World, keep: &BTreeSet<EntityId>) -> World {
    let mut sub = w.clone();
    let dead: Vec<bool> = w.bodies.id.iter().map(|id| !keep.contains(id)).collect();
    sub.bodies.remove_flagged(&dead);
    let dynamic_outside = |id: &EntityId| w.bodies.slot(*id).is_some() && !keep.contains(id);
    sub.touching.retain(|t| !dynamic_outside(&t.a) && !dynamic_outside(&t.b));
    sub
}

/// The re-simulated interval for the reach set: per tick, the events, the sub-world after the
/// tick, and the path boxes (by sub-world slot at the tick's start).
struct SubRun {
    events: Vec<Vec<CollisionEvent>>,
    after: Vec<World>,
    paths: Vec<(Vec<EntityId>, Vec<Aabb>)>,
    rays: Vec<RayResult>,
    skipped: Vec<impact_core::sim::output::Skipped>,
}

fn simulate(s: &Session, from: Tick, now: Tick, reach: &BTreeSet<EntityId>) -> Option<SubRun> {
    let mut w = subset(&s.history.get(from)?.state, reach);
    let mut stepper = Stepper::new(s.stepper.plan().clone(), false);
    stepper.set_pool(s.stepper.pool().clone());
    let mut out = TickOutput::default();
    let mut run =
        SubRun { events: Vec::new(), after: Vec::new(), paths: Vec::new(), rays: Vec::new(), skipped: Vec::new() };
    let cap = s.world.config.max_resolutions_per_tick;
    let mut scratch = BTreeSet::new();
    for k in from.0..now.0 {
        let f = s.history.get(Tick(k))?;
        let inputs: Vec<TickInput> = f
            .inputs
            .iter()
            .filter(|i| {
                scratch.clear();
                entities(i, f, &mut scratch);
                !scratch.is_empty() && scratch.iter().all(|e| reach.contains(e))
            })
            .cloned()
            .collect();
        let ids = w.bodies.id.clone();
        stepper.step_with(&mut w, &f.system, &inputs, &mut out);
        // The full run's resolutions are at most the old run's plus the reach set's new ones.
        if f.resolutions.saturating_add(stepper.stats.resolutions) >= cap {
            return None;
        }
        // The reach set must live and die as before.
        let next = s.history.get(Tick(k + 1)).map_or(&s.world, |n| &n.state);
        let alive_before: Vec<EntityId> = next.bodies.id.iter().filter(|id| reach.contains(id)).copied().collect();
        if alive_before != w.bodies.id {
            return None;
        }
        run.events.push(std::mem::take(&mut out.events));
        run.paths.push((ids, stepper.last_paths().to_vec()));
        run.after.push(w.clone());
        run.rays.append(&mut out.rays);
        run.skipped.append(&mut out.skipped);
    }
    Some(run)
}

/// Bodies outside the reach set whose old path boxes the new paths cross.
fn crossings(s: &Session, from: Tick, run: &SubRun, reach: &BTreeSet<EntityId>) -> BTreeSet<EntityId> {
    let mut extra = BTreeSet::new();
    for (n, (ids, boxes)) in run.paths.iter().enumerate() {
        let f = s.history.get(Tick(from.0 + n as u32)).expect("held");
        debug_assert_eq!(ids.len(), boxes.len());
        let Some(hull) = boxes.iter().copied().reduce(|a, b| a.union(&b)) else { continue };
        let set = SortedBoxes::new(boxes.iter().copied());
        for (slot, p) in f.paths.iter().enumerate() {
            let id = f.state.bodies.id[slot];
            if !reach.contains(&id) && p.overlaps(&hull) && set.hits(p) {
                extra.insert(id);
            }
        }
    }
    extra
}

/// Writes the reach set's new states into the world `w` (bodies outside it keep theirs).
fn patch(w: &mut World, sub: &World, reach: &BTreeSet<EntityId>) {
    for (k, id) in sub.bodies.id.iter().enumerate() {
        let slot = w.bodies.slot(*id).expect("alive sets were checked equal");
        w.bodies.pos[slot] = sub.bodies.pos[k];
        w.bodies.vel[slot] = sub.bodies.vel[k];
        w.bodies.asleep[slot] = sub.bodies.asleep[k];
        w.bodies.still_ticks[slot] = sub.bodies.still_ticks[k];
    }
    let dynamic_in = |id: &EntityId| reach.contains(id);
    w.touching.retain(|t| !dynamic_in(&t.a) && !dynamic_in(&t.b));
    w.touching.extend(sub.touching.iter().copied());
    w.touching.sort_by_key(|t| t.key());
    w.touching.dedup_by_key(|t| t.key());
}

/// Re-simulates only what the late inputs can reach. Returns false (having changed nothing)
/// when that cannot be shown equal to a full re-simulation; the caller then does the full one.
pub fn resimulate(s: &mut Session, from: Tick, adv: &mut Advance) -> bool {
    let now = s.world.tick;
    let mut reach = BTreeSet::new();
    for k in from.0..now.0 {
        let Some(f) = s.history.get(Tick(k)) else { return false };
        if f.capped || f.paths.len() != f.state.bodies.len() || !f.system.is_empty() {
            return false;
        }
        for input in &f.inputs {
            // A rewound ray reads a past world the sub-world does not hold: the full path.
            // A spawn adds a body the old run never had, a teleport moves one where its path
            // never went, a class change alters every rule it meets: no reach holds them. Only
            // motion is copied back from the sub-world, not a game state: that too.
            let unbounded = |a: &Action| {
                matches!(
                    a,
                    Action::SpawnProjectile { .. }
                        | Action::Spawn { .. }
                        | Action::Teleport { .. }
                        | Action::SetClass { .. }
                        | Action::SetState { .. }
                )
            };
            if !input.rewound.is_empty() || input.actions.iter().any(unbounded) {
                return false;
            }
            if s.fresh.contains(&(input.client, input.seq)) {
                entities(input, f, &mut reach);
            }
        }
    }
    let limit = (s.world.bodies.len() / 4).max(8);
    if reach.is_empty() || reach.len() > limit {
        return false;
    }
    let mut rounds = 0;
    let run = loop {
        rounds += 1;
        if rounds > MAX_ROUNDS || !grow(s, from, now, &mut reach, limit) {
            return false;
        }
        let Some(run) = simulate(s, from, now, &reach) else { return false };
        let extra = crossings(s, from, &run, &reach);
        if extra.is_empty() {
            break run;
        }
        reach.extend(extra);
    };
    // Merge: events, states, path boxes, tick by tick.
    let in_reach = |e: &CollisionEvent| reach.contains(&e.a) || reach.contains(&e.b);
    for (n, k) in (from.0..now.0).enumerate() {
        let tick = Tick(k);
        let old = &s.history.get(tick).expect("held").events;
        let mut events: Vec<CollisionEvent> = old.iter().filter(|e| !in_reach(e)).cloned().collect();
        events.extend(run.events[n].iter().cloned());
        events.sort_by(|x, y| {
            x.toi.total_cmp(&y.toi).then(x.a.cmp(&y.a)).then(x.b.cmp(&y.b)).then(x.phase.cmp(&y.phase))
        });
        s.publish_resimulated(tick, events, adv);
        let (ids, boxes) = &run.paths[n];
        let f = s.history.get_mut(tick).expect("held");
        for (id, b) in ids.iter().zip(boxes) {
            if let Some(slot) = f.state.bodies.slot(*id) {
                f.paths[slot] = *b;
            }
        }
        if k + 1 < now.0 {
            let next = s.history.get_mut(Tick(k + 1)).expect("held");
            patch(next.state_mut(), &run.after[n], &reach);
        } else {
            patch(&mut s.world, &run.after[n], &reach);
        }
    }
    for r in run.rays {
        if s.fresh.contains(&(r.client, r.seq)) {
            adv.rays.push(r);
        }
    }
    adv.skipped.extend(run.skipped);
    true
}
