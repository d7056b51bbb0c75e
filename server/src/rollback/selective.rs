//! Selective re-simulation: re-simulate only the bodies a late input can reach.
//!
//! The reach set `R` starts with what the late inputs touch. It grows, to a fixpoint, with every
//! body whose path box (kept per tick in the history) overlapped the path box of a body in `R`
//! at the same tick, and with everything any other input of the interval touches once that input
//! touches `R`. An input touches the bodies it acts on and, for each of its hitscan rays, the
//! shooter and every body whose path box the ray's segment crosses at the tick the ray is tested
//! against: the input's own tick, or the view tick a rewound ray looks at. A rewound ray whose
//! view tick is not after the rollback's first tick sees a world the rollback leaves as it was:
//! it touches the body it hits there instead. `R` is then re-simulated alone, with the static world, in a
//! sub-world (rewound rays cast against the sub-world's own past, or the unchanged history); the
//! new paths are checked against the old path boxes of everything outside `R` and against the
//! rays of every input left out, and any meeting grows `R` and starts again.
//!
//! At the fixpoint no body outside `R` came near a body in `R` in the old run or the new one, and
//! no ray left out came near one, so bodies and rays outside `R` follow exactly their recorded
//! history and bodies in `R` exactly what a full re-simulation would give them: impacts resolve in
//! (time, body, partner) order, and slot order is id order in the world and in the sub-world
//! alike. What cannot be shown that way falls back to a full re-simulation: a spawn in the
//! interval (entity ids are global), a reach set that is not small, a tick that hit (or could
//! hit) the per-tick resolution cap, or a re-simulation that destroys a different set of bodies
//! than before. `tests/selective.rs` checks equality with a full
//! re-simulation on random scenes with late inputs, on-time rays and rewound rays.

use super::{hitscan, Advance, Session};
use glam::DVec3;
use impact_core::geometry::Aabb;
use impact_core::sim::input::RewoundRay;
use impact_core::sim::ray_index::RayIndex;
use impact_core::sim::{Stepper, TickInput, TickOutput, World};
use impact_protocol::{Action, CollisionEvent, EntityId, RayResult, Tick};
use smallvec::SmallVec;
use std::collections::BTreeSet;
use std::sync::OnceLock;

/// Tolerance of the segment tests against path boxes, m (they must never miss a body a ray could
/// hit: the boxes already hold each body's whole shape).
const RAY_SLACK_M: f64 = 1e-6;

/// What one input of the interval touches.
struct Touch {
    /// The bodies its actions act on, each ray's shooter, and what its rays hit in a past world
    /// the rollback leaves unchanged (inline: a rollback gathers one per input of its interval,
    /// and an input names one or two).
    named: SmallVec<[EntityId; 2]>,
    /// Its rays' segments (rays cast again in the re-simulation), tested against the path boxes
    /// of the tick `at`.
    rays: SmallVec<[(DVec3, DVec3); 1]>,
    /// The tick whose path boxes `rays` are tested against.
    at: Tick,
    /// Whether the sub-world re-simulates it (it touches the reach set).
    inside: bool,
}

impl Touch {
    /// `named`, and every body whose old path box at `at` one of its rays crosses.
    fn all(&self, s: &Session) -> Vec<EntityId> {
        let mut out = self.named.to_vec();
        if let Some(f) = s.history.get(self.at) {
            let mut slots = Vec::new();
            for (a, b) in &self.rays {
                slots.clear();
                f.paths_overlapping(&Aabb { min: a.min(*b), max: a.max(*b) }, &mut slots);
                for &slot in &slots {
                    if f.paths[slot as usize].crosses_segment(*a, *b, RAY_SLACK_M) {
                        out.push(f.state.bodies.id[slot as usize]);
                    }
                }
            }
        }
        out
    }

    /// Whether one of its rays crosses `p`.
    fn crosses(&self, p: &Aabb) -> bool {
        self.rays.iter().any(|(a, b)| p.crosses_segment(*a, *b, RAY_SLACK_M))
    }
}

/// The reach set as it grows: the bodies in it, and those whose neighbours (bodies, inputs) are
/// still to be looked for.
struct Reach {
    set: BTreeSet<EntityId>,
    todo: Vec<EntityId>,
}

