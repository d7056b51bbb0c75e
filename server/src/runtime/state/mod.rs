//! The state streams: every body on `state`, and per client on `client/{id}/state` the bodies
//! near its avatar within a byte budget, as full frames at an interval and deltas between
//! (PROTOCOL.md, "State streams").
//!
//! The tick thread only copies what moves (positions, velocities, sleep flags: three arrays)
//! and hands the copy to this module's thread through a queue of two; a frame that finds the
//! queue full is skipped and counted. Everything else runs here: the area-of-interest search,
//! each receiver's delta against what it holds, the budget, encoding and publishing.
//!
//! Each receiver's held set is the bodies it was last sent, with the motion and the tick it was
//! sent at. A receiver draws a body carried from that at its velocity, so a body is sent again
//! only when it is more than a millimetre from where it was carried to (or its velocity changed
//! by a mm/s, or it fell asleep or woke): a body flying straight costs nothing after the frame
//! that showed it, and the budget goes to the bodies something changed (dead reckoning, as
//! DIS and the Tribes networking model send an entity when its extrapolation drifts past a
//! threshold). When a frame's changes exceed the budget, the nearest go
//! first; a body held back gains priority every frame it waits (its distance is divided by one
//! plus the frames it waited), so none starves. The budget is a token bucket: a second's worth of
//! bytes at most, refilled each frame, so a full frame may spend what the deltas left.

mod frame;
mod grid;
mod thread;

use frame::{avatar_state, build, estimate, f32x3, info_bytes, info_key, publish, touches_of, Held, Marks, Remap};
use glam::DVec3;
use grid::{AreaGrid, Filed};
use impact_core::sim::world::{BodyTable, SimConfig, StaticWorld, Touch};
use impact_protocol::{keys, BodyMotion, ClientId, Encoding, EntityId, StateFrame, Tick, WorldId};
use std::collections::BTreeMap;
use std::sync::atomic::AtomicU64;
use std::sync::Arc;
pub use thread::run;

/// How the state streams run.
#[derive(Clone, Debug, PartialEq)]
pub struct StateOptions {
    /// Frames per second on every stream (0: no state streams).
    pub hz: u32,
    /// Radius of a client's area of interest around its avatar, metres.
    pub aoi_m: f64,
    /// Bytes per second one client's stream may use on average (a second's worth may burst).
    pub bytes_per_s: u32,
    /// A full frame every this many frames (the rest are deltas).
    pub full_every: u32,
}

impl Default for StateOptions {
    fn default() -> Self {
        StateOptions { hz: 20, aoi_m: 10.0, bytes_per_s: 32 * 1024, full_every: 40 }
    }
}

/// A client whose stream is due: its avatar is the centre of its area of interest.
#[derive(Clone, Debug)]
pub struct Watcher {
    /// The client.
    pub client: ClientId,
    /// Its avatar.
    pub avatar: EntityId,
    /// The encoding it asked for.
    pub encoding: Encoding,
    /// It asked for a full frame (after a gap in its frame numbers).
    pub full: bool,
}

/// What the tick thread hands over: the moving state of one tick, and the parts that do not
/// move by reference.
#[derive(Debug)]
pub struct Capture {
    /// The tick the positions are at.
    pub tick: Tick,
    /// Ids, classes, shapes and bounds of the dynamic bodies (shared, not copied).
    pub table: Arc<BodyTable>,
    /// Positions.
    pub pos: Vec<DVec3>,
    /// Velocities.
    pub vel: Vec<DVec3>,
    /// Sleep flags.
    pub asleep: Vec<bool>,
    /// Sleep countdowns.
    pub still: Vec<u16>,
    /// The contact cache's pairs that involve a watcher's avatar (what the core carries between
    /// ticks for them).
    pub touching: Vec<Touch>,
    /// Static geometry and terrain.
    pub statics: Arc<StaticWorld>,
    /// Class names and whether each is static.
    pub config: Arc<SimConfig>,
    /// Clients with an avatar.
    pub watchers: Vec<Watcher>,
}

