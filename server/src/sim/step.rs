//! One tick: inputs, integration, broadphase on swept bounds, time of impact, resolution in
//! time-of-impact order, begin/end events. The result is a function of the world and the
//! inputs only; [`Stepper`] holds reusable buffers and counters, never state that changes a
//! result.

use crate::broadphase::Broadphase;
use crate::narrow::{self, Contact, Kernel};
use crate::sim::input::{self, TickInput};
use crate::sim::plan::Plan;
use crate::sim::shape::{Aabb, Shape};
use crate::sim::world::{ClassId, Rule, World};
use crate::toi::analytic::{swept_sphere, SweptSphere};
use crate::toi::bisect::first_contact;
use glam::{DQuat, DVec3};
use impact_protocol::{CollisionEvent, EntityId, EventStatus, Phase, RayResult, Response};
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::time::{Duration, Instant};

/// Gauss-Seidel passes of the end-of-tick settle.
const SETTLE_PASSES: u32 = 16;

/// Most conservative-advancement steps for one fast pair before sampling takes over.
const CA_MAX_STEPS: u32 = 16;

/// Extra fraction of the normal velocity removed by slide and inelastic contacts.
const SLIDE_OVERCLIP: f64 = 1.0e-3;

/// Most resolutions one body may take part in per tick before its motion for the rest of the
/// tick is frozen where it stands (never inside anything). Bounds pathological piles.
const MAX_RESOLUTIONS_PER_BODY: u32 = 16;

/// The other side of a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Partner {
    /// A dynamic body (slot).
    Body(u32),
    /// A static body (index into the static world).
    Static(u32),
    /// The terrain.
    Terrain,
}

/// Time spent per stage and work counted, for the last tick and accumulated.
#[derive(Clone, Debug, Default)]
pub struct StageStats {
    /// Applying inputs (and ray queries).
    pub inputs: Duration,
    /// Integration and swept bounds.
    pub integrate: Duration,
    /// Broadphase.
    pub broadphase: Duration,
    /// Narrowphase and time of impact.
    pub narrowphase: Duration,
    /// Resolution.
    pub resolve: Duration,
    /// Contact bookkeeping and events.
    pub events: Duration,
    /// Ticks counted.
    pub ticks: u64,
    /// Narrowphase pairs tested in the last tick.
    pub pairs_tested: u32,
    /// Impacts resolved in the last tick.
    pub resolutions: u32,
    /// Ticks whose resolutions hit the per-tick cap.
    pub resolution_cap_hits: u64,
    /// Overlap tests spent by bisection and sampling, last tick.
    pub toi_tests: u32,
    /// Body-ticks frozen by the per-body resolution cap, since start.
    pub frozen: u64,
}

impl StageStats {
    /// `(name, total time)` per stage, in tick order.
    pub fn stages(&self) -> [(&'static str, Duration); 6] {
        [
            ("inputs", self.inputs),
            ("integrate", self.integrate),
            ("broadphase", self.broadphase),
            ("narrowphase", self.narrowphase),
            ("resolve", self.resolve),
            ("events", self.events),
        ]
    }
}

/// What one tick produced besides the new state.
#[derive(Clone, Debug, Default)]
pub struct TickOutput {
    /// Collision events in `(toi, a, b, phase)` order.
    pub events: Vec<CollisionEvent>,
    /// Results of the tick's hitscan rays, in input order.
    pub rays: Vec<RayResult>,
    /// Inputs (or actions) that could not apply, with why: `(client, seq, reason)`.
    pub skipped: Vec<input::Skipped>,
    /// Avatars spawned by system actions this tick: `(owner, entity)`.
    pub spawned: Vec<(impact_protocol::ClientId, EntityId)>,
}

#[derive(Clone, Copy, Debug)]
struct Impact {
    t: f64,
    a: u32,
    b: Partner,
    ver_a: u32,
    ver_b: u32,
    /// Contact at the reported pose (touching or penetrating), `a` at the origin.
    contact: Contact,
    /// Penetrating at the start of the interval (no time of impact to find).
    started_inside: bool,
}

/// An impact's place in the resolution order, with its index in `Stepper::impacts`: the heap
/// moves these 32 bytes, not the 96-byte impact (a pile pops hundreds of thousands a second).
#[derive(Clone, Copy, Debug)]
struct Queued {
    t: f64,
    a: u32,
    b: Partner,
    ver_a: u32,
    ver_b: u32,
    index: u32,
}

impl PartialEq for Queued {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Queued {}
impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Queued {
    /// Reversed so the max-heap pops the earliest impact; ties broken by the pair (and, between
    /// copies of one impact, which are equal in every field, by index).
    fn cmp(&self, other: &Self) -> Ordering {
        other.t.total_cmp(&self.t).then_with(|| {
            (other.a, other.b, other.ver_a, other.ver_b, other.index)
                .cmp(&(self.a, self.b, self.ver_a, self.ver_b, self.index))
        })
    }
}

/// A pair to test this tick.
#[derive(Clone, Copy, Debug)]
struct Cand {
    a: u32,
    b: Partner,
    /// Contact at the end of the step on the paths the tick started with (within the slop).
    /// Valid while neither body's path changed.
    end: Option<Contact>,
    /// `end` was computed (candidates found mid-step have none).
    end_valid: bool,
}

impl Cand {
    fn new(a: u32, b: Partner) -> Cand {
        Cand { a, b, end: None, end_valid: false }
    }
}

/// One pair's story this tick, for events.
#[derive(Clone, Copy, Debug)]
struct PairRecord {
    key: (EntityId, EntityId),
    t: f64,
    point: DVec3,
    normal_lo_hi: DVec3,
    depth: f64,
    closing: f64,
    response: Response,
}

/// The stepper: plan, broadphase and every buffer a tick needs, reused across ticks.
#[derive(Debug)]
pub struct Stepper {
    plan: Plan,
    broadphase: Broadphase,
    /// Stage times and counters.
    pub stats: StageStats,
    profile: bool,
    aabbs: Vec<Aabb>,
    base: Vec<DVec3>,
    t0: Vec<f64>,
    version: Vec<u32>,
    moving: Vec<bool>,
    dead: Vec<bool>,
    count: Vec<u32>,
    clip: Vec<[DVec3; 3]>,
    clip_len: Vec<u8>,
    pairs: Vec<(u32, u32)>,
    candidates: Vec<Cand>,
    heap: BinaryHeap<Queued>,
    impacts: Vec<Impact>,
    triggers: Vec<Impact>,
    records: Vec<PairRecord>,
    end_records: Vec<PairRecord>,
    end_order: Vec<(u64, u32)>,
    touching_now: Vec<(EntityId, EntityId)>,
    query_buf: Vec<u32>,
    static_buf: Vec<u32>,
    partner_buf: Vec<Partner>,
    settled: Vec<u32>,
}

impl Stepper {
    /// A stepper for `plan`. With `profile`, stage times are measured (the clock is read only
    /// for the statistics; it never reaches a result).
    pub fn new(plan: Plan, profile: bool) -> Stepper {
        Stepper {
            broadphase: Broadphase::new(plan.broadphase),
            plan,
            stats: StageStats::default(),
            profile,
            aabbs: Vec::new(),
            base: Vec::new(),
            t0: Vec::new(),
            version: Vec::new(),
            moving: Vec::new(),
            dead: Vec::new(),
            count: Vec::new(),
            clip: Vec::new(),
            clip_len: Vec::new(),
            pairs: Vec::new(),
            candidates: Vec::new(),
            heap: BinaryHeap::new(),
            impacts: Vec::new(),
            triggers: Vec::new(),
            records: Vec::new(),
            end_records: Vec::new(),
            end_order: Vec::new(),
            touching_now: Vec::new(),
            query_buf: Vec::new(),
            static_buf: Vec::new(),
            partner_buf: Vec::new(),
            settled: Vec::new(),
        }
    }

