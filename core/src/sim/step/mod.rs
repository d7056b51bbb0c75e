//! One tick: inputs, integration, broadphase on swept bounds, time of impact, resolution in
//! time-of-impact order, settling, begin/end events. The result is a function of the world and
//! the inputs only; [`Stepper`] holds reusable buffers and counters, never state that changes a
//! result.
//!
//! [`Stepper::step_with`] reads as the list of stages; each stage is a file here, and its timer
//! in [`StageStats`] has the file's name: `integrate`, `contacts`, `broadphase`, `narrowphase`,
//! `resolve`, `settle`, `events`, `sleep`.

mod broadphase;
mod contacts;
mod events;
mod integrate;
mod narrowphase;
mod resolve;
mod settle;
mod sleep;

use crate::broadphase::grid::Grid;
use crate::broadphase::Broadphase;
use crate::geometry::{Aabb, Shape};
use crate::narrow::{self, Contact, Kernel};
use crate::sim::input::{self, TickInput};
use crate::sim::plan::Plan;
use crate::sim::world::{ClassId, Rule, TouchHint, World};
use glam::{DQuat, DVec3};
use impact_protocol::{EntityId, Response};
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::time::{Duration, Instant};

/// The other side of a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Partner {
    /// A dynamic body (slot).
    Body(u32),
    /// A static body (index into the static world).
    Static(u32),
    /// The terrain.
    Terrain,
}

impl Partner {
    /// The dynamic slot, or [`TouchHint::NOT_A_BODY`].
    fn slot(self) -> u32 {
        match self {
            Partner::Body(j) => j,
            _ => TouchHint::NOT_A_BODY,
        }
    }
}

/// Time spent per stage and work counted, for the last tick and accumulated.
#[derive(Clone, Debug, Default)]
pub struct StageStats {
    /// Applying inputs (and ray queries).
    pub inputs: Duration,
    /// Wakes and gravity.
    pub integrate: Duration,
    /// The resting-contact solver.
    pub contacts: Duration,
    /// Swept bounds and broadphase.
    pub broadphase: Duration,
    /// Narrowphase and time of impact.
    pub narrowphase: Duration,
    /// Resolution.
    pub resolve: Duration,
    /// Final positions and the settle passes.
    pub settle: Duration,
    /// Still timers, islands and falling asleep.
    pub sleep: Duration,
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
    /// Bodies awake at the end of the last tick.
    pub awake: u32,
    /// Bodies asleep at the end of the last tick.
    pub asleep: u32,
    /// Ticks skipped whole because every body slept, since start.
    pub idle_ticks: u64,
}

impl StageStats {
    /// `(name, total time)` per stage, in tick order.
    pub fn stages(&self) -> [(&'static str, Duration); 9] {
        [
            ("inputs", self.inputs),
            ("integrate", self.integrate),
            ("contacts", self.contacts),
            ("broadphase", self.broadphase),
            ("narrowphase", self.narrowphase),
            ("resolve", self.resolve),
            ("settle", self.settle),
            ("events", self.events),
            ("sleep", self.sleep),
        ]
    }
}

use crate::par::Pool;
use crate::sim::output::TickOutput;

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
}

impl Cand {
    fn new(a: u32, b: Partner) -> Cand {
        Cand { a, b }
    }
}

/// A candidate's answers from the narrowphase: its first contact over the step, its contact at
/// the end of the step, and the overlap tests spent.
#[derive(Clone, Copy, Debug)]
struct Found {
    imp: Option<Impact>,
    end: Option<Contact>,
    tests: u32,
}