impl Capture {
    /// Copies what moves out of `world`.
    pub fn of(world: &impact_core::sim::World, watchers: Vec<Watcher>) -> Capture {
        let b = &world.bodies;
        let mut avatars: Vec<EntityId> = watchers.iter().map(|v| v.avatar).collect();
        avatars.sort_unstable();
        let watched = |e: EntityId| avatars.binary_search(&e).is_ok();
        Capture {
            tick: world.tick,
            table: b.table(),
            pos: b.pos.clone(),
            vel: b.vel.clone(),
            asleep: b.asleep.clone(),
            still: b.still_ticks.clone(),
            // Only the watchers' avatars' contacts are sent: copy those, not the whole cache.
            touching: world.touching.iter().filter(|t| watched(t.a) || watched(t.b)).copied().collect(),
            statics: world.statics.clone(),
            config: world.config.clone(),
            watchers,
        }
    }
}

/// Counters of the state thread, shared with stats and metrics.
#[derive(Debug, Default)]
pub struct StateCounters {
    /// Frames published on the world stream.
    pub world_frames: AtomicU64,
    /// Bytes published on the world stream.
    pub world_bytes: AtomicU64,
    /// Frames published on client streams.
    pub client_frames: AtomicU64,
    /// Bytes published on client streams.
    pub client_bytes: AtomicU64,
    /// Bodies held back by a client's byte budget (summed over frames).
    pub deferred: AtomicU64,
    /// Captures skipped because the state thread was still busy with the one before.
    pub skipped: AtomicU64,
    /// Nanoseconds the state thread spent building, encoding and publishing.
    pub busy_ns: AtomicU64,
    /// Nanoseconds the state thread waited for ticks under way to end (not in `busy_ns`).
    pub waited_ns: AtomicU64,
    /// Nanoseconds the tick thread spent copying the state for it.
    pub capture_ns: AtomicU64,
}

/// One body of a frame's world, in entity order.
#[derive(Clone, Copy, Debug)]
struct Entry {
    motion: BodyMotion,
    lo: DVec3,
    hi: DVec3,
    src: Src,
    /// What its [`BodyInfo`] says that can change (class, game state), as a hash: a receiver
    /// that holds another is sent the info again.
    info: u64,
    /// The bytes its [`BodyInfo`] is budgeted at (found once a frame, not per receiver).
    info_bytes: u32,
}

#[derive(Clone, Copy, Debug)]
enum Src {
    Dynamic(usize),
    Static(usize),
    Terrain,
}

/// The state streams of one world.
#[derive(Debug)]
pub struct Streams {
    opts: StateOptions,
    world_key: String,
    world_id: WorldId,
    encoding: Encoding,
    world: Held,
    clients: BTreeMap<ClientId, Held>,
    frames: u32,
    entries: Vec<Entry>,
    /// The bodies no larger than half `aoi_m`, by cell of half `aoi_m`.
    grid: AreaGrid,
    filed: Vec<Filed>,
    /// Bodies larger than a cell, tested against every client.
    large: Vec<u32>,
    /// The largest half size of a body in the grid.
    reach: f64,
    scratch: Vec<(f64, u32)>,
    /// The capture's contacts by body ([`frame::touches_of`]).
    touches: Vec<(EntityId, u32)>,
    /// Last frame's entry indices to this frame's.
    remap: Remap,
    marks: Marks,
    counts: StreamCounts,
}

/// What the client streams showed, summed over their frames.
#[derive(Clone, Copy, Debug, Default)]
pub struct StreamCounts {
    /// Client frames built.
    pub client_frames: u64,
    /// Bodies in the clients' areas.
    pub in_area: u64,
    /// Bodies sent (entered or moved).
    pub sent: u64,
}

/// A frame ready to publish.
#[derive(Debug)]
pub struct Publish {
    /// Key.
    pub key: String,
    /// Encoded frame.
    pub bytes: Vec<u8>,
    /// Its encoding.
    pub encoding: Encoding,
    /// The client whose stream it is (`None`: the world stream).
    pub client: Option<ClientId>,
    /// Bodies its budget held back.
    pub deferred: u32,
    /// The frame (kept for tests; `None` in the running server).
    pub frame: Option<StateFrame>,
}

impl Streams {
    /// Streams for `world`, broadcast in `encoding`.
    pub fn new(world_id: WorldId, opts: StateOptions, encoding: Encoding) -> Streams {
        Streams {
            world_key: keys::STATE.key(&world_id, None),
            world_id,
            encoding,
            world: Held::default(),
            clients: BTreeMap::new(),
            frames: 0,
            entries: Vec::new(),
            grid: AreaGrid::default(),
            filed: Vec::new(),
            large: Vec::new(),
            reach: 0.0,
            scratch: Vec::new(),
            touches: Vec::new(),
            remap: Remap::default(),
            marks: Marks::default(),
            counts: StreamCounts::default(),
            opts,
        }
    }