    /// The box each body's path stayed within during the last tick, by slot of the world as it
    /// was at that tick's start (swept bounds, grown wherever a path changed mid-step).
    /// Rollback keeps them to find what a late input can reach.
    pub fn last_paths(&self) -> &[Aabb] {
        &self.aabbs
    }

    /// The plan in use.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    fn lap(&self, since: &mut Option<Instant>, slot: fn(&mut StageStats) -> &mut Duration, stats: &mut StageStats) {
        if let Some(start) = since {
            let now = Instant::now();
            *slot(stats) += now - *start;
            *start = now;
        }
    }

    /// Advances `w` by one tick with `inputs` (any order: they are applied sorted by client and
    /// sequence number). Events and ray results go to `out` (cleared first).
    pub fn step(&mut self, w: &mut World, inputs: &[TickInput], out: &mut TickOutput) {
        self.step_with(w, &[], inputs, out);
    }

    /// [`Stepper::step`] with the server's own actions for the tick, applied first.
    pub fn step_with(
        &mut self,
        w: &mut World,
        system: &[input::SystemAction],
        inputs: &[TickInput],
        out: &mut TickOutput,
    ) {
        out.events.clear();
        out.rays.clear();
        out.skipped.clear();
        out.spawned.clear();
        let mut stats = std::mem::take(&mut self.stats);
        let mut clock = self.profile.then(Instant::now);

        // 1. The server's actions, then inputs, then hitscan against the world as it stands at
        //    the start of the tick.
        let first_new = w.next_entity;
        let first_tick = w.tick.0 == 0;
        input::apply_system(w, system, out);
        input::apply(w, inputs, out);
        self.lap(&mut clock, |s| &mut s.inputs, &mut stats);

        // 2. Integrate: gravity, then constant velocity over the step.
        let cfg = w.config.clone();
        let dt = cfg.dt;
        let n = w.bodies.len();
        let b = &mut w.bodies;
        if self.plan.gravity {
            for i in 0..n {
                if b.inv_mass[i] > 0.0 && cfg.classes.props[b.class[i].0 as usize].gravity {
                    b.vel[i] += cfg.gravity * dt;
                }
            }
        }
        let slop = cfg.contact_slop_m;
        // Plain indexed writes into buffers sized once: this loop runs for every body every tick.
        self.aabbs.resize(n, Aabb::EMPTY);
        self.base.clear();
        self.base.extend_from_slice(&b.pos);
        self.t0.clear();
        self.t0.resize(n, 0.0);
        self.version.clear();
        self.version.resize(n, 0);
        self.moving.clear();
        // A body at rest is not re-tested against another at rest, except on its first tick:
        // the scene's bodies at tick 0 and bodies spawned this tick may have been placed
        // overlapping something, and nothing else would ever separate them.
        self.moving.extend(b.vel.iter().zip(&b.id).map(|(v, id)| *v != DVec3::ZERO || first_tick || id.0 >= first_new));
        self.dead.clear();
        self.dead.resize(n, false);
        self.count.clear();
        self.count.resize(n, 0);
        self.clip_len.clear();
        self.clip_len.resize(n, 0);
        self.clip.resize(n, [DVec3::ZERO; 3]);
        let pad = DVec3::splat(slop);
        for i in 0..n {
            let p0 = b.pos[i];
            let p1 = p0 + b.vel[i] * dt;
            self.aabbs[i] = Aabb { min: p0.min(p1) + b.aabb_lo[i] - pad, max: p0.max(p1) + b.aabb_hi[i] + pad };
        }
        self.lap(&mut clock, |s| &mut s.integrate, &mut stats);

        // 3. Broadphase: dynamic pairs, then statics and terrain for moving bodies.
        self.broadphase.pairs(&self.aabbs, &mut self.pairs);
        self.candidates.clear();
        for &(i, j) in &self.pairs {
            if !self.moving[i as usize] && !self.moving[j as usize] {
                continue; // both resting: nothing can change between them
            }
            if cfg.classes.rule(b.class[i as usize], b.class[j as usize]) == Rule::Ignore {
                continue;
            }
            self.candidates.push(Cand::new(i, Partner::Body(j)));
        }
        if self.plan.statics || self.plan.terrain {
            for i in 0..n {
                if !self.moving[i] {
                    continue;
                }
                self.static_partners(w, i as u32, self.aabbs[i]);
                self.candidates.extend(self.partner_buf.iter().map(|&p| Cand::new(i as u32, p)));
            }
        }
        self.lap(&mut clock, |s| &mut s.broadphase, &mut stats);

        // 4. Narrowphase and time of impact for every candidate, and whether it touches at the
        //    end of the step on its current path (reused for events if nothing changes it).
        //    Triggers change no path, so they wait outside the heap and are settled after it.
        stats.pairs_tested = self.candidates.len() as u32;
        stats.toi_tests = 0;
        self.heap.clear();
        self.impacts.clear();
        self.triggers.clear();
        for k in 0..self.candidates.len() {
            let Cand { a, b: p, .. } = self.candidates[k];
            let (imp, end) = match self.sphere_pair(w, a, p) {
                Some(fast) => fast,
                None => {
                    let imp = self.impact(w, a, p, 0.0, &mut stats.toi_tests);
                    (imp, self.end_contact(w, a, p))
                }
            };
            self.candidates[k].end = end;
            self.candidates[k].end_valid = true;
            if let Some(imp) = imp {
                self.schedule(w, imp);
            }
        }
        self.lap(&mut clock, |s| &mut s.narrowphase, &mut stats);

        // 5. Resolve in time-of-impact order; a body whose path changes is re-tested against
        //    everything its new path can reach.
        self.records.clear();
        let mut resolutions = 0u32;
        while let Some(q) = self.heap.pop() {
            let imp = self.impacts[q.index as usize];
            let i = imp.a as usize;
            if self.dead[i] || matches!(imp.b, Partner::Body(j) if self.dead[j as usize]) {
                continue;
            }
            if !self.is_current(&imp) {
                // A path changed since this was computed: test again from the later change.
                if let Some(again) = self.impact(w, imp.a, imp.b, self.search_from(&imp), &mut stats.toi_tests) {
                    self.schedule(w, again);
                }
                continue;
            }
            if imp.started_inside && imp.contact.depth <= cfg.contact_slop_m && separating(w, &imp) {
                // Touching within the slop and already moving apart: nothing to resolve.
                continue;
            }
            if !imp.started_inside && closing_speed(w, &imp) * (1.0 - imp.t) * cfg.dt <= 0.5 * cfg.contact_slop_m {
                // A resting contact: even unresolved, the pair cannot sink deeper than half the
                // slop by the end of the tick, and the next tick starts by pushing it apart.
                // Resolving it would only set off a chain of micro-impacts through a pile.
                continue;
            }
            if resolutions >= cfg.max_resolutions_per_tick {
                stats.resolution_cap_hits += 1;
                break;
            }
            resolutions += 1;
            self.count[i] += 1;
            if let Partner::Body(j) = imp.b {
                self.count[j as usize] += 1;
            }
            let over = |this: &Stepper, k: usize| this.count[k] > MAX_RESOLUTIONS_PER_BODY;
            if over(self, i) || matches!(imp.b, Partner::Body(j) if over(self, j as usize)) {
                for k in
                    [Some(i), if let Partner::Body(j) = imp.b { Some(j as usize) } else { None }].into_iter().flatten()
                {
                    if over(self, k) && self.t0[k] < 1.0 {
                        self.base[k] = self.pos_at(w, k, imp.t);
                        self.t0[k] = 1.0;
                        self.version[k] += 1;
                        stats.frozen += 1;
                    }
                }
                continue;
            }
            let changed = self.resolve(w, &imp);
            for body in changed.into_iter().flatten() {
                self.requery(w, body, &mut stats.toi_tests);
            }
        }
        // Triggers: record those whose bodies kept their paths; search again those that changed.
        let mut triggers = std::mem::take(&mut self.triggers);
        for imp in &triggers {
            if self.dead[imp.a as usize] || matches!(imp.b, Partner::Body(j) if self.dead[j as usize]) {
                continue;
            }
            if self.is_current(imp) {
                self.resolve(w, imp);
            } else if let Some(again) = self.impact(w, imp.a, imp.b, self.search_from(imp), &mut stats.toi_tests) {
                self.resolve(w, &again);
            }
        }
        triggers.clear();
        self.triggers = triggers;
        stats.resolutions = resolutions;
        self.lap(&mut clock, |s| &mut s.resolve, &mut stats);

        // 6. Final positions, touching set, events, removals.
        let b = &mut w.bodies;
        for i in 0..n {
            b.pos[i] = self.base[i] + b.vel[i] * ((1.0 - self.t0[i]) * dt);
        }
        self.settle(w);
        self.finish_events(w, out);
        if self.dead.contains(&true) {
            w.bodies.remove_flagged(&self.dead);
        }
        w.tick = w.tick.next();
        self.lap(&mut clock, |s| &mut s.events, &mut stats);
        stats.ticks += 1;
        self.stats = stats;
    }

