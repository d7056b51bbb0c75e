//! The world state: dynamic bodies as struct-of-arrays, the immutable static part (shared by
//! every snapshot through an `Arc`), and the class table that decides responses.

use crate::broadphase::StaticIndex;
use crate::geometry::{Aabb, Shape};
use crate::par::{Pool, MIN_PIECE_HEAVY};
use crate::terrain::heightfield::HeightField;
use crate::toi::bisect::BisectConfig;
use glam::{DQuat, DVec3};
use impact_protocol::{ClientId, EntityId, GameState, Tick};
use std::sync::Arc;

/// Index into the class table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ClassId(pub u16);

/// What happens when two classes meet. Stored per ordered pair of classes; `Destroy` names the
/// bodies that go, relative to that order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rule {
    /// No test at all: the pair is filtered out before the narrowphase.
    Ignore,
    /// An event only; bodies pass through each other.
    Trigger,
    /// Reflect velocities along the normal with this restitution (0 = inelastic, 1 = elastic).
    Bounce {
        /// Coefficient of restitution in [0, 1].
        restitution: f64,
    },
    /// Remove the approaching normal velocity and keep moving tangentially for the rest of the
    /// step (players on walls).
    Slide,
    /// The moving bodies stop at the contact.
    Stop,
    /// Remove the first and/or second body.
    Destroy {
        /// Remove the body of the row class.
        first: bool,
        /// Remove the body of the column class.
        second: bool,
        /// If set, the surviving body bounces off the destroyed one with this restitution
        /// (breakout's ball off a brick); if not, it passes on.
        restitution: Option<f64>,
    },
}

impl Rule {
    /// Whether the rule stops the two bodies in each other, so that what is left overlapping is
    /// pushed apart at the end of the tick.
    pub fn stops(self) -> bool {
        matches!(self, Rule::Bounce { .. } | Rule::Slide | Rule::Stop)
    }

    /// The same rule seen from the other body's side.
    pub fn swapped(self) -> Rule {
        match self {
            Rule::Destroy { first, second, restitution } => Rule::Destroy { first: second, second: first, restitution },
            other => other,
        }
    }
}

/// Per-class properties.
#[derive(Clone, Debug, PartialEq)]
pub struct ClassProps {
    /// Class name from the scene.
    pub name: String,
    /// Static geometry: never moves, never tested against other static geometry.
    pub is_static: bool,
    /// Largest speed an input may set, m/s.
    pub max_speed_mps: f64,
    /// Whether gravity applies.
    pub gravity: bool,
    /// Density for bodies spawned without a mass, kg/m^3.
    pub density_kg_m3: f64,
    /// Whether bodies of this class may fall asleep.
    pub can_sleep: bool,
    /// The controller, if its bodies are characters (see [`crate::sim::character`]).
    pub character: Option<CharacterProps>,
}

/// A character class's controller, resolved (the scene's degrees and heights already turned
/// into the numbers the tick uses, so a client receives them as they are).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CharacterProps {
    /// Speed on the ground at a full `move`, m/s.
    pub walk_speed_mps: f64,
    /// The vertical speed a jump starts with, m/s.
    pub jump_speed_mps: f64,
    /// Ground is walkable where its normal's component along up is at least this.
    pub min_ground_normal_up: f64,
    /// The highest ledge it walks onto without a jump, m.
    pub step_height_m: f64,
    /// The fraction of the horizontal difference a `move` makes up in the air.
    pub air_control: f64,
}

/// The class table: properties and the response rule for every ordered pair.
#[derive(Clone, Debug, PartialEq)]
pub struct Classes {
    /// Properties by [`ClassId`].
    pub props: Vec<ClassProps>,
    rules: Vec<Rule>,
}

impl Classes {
    /// A table where every pair follows `default`.
    pub fn new(props: Vec<ClassProps>, default: Rule) -> Classes {
        let n = props.len();
        Classes { props, rules: vec![default; n * n] }
    }

    /// Sets the rule for `(a, b)` and its mirror for `(b, a)`.
    pub fn set_rule(&mut self, a: ClassId, b: ClassId, rule: Rule) {
        let n = self.props.len();
        self.rules[a.0 as usize * n + b.0 as usize] = rule;
        self.rules[b.0 as usize * n + a.0 as usize] = rule.swapped();
    }