    /// What the client streams showed so far.
    pub fn counts(&self) -> StreamCounts {
        self.counts
    }

    /// Builds this capture's frames: the world stream's (when `world` says someone listens),
    /// then each viewer's. `keep` keeps the decoded frames in the result (tests).
    pub fn frames(&mut self, cap: &Capture, world: bool, keep: bool) -> Vec<Publish> {
        self.frames_between(cap, world, keep, &mut || {})
    }

    /// [`Streams::frames`], calling `pause` before each stream's frame (the state thread waits
    /// there for a tick under way: [`TickGate`](crate::runtime::gate::TickGate)).
    pub fn frames_between(&mut self, cap: &Capture, world: bool, keep: bool, pause: &mut dyn FnMut()) -> Vec<Publish> {
        pause();
        self.index(cap);
        let full = self.frames % self.opts.full_every.max(1) == 0;
        self.frames = self.frames.wrapping_add(1);
        let mut out = Vec::with_capacity(cap.watchers.len() + 1);
        // The world stream: every body, no budget; skipped while nobody listens, and full again
        // for whoever comes.
        if world {
            pause();
            let all: Vec<(f64, u32)> = (0..self.entries.len() as u32).map(|i| (0.0, i)).collect();
            let world_key = self.world_key.clone();
            let full = full || self.world.bodies.is_empty();
            let frame =
                build(&mut self.world, (&self.entries, &self.remap), &mut self.marks, cap, &all, None, full, None);
            out.extend(publish(world_key, None, frame, self.encoding, keep));
        } else {
            self.world.bodies.clear();
        }
        // Client streams.
        let per_frame = f64::from(self.opts.bytes_per_s) / f64::from(self.opts.hz.max(1));
        let cap_tokens = f64::from(self.opts.bytes_per_s).max(per_frame);
        let mut seen = std::collections::BTreeSet::new();
        touches_of(cap, &mut self.touches);
        for v in &cap.watchers {
            pause();
            let Ok(at) = self.entries.binary_search_by_key(&v.avatar, |e| e.motion.0) else {
                continue;
            };
            let centre = self.entries[at];
            seen.insert(v.client);
            let c =
                DVec3::new(f64::from(centre.motion.1[0]), f64::from(centre.motion.1[1]), f64::from(centre.motion.1[2]));
            self.near(c);
            let held = self.clients.entry(v.client).or_insert_with(|| Held {
                key: keys::CLIENT_STATE.key(&self.world_id, Some(v.client)),
                tokens: per_frame,
                ..Held::default()
            });
            held.tokens = (held.tokens + per_frame).min(cap_tokens);
            // A new receiver starts from a full frame, and one that asked for it gets one.
            let full = full || held.frame == 0 || v.full;
            let at = (&self.entries[..], &self.remap);
            let mut frame = build(held, at, &mut self.marks, cap, &self.scratch, Some(held.tokens), full, Some(c));
            frame.avatar = avatar_state(cap, v.avatar, &self.touches);
            held.tokens = (held.tokens - estimate(&frame) as f64).max(0.0);
            self.counts.client_frames += 1;
            self.counts.in_area += self.scratch.len() as u64;
            self.counts.sent += frame.moved.len() as u64;
            out.extend(publish(held.key.clone(), Some(v.client), frame, v.encoding, keep));
        }
        // A client gone (or without an avatar) starts again from a full frame when it returns.
        self.clients.retain(|c, _| seen.contains(c));
        out
    }

    /// The grid's cell size: half the area's radius.
    fn cell(&self) -> f64 {
        (self.opts.aoi_m * 0.5).max(1e-3)
    }