    /// The static bodies and terrain body `i` can meet within `aabb`, into `partner_buf`.
    fn static_partners(&mut self, w: &World, i: u32, aabb: Aabb) {
        let b = &w.bodies;
        self.partner_buf.clear();
        if self.plan.statics {
            w.statics.index.query(&aabb, &mut self.static_buf);
            for &s in &self.static_buf {
                if w.config.classes.rule(b.class[i as usize], w.statics.class[s as usize]) != Rule::Ignore {
                    self.partner_buf.push(Partner::Static(s));
                }
            }
        }
        if let Some(t) = &w.statics.terrain {
            if t.field.aabb().overlaps(&aabb) && w.config.classes.rule(b.class[i as usize], t.class) != Rule::Ignore {
                self.partner_buf.push(Partner::Terrain);
            }
        }
    }

    /// Adds a pair found mid-step to `candidates`. A pair found again is listed again, on
    /// purpose: the settle passes walk this list, and the repeats (pairs around bodies that were
    /// pushed or re-routed) give the busiest contacts more Gauss-Seidel iterations. Removing them
    /// made a 1,000-ball pile 1.5x faster but left 1.6 % of a radius of penetration instead of
    /// 0.02 %, and four times the passes did not recover it (0.43 %).
    fn add_candidate(&mut self, a: u32, b: Partner) {
        self.candidates.push(Cand::new(a, b));
    }

    /// Position of dynamic body `i` at step fraction `t` along its current path.
    #[inline]
    fn pos_at(&self, w: &World, i: usize, t: f64) -> DVec3 {
        self.base[i] + w.bodies.vel[i] * ((t - self.t0[i]).max(0.0) * w.config.dt)
    }

    /// Position and velocity of the partner at `t`.
    #[inline]
    fn partner_at(&self, w: &World, p: Partner, t: f64) -> (DVec3, DVec3) {
        match p {
            Partner::Body(j) => (self.pos_at(w, j as usize, t), w.bodies.vel[j as usize]),
            Partner::Static(s) => (w.statics.pos[s as usize], DVec3::ZERO),
            Partner::Terrain => (DVec3::ZERO, DVec3::ZERO),
        }
    }

    /// Contact between body `i` at `pa` and the partner at `pb` (`a` at the origin).
    fn contact(&self, w: &World, i: usize, pa: DVec3, p: Partner, pb: DVec3, margin: f64) -> Option<Contact> {
        let b = &w.bodies;
        let (sa, ra) = (&b.shape[i], b.rot[i]);
        match p {
            Partner::Body(j) => {
                convex_contact(&self.plan, sa, ra, &b.shape[j as usize], b.rot[j as usize], pb - pa, margin)
            }
            Partner::Static(s) => {
                let s = s as usize;
                convex_contact(&self.plan, sa, ra, &w.statics.shape[s], w.statics.rot[s], pb - pa, margin)
            }
            Partner::Terrain => {
                let t = w.statics.terrain.as_ref()?;
                crate::narrow::terrain_contact(sa, ra, pa, &t.field, margin)
            }
        }
    }