    /// Sets the rule for the ordered pair `(a, b)` only (a table read whole, both orders given).
    pub(crate) fn set_one(&mut self, a: ClassId, b: ClassId, rule: Rule) {
        let n = self.props.len();
        self.rules[a.0 as usize * n + b.0 as usize] = rule;
    }

    /// The rule when a body of class `a` meets one of class `b`.
    #[inline]
    pub fn rule(&self, a: ClassId, b: ClassId) -> Rule {
        self.rules[a.0 as usize * self.props.len() + b.0 as usize]
    }

    /// Whether some pair of classes has a rule that stops bodies in each other ([`Rule::Bounce`],
    /// [`Rule::Slide`], [`Rule::Stop`]): the only pairs the settle passes push apart. A world of
    /// triggers, say, has none, and its tick skips asking every pair.
    pub(crate) fn any_stopping(&self) -> bool {
        self.rules.iter().any(|r| r.stops())
    }

    /// Looks a class up by name.
    pub fn by_name(&self, name: &str) -> Option<ClassId> {
        self.props.iter().position(|p| p.name == name).map(|i| ClassId(i as u16))
    }

    /// Number of classes.
    pub fn len(&self) -> usize {
        self.props.len()
    }

    /// Whether the table is empty.
    pub fn is_empty(&self) -> bool {
        self.props.is_empty()
    }
}

/// Simulation settings fixed for a run.
#[derive(Clone, Debug)]
pub struct SimConfig {
    /// Ticks per second.
    pub tick_hz: u32,
    /// Step length, seconds (`1 / tick_hz`; exact in binary for powers of two such as 64).
    pub dt: f64,
    /// Gravity, m/s^2, world frame.
    pub gravity: DVec3,
    /// Classes and responses.
    pub classes: Classes,
    /// Time-of-impact search settings.
    pub bisect: BisectConfig,
    /// Two bodies closer than this (m) count as touching for begin/end events.
    pub contact_slop_m: f64,
    /// Closing speeds at or below this (m/s) get no rebound: a resting contact.
    pub bounce_threshold_mps: f64,
    /// Most contact resolutions per tick (bounds the work a pathological pile can cause).
    pub max_resolutions_per_tick: u32,
    /// Coulomb friction coefficient of resting contacts (a body on a support): the tangential
    /// speed a support removes per tick is at most this times the normal speed it cancels.
    pub friction: f64,
    /// A body slower than this (m/s) counts as still, for sleeping.
    pub sleep_speed_mps: f64,
    /// An island whose bodies have all been still this many ticks falls asleep (0: never).
    pub sleep_after_ticks: u32,
    /// Under gravity, islands also sleep in parts, from the bottom up ([`crate::sim::island`]).
    pub partial_sleep: bool,
    /// Most bodies the world may hold (spawns beyond it are refused).
    pub max_bodies: u32,
    /// Rollback window in ticks.
    pub window_ticks: u32,
    /// How far ahead of the server an input's tick may be, ticks.
    pub input_lead_ticks: u32,
    /// How far back a hitscan ray may be rewound, ticks (also bounded by the history window).
    pub max_rewind_ticks: u32,
    /// The class of client-spawned projectiles (`None`: spawning is refused).
    pub projectile_class: Option<ClassId>,
}

impl SimConfig {
    /// The direction "down" when islands sleep in parts ([`crate::sim::island`]): gravity, when
    /// `partial_sleep` is set and there is gravity; `None` otherwise.
    pub fn sleeps_in_parts(&self) -> Option<DVec3> {
        (self.partial_sleep && self.gravity != DVec3::ZERO).then_some(self.gravity)
    }
}

/// Ticks of history a rollback window of `rollback_ms` holds at `tick_hz` (rounded up, so the
/// window is never shorter than asked).
pub fn window_ticks(rollback_ms: u32, tick_hz: u32) -> u32 {
    (u64::from(rollback_ms) * u64::from(tick_hz)).div_ceil(1000) as u32
}

/// Static geometry and terrain: immutable for the run, shared by every snapshot.
#[derive(Debug)]
pub struct StaticWorld {
    /// Entity ids, ascending.
    pub id: Vec<EntityId>,
    /// Classes.
    pub class: Vec<ClassId>,
    /// Shapes.
    pub shape: Vec<Shape>,
    /// Positions, m.
    pub pos: Vec<DVec3>,
    /// Orientations.
    pub rot: Vec<DQuat>,
    /// World bounds of each static body.
    pub aabb: Vec<Aabb>,
    /// BVH over `aabb`.
    pub index: StaticIndex,
    /// The height field, if the scene has terrain.
    pub terrain: Option<Terrain>,
}