/// One pair's story this tick, for events.
#[derive(Clone, Copy, Debug)]
struct PairRecord {
    key: (EntityId, EntityId),
    /// The dynamic slots of `key`'s two sides ([`TouchHint::NOT_A_BODY`] for static geometry and
    /// terrain).
    slots: [u32; 2],
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
    /// Threads for the stages that are maps over bodies or pairs.
    pool: Pool,
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
    /// Moving bodies' static and terrain partners, before they join `candidates`.
    static_cands: Vec<Cand>,
    /// The narrowphase's answers, by candidate (candidates found later in the tick have none).
    found: Vec<Found>,
    /// The candidates a settle pass may push, by index.
    pushable: Vec<u32>,
    /// Settle's stamps: per body, the sequence number of its last push this tick; per pushable
    /// entry, the number a check that needed no push was made at (0: not yet).
    last_push: Vec<u64>,
    checked_at: Vec<u64>,
    heap: BinaryHeap<Queued>,
    impacts: Vec<Impact>,
    triggers: Vec<Impact>,
    records: Vec<PairRecord>,
    end_records: Vec<PairRecord>,
    end_order: Vec<(u64, u32)>,
    record_order: Vec<(u64, i64, u32)>,
    touching_now: Vec<crate::sim::world::Touch>,
    query_buf: Vec<u32>,
    static_buf: Vec<u32>,
    partner_buf: Vec<Partner>,
    settled: Vec<u32>,
    /// Awake bodies after this tick's wakes (set by `integrate`).
    awake: usize,
    wake_seeds: Vec<u32>,
    /// The character controller's buffers.
    characters: crate::sim::character::Scratch,
    islands: crate::sim::island::Islands,
    rows: Vec<contacts::Row>,
    contact_impulse: Vec<(f64, DVec3)>,
    /// Slots of `World::touching`'s pairs as the tick began (set by `contacts`).
    touch_slots: Vec<[Option<u32>; 2]>,
    /// The slots of the touching list this stepper last wrote, by entry (see
    /// [`World::touching_slots`]).
    touch_hints: Vec<TouchHint>,
    touch_hints_next: Vec<TouchHint>,
    /// Sleepers are kept out of the broadphase method this tick (see `dynamic_pairs`).
    split: bool,
    /// When split: the slots the broadphase method holds (ascending) and their boxes.
    bp_slots: Vec<u32>,
    bp_boxes: Vec<Aabb>,
    /// The sleeping bodies' boxes `(box, slot)` that `sleepers` was built from, the boxes alone,
    /// and the index (a grid: sleepers barely overlap, and it is rebuilt only on change).
    sleeper_boxes: Vec<(Aabb, u32)>,
    sleeper_scratch: Vec<(Aabb, u32)>,
    sleeper_only: Vec<Aabb>,
    sleepers: Grid,
}

impl Stepper {
    /// A stepper for `plan`. With `profile`, stage times are measured (the clock is read only
    /// for the statistics; it never reaches a result).
    pub fn new(plan: Plan, profile: bool) -> Stepper {
        Stepper {
            broadphase: Broadphase::new(plan.broadphase),
            plan,
            pool: Pool::sequential(),
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
            static_cands: Vec::new(),
            found: Vec::new(),
            pushable: Vec::new(),
            last_push: Vec::new(),
            checked_at: Vec::new(),
            heap: BinaryHeap::new(),
            impacts: Vec::new(),
            triggers: Vec::new(),
            records: Vec::new(),
            end_records: Vec::new(),
            end_order: Vec::new(),
            record_order: Vec::new(),
            touching_now: Vec::new(),
            query_buf: Vec::new(),
            static_buf: Vec::new(),
            partner_buf: Vec::new(),
            settled: Vec::new(),
            awake: 0,
            wake_seeds: Vec::new(),
            characters: Default::default(),
            islands: Default::default(),
            rows: Vec::new(),
            contact_impulse: Vec::new(),
            touch_slots: Vec::new(),
            touch_hints: Vec::new(),
            touch_hints_next: Vec::new(),
            split: false,
            bp_slots: Vec::new(),
            bp_boxes: Vec::new(),
            sleeper_boxes: Vec::new(),
            sleeper_scratch: Vec::new(),
            sleeper_only: Vec::new(),
            sleepers: Grid::default(),
        }
    }

    /// Runs the parallel stages on `pool` from now on (results do not change).
    pub fn set_pool(&mut self, pool: Pool) {
        self.pool = pool;
    }