    /// The first contact of body `a` with `p` in `[from, 1]`, if any.
    /// Whether neither body's path changed since `imp` was computed.
    fn is_current(&self, imp: &Impact) -> bool {
        let ver_b = match imp.b {
            Partner::Body(j) => self.version[j as usize],
            _ => 0,
        };
        imp.ver_a == self.version[imp.a as usize] && imp.ver_b == ver_b
    }

    /// The time from which a stale impact must be searched again: the later path change.
    fn search_from(&self, imp: &Impact) -> f64 {
        match imp.b {
            Partner::Body(j) => self.t0[imp.a as usize].max(self.t0[j as usize]),
            _ => self.t0[imp.a as usize],
        }
    }

    fn class_pair(&self, w: &World, a: u32, p: Partner) -> (ClassId, ClassId) {
        let ca = w.bodies.class[a as usize];
        let cb = match p {
            Partner::Body(j) => w.bodies.class[j as usize],
            Partner::Static(s) => w.statics.class[s as usize],
            Partner::Terrain => w.statics.terrain.as_ref().map_or(ca, |t| t.class),
        };
        (ca, cb)
    }

    fn is_trigger(&self, w: &World, imp: &Impact) -> bool {
        let (ca, cb) = self.class_pair(w, imp.a, imp.b);
        matches!(w.config.classes.rule(ca, cb), Rule::Trigger | Rule::Ignore)
    }

    /// Contact at the end of the step on the current paths, within the slop.
    fn end_contact(&self, w: &World, a: u32, p: Partner) -> Option<Contact> {
        let pa = self.pos_at(w, a as usize, 1.0);
        let (pb, _) = self.partner_at(w, p, 1.0);
        self.contact(w, a as usize, pa, p, pb, w.config.contact_slop_m)
    }

    /// The fast path for two spheres at the start of a tick (the bulk of most scenes): start
    /// overlap, the analytic time of impact and the end-of-step contact from one relative
    /// position and displacement. `None` when the pair is not two spheres (or the plan says
    /// no).
    #[inline]
    fn sphere_pair(&self, w: &World, a: u32, p: Partner) -> Option<(Option<Impact>, Option<Contact>)> {
        if !self.plan.analytic_spheres {
            return None;
        }
        let b = &w.bodies;
        let i = a as usize;
        let Shape::Sphere { radius: r1 } = b.shape[i] else { return None };
        let (r2, pb, vb, ver_b) = match p {
            Partner::Body(j) => match b.shape[j as usize] {
                Shape::Sphere { radius } => (radius, b.pos[j as usize], b.vel[j as usize], 0),
                _ => return None,
            },
            Partner::Static(s) => match w.statics.shape[s as usize] {
                Shape::Sphere { radius } => (radius, w.statics.pos[s as usize], DVec3::ZERO, 0),
                _ => return None,
            },
            Partner::Terrain => return None,
        };
        let r = r1 + r2;
        let d0 = pb - b.pos[i];
        let rel = (vb - b.vel[i]) * w.config.dt;
        let d1 = d0 + rel;
        let slop = w.config.contact_slop_m;
        let end = if d1.length_squared() < (r + slop) * (r + slop) {
            narrow::sphere_sphere::contact(r1, r2, d1)
        } else {
            None
        };
        let mk = |t: f64, contact: Contact, started_inside: bool| Impact {
            t,
            a,
            b: p,
            ver_a: 0,
            ver_b,
            contact,
            started_inside,
        };
        let imp = if d0.length_squared() < r * r {
            narrow::sphere_sphere::contact(r1, r2, d0).map(|c| mk(0.0, c, true))
        } else {
            match swept_sphere(-d0, -rel, r) {
                SweptSphere::Hit(s) => narrow::sphere_sphere::contact(r1, r2, d0 + rel * s)
                    .map(|c| mk(s, Contact { depth: c.depth.max(0.0), ..c }, false)),
                _ => None,
            }
        };
        Some((imp, end))
    }