/// Height-field terrain as an entity.
#[derive(Debug)]
pub struct Terrain {
    /// Its entity id.
    pub id: EntityId,
    /// Its class.
    pub class: ClassId,
    /// The surface.
    pub field: HeightField,
}

/// What a dynamic body keeps for its life: everything but position and velocity. Shared by
/// every snapshot through an `Arc` and copied only when a body is added or removed, so a
/// snapshot of the world costs two arrays, not eleven.
#[derive(Clone, Debug, Default)]
pub struct BodyTable {
    /// Entity ids, strictly ascending.
    pub id: Vec<EntityId>,
    /// Classes.
    pub class: Vec<ClassId>,
    /// Shapes.
    pub shape: Vec<Shape>,
    /// Bounding radius of each shape, m.
    pub radius: Vec<f64>,
    /// World-frame bounds of each shape relative to its position (lower corner), m. Fixed,
    /// because orientations are.
    pub aabb_lo: Vec<DVec3>,
    /// Upper corner of the same, m.
    pub aabb_hi: Vec<DVec3>,
    /// Fixed orientations.
    pub rot: Vec<DQuat>,
    /// Inverse masses, 1/kg (0 = immovable but not static: it can still be destroyed).
    pub inv_mass: Vec<f64>,
    /// Owning client, if any.
    pub owner: Vec<Option<ClientId>>,
    /// Game state, as game logic set it: no part of the physics, but of the world (rolled
    /// back, replayed, hashed). Each body's behind its own `Arc`, so the copy of the table
    /// that game logic's first command of a tick makes shares every state but the one it sets
    /// (copying every map was 9 % of the tick thread's time in a 300-player deathmatch).
    pub game: Vec<Arc<GameState>>,
    /// The tick of each body's last teleport (game logic's), if any: where its path breaks, so
    /// that no client draws or predicts across it.
    pub teleported: Vec<Option<Tick>>,
}

/// A pair touching at the end of a tick: the contact cache a resting body's support is read
/// from at the next tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Touch {
    /// The lower entity id.
    pub a: EntityId,
    /// The higher entity id.
    pub b: EntityId,
    /// Unit contact normal, world frame, pointing from `a` to `b`.
    pub normal: DVec3,
    /// Overlap at the end of the tick, m (0 when only within the slop).
    pub depth: f64,
    /// Normal impulse the resting-contact solver last needed to hold the pair, N s (its warm
    /// start at the next tick; 0 for a new contact).
    pub impulse: f64,
    /// Friction impulse it last needed, N s, world frame (its warm start likewise).
    pub friction_impulse: DVec3,
}

/// Where a touching pair's two sides were when the list was written: dynamic slots, or
/// [`TouchHint::NOT_A_BODY`]. See [`World::touching_slots`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct TouchHint {
    /// The pair, as [`Touch::key`].
    pub key: (EntityId, EntityId),
    /// The slots of `key.0` and `key.1`.
    pub slots: [u32; 2],
}

impl TouchHint {
    /// A side that is static geometry or terrain.
    pub(crate) const NOT_A_BODY: u32 = u32::MAX;
}

impl Touch {
    /// `(a, b)`: the order the touching list is sorted in.
    #[inline]
    pub fn key(&self) -> (EntityId, EntityId) {
        (self.a, self.b)
    }
}

/// Dynamic bodies, struct-of-arrays, sorted by ascending entity id (spawns append larger ids and
/// removals keep the order), so iteration order is the id order and never a hash order. The
/// per-body constants live in a shared [`BodyTable`] (reached through `Deref`: `bodies.id[i]`).
#[derive(Clone, Debug, Default)]
pub struct Bodies {
    /// Centre positions, world frame, m.
    pub pos: Vec<DVec3>,
    /// Velocities, m/s.
    pub vel: Vec<DVec3>,
    /// Asleep: not integrated, not a mover in the broadphase, no events; an obstacle for awake
    /// bodies. A sleeping body's velocity is zero.
    pub asleep: Vec<bool>,
    /// Consecutive ticks the body has ended slower than the sleep speed (saturating).
    pub still_ticks: Vec<u16>,
    table: Arc<BodyTable>,
}

impl std::ops::Deref for Bodies {
    type Target = BodyTable;
    fn deref(&self) -> &BodyTable {
        &self.table
    }
}