    /// The threads in use.
    pub fn pool(&self) -> &Pool {
        &self.pool
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
    ///
    /// The tick is this list of stages, one file each, timed under the same names.
    pub fn step_with(
        &mut self,
        w: &mut World,
        system: &[input::SystemAction],
        inputs: &[TickInput],
        out: &mut TickOutput,
    ) {
        let pool = self.pool.clone();
        pool.run(w.bodies.len(), || self.stages(w, system, inputs, out));
    }

    /// The stages of [`Stepper::step_with`], on a thread of the pool.
    fn stages(&mut self, w: &mut World, system: &[input::SystemAction], inputs: &[TickInput], out: &mut TickOutput) {
        out.events.clear();
        out.rays.clear();
        out.skipped.clear();
        out.spawned.clear();
        let mut stats = std::mem::take(&mut self.stats);
        let mut clock = self.profile.then(Instant::now);

        // 1. The server's actions, then inputs, then hitscan against the world as it stands at
        //    the start of the tick.
        let first_new = w.next_entity;
        input::apply_system(w, system, out);
        input::apply(w, inputs, out);
        self.lap(&mut clock, |s| &mut s.inputs, &mut stats);
        // 2. Wakes and gravity.
        self.integrate(w);
        self.lap(&mut clock, |s| &mut s.integrate, &mut stats);
        // 3. Resting contacts held before anything moves.
        self.solve_contacts(w);
        self.lap(&mut clock, |s| &mut s.contacts, &mut stats);
        self.swept_bounds(w, first_new);
        if self.awake == 0 {
            // Every body asleep and nothing woke one: nothing can move, touch or end.
            events::sort_events(&mut out.events);
            stats.pairs_tested = 0;
            stats.resolutions = 0;
            stats.toi_tests = 0;
            stats.idle_ticks += 1;
            self.lap(&mut clock, |s| &mut s.broadphase, &mut stats);
            self.finish_tick(w, clock, stats);
            return;
        }
        // 4. Pairs that may touch: dynamic pairs, then statics and terrain for moving bodies.
        self.find_candidates(w);
        self.lap(&mut clock, |s| &mut s.broadphase, &mut stats);
        // 5. First contact and end-of-step contact for every candidate.
        self.narrowphase(w, &mut stats);
        self.lap(&mut clock, |s| &mut s.narrowphase, &mut stats);
        // 6. Impacts in time-of-impact order.
        self.resolve_impacts(w, &mut stats);
        self.lap(&mut clock, |s| &mut s.resolve, &mut stats);
        // 7. Final positions, then what resolution left overlapping.
        self.settle(w);
        self.lap(&mut clock, |s| &mut s.settle, &mut stats);
        // 8. Touching set, begin/end events, removals.
        self.finish_events(w, out);
        self.lap(&mut clock, |s| &mut s.events, &mut stats);
        // 9. Still timers; islands that stayed still long enough fall asleep.
        self.sleep(w);
        self.finish_tick(w, clock, stats);
    }

    /// Counts, times the sleep stage, and moves the world to its next tick.
    fn finish_tick(&mut self, w: &mut World, mut clock: Option<Instant>, mut stats: StageStats) {
        let (awake, asleep) = w.awake_asleep();
        stats.awake = awake as u32;
        stats.asleep = asleep as u32;
        self.lap(&mut clock, |s| &mut s.sleep, &mut stats);
        w.tick = w.tick.next();
        stats.ticks += 1;
        self.stats = stats;
    }

    /// The contact at the end of the step that the narrowphase found for candidate `k` (`None`
    /// inside: apart), while neither body's path has changed since; `None` when it must be
    /// computed again.
    fn end_if_unchanged(&self, k: usize) -> Option<Option<Contact>> {
        let found = self.found.get(k)?;
        let Cand { a, b } = self.candidates[k];
        let changed = self.version[a as usize] != 0 || matches!(b, Partner::Body(j) if self.version[j as usize] != 0);
        (!changed).then_some(found.end)
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

    fn class_pair(&self, w: &World, a: u32, p: Partner) -> (ClassId, ClassId) {
        let ca = w.bodies.class[a as usize];
        let cb = match p {
            Partner::Body(j) => w.bodies.class[j as usize],
            Partner::Static(s) => w.statics.class[s as usize],
            Partner::Terrain => w.statics.terrain.as_ref().map_or(ca, |t| t.class),
        };
        (ca, cb)
    }
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