    fn impact(&self, w: &World, a: u32, p: Partner, from: f64, tests: &mut u32) -> Option<Impact> {
        let i = a as usize;
        let b = &w.bodies;
        let dt = w.config.dt;
        let pa = self.pos_at(w, i, from);
        let (pb, vb) = self.partner_at(w, p, from);
        let va = b.vel[i];
        let ver_a = self.version[i];
        let ver_b = match p {
            Partner::Body(j) => self.version[j as usize],
            _ => 0,
        };
        let mk = |t: f64, contact: Contact, started_inside: bool| Impact {
            t,
            a,
            b: p,
            ver_a,
            ver_b,
            contact,
            started_inside,
        };
        // Already overlapping at the start of the interval: depth and normal now.
        if let Some(c) = self.contact(w, i, pa, p, pb, 0.0).filter(|c| c.depth > 0.0) {
            return Some(mk(from, c, true));
        }
        let span = 1.0 - from;
        let rel = (vb - va) * (dt * span); // b's displacement relative to a over [from, 1]
        if rel == DVec3::ZERO {
            return None;
        }
        let d0 = pb - pa;
        // Spheres: the exact swept-sphere time of impact.
        if let (Partner::Body(_) | Partner::Static(_), true) = (p, self.plan.analytic_spheres) {
            let sb = match p {
                Partner::Body(j) => &b.shape[j as usize],
                Partner::Static(s) => &w.statics.shape[s as usize],
                Partner::Terrain => unreachable!(),
            };
            if let (Shape::Sphere { radius: r1 }, Shape::Sphere { radius: r2 }) = (&b.shape[i], sb) {
                // DESIGN.md's A = P1 - Q1 and B = (P2 - P1) - (Q2 - Q1), with P = a and Q = b.
                return match swept_sphere(-d0, -rel, r1 + r2) {
                    SweptSphere::Hit(s) => {
                        let d = d0 + rel * s;
                        let c = narrow::sphere_sphere::contact(*r1, *r2, d)?;
                        Some(mk(from + span * s, Contact { depth: c.depth.max(0.0), ..c }, false))
                    }
                    _ => None,
                };
            }
        }
        // Overlap testing with bisection; fast pairs are sampled so they cannot tunnel.
        let travel = rel.length();
        let extent_b = match p {
            Partner::Body(j) => b.shape[j as usize].min_extent(),
            Partner::Static(s) => w.statics.shape[s as usize].min_extent(),
            Partner::Terrain => 0.0,
        };
        let step_m = if self.plan.ccd_sampling { 0.5 * (b.shape[i].min_extent() + extent_b) } else { f64::INFINITY };
        let overlaps = |t: f64| {
            let qa = pa + va * ((t - from) * dt);
            let qb = pb + vb * ((t - from) * dt);
            self.contact(w, i, qa, p, qb, 0.0).is_some_and(|c| c.depth > 0.0)
        };
        // A fast convex pair first advances conservatively: the gap between two convex shapes
        // closes no faster than their relative speed, so stepping by gap / speed can never pass
        // the first contact. It brings a bullet to its wall in one or two exact distance queries
        // instead of hundreds of overlap samples; sampling and bisection finish from there.
        let mut start = from;
        let convex = match p {
            Partner::Body(_) => true,
            Partner::Static(s) => w.statics.shape[s as usize].is_convex(),
            Partner::Terrain => false,
        };
        if travel > step_m && convex {
            let per_t = travel / span; // relative distance per unit of step fraction
            for _ in 0..CA_MAX_STEPS {
                *tests += 1;
                let qa = pa + va * ((start - from) * dt);
                let qb = pb + vb * ((start - from) * dt);
                let Some(c) = self.contact(w, i, qa, p, qb, f64::INFINITY) else { break };
                let gap = -c.depth;
                if gap <= 0.5 * step_m {
                    break;
                }
                // 0.999: parry's GJK distance is approximate; never step on its last digits.
                start += 0.999 * gap / per_t;
                if start >= 1.0 {
                    return None;
                }
            }
        }
        let remaining = travel * (1.0 - start) / span;
        let bracket = first_contact(start, remaining, step_m, &w.config.bisect, overlaps)?;
        *tests += bracket.tests;
        // Report the pose just before contact (lo); the normal and point come from the first
        // overlapping pose (hi), where the contact is defined.
        let qa = pa + va * ((bracket.hi - from) * dt);
        let qb = pb + vb * ((bracket.hi - from) * dt);
        let c = self.contact(w, i, qa, p, qb, 0.0)?;
        let shift = va * ((bracket.hi - bracket.lo) * dt);
        Some(mk(bracket.lo, Contact { point: c.point + shift, depth: 0.0, ..c }, false))
    }

    /// Applies the response for one impact. Returns the bodies whose paths changed.
    fn resolve(&mut self, w: &mut World, imp: &Impact) -> [Option<u32>; 2] {
        // The settings are shared (`Arc`); hold them through a second handle only where a
        // body's path changes, not for every recorded trigger.
        let classes = &w.config.classes;
        let i = imp.a as usize;
        let t = imp.t;
        let (class_b, id_b, inv_mb) = match imp.b {
            Partner::Body(j) => (w.bodies.class[j as usize], w.bodies.id[j as usize], w.bodies.inv_mass[j as usize]),
            Partner::Static(s) => (w.statics.class[s as usize], w.statics.id[s as usize], 0.0),
            Partner::Terrain => {
                let t = w.statics.terrain.as_ref().expect("terrain partner implies terrain");
                (t.class, t.id, 0.0)
            }
        };
        let class_a = w.bodies.class[i];
        let rule = classes.rule(class_a, class_b);
        let pa = self.pos_at(w, i, t);
        let (pb, vb) = self.partner_at(w, imp.b, t);
        let va = w.bodies.vel[i];
        let n = imp.contact.normal;
        let closing = -(vb - va).dot(n);
        let inv_ma = w.bodies.inv_mass[i];
        let response = response_of(rule);
        self.records.push(PairRecord {
            key: (w.bodies.id[i], id_b),
            t,
            point: pa + imp.contact.point,
            normal_lo_hi: n,
            depth: imp.contact.depth,
            closing,
            response,
        });
        let mut changed = [None, None];
        if matches!(rule, Rule::Ignore | Rule::Trigger) {
            return changed;
        }
        let cfg = w.config.clone();
        let j = match imp.b {
            Partner::Body(j) => Some(j as usize),
            _ => None,
        };
        let mut set_path =
            |this: &mut Stepper, w: &mut World, body: usize, new_pos: DVec3, new_vel: DVec3, slot: usize| {
                // A change too small to move the body by half the slop over the rest of the tick
                // does not need its new path searched again.
                let shift = (new_pos - this.pos_at(w, body, t)).length()
                    + (new_vel - w.bodies.vel[body]).length() * (1.0 - t) * w.config.dt;
                this.base[body] = new_pos;
                this.t0[body] = t;
                w.bodies.vel[body] = new_vel;
                this.version[body] += 1;
                this.moving[body] = true;
                if shift > 0.5 * w.config.contact_slop_m {
                    changed[slot] = Some(body as u32);
                }
            };
        match rule {
            Rule::Ignore | Rule::Trigger => {}
            Rule::Destroy { first, second, restitution } => {
                if first {
                    self.dead[i] = true;
                    self.version[i] += 1;
                }
                if let (true, Some(j)) = (second, j) {
                    self.dead[j] = true;
                    self.version[j] += 1;
                }
                // The survivor bounces off the destroyed body as off a wall, if asked to.
                if let (Some(e), true) = (restitution, closing > 0.0) {
                    if !first && inv_ma > 0.0 {
                        set_path(self, w, i, pa, va - n * ((1.0 + e) * va.dot(n).max(0.0)), 0);
                    } else if let (false, Some(j)) = (second, j) {
                        if inv_mb > 0.0 {
                            set_path(self, w, j, pb, vb - n * ((1.0 + e) * vb.dot(n).min(0.0)), 1);
                        }
                    }
                }
            }
            Rule::Bounce { .. } | Rule::Slide | Rule::Stop => {
                let inv_sum = inv_ma + inv_mb;
                if inv_sum == 0.0 {
                    return changed; // two immovable bodies
                }
                // Push apart what overlaps deeper than the slop, in proportion to the inverse
                // masses, back to half the slop: a pile then rests within the slop instead of
                // each push driving a body into its other neighbours (and with a tiny slop this
                // is a hair short of exact separation, which rounding could not keep anyway).
                let excess = imp.contact.depth - 0.5 * cfg.contact_slop_m;
                let push =
                    if imp.started_inside && imp.contact.depth > cfg.contact_slop_m { n * excess } else { DVec3::ZERO };
                let new_pa = pa - push * (inv_ma / inv_sum);
                let new_pb = pb + push * (inv_mb / inv_sum);
                let (mut new_va, mut new_vb) = (va, vb);
                if closing > 0.0 {
                    match rule {
                        Rule::Bounce { restitution } => {
                            // Impulse along n: dv = -(1 + e) (v.n) n, shared by inverse mass.
                            // Below the bounce threshold the contact is resting: no rebound, so a
                            // body on the ground under gravity settles instead of hopping.
                            let e = if closing > cfg.bounce_threshold_mps { restitution } else { 0.0 };
                            // Only a resting (e = 0) contact is overclipped; an elastic bounce must
                            // conserve energy exactly.
                            let over = if e == 0.0 { 1.0 + SLIDE_OVERCLIP } else { 1.0 };
                            let jn = (1.0 + e) * closing * over / inv_sum;
                            new_va = va - n * (jn * inv_ma);
                            new_vb = vb + n * (jn * inv_mb);
                            if e == 0.0 && inv_mb == 0.0 {
                                // A resting contact with static geometry slides like a player: in
                                // a crease (a valley of the terrain) it keeps to the crease.
                                new_va = self.clip_slide(i, -n, new_va);
                            }
                        }
                        Rule::Slide => {
                            // Remove the approaching normal velocity and a hair more (as Quake's
                            // overclip does), so rounding cannot leave the body creeping into the
                            // wall and re-resolving the same contact.
                            let jn = closing * (1.0 + SLIDE_OVERCLIP) / inv_sum;
                            new_va = va - n * (jn * inv_ma);
                            new_vb = vb + n * (jn * inv_mb);
                            if inv_mb == 0.0 {
                                new_va = self.clip_slide(i, -n, new_va);
                            }
                        }
                        Rule::Stop => {
                            if inv_ma > 0.0 {
                                new_va = DVec3::ZERO;
                            }
                            if inv_mb > 0.0 {
                                new_vb = DVec3::ZERO;
                            }
                        }
                        _ => {}
                    }
                }
                if inv_ma > 0.0 {
                    set_path(self, w, i, new_pa, new_va, 0);
                }
                if let (Some(j), true) = (j, inv_mb > 0.0) {
                    set_path(self, w, j, new_pb, new_vb, 1);
                }
            }
        }
        changed
    }