/// A body to add.
#[derive(Clone, Debug)]
pub struct NewBody {
    /// Class.
    pub class: ClassId,
    /// Shape.
    pub shape: Shape,
    /// Position, m.
    pub pos: DVec3,
    /// Velocity, m/s.
    pub vel: DVec3,
    /// Orientation.
    pub rot: DQuat,
    /// Inverse mass, 1/kg.
    pub inv_mass: f64,
    /// Owner.
    pub owner: Option<ClientId>,
}

impl Bodies {
    /// What the bodies keep for life, shared (a clone of the `Arc`, not of the table).
    pub fn table(&self) -> Arc<BodyTable> {
        self.table.clone()
    }

    /// Number of bodies.
    pub fn len(&self) -> usize {
        self.id.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.id.is_empty()
    }

    /// Changes the class of the body in `slot` (game logic's `set_class`; copies the shared
    /// table once if a snapshot still holds it).
    pub fn set_class(&mut self, slot: usize, class: ClassId) {
        Arc::make_mut(&mut self.table).class[slot] = class;
    }

    /// Records that the body in `slot` was teleported at `tick` (`None`: never was; a
    /// predictor taking the server's word).
    pub fn set_teleported(&mut self, slot: usize, tick: impl Into<Option<Tick>>) {
        Arc::make_mut(&mut self.table).teleported[slot] = tick.into();
    }

    /// Sets the game state of the body in `slot`.
    pub fn set_game(&mut self, slot: usize, state: GameState) {
        Arc::make_mut(&mut self.table).game[slot] = Arc::new(state);
    }

    /// The slot of an entity (binary search: ids are sorted).
    pub fn slot(&self, id: EntityId) -> Option<usize> {
        self.id.binary_search(&id).ok()
    }

    /// The slot of an entity, searched from `cursor` (the last answer's place, updated): for ids
    /// looked up in ascending order, as the sides of the sorted touching list mostly are, each
    /// costs a step or two instead of a binary search over every body. Same answers as
    /// [`Bodies::slot`].
    pub(crate) fn slot_from(&self, cursor: &mut usize, id: EntityId) -> Option<usize> {
        let ids = &self.id;
        let n = ids.len();
        let start = (*cursor).min(n);
        // p: the first place whose id is not below `id`.
        let p = if start == n || ids[start] >= id {
            if start == 0 || ids[start - 1] < id {
                start
            } else {
                ids[..start].partition_point(|&x| x < id)
            }
        } else {
            // Ahead of the cursor: gallop (1, 2, 4, ... places) past it, then search that span.
            let mut lo = start;
            let mut step = 1;
            let mut hi = start + 1;
            while hi < n && ids[hi] < id {
                lo = hi;
                step <<= 1;
                hi = lo + step;
            }
            let hi = hi.min(n);
            lo + 1 + ids[lo + 1..hi].partition_point(|&x| x < id)
        };
        *cursor = p;
        (p < n && ids[p] == id).then_some(p)
    }

    /// Appends a body with an id larger than every existing one.
    pub fn push(&mut self, id: EntityId, b: NewBody) {
        assert!(self.id.last().is_none_or(|&last| last < id), "entity ids must ascend");
        self.pos.push(b.pos);
        self.vel.push(b.vel);
        self.asleep.push(false);
        self.still_ticks.push(0);
        let t = Arc::make_mut(&mut self.table);
        t.id.push(id);
        t.class.push(b.class);
        t.radius.push(b.shape.bounding_radius());
        let bounds = b.shape.world_aabb(DVec3::ZERO, b.rot);
        t.aabb_lo.push(bounds.min);
        t.aabb_hi.push(bounds.max);
        t.shape.push(b.shape);
        t.rot.push(b.rot);
        t.inv_mass.push(b.inv_mass);
        t.owner.push(b.owner);
        t.game.push(Arc::default());
        t.teleported.push(None);
    }