    /// Lays the capture out in entity order and files it into the grid.
    fn index(&mut self, cap: &Capture) {
        self.entries.clear();
        let st = &cap.statics;
        let statics = (0..st.id.len()).map(|i| Entry {
            motion: BodyMotion(st.id[i], f32x3(st.pos[i]), [0.0; 3], false),
            lo: st.aabb[i].min,
            hi: st.aabb[i].max,
            src: Src::Static(i),
            info: 0,
            info_bytes: 0,
        });
        let terrain = st.terrain.as_ref().map(|t| {
            let b = t.field.aabb();
            Entry {
                motion: BodyMotion(t.id, f32x3(t.field.origin()), [0.0; 3], false),
                lo: b.min,
                hi: b.max,
                src: Src::Terrain,
                info: 0,
                info_bytes: 0,
            }
        });
        let t = &cap.table;
        let dynamic = (0..t.id.len()).map(|i| Entry {
            motion: BodyMotion(t.id[i], f32x3(cap.pos[i]), f32x3(cap.vel[i]), cap.asleep[i]),
            lo: cap.pos[i] + t.aabb_lo[i],
            hi: cap.pos[i] + t.aabb_hi[i],
            src: Src::Dynamic(i),
            info: info_key(t.class[i], &t.game[i], t.teleported[i]),
            info_bytes: 0,
        });
        self.entries.extend(statics.chain(terrain).chain(dynamic));
        self.entries.sort_by_key(|e| e.motion.0);
        for e in &mut self.entries {
            e.info_bytes = info_bytes(cap, e) as u32;
        }
        self.remap.advance(&self.entries);
        self.large.clear();
        self.filed.clear();
        self.reach = 0.0;
        let cell = self.cell();
        for (i, e) in self.entries.iter().enumerate() {
            let half = (e.hi - e.lo) * 0.5;
            if half.max_element() > cell {
                self.large.push(i as u32);
                continue;
            }
            self.reach = self.reach.max(half.max_element());
            self.filed.push(Filed { lo: e.lo, hi: e.hi, i: i as u32 });
        }
        self.grid.build(cell, &self.filed);
    }