    /// Slides body `i` along every wall plane it touched this tick (up to three): its velocity
    /// keeps no component into any of them. Two planes leave motion along their crease; three
    /// stop it. `wall_normal` points out of the wall, towards the body.
    fn clip_slide(&mut self, i: usize, wall_normal: DVec3, v: DVec3) -> DVec3 {
        let len = self.clip_len[i] as usize;
        if len < 3 {
            self.clip[i][len] = wall_normal;
            self.clip_len[i] += 1;
        }
        let planes = &self.clip[i][..self.clip_len[i] as usize];
        let mut out = v;
        for (k, n) in planes.iter().enumerate() {
            let vn = out.dot(*n);
            if vn < 0.0 {
                out -= *n * vn;
                // Clipping against this plane may push back into an earlier one: then only the
                // crease between them is free.
                for m in planes.iter().take(k) {
                    if out.dot(*m) < -1e-12 {
                        let crease = n.cross(*m).normalize_or_zero();
                        out = crease * crease.dot(v);
                        if planes.len() >= 3 {
                            return DVec3::ZERO;
                        }
                    }
                }
            }
        }
        out
    }

    /// Settles what the time-of-impact resolution left overlapping: a few Gauss-Seidel passes
    /// over the tick's pairs push apart any pair deeper than the contact slop (back to half the
    /// slop, in proportion to the inverse masses) and remove its approaching normal velocity
    /// (inelastic). Impacts are resolved exactly, in time order, before this; what remains is
    /// resting contact in piles and stacks, which sequential impacts alone cannot hold (each push
    /// drives a body into its other neighbours). Bounded: `SETTLE_PASSES` passes.
    fn settle(&mut self, w: &mut World) {
        let slop = w.config.contact_slop_m;
        for _ in 0..SETTLE_PASSES {
            let mut moved = false;
            for k in 0..self.candidates.len() {
                let Cand { a, b: p, end, end_valid } = self.candidates[k];
                let i = a as usize;
                if self.dead[i] || matches!(p, Partner::Body(j) if self.dead[j as usize]) {
                    continue;
                }
                // A pair neither of whose paths changed keeps the end contact found with its time
                // of impact (same positions, same kernel): clear of the slop there, nothing to do.
                let unchanged = end_valid
                    && self.version[i] == 0
                    && !matches!(p, Partner::Body(j) if self.version[j as usize] != 0);
                if unchanged && end.is_none_or(|c| c.depth <= slop) {
                    continue;
                }
                let (ca, cb) = self.class_pair(w, a, p);
                if !matches!(w.config.classes.rule(ca, cb), Rule::Bounce { .. } | Rule::Slide | Rule::Stop) {
                    continue;
                }
                let pa = w.bodies.pos[i];
                let (pb, inv_mb) = match p {
                    Partner::Body(j) => (w.bodies.pos[j as usize], w.bodies.inv_mass[j as usize]),
                    Partner::Static(s) => (w.statics.pos[s as usize], 0.0),
                    Partner::Terrain => (DVec3::ZERO, 0.0),
                };
                let Some(c) = self.contact(w, i, pa, p, pb, 0.0) else { continue };
                if c.depth <= slop {
                    continue;
                }
                let inv_ma = w.bodies.inv_mass[i];
                let inv_sum = inv_ma + inv_mb;
                if inv_sum == 0.0 {
                    continue;
                }
                let push = c.normal * (c.depth - 0.5 * slop);
                w.bodies.pos[i] -= push * (inv_ma / inv_sum);
                let vb = match p {
                    Partner::Body(j) => {
                        w.bodies.pos[j as usize] += push * (inv_mb / inv_sum);
                        w.bodies.vel[j as usize]
                    }
                    _ => DVec3::ZERO,
                };
                let closing = -(vb - w.bodies.vel[i]).dot(c.normal);
                if closing > 0.0 {
                    let jn = closing / inv_sum;
                    w.bodies.vel[i] -= c.normal * (jn * inv_ma);
                    if let Partner::Body(j) = p {
                        w.bodies.vel[j as usize] += c.normal * (jn * inv_mb);
                    }
                }
                // Their end-of-tick contacts must be recomputed for events.
                self.version[i] += 1;
                self.settled.push(a);
                if let Partner::Body(j) = p {
                    self.version[j as usize] += 1;
                    self.settled.push(j);
                }
                moved = true;
            }
            if !moved {
                break;
            }
            // A body pushed out of one contact may have been pushed into something that was not
            // a partner this tick: give it the partners its new position reaches.
            let mut pushed = std::mem::take(&mut self.settled);
            pushed.sort_unstable();
            pushed.dedup();
            for &body in &pushed {
                let i = body as usize;
                let here = w.bodies.shape[i].world_aabb(w.bodies.pos[i], w.bodies.rot[i]).inflated(slop);
                let mut buf = std::mem::take(&mut self.query_buf);
                self.broadphase.query(&self.aabbs, &here, &mut buf);
                for &j in &buf {
                    if j != body && !self.dead[j as usize] {
                        self.add_candidate(body.min(j), Partner::Body(body.max(j)));
                    }
                }
                self.query_buf = buf;
                if self.plan.statics || self.plan.terrain {
                    self.static_partners(w, body, here);
                    for k in 0..self.partner_buf.len() {
                        self.add_candidate(body, self.partner_buf[k]);
                    }
                    self.aabbs[i] = self.aabbs[i].union(&here);
                }
            }
            pushed.clear();
            self.settled = pushed;
        }
    }