    /// The bodies at `slots` (ascending), in that order: what [`Bodies::remove_flagged`] leaves
    /// of the rest, copying only what is kept.
    pub fn select(&self, slots: &[usize]) -> Bodies {
        fn pick<T: Clone>(v: &[T], slots: &[usize]) -> Vec<T> {
            slots.iter().map(|&k| v[k].clone()).collect()
        }
        let t = &self.table;
        Bodies {
            pos: pick(&self.pos, slots),
            vel: pick(&self.vel, slots),
            asleep: pick(&self.asleep, slots),
            still_ticks: pick(&self.still_ticks, slots),
            table: Arc::new(BodyTable {
                id: pick(&t.id, slots),
                class: pick(&t.class, slots),
                shape: pick(&t.shape, slots),
                radius: pick(&t.radius, slots),
                aabb_lo: pick(&t.aabb_lo, slots),
                aabb_hi: pick(&t.aabb_hi, slots),
                rot: pick(&t.rot, slots),
                inv_mass: pick(&t.inv_mass, slots),
                owner: pick(&t.owner, slots),
                game: pick(&t.game, slots),
                teleported: pick(&t.teleported, slots),
            }),
        }
    }

    /// Removes the slots flagged in `dead`, keeping the order of the rest.
    pub fn remove_flagged(&mut self, dead: &[bool]) {
        fn keep<T>(v: &mut Vec<T>, dead: &[bool]) {
            let mut i = 0;
            v.retain(|_| {
                let k = !dead[i];
                i += 1;
                k
            });
        }
        keep(&mut self.pos, dead);
        keep(&mut self.vel, dead);
        keep(&mut self.asleep, dead);
        keep(&mut self.still_ticks, dead);
        let t = Arc::make_mut(&mut self.table);
        keep(&mut t.id, dead);
        keep(&mut t.class, dead);
        keep(&mut t.shape, dead);
        keep(&mut t.radius, dead);
        keep(&mut t.aabb_lo, dead);
        keep(&mut t.aabb_hi, dead);
        keep(&mut t.rot, dead);
        keep(&mut t.inv_mass, dead);
        keep(&mut t.owner, dead);
        keep(&mut t.game, dead);
        keep(&mut t.teleported, dead);
    }

    /// Velocities to write and the constants beside them, borrowed together.
    pub(crate) fn vel_and_table(&mut self) -> (&mut [DVec3], &BodyTable) {
        (&mut self.vel, &self.table)
    }

    /// Whether two body sets share the same table (same bodies, same constants).
    pub fn same_table(&self, other: &Bodies) -> bool {
        Arc::ptr_eq(&self.table, &other.table)
    }
}

/// The whole simulation state at the start of a tick. Cloning it is the snapshot rollback
/// keeps: the dynamic arrays are copied, the static part and the config are shared.
#[derive(Clone, Debug)]
pub struct World {
    /// The next tick to simulate.
    pub tick: Tick,
    /// Dynamic bodies.
    pub bodies: Bodies,
    /// The id the next spawned body gets.
    pub next_entity: u32,
    /// Pairs touching at the end of the previous tick, with their normals, sorted by
    /// `(lower id, higher id)`.
    pub touching: Vec<Touch>,
    /// Static geometry and terrain.
    pub statics: Arc<StaticWorld>,
    /// Settings.
    pub config: Arc<SimConfig>,
}

impl World {
    /// Adds a dynamic body and returns its id, or `None` when the world is full or has spent its
    /// ids (ids are never reused: after `u32::MAX - 1` there are none).
    pub fn spawn(&mut self, b: NewBody) -> Option<EntityId> {
        if self.bodies.len() >= self.config.max_bodies as usize {
            return None;
        }
        let id = EntityId(self.next_entity);
        self.next_entity = self.next_entity.checked_add(1)?;
        self.bodies.push(id, b);
        Some(id)
    }

    /// The dynamic slots of each touching pair's two sides, in list order (`None` for static
    /// geometry and terrain), into `out` (cleared first).
    ///
    /// `hints` are the slots the stepper knew when it wrote the list (by entry; any list will
    /// do, even another world's): an entry whose pair matches and whose slots still hold those
    /// ids is taken as is, the rest are searched for. The list's higher ids are in no order,
    /// so searching costs a binary search a pair; the hints make a tick that follows a tick
    /// one load. A map over the pairs, cut over `pool` (each piece starts its own cursors).
    pub(crate) fn touching_slots(&self, out: &mut Vec<[Option<u32>; 2]>, hints: &[TouchHint], pool: &Pool) {
        out.clear();
        let b = &self.bodies;
        // A hinted slot holds the id, or the side was static at the hint, and an id that was
        // static geometry or terrain is never a body.
        let check = |slot: u32, id: EntityId| {
            if slot == TouchHint::NOT_A_BODY {
                Some(None)
            } else {
                (b.id.get(slot as usize) == Some(&id)).then_some(Some(slot))
            }
        };
        pool.extend(self.touching.len(), MIN_PIECE_HEAVY, out, |range, out| {
            let (mut ca, mut cb) = (0, 0);
            for k in range {
                let t = &self.touching[k];
                let hinted = hints.get(k).filter(|h| h.key == t.key());
                let a = hinted.and_then(|h| check(h.slots[0], t.a));
                let a = a.unwrap_or_else(|| b.slot_from(&mut ca, t.a).map(|s| s as u32));
                let bb = hinted.and_then(|h| check(h.slots[1], t.b));
                let bb = bb.unwrap_or_else(|| b.slot_from(&mut cb, t.b).map(|s| s as u32));
                out.push([a, bb]);
            }
        });
    }