impl Reach {
    fn add(&mut self, ids: impl IntoIterator<Item = EntityId>) {
        for id in ids {
            if self.set.insert(id) {
                self.todo.push(id);
            }
        }
    }
}

/// What each input of `[from, now)` touches, by tick and input; `None` when an input there
/// cannot be bounded (the full re-simulation then runs).
fn touches(s: &Session, from: Tick, now: Tick) -> Option<Vec<Vec<Touch>>> {
    let oldest = s.history.oldest()?;
    let max_rewind = s.world.config.max_rewind_ticks;
    let mut out = Vec::with_capacity((now.0 - from.0) as usize);
    // Static geometry is in every sub-world: what a ray hit there names no body.
    let statics = &s.world.statics;
    let fixed =
        |e: &EntityId| statics.id.binary_search(e).is_ok() || statics.terrain.as_ref().is_some_and(|t| t.id == *e);
    let mut rays = Vec::new();
    let mut hits = Vec::new();
    for k in from.0..now.0 {
        let f = s.history.get(Tick(k))?;
        if f.capped || f.paths.len() != f.state.bodies.len() || !f.system.is_empty() {
            return None;
        }
        let mut touches = Vec::with_capacity(f.inputs.len());
        for input in &f.inputs {
            // A spawn adds a body the old run never had, a teleport moves one where its path
            // never went, a class change alters every rule it meets: no reach holds them. Only
            // motion is copied back from the sub-world, not a game state: that too. A logged
            // input's rays are not cast again: the full path keeps their logged hits.
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
            if input.logged || input.actions.iter().any(unbounded) {
                return None;
            }
            let mut t = Touch { named: SmallVec::new(), rays: SmallVec::new(), at: Tick(k), inside: false };
            for a in &input.actions {
                match a {
                    Action::SetVelocity { entity, .. }
                    | Action::ApplyImpulse { entity, .. }
                    | Action::Move { entity, .. }
                    | Action::Despawn { entity } => t.named.push(*entity),
                    Action::FireRay { shooter, origin, direction, max_distance_m } => {
                        t.named.push(*shooter);
                        let o = DVec3::from_array(*origin);
                        t.rays.push((o, o + DVec3::from_array(*direction).normalize_or_zero() * *max_distance_m));
                    }
                    _ => {}
                }
            }
            touches.push(t);
        }
        // Rewound rays: where the full re-simulation would cast them.
        let shots = hitscan::shots(Tick(k), &f.inputs, max_rewind, oldest);
        for group in shots.chunk_by(|a, b| a.input == b.input) {
            let (n, view) = (group[0].input, group[0].view);
            let t = &mut touches[n];
            if view > from {
                // Cast again in the sub-world at its view tick.
                t.at = view;
                continue;
            }
            // That world (the start of `from` at the latest) does not change: the ray hits there
            // what it hit before, or, cast for the first time, what it hits there now.
            t.rays.clear();
            let input = &f.inputs[n];
            if input.rewound.is_empty() {
                let past = s.history.get(view)?;
                rays.clear();
                rays.extend(group.iter().map(|sh| sh.ray));
                impact_core::sim::ray_index::cast_many_indexed(&past.state, past.ray_index(), &rays, &mut hits);
                t.named.extend(hits.drain(..).flatten().map(|h| h.entity).filter(|e| !fixed(e)));
            } else {
                let hit = input.rewound.iter().filter_map(|r| r.hit.as_ref()).map(|h| h.entity);
                t.named.extend(hit.filter(|e| !fixed(e)));
            }
        }
        out.push(touches);
    }
    Some(out)
}

/// The inputs with rays, by the tick their rays are tested at (as offsets from `from`): (tick
/// offset of the input, its index).
fn rays_at(from: Tick, now: Tick, touches: &[Vec<Touch>]) -> Vec<Vec<(usize, usize)>> {
    let mut out = vec![Vec::new(); (now.0 - from.0) as usize];
    for (m, ts) in touches.iter().enumerate() {
        for (i, t) in ts.iter().enumerate().filter(|(_, t)| !t.rays.is_empty()) {
            out[(t.at.0 - from.0) as usize].push((m, i));
        }
    }
    out
}