    /// A body's path changed mid-step: test its new path against everything it can reach.
    fn requery(&mut self, w: &World, body: u32, tests: &mut u32) {
        let i = body as usize;
        if self.dead[i] {
            return;
        }
        let b = &w.bodies;
        let t = self.t0[i];
        let p_now = self.base[i];
        let p_end = self.pos_at(w, i, 1.0);
        let a0 = b.shape[i].world_aabb(p_now, b.rot[i]);
        let swept = a0.union(&a0.translated(p_end - p_now)).inflated(w.config.contact_slop_m);
        // Other dynamic bodies: their full-step boxes still bound them unless they changed too,
        // in which case they were (or will be) re-queried themselves.
        let mut buf = std::mem::take(&mut self.query_buf);
        self.broadphase.query(&self.aabbs, &swept, &mut buf);
        for &j in &buf {
            if j == body || self.dead[j as usize] {
                continue;
            }
            if w.config.classes.rule(b.class[i], b.class[j as usize]) == Rule::Ignore {
                continue;
            }
            let (lo, hi) = (body.min(j), body.max(j));
            let from = t.max(self.t0[j as usize]);
            if let Some(imp) = self.impact(w, lo, Partner::Body(hi), from, tests) {
                self.schedule(w, imp);
            }
        }
        self.query_buf = buf;
        self.aabbs[i] = self.aabbs[i].union(&swept);
        if self.plan.statics || self.plan.terrain {
            self.static_partners(w, body, swept);
            for k in 0..self.partner_buf.len() {
                let p = self.partner_buf[k];
                if let Some(imp) = self.impact(w, body, p, t, tests) {
                    self.schedule(w, imp);
                }
                self.add_candidate(body, p);
            }
        }
        // Make sure the pair list used for end-of-tick touching includes new partners.
        for k in 0..self.query_buf.len() {
            let j = self.query_buf[k];
            if j != body && !self.dead[j as usize] {
                self.add_candidate(body.min(j), Partner::Body(body.max(j)));
            }
        }
    }

    /// Queues an impact: triggers aside (they change no path), the rest on the heap.
    fn schedule(&mut self, w: &World, imp: Impact) {
        if self.is_trigger(w, &imp) {
            self.triggers.push(imp);
        } else {
            let index = self.impacts.len() as u32;
            self.heap.push(Queued { t: imp.t, a: imp.a, b: imp.b, ver_a: imp.ver_a, ver_b: imp.ver_b, index });
            self.impacts.push(imp);
        }
    }