    /// The bodies within `aoi_m` of `c` (distance to their bounds) into `scratch`, as
    /// `(squared distance, entry)`, in the order of the grid's cells (no square root: the
    /// squares order the same).
    fn near(&mut self, c: DVec3) {
        // A local list: pushed to in the hot loop, its length stays in a register.
        let mut scratch = std::mem::take(&mut self.scratch);
        scratch.clear();
        let r = self.opts.aoi_m;
        let (r2, dist2) = (r * r, |lo: DVec3, hi: DVec3| (lo - c).max(c - hi).max(DVec3::ZERO).length_squared());
        // A body in the area has its centre within the radius plus its own half size (at most
        // `reach`) of the centre. Each (x, y) column of cells, grown by `reach`, is `dxy` across
        // from the centre; the area's chord through it is `(r² - dxy²)^½` each way in z, so its
        // bodies' centres are within that plus `reach` of the centre's z: the cells read are the
        // sphere's, not the cube's around it.
        let g = &self.grid;
        let span = r + self.reach;
        let (lo, hi) = (g.cell_of(c - DVec3::splat(span)), g.cell_of(c + DVec3::splat(span)));
        if (0..3).all(|k| hi[k] >= 0 && lo[k] < g.dims[k]) {
            let clamp = |v: i64, k: usize| v.clamp(0, g.dims[k] - 1);
            let reach = self.reach;
            // The distance from `v` to the cells `a..=a` along an axis, grown by `reach`.
            let across = |v: f64, a: i64, o: f64| {
                let (l, h) = (o + a as f64 * g.size - reach, o + (a + 1) as f64 * g.size + reach);
                (l - v).max(v - h).max(0.0)
            };
            for x in clamp(lo[0], 0)..=clamp(hi[0], 0) {
                let dx = across(c.x, x, g.origin.x);
                for y in clamp(lo[1], 1)..=clamp(hi[1], 1) {
                    let dy = across(c.y, y, g.origin.y);
                    let dxy2 = dx * dx + dy * dy;
                    if dxy2 > r2 {
                        continue;
                    }
                    let h = (r2 - dxy2).sqrt() + reach;
                    let (z0, z1) = (g.cell_of(c - DVec3::splat(h))[2], g.cell_of(c + DVec3::splat(h))[2]);
                    if z1 < 0 || z0 >= g.dims[2] {
                        continue;
                    }
                    let (z0, z1) = (clamp(z0, 2), clamp(z1, 2));
                    let (a, b) = (g.start[g.index([x, y, z0])], g.start[g.index([x, y, z1]) + 1]);
                    for f in &g.items[a as usize..b as usize] {
                        let d2 = dist2(f.lo, f.hi);
                        if d2 <= r2 {
                            scratch.push((d2, f.i));
                        }
                    }
                }
            }
        }
        for &i in &self.large {
            let e = &self.entries[i as usize];
            let d2 = dist2(e.lo, e.hi);
            if d2 <= r2 {
                scratch.push((d2, i));
            }
        }
        self.scratch = scratch;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;
    use impact_core::scene::Scene;
    use impact_core::sim::world::NewBody;
    use impact_protocol::{decode, BodyInfo, ServerMessage};

    /// The arena with a player sphere for each of `players` clients, spread along x.
    fn arena(players: u32) -> (impact_core::sim::World, Vec<Watcher>) {
        let scene = Scene::load(&Scene::bundled_path("arena")).unwrap();
        let mut w = scene.world;
        let player = w.config.classes.props.iter().position(|p| p.name == "player").unwrap();
        let mut watchers = Vec::new();
        for k in 0..players {
            let id = w
                .spawn(NewBody {
                    class: impact_core::sim::world::ClassId(player as u16),
                    shape: impact_core::geometry::Shape::Sphere { radius: 0.5 },
                    pos: DVec3::new(-25.0 + 10.0 * f64::from(k), 5.0, 0.0),
                    vel: DVec3::ZERO,
                    rot: DQuat::IDENTITY,
                    inv_mass: 1.0,
                    owner: Some(ClientId(k + 1)),
                })
                .unwrap();
            watchers.push(Watcher { client: ClientId(k + 1), avatar: id, encoding: Encoding::MsgPack, full: false });
        }
        (w, watchers)
    }

    /// What a receiver holds after applying a frame (`false` when it had to wait for a full one).
    fn apply(held: &mut BTreeMap<EntityId, (BodyMotion, Option<BodyInfo>)>, f: &StateFrame) {
        if f.full {
            held.clear();
        }
        for e in &f.left {
            held.remove(e);
        }
        for i in &f.entered {
            held.insert(i.entity, (BodyMotion(i.entity, [0.0; 3], [0.0; 3], false), Some(i.clone())));
        }
        for m in &f.moved {
            let slot = held.get_mut(&m.0).expect("a moved body was entered before");
            slot.0 = *m;
        }
    }

    /// Distance from `c` to a body's bounds as a receiver knows them.
    fn distance(m: &BodyMotion, info: &BodyInfo, c: DVec3) -> f64 {
        let v = |a: [f32; 3]| DVec3::new(f64::from(a[0]), f64::from(a[1]), f64::from(a[2]));
        let (mid, half) = (v(m.1) + v(info.offset_m), v(info.half_extents_m));
        ((mid - half) - c).max(c - (mid + half)).max(DVec3::ZERO).length()
    }

    fn opts() -> StateOptions {
        StateOptions { hz: 20, aoi_m: 12.0, bytes_per_s: 16 * 1024, full_every: 10 }
    }

    fn decoded(p: &Publish) -> StateFrame {
        match decode::<ServerMessage>(&p.bytes, p.encoding, impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES).unwrap()
        {
            ServerMessage::State(f) => f,
            other => panic!("{other:?}"),
        }
    }

    /// A receiver draws each body carried from its last sample at its velocity; the world stream
    /// keeps that within a millimetre of the world and sends only the bodies something changed.
    #[test]
    fn the_world_stream_keeps_a_receiver_within_a_millimetre_of_the_world() {
        let (mut w, _) = arena(0);
        let dt = w.config.dt;
        let mut s = Streams::new(WorldId::new("arena").unwrap(), opts(), Encoding::MsgPack);
        let mut held = BTreeMap::new();
        let mut sent_at = BTreeMap::new();
        let statics = w.statics.id.len();
        for frame in 0..25u32 {
            // Every ball flies on at its velocity, and a third of them (a different third each
            // frame) bounce: their x velocity reversed.
            let mut bounced = std::collections::BTreeSet::new();
            for i in 0..w.bodies.len() {
                let v = w.bodies.vel[i];
                w.bodies.pos[i] += v * dt;
                if i % 3 == frame as usize % 3 && v.x.abs() > 1e-3 {
                    w.bodies.vel[i].x = -v.x;
                    bounced.insert(w.bodies.id[i]);
                }
            }
            if frame % 7 == 6 {
                let mut dead = vec![false; w.bodies.len()];
                dead[w.bodies.len() / 2] = true;
                w.bodies.remove_flagged(&dead);
            }
            // And add one now and then: every body after it in entity order moves up a place.
            if frame % 5 == 3 {
                let class = w.config.classes.props.iter().position(|p| p.name == "player").unwrap();
                w.spawn(NewBody {
                    class: impact_core::sim::world::ClassId(class as u16),
                    shape: impact_core::geometry::Shape::Sphere { radius: 0.5 },
                    pos: DVec3::new(f64::from(frame), 3.0, -5.0),
                    vel: DVec3::ZERO,
                    rot: DQuat::IDENTITY,
                    inv_mass: 1.0,
                    owner: None,
                })
                .unwrap();
            }
            w.tick = Tick(frame);
            let out = s.frames(&Capture::of(&w, Vec::new()), true, true);
            assert_eq!(out.len(), 1);
            let f = decoded(&out[0]);
            assert_eq!(f.frame, frame);
            assert_eq!(f.full, frame % 10 == 0, "frame {frame}");
            apply(&mut held, &f);
            sent_at.extend(f.moved.iter().map(|m| (m.0, f.tick)));
            assert_eq!(held.len(), w.bodies.len() + statics, "frame {frame}");
            for i in 0..w.bodies.len() {
                let (e, (m, info)) = (w.bodies.id[i], &held[&w.bodies.id[i]]);
                let s = f64::from(f.tick.0 - sent_at[&e].0) * dt;
                for k in 0..3 {
                    let drawn = f64::from(m.1[k]) + f64::from(m.2[k]) * s;
                    let (p, v) = (w.bodies.pos[i][k], w.bodies.vel[i][k]);
                    assert!((drawn - p).abs() < 1.01e-3, "body {e} at frame {frame}: drawn {drawn}, at {p}");
                    assert!((f64::from(m.2[k]) - v).abs() < 1.01e-3, "body {e} at frame {frame}: {:?}", m.2);
                }
                assert!(!info.as_ref().unwrap().fixed);
            }
            if !f.full && frame > 0 {
                // A delta carries the bodies that bounced (and those that entered), none that
                // flew straight on.
                let entered: Vec<EntityId> = f.entered.iter().map(|i| i.entity).collect();
                for m in &f.moved {
                    assert!(bounced.contains(&m.0) || entered.contains(&m.0), "frame {frame}: {} sent", m.0);
                }
                let still_there = bounced.iter().filter(|e| w.bodies.slot(**e).is_some()).count();
                assert!(f.moved.len() >= still_there, "frame {frame}: {} sent, {still_there} bounced", f.moved.len());
            }
        }
    }

    #[test]
    fn a_client_stream_shows_its_area_nearest_first_within_its_budget() {
        let (mut w, watchers) = arena(4);
        let o = opts();
        let mut s = Streams::new(WorldId::new("arena").unwrap(), o.clone(), Encoding::MsgPack);
        let mut held: Vec<BTreeMap<EntityId, (BodyMotion, Option<BodyInfo>)>> = vec![BTreeMap::new(); watchers.len()];
        let mut sent = vec![0usize; watchers.len()];
        let frames = 60u32;
        for frame in 0..frames {
            for p in w.bodies.pos.iter_mut() {
                p.z += 0.05;
            }
            let out = s.frames(&Capture::of(&w, watchers.clone()), false, true);
            assert_eq!(out.len(), watchers.len(), "no world stream when nobody listens");
            for (k, p) in out.iter().enumerate() {
                let f = decoded(p);
                assert_eq!(p.key, format!("impact/v1/arena/client/{}/state", k + 1));
                sent[k] += p.bytes.len();
                assert!(p.bytes.len() <= estimate(&f), "{} bytes, estimated {}", p.bytes.len(), estimate(&f));
                let c = f.centre.unwrap();
                let centre = DVec3::new(f64::from(c[0]), f64::from(c[1]), f64::from(c[2]));
                apply(&mut held[k], &f);
                // Everything it holds is in its area (distance to the body's bounds).
                for (m, info) in held[k].values() {
                    let d = distance(m, info.as_ref().unwrap(), centre);
                    assert!(d <= o.aoi_m + 0.06, "frame {frame}: {} at {d} m", m.0);
                }
                // Its own avatar is the nearest body: always shown.
                assert!(held[k].contains_key(&watchers[k].avatar));
                if frame == 0 {
                    // The first (full) frame: the budget binds, and what it sent is nearer
                    // than what it deferred.
                    assert!(f.deferred > 0, "the budget should bind in a 12 m area of the arena");
                    let motion = |e: EntityId| *f.moved.iter().find(|m| m.0 == e).unwrap();
                    let farthest_sent =
                        f.entered.iter().map(|i| distance(&motion(i.entity), i, centre)).fold(0.0, f64::max);
                    s.near(centre);
                    let closer = s.scratch.iter().filter(|(d, _)| *d < farthest_sent - 1e-3).count();
                    assert!(closer <= f.entered.len(), "{closer} bodies nearer than the farthest sent");
                }
            }
        }
        // The token bucket: at most a second's worth above the rate, over the run.
        let seconds = f64::from(frames) / f64::from(o.hz);
        for (k, b) in sent.iter().enumerate() {
            let bound = f64::from(o.bytes_per_s) * (seconds + 1.0);
            assert!((*b as f64) <= bound, "client {k}: {b} bytes in {seconds} s, bound {bound}");
            assert!((*b as f64) > 0.5 * f64::from(o.bytes_per_s) * seconds, "client {k} used little: {b}");
        }
    }

    /// A client that asks (after a gap) gets a full frame at the next capture, and deltas again
    /// after it; a client that did not ask is not disturbed. Each frame carries the avatar's
    /// exact state.
    #[test]
    fn a_full_frame_comes_when_asked() {
        let (w, watchers) = arena(2);
        let mut s = Streams::new(WorldId::new("arena").unwrap(), opts(), Encoding::MsgPack);
        let fulls = |s: &mut Streams, ask: bool| -> Vec<bool> {
            let mut ws = watchers.clone();
            ws[0].full = ask;
            s.frames(&Capture::of(&w, ws), false, true).iter().map(|p| decoded(p).full).collect()
        };
        let first = s.frames(&Capture::of(&w, watchers.clone()), false, true);
        let f = decoded(&first[0]);
        assert!(f.full, "a new receiver starts full");
        // What a game needs to draw a body: its shape in its own frame (the arena's are unrotated
        // spheres: no rotation sent).
        let me = f.entered.iter().find(|b| b.entity == watchers[0].avatar).expect("the avatar entered");
        assert_eq!(me.local_shape, Some(impact_protocol::ShapeSpec::Sphere { radius_m: 0.5 }));
        assert_eq!(me.rotation, None);
        assert_eq!(fulls(&mut s, false), [false, false]);
        assert_eq!(fulls(&mut s, false), [false, false]);
        assert_eq!(fulls(&mut s, true), [true, false]);
        assert_eq!(fulls(&mut s, false), [false, false]);
        let f = decoded(&s.frames(&Capture::of(&w, watchers.clone()), false, true)[0]);
        let a = f.avatar.expect("the avatar's state");
        let i = w.bodies.slot(watchers[0].avatar).unwrap();
        assert_eq!(
            (a.entity, a.position, a.velocity),
            (watchers[0].avatar, w.bodies.pos[i].to_array(), w.bodies.vel[i].to_array())
        );
    }

    /// Each client's frame carries its own avatar's contacts with static geometry, in the
    /// contact list's order, whichever side of the pair the avatar is: not another avatar's, and
    /// not those with other bodies.
    #[test]
    fn a_client_frame_carries_its_own_avatars_contacts_with_statics() {
        let (mut w, watchers) = arena(3);
        let [a, b, c] = [0, 1, 2].map(|k| watchers[k].avatar);
        let (s0, s1) = (w.statics.id[0], w.statics.id[1]);
        let touch = |x: EntityId, y: EntityId, depth: f64| impact_core::sim::world::Touch {
            a: x.min(y),
            b: x.max(y),
            normal: DVec3::Y,
            depth,
            impulse: 0.0,
            friction_impulse: DVec3::ZERO,
        };
        w.touching = vec![touch(c, s0, 0.3), touch(a, s1, 0.1), touch(a, b, 0.9), touch(s0, a, 0.2)];
        let mut s = Streams::new(WorldId::new("arena").unwrap(), opts(), Encoding::MsgPack);
        let out = s.frames(&Capture::of(&w, watchers.clone()), false, true);
        let contacts: Vec<Vec<(EntityId, f64)>> = out
            .iter()
            .map(|p| {
                decoded(p).avatar.expect("the avatar's state").touching.iter().map(|t| (t.other, t.depth_m)).collect()
            })
            .collect();
        assert_eq!(contacts, [vec![(s1, 0.1), (s0, 0.2)], vec![], vec![(s0, 0.3)]]);
    }

    /// A held body whose info changed is sent whole again; held back by the budget, the
    /// receiver still has it, so when it leaves it is said to leave.
    #[test]
    fn a_body_whose_info_waits_for_the_budget_is_still_said_to_leave() {
        let (mut w, watchers) = arena(1);
        let mut s = Streams::new(
            WorldId::new("arena").unwrap(),
            StateOptions { bytes_per_s: 1 << 24, ..opts() },
            Encoding::MsgPack,
        );
        let f0 = decoded(&s.frames(&Capture::of(&w, watchers.clone()), false, true)[0]);
        let avatar = watchers[0].avatar;
        let near = f0.moved.iter().find(|m| m.0 != avatar && w.bodies.slot(m.0).is_some()).unwrap().0;
        let slot = w.bodies.slot(near).unwrap();
        w.bodies.set_game(slot, impact_protocol::GameState([("health".to_string(), 75.0)].into()));
        // A budget too small for its info this frame.
        s.opts.bytes_per_s = 300 * s.opts.hz;
        s.clients.get_mut(&ClientId(1)).unwrap().tokens = 0.0;
        let f1 = decoded(&s.frames(&Capture::of(&w, watchers.clone()), false, true)[0]);
        assert!(!f1.full && f1.deferred > 0 && f1.entered.iter().all(|i| i.entity != near), "{f1:?}");
        w.bodies.pos[slot] = DVec3::new(28.0, 18.0, 28.0);
        let f2 = decoded(&s.frames(&Capture::of(&w, watchers), false, true)[0]);
        assert_eq!(f2.left, vec![near]);
    }

    #[test]
    fn a_body_that_leaves_the_area_is_said_to_leave() {
        let (mut w, watchers) = arena(1);
        let mut s = Streams::new(
            WorldId::new("arena").unwrap(),
            StateOptions { bytes_per_s: 1 << 24, ..opts() },
            Encoding::Json,
        );
        let f0 = decoded(&s.frames(&Capture::of(&w, watchers.clone()), false, true)[0]);
        // With the budget out of the way, the stream shows exactly the bodies in the area.
        let c = w.bodies.pos[w.bodies.slot(watchers[0].avatar).unwrap()];
        let mut expected: Vec<EntityId> = s
            .entries
            .iter()
            .filter(|e| (e.lo - c).max(c - e.hi).max(DVec3::ZERO).length() <= s.opts.aoi_m)
            .map(|e| e.motion.0)
            .collect();
        expected.sort();
        assert!(expected.len() > 20, "{} bodies in the area", expected.len());
        assert_eq!(f0.moved.iter().map(|m| m.0).collect::<Vec<_>>(), expected);
        let avatar = watchers[0].avatar;
        let near = f0.moved.iter().find(|m| m.0 != avatar && w.bodies.slot(m.0).is_some()).unwrap().0;
        let slot = w.bodies.slot(near).unwrap();
        w.bodies.pos[slot] = DVec3::new(28.0, 18.0, 28.0);
        let f1 = decoded(&s.frames(&Capture::of(&w, watchers), false, true)[0]);
        assert!(!f1.full);
        assert_eq!(f1.left, vec![near]);
        assert!(f1.moved.iter().all(|m| m.0 != near));
    }

    #[test]
    fn the_state_thread_may_pause_before_the_capture_and_before_each_stream() {
        let (w, watchers) = arena(3);
        let id = WorldId::new("arena").unwrap();
        let (mut plain, mut paused) =
            (Streams::new(id.clone(), opts(), Encoding::MsgPack), Streams::new(id, opts(), Encoding::MsgPack));
        for world in [true, false] {
            let cap = Capture::of(&w, watchers.clone());
            let mut pauses = 0;
            let a = paused.frames_between(&cap, world, false, &mut || pauses += 1);
            let b = plain.frames(&cap, world, false);
            assert_eq!(pauses, 1 + usize::from(world) + watchers.len(), "world stream {world}");
            let bytes = |v: &[Publish]| v.iter().map(|p| (p.key.clone(), p.bytes.clone())).collect::<Vec<_>>();
            assert_eq!(bytes(&a), bytes(&b), "pausing changed the frames");
        }
    }
}