/// Grows the reach set with the old run's neighbours and the inputs touching it, to a fixpoint:
/// each body that joins is looked at once, at every tick of the interval (its path box against
/// the others', through the frame's grid, and against the rays of the inputs left out). Gives up
/// (false) as soon as it holds more than `limit` bodies: the full re-simulation is then cheaper
/// than growing on.
fn grow(s: &Session, from: Tick, now: Tick, touches: &mut [Vec<Touch>], reach: &mut Reach, limit: usize) -> bool {
    let rays_at = rays_at(from, now, touches);
    let mut slots = Vec::new();
    while let Some(e) = reach.todo.pop() {
        for (n, k) in (from.0..now.0).enumerate() {
            let f = s.history.get(Tick(k)).expect("held");
            let Some(slot) = f.state.bodies.slot(e) else { continue };
            let b = f.paths[slot];
            slots.clear();
            f.paths_overlapping(&b, &mut slots);
            reach.add(slots.iter().map(|&j| f.state.bodies.id[j as usize]));
            // Inputs whose rays are tested at this tick, wherever they apply.
            for &(m, i) in &rays_at[n] {
                let t = &mut touches[m][i];
                if !t.inside && t.crosses(&b) {
                    t.inside = true;
                    reach.add(t.all(s));
                }
            }
            for t in touches[n].iter_mut().filter(|t| !t.inside && t.named.contains(&e)) {
                t.inside = true;
                reach.add(t.all(s));
            }
        }
        if reach.set.len() > limit {
            return false;
        }
    }
    true
}

/// Rounds of grow, re-simulate, check before giving up for a full re-simulation: each round
/// re-simulates the whole interval, so a reach set that keeps finding new bodies costs more than
/// the full run it was meant to save.
const MAX_ROUNDS: usize = 3;

/// `w` with only the dynamic bodies in `keep` (and contacts among them or with static
/// geometry).
fn subset(w: &World, keep: &BTreeSet<EntityId>) -> World {
    let slots: Vec<usize> = keep.iter().filter_map(|id| w.bodies.slot(*id)).collect();
    let dynamic_outside = |id: &EntityId| w.bodies.slot(*id).is_some() && !keep.contains(id);
    World {
        tick: w.tick,
        bodies: w.bodies.select(&slots),
        next_entity: w.next_entity,
        touching: w.touching.iter().filter(|t| !dynamic_outside(&t.a) && !dynamic_outside(&t.b)).copied().collect(),
        statics: w.statics.clone(),
        config: w.config.clone(),
    }
}

/// The re-simulated interval for the reach set: per tick, the events, the sub-world at the
/// tick's start (and after the last), the path boxes (by sub-world slot at the tick's start) and
/// the re-simulated inputs' rewound rays.
struct SubRun {
    events: Vec<Vec<CollisionEvent>>,
    /// `starts[n]`: the sub-world at the start of tick `from + n`; one more: after the last.
    starts: Vec<(World, OnceLock<RayIndex>)>,
    paths: Vec<(Vec<EntityId>, Vec<Aabb>)>,
    /// Per tick: (input index in the frame, its rewound rays as cast now).
    rewound: Vec<Vec<(usize, Vec<RewoundRay>)>>,
    rays: Vec<RayResult>,
    skipped: Vec<impact_core::sim::output::Skipped>,
}