    /// Bodies awake and asleep.
    pub fn awake_asleep(&self) -> (usize, usize) {
        let flags = &self.bodies.asleep;
        let asleep = if flags.contains(&true) { flags.iter().filter(|a| **a).count() } else { 0 };
        (self.bodies.len() - asleep, asleep)
    }

    /// The class of any entity, dynamic, static or terrain.
    pub fn class_of(&self, id: EntityId) -> Option<ClassId> {
        if let Some(s) = self.bodies.slot(id) {
            return Some(self.bodies.class[s]);
        }
        if let Ok(s) = self.statics.id.binary_search(&id) {
            return Some(self.statics.class[s]);
        }
        self.statics.terrain.as_ref().filter(|t| t.id == id).map(|t| t.class)
    }

    /// A deterministic 64-bit hash of what a client needs beside its own avatar to step it as the
    /// server does: the rules (every `SimConfig` value) and the static world (ids, classes,
    /// shapes, exact positions, orientations and bounds of the static bodies, and the terrain).
    /// A client that built its world from the server's description (`query/scene`) or its own
    /// copy of the scene compares it with the server's (`Welcome::scene_hash`): equal, its
    /// prediction runs on the same world.
    pub fn scene_hash(&self) -> u64 {
        let mut h = StateHasher::new();
        let text = |h: &mut StateHasher, s: &str| s.bytes().for_each(|b| h.u64(u64::from(b)));
        // Rust prints an f64 as the shortest text that reads back to the same bits, the same
        // on every platform: the rules' Debug text is an exact fingerprint of them.
        text(&mut h, &format!("{:?}", self.config));
        let st = &self.statics;
        for i in 0..st.id.len() {
            h.u64(u64::from(st.id[i].0) << 16 | u64::from(st.class[i].0));
            for v in [st.pos[i], st.aabb[i].min, st.aabb[i].max] {
                h.f64(v.x);
                h.f64(v.y);
                h.f64(v.z);
            }
            for c in st.rot[i].to_array() {
                h.f64(c);
            }
            text(&mut h, &format!("{:?}", st.shape[i].to_spec()));
        }
        if let Some(t) = &st.terrain {
            text(&mut h, &format!("{:?}", t));
        }
        h.finish()
    }

    /// A deterministic 64-bit hash of the state (FNV-1a over the exact bits of every field that
    /// can change). Equal states hash equal on every platform.
    pub fn state_hash(&self) -> u64 {
        let mut h = StateHasher::new();
        h.u64(u64::from(self.tick.0));
        h.u64(u64::from(self.next_entity));
        let b = &self.bodies;
        for i in 0..b.len() {
            h.u64(u64::from(b.id[i].0));
            h.u64(u64::from(b.class[i].0));
            for v in [b.pos[i], b.vel[i]] {
                h.f64(v.x);
                h.f64(v.y);
                h.f64(v.z);
            }
            h.f64(b.inv_mass[i]);
            h.u64(b.owner[i].map_or(u64::MAX, |c| u64::from(c.0)));
            h.u64(u64::from(b.asleep[i]) << 16 | u64::from(b.still_ticks[i]));
            for (k, v) in &b.game[i].0 {
                h.bytes(k.as_bytes());
                h.f64(*v);
            }
            if let Some(t) = b.teleported[i] {
                h.u64(1 << 32 | u64::from(t.0));
            }
        }
        for t in &self.touching {
            h.u64(u64::from(t.a.0) << 32 | u64::from(t.b.0));
            h.f64(t.normal.x);
            h.f64(t.normal.y);
            h.f64(t.normal.z);
            h.f64(t.depth);
            h.f64(t.impulse);
            for c in t.friction_impulse.to_array() {
                h.f64(c);
            }
        }
        h.finish()
    }
}