    /// Builds the touching set at the end of the tick and turns the tick's story into begin,
    /// end and destroy events.
    fn finish_events(&mut self, w: &mut World, out: &mut TickOutput) {
        let cfg = w.config.clone();
        let slop = cfg.contact_slop_m;
        let tick = w.tick;
        let b = &w.bodies;
        // Touching at the end: every candidate pair still alive, within the slop. A pair whose
        // paths never changed reuses the end contact found with its time of impact. (Pairs
        // found twice mid-step give duplicate entries, removed below.)
        self.touching_now.clear();
        let mut end_records = std::mem::take(&mut self.end_records);
        end_records.clear();
        for cand in &self.candidates {
            let (a, p) = (cand.a, cand.b);
            let i = a as usize;
            if self.dead[i] || matches!(p, Partner::Body(j) if self.dead[j as usize]) {
                continue;
            }
            let (id_b, class_b) = match p {
                Partner::Body(j) => (b.id[j as usize], b.class[j as usize]),
                Partner::Static(s) => (w.statics.id[s as usize], w.statics.class[s as usize]),
                Partner::Terrain => {
                    let t = w.statics.terrain.as_ref().expect("terrain");
                    (t.id, t.class)
                }
            };
            let pa = b.pos[i];
            let pb = match p {
                Partner::Body(j) => b.pos[j as usize],
                Partner::Static(s) => w.statics.pos[s as usize],
                Partner::Terrain => DVec3::ZERO,
            };
            let unchanged = cand.end_valid
                && self.version[i] == 0
                && !matches!(p, Partner::Body(j) if self.version[j as usize] != 0);
            let end = if unchanged { cand.end } else { self.contact(w, i, pa, p, pb, slop) };
            if let Some(c) = end {
                let vb = match p {
                    Partner::Body(j) => b.vel[j as usize],
                    _ => DVec3::ZERO,
                };
                end_records.push(PairRecord {
                    key: (b.id[i], id_b),
                    t: 1.0,
                    point: pa + c.point,
                    normal_lo_hi: c.normal,
                    depth: c.depth.max(0.0),
                    closing: -(vb - b.vel[i]).dot(c.normal),
                    response: response_of(cfg.classes.rule(b.class[i], class_b)),
                });
            }
        }
        // Three sorted lists, walked together by pair key: P, the pairs touching before; E, the
        // pairs touching now that were tested (`end_records`); R, this tick's impacts (the
        // first per pair). A linear merge instead of a lookup per pair keeps this stage O(n).
        // E is sorted as 16-byte (packed key, index) entries rather than 88-byte records; of
        // a pair tested twice, the first tested stays.
        let key_of = |r: &PairRecord| ordered(r.key.0, r.key.1);
        let pack = |(a, b): (EntityId, EntityId)| u64::from(a.0) << 32 | u64::from(b.0);
        let unpack = |k: u64| (EntityId((k >> 32) as u32), EntityId(k as u32));
        let mut end_order = std::mem::take(&mut self.end_order);
        end_order.clear();
        end_order.extend(end_records.iter().enumerate().map(|(k, r)| (pack(key_of(r)), k as u32)));
        end_order.sort_unstable();
        end_order.dedup_by_key(|e| e.0);
        self.records.sort_by(|x, y| key_of(x).cmp(&key_of(y)).then(x.t.total_cmp(&y.t)));
        self.records.dedup_by(|x, y| key_of(x) == key_of(y)); // keeps the earliest impact
                                                              // Resting pairs were not candidates: they keep touching while both ends stay put.
        let still = |id: EntityId| match b.slot(id) {
            Some(s) => !self.dead[s] && !self.moving[s],
            None => true, // static or terrain
        };
        let prev = &w.touching;
        let (mut ip, mut ie, mut ir) = (0, 0, 0);
        loop {
            let kp = prev.get(ip).copied();
            let ke = end_order.get(ie).map(|e| unpack(e.0));
            let kr = self.records.get(ir).map(key_of);
            let Some(key) = [kp, ke, kr].into_iter().flatten().min() else { break };
            let was = kp == Some(key);
            let tested = ke == Some(key);
            let impact = if kr == Some(key) { Some(self.records[ir]) } else { None };
            let end = if tested { Some(end_records[end_order[ie].1 as usize]) } else { None };
            let now = tested || (was && impact.is_none() && still(key.0) && still(key.1));
            if now {
                self.touching_now.push(key);
            }
            match (was, impact) {
                (false, Some(r)) => {
                    // A new contact: it begins at its time of impact, and ends in the same tick
                    // if the pair bounced apart.
                    out.events.push(event(tick, &r, Phase::Begin));
                    if !now {
                        out.events.push(event(tick, &r, Phase::End));
                    }
                }
                (false, None) => {
                    if let Some(e) = end {
                        // Touching now with no impact (slid or grew into contact).
                        out.events.push(event(tick, &e, Phase::Begin));
                    }
                }
                (true, Some(r)) => {
                    // A continuing contact: only its end is news (destroyed, or bounced apart).
                    if r.response == Response::Destroy || !now {
                        out.events.push(event(tick, &r, Phase::End));
                    }
                }
                (true, None) => {
                    if !now {
                        out.events.push(end_without_contact(w, tick, key, &self.dead));
                    }
                }
            }
            ip += usize::from(was);
            ie += usize::from(tested);
            ir += usize::from(impact.is_some());
        }
        out.events.sort_by(|x, y| {
            x.toi.total_cmp(&y.toi).then(x.a.cmp(&y.a)).then(x.b.cmp(&y.b)).then(x.phase.cmp(&y.phase))
        });
        out.events.dedup_by(|x, y| x.key() == y.key());
        w.touching.clear();
        w.touching.extend_from_slice(&self.touching_now);
        self.end_records = end_records;
        self.end_order = end_order;
    }
}

/// Approach speed of an impact's pair along its normal (positive when closing), m/s.
fn closing_speed(w: &World, imp: &Impact) -> f64 {
    let vb = match imp.b {
        Partner::Body(j) => w.bodies.vel[j as usize],
        _ => DVec3::ZERO,
    };
    -(vb - w.bodies.vel[imp.a as usize]).dot(imp.contact.normal)
}

/// Whether the pair of an impact is moving apart along its normal.
fn separating(w: &World, imp: &Impact) -> bool {
    closing_speed(w, imp) <= 0.0
}

/// Convex contact with the plan's kernel choice (analytic, or GJK when the plan forces the
/// general path). Triangle meshes always take the mesh kernel.
fn convex_contact(plan: &Plan, a: &Shape, ra: DQuat, b: &Shape, rb: DQuat, d: DVec3, margin: f64) -> Option<Contact> {
    if plan.force_general && Kernel::for_pair(a.kind(), b.kind()) != Kernel::Mesh {
        return narrow::general::contact(a, ra, b, rb, d, margin);
    }
    narrow::contact(a, ra, b, rb, d, margin)
}

fn ordered(a: EntityId, b: EntityId) -> (EntityId, EntityId) {
    if a <= b {
        (a, b)
    } else {
        (b, a)
    }
}

fn response_of(rule: Rule) -> Response {
    match rule {
        Rule::Ignore | Rule::Trigger => Response::Trigger,
        Rule::Bounce { .. } => Response::Bounce,
        Rule::Slide => Response::Slide,
        Rule::Stop => Response::Stop,
        Rule::Destroy { .. } => Response::Destroy,
    }
}

fn event(tick: impact_protocol::Tick, r: &PairRecord, phase: Phase) -> CollisionEvent {
    // Events name the lower id first, with the normal pointing from it to the other.
    let (a, b, normal) =
        if r.key.0 <= r.key.1 { (r.key.0, r.key.1, r.normal_lo_hi) } else { (r.key.1, r.key.0, -r.normal_lo_hi) };
    CollisionEvent {
        tick,
        toi: r.t.clamp(0.0, 1.0),
        a,
        b,
        point: r.point.to_array(),
        normal: normal.to_array(),
        depth_m: r.depth,
        closing_speed_mps: r.closing,
        phase,
        response: r.response,
        status: EventStatus::Provisional,
    }
}

/// An end event for a pair that moved apart so far this tick that it was not even a broadphase
/// candidate: the point is between the two centres, the normal along them.
fn end_without_contact(
    w: &World,
    tick: impact_protocol::Tick,
    key: (EntityId, EntityId),
    dead: &[bool],
) -> CollisionEvent {
    let pos = |id: EntityId| -> DVec3 {
        if let Some(s) = w.bodies.slot(id) {
            return w.bodies.pos[s];
        }
        match w.statics.id.binary_search(&id) {
            Ok(s) => w.statics.pos[s],
            Err(_) => DVec3::ZERO,
        }
    };
    let (pa, ca) = (pos(key.0), w.class_of(key.0));
    let (pb, cb) = (pos(key.1), w.class_of(key.1));
    let destroyed = [key.0, key.1].iter().any(|id| w.bodies.slot(*id).is_some_and(|s| dead[s]));
    let response = match (ca, cb) {
        _ if destroyed => Response::Destroy,
        (Some(a), Some(b)) => response_of(w.config.classes.rule(a, b)),
        _ => Response::Trigger,
    };
    CollisionEvent {
        tick,
        toi: 1.0,
        a: key.0,
        b: key.1,
        point: ((pa + pb) * 0.5).to_array(),
        normal: (pb - pa).normalize_or(DVec3::Y).to_array(),
        depth_m: 0.0,
        closing_speed_mps: 0.0,
        phase: Phase::End,
        response,
        status: EventStatus::Provisional,
    }
}