fn simulate(s: &Session, from: Tick, now: Tick, reach: &BTreeSet<EntityId>, touches: &[Vec<Touch>]) -> Option<SubRun> {
    let mut w = subset(&s.history.get(from)?.state, reach);
    let mut stepper = Stepper::new(s.stepper.plan().clone(), false);
    stepper.set_pool(s.stepper.pool().clone());
    let mut out = TickOutput::default();
    let mut run = SubRun {
        events: Vec::new(),
        starts: Vec::new(),
        paths: Vec::new(),
        rewound: Vec::new(),
        rays: Vec::new(),
        skipped: Vec::new(),
    };
    let cap = s.world.config.max_resolutions_per_tick;
    let oldest = s.history.oldest()?;
    let max_rewind = s.world.config.max_rewind_ticks;
    for (n, k) in (from.0..now.0).enumerate() {
        let f = s.history.get(Tick(k))?;
        let picked: Vec<usize> = (0..f.inputs.len()).filter(|&i| touches[n][i].inside).collect();
        let mut inputs: Vec<TickInput> = picked.iter().map(|&i| f.inputs[i].clone()).collect();
        // Rewound rays see the sub-world's past where the rollback changed it, the history
        // before that.
        let starts = &run.starts;
        hitscan::rewind_rays(Tick(k), &mut inputs, max_rewind, oldest, Some(from), &w, |v| {
            if v <= from {
                s.history.get(v).map(|p| (&p.state, p.ray_index()))
            } else {
                let (world, index) = starts.get((v.0 - from.0) as usize)?;
                Some((world, index.get_or_init(|| RayIndex::build(world))))
            }
        });
        run.rewound.push(picked.iter().zip(&inputs).map(|(&i, input)| (i, input.rewound.clone())).collect());
        run.starts.push((w.clone(), OnceLock::new()));
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
        run.rays.append(&mut out.rays);
        run.skipped.append(&mut out.skipped);
    }
    run.starts.push((w, OnceLock::new()));
    Some(run)
}

/// Bodies outside the reach set whose old path boxes the new paths cross, and everything the
/// inputs left out touch whose rays the new paths cross.
fn crossings(
    s: &Session,
    from: Tick,
    run: &SubRun,
    reach: &BTreeSet<EntityId>,
    touches: &[Vec<Touch>],
) -> BTreeSet<EntityId> {
    let now = Tick(from.0 + run.paths.len() as u32);
    let rays_at = rays_at(from, now, touches);
    let mut extra = BTreeSet::new();
    let mut slots = Vec::new();
    for (n, (ids, boxes)) in run.paths.iter().enumerate() {
        let f = s.history.get(Tick(from.0 + n as u32)).expect("held");
        debug_assert_eq!(ids.len(), boxes.len());
        for b in boxes {
            slots.clear();
            f.paths_overlapping(b, &mut slots);
            extra.extend(slots.iter().map(|&j| f.state.bodies.id[j as usize]).filter(|id| !reach.contains(id)));
            for &(m, i) in &rays_at[n] {
                let t = &touches[m][i];
                if !t.inside && t.crosses(b) {
                    extra.extend(t.all(s));
                }
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
    let Some(mut touches) = touches(s, from, now) else { return false };
    let limit = (s.world.bodies.len() / 8).max(8);
    let mut reach = Reach { set: BTreeSet::new(), todo: Vec::new() };
    for (n, k) in (from.0..now.0).enumerate() {
        let f = s.history.get(Tick(k)).expect("held");
        for (t, input) in touches[n].iter_mut().zip(&f.inputs) {
            if s.fresh.contains(&(input.client, input.seq)) {
                t.inside = true;
                reach.add(t.all(s));
            }
        }
        if reach.set.len() > limit {
            return false;
        }
    }
    if reach.set.is_empty() {
        return false;
    }
    let mut rounds = 0;
    let run = loop {
        rounds += 1;
        if rounds > MAX_ROUNDS || !grow(s, from, now, &mut touches, &mut reach, limit) {
            return false;
        }
        let Some(run) = simulate(s, from, now, &reach.set, &touches) else { return false };
        let extra = crossings(s, from, &run, &reach.set, &touches);
        if extra.is_empty() {
            break run;
        }
        reach.add(extra);
    };
    let reach = reach.set;
    // Merge: events, states, path boxes, rewound rays, tick by tick.
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
                f.set_path(slot, *b);
            }
        }
        for (i, rewound) in &run.rewound[n] {
            f.inputs[*i].rewound.clone_from(rewound);
        }
        let after = &run.starts[n + 1].0;
        if k + 1 < now.0 {
            let next = s.history.get_mut(Tick(k + 1)).expect("held");
            let slots: Vec<usize> = after.bodies.id.iter().filter_map(|id| next.state.bodies.slot(*id)).collect();
            patch(next.state_moved(slots), after, &reach);
        } else {
            patch(&mut s.world, after, &reach);
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