/// The 64-bit state hash: words mixed in by rotate, xor and multiply (FxHasher's step).
#[derive(Debug)]
pub(crate) struct StateHasher(u64);

impl StateHasher {
    /// A fresh hasher.
    pub fn new() -> StateHasher {
        StateHasher(0xcbf2_9ce4_8422_2325)
    }
    /// Mixes in a u64, a word at a time (rotate, xor, multiply, as rustc's FxHasher): a
    /// byte at a time (FNV-1a) took 10 % of the tick at 1,000 clients once the input log
    /// hashed every confirmed tick.
    pub fn u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
    /// Mixes in the exact bits of an f64.
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    /// Mixes in bytes: their length, then eight at a time.
    pub fn bytes(&mut self, b: &[u8]) {
        self.u64(b.len() as u64);
        for c in b.chunks(8) {
            let mut w = [0u8; 8];
            w[..c.len()].copy_from_slice(c);
            self.u64(u64::from_le_bytes(w));
        }
    }
    /// The hash.
    pub fn finish(&self) -> u64 {
        self.0
    }
}

impl Default for StateHasher {
    fn default() -> Self {
        StateHasher::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A table of triggers (and ignored or destroying pairs) has no stopping rule, so the settle
    /// stage skips it; one bouncing, sliding or stopping pair anywhere in the table is found.
    #[test]
    fn any_stopping_finds_one_stopping_pair() {
        let class = |name: &str| ClassProps {
            name: name.into(),
            is_static: false,
            max_speed_mps: 10.0,
            gravity: false,
            density_kg_m3: 1000.0,
            can_sleep: true,
            character: None,
        };
        let mut table = Classes::new(vec![class("ball"), class("wall"), class("brick")], Rule::Trigger);
        table.set_rule(ClassId(0), ClassId(1), Rule::Ignore);
        table.set_rule(ClassId(0), ClassId(2), Rule::Destroy { first: false, second: true, restitution: None });
        assert!(!table.any_stopping());
        for rule in [Rule::Bounce { restitution: 0.5 }, Rule::Slide, Rule::Stop] {
            let mut t = table.clone();
            t.set_rule(ClassId(2), ClassId(1), rule);
            assert!(t.any_stopping(), "{rule:?}");
        }
    }

    /// Entity ids are never reused: the world that spent them (2^32 - 1 spawns) spawns no more
    /// (`None`, as a full world does) and goes on stepping what it has.
    #[test]
    fn entity_ids_near_their_end_are_not_reused() {
        let text = "[world]\nname = \"w\"\n[[class]]\nname = \"ball\"\n";
        let mut w = crate::scene::Scene::parse(text, "<w>").expect("valid").world;
        w.next_entity = u32::MAX - 2;
        let ball = |x: f64| NewBody {
            class: ClassId(0),
            shape: Shape::Sphere { radius: 0.5 },
            pos: DVec3::new(x, 0.0, 0.0),
            vel: DVec3::X,
            rot: DQuat::IDENTITY,
            inv_mass: 1.0,
            owner: None,
        };
        let ids: Vec<Option<EntityId>> = (0..4).map(|k| w.spawn(ball(f64::from(k) * 3.0))).collect();
        assert_eq!(ids, [Some(EntityId(u32::MAX - 2)), Some(EntityId(u32::MAX - 1)), None, None]);
        assert_eq!((w.bodies.len(), w.next_entity), (2, u32::MAX));
        let hash = w.state_hash();
        let mut stepper = crate::sim::step::Stepper::new(crate::sim::Plan::for_world(&w), false);
        stepper.step(&mut w, &[], &mut crate::sim::TickOutput::default());
        assert_ne!(w.state_hash(), hash, "the bodies it has still move");
    }

    proptest! {
        /// The cursor search answers what the binary search answers, whatever order the ids
        /// are asked in and wherever the cursor was left.
        #[test]
        fn slot_from_equals_slot(gaps in proptest::collection::vec(1u32..5, 0..80),
                                 asks in proptest::collection::vec(0u32..400, 0..120)) {
            let mut b = Bodies::default();
            let mut id = 0;
            for g in gaps {
                id += g;
                b.push(EntityId(id), NewBody {
                    class: ClassId(0),
                    shape: Shape::Sphere { radius: 0.5 },
                    pos: DVec3::ZERO,
                    vel: DVec3::ZERO,
                    rot: DQuat::IDENTITY,
                    inv_mass: 1.0,
                    owner: None,
                });
            }
            let mut cursor = 0;
            for a in asks {
                prop_assert_eq!(b.slot_from(&mut cursor, EntityId(a)), b.slot(EntityId(a)));
            }
            // Ascending asks, the common case, too.
            let mut cursor = 0;
            for a in 0..400 {
                prop_assert_eq!(b.slot_from(&mut cursor, EntityId(a)), b.slot(EntityId(a)));
            }
        }

        /// Selecting the kept slots gives what removing the others does, field by field.
        #[test]
        fn select_equals_remove_flagged(n in 0u32..40, dead in proptest::collection::vec(any::<bool>(), 40)) {
            let mut b = Bodies::default();
            for k in 0..n {
                b.push(EntityId(2 * k + 1), NewBody {
                    class: ClassId((k % 3) as u16),
                    shape: Shape::Sphere { radius: 0.25 + f64::from(k % 4) },
                    pos: DVec3::new(f64::from(k), 1.0, -f64::from(k)),
                    vel: DVec3::new(0.5, f64::from(k), 0.0),
                    rot: DQuat::from_rotation_y(f64::from(k)),
                    inv_mass: 1.0 / f64::from(k + 1),
                    owner: (k % 2 == 0).then_some(ClientId(k)),
                });
                b.still_ticks[k as usize] = k as u16;
                b.asleep[k as usize] = k % 5 == 0;
            }
            let dead = &dead[..n as usize];
            let kept: Vec<usize> = (0..n as usize).filter(|&k| !dead[k]).collect();
            let picked = b.select(&kept);
            let mut removed = b.clone();
            removed.remove_flagged(dead);
            prop_assert_eq!(format!("{picked:?}"), format!("{removed:?}"));
        }

        /// Slots from hints equal slots searched for, whatever the hints: right, stale (a body
        /// removed since moved every slot after it), for other pairs, or too few.
        #[test]
        fn hinted_slots_equal_searched(n in 2u32..60, pairs in proptest::collection::vec((0u32..80, 0u32..80), 0..60),
                                       removed in 0u32..60, shuffle in 0usize..4, cut in 0usize..60) {
            let text = "[world]\nname = \"w\"\n[[class]]\nname = \"ball\"\n";
            let mut w = crate::scene::Scene::parse(text, "<w>").expect("valid").world;
            for k in 0..n {
                w.spawn(NewBody {
                    class: ClassId(0),
                    shape: Shape::Sphere { radius: 0.5 },
                    pos: DVec3::new(f64::from(k), 0.0, 0.0),
                    vel: DVec3::ZERO,
                    rot: DQuat::IDENTITY,
                    inv_mass: 1.0,
                    owner: None,
                });
            }
            // Ids at or past `n` are not bodies (they stand for static geometry here).
            let mut keys: Vec<(u32, u32)> = pairs.into_iter().filter(|p| p.0 < p.1).collect();
            keys.sort_unstable();
            keys.dedup();
            w.touching = keys.iter().map(|&(a, b)| Touch {
                a: EntityId(a), b: EntityId(b), normal: DVec3::X, depth: 0.0, impulse: 0.0,
                friction_impulse: DVec3::ZERO,
            }).collect();
            let pool = Pool::sequential();
            let mut searched = Vec::new();
            w.touching_slots(&mut searched, &[], &pool);
            let hint = |s: &[Option<u32>; 2], t: &Touch| TouchHint {
                key: t.key(), slots: s.map(|s| s.unwrap_or(TouchHint::NOT_A_BODY)),
            };
            let right: Vec<TouchHint> = searched.iter().zip(&w.touching).map(|(s, t)| hint(s, t)).collect();
            let mut hints = right.clone();
            let turn = shuffle.min(hints.len());
            hints.rotate_left(turn);
            hints.truncate(cut);
            for hs in [right, hints] {
                let mut hinted = Vec::new();
                w.touching_slots(&mut hinted, &hs, &pool);
                prop_assert_eq!(&hinted, &searched);
                // The same hints after a body is removed: every slot past it has moved.
                let mut v = w.clone();
                let dead: Vec<bool> = (0..n).map(|k| k == removed % n).collect();
                v.bodies.remove_flagged(&dead);
                let (mut want, mut got) = (Vec::new(), Vec::new());
                v.touching_slots(&mut want, &[], &pool);
                v.touching_slots(&mut got, &hs, &pool);
                prop_assert_eq!(got, want);
            }
        }
    }
}
