//! One receiver's frame: what it holds against what is near, within its byte budget, and the
//! bodies' infos and the avatar's state the frame carries.
//!
//! A receiver's work is the bodies it holds and the bodies near it, nothing else: what it holds
//! is found in the frame's entries through the index each body had last frame (carried over by
//! [`Remap`] once a frame for every receiver), and marks stamped per receiver say which bodies
//! are near and which held, so neither list is sorted or searched.

use super::{Capture, Entry, Publish, Src};
use glam::DVec3;
use impact_protocol::{
    encode_into, AvatarState, AvatarTouch, BodyInfo, BodyMotion, BodyShape, ClientId, Encoding, EntityId, GameState,
    ServerMessage, StateFrame, Tick,
};

/// What a receiver holds: the bodies it was sent (in no order) and the motion it was sent.
#[derive(Debug, Default)]
pub(super) struct Held {
    pub(super) bodies: Vec<HeldBody>,
    pub(super) frame: u32,
    /// Bytes it may still spend (token bucket).
    pub(super) tokens: f64,
    pub(super) key: String,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct HeldBody {
    /// Its index in the entries of the frame it was last built in.
    at: u32,
    motion: BodyMotion,
    /// The tick of the frame that sent it `motion`.
    sent: Tick,
    /// The [`Entry::info`] it was sent.
    info: u64,
    /// Frames it has changed without being sent.
    waited: u32,
}

/// Upper bounds on the MessagePack size of a frame's parts (the budget is kept on these, so
/// the bytes sent never exceed it).
const FRAME_BYTES: usize = 160;
const MOTION_BYTES: usize = 40;
const INFO_BYTES: usize = 210; // plus the class name; 90 of it the rotation and the local shape
const LEFT_BYTES: usize = 5;
/// The avatar's state on a client's stream (its key, six fields, f64s at 9 bytes), and each of
/// its contacts.
const AVATAR_BYTES: usize = 136;
const TOUCH_BYTES: usize = 128;

pub(super) fn f32x3(v: DVec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// How far, metres (and m/s), a body may be from what its receiver draws before it is sent again.
const DRIFT: f64 = 1e-3;

/// Whether a receiver that was sent `held` `elapsed_s` seconds ago would now draw the body more
/// than [`DRIFT`] from `now` (in any axis), or with a velocity or sleep flag it no longer has. A
/// receiver carries what it holds at its velocity (PROTOCOL.md, "State streams"), the same sum
/// in the same precision as here, so a body on a straight path is not sent again until something
/// changes its motion: the budget goes to the bodies that did.
fn changed(held: &BodyMotion, now: &BodyMotion, elapsed_s: f64) -> bool {
    let (p, v) = (|k: usize| f64::from(held.1[k]), |k: usize| f64::from(held.2[k]));
    held.3 != now.3
        || (0..3).any(|k| {
            (p(k) + v(k) * elapsed_s - f64::from(now.1[k])).abs() > DRIFT || (v(k) - f64::from(now.2[k])).abs() > DRIFT
        })
}

/// What can change in a body's info, as a hash (see [`Entry::info`]).
pub(super) fn info_key(class: impact_core::sim::world::ClassId, game: &GameState, teleported: Option<Tick>) -> u64 {
    use std::hash::{Hash, Hasher};
    if game.is_empty() && teleported.is_none() {
        return u64::from(class.0);
    }
    let mut h = std::collections::hash_map::DefaultHasher::new();
    class.0.hash(&mut h);
    teleported.map(|t| t.0).hash(&mut h);
    for (k, v) in &game.0 {
        k.hash(&mut h);
        v.to_bits().hash(&mut h);
    }
    h.finish() | 1 << 63
}

/// A body's class id.
fn class_of(cap: &Capture, e: &Entry) -> Option<impact_core::sim::world::ClassId> {
    match e.src {
        Src::Dynamic(i) => Some(cap.table.class[i]),
        Src::Static(i) => Some(cap.statics.class[i]),
        Src::Terrain => cap.statics.terrain.as_ref().map(|t| t.class),
    }
}

/// A body's class name ("" if the class is unknown).
fn class_name<'a>(cap: &'a Capture, e: &Entry) -> &'a str {
    class_of(cap, e).and_then(|c| cap.config.classes.props.get(c.0 as usize)).map_or("", |p| p.name.as_str())
}

fn info(cap: &Capture, e: &Entry) -> BodyInfo {
    let half = (e.hi - e.lo) * 0.5;
    let pos = DVec3::new(f64::from(e.motion.1[0]), f64::from(e.motion.1[1]), f64::from(e.motion.1[2]));
    let offset = (e.hi + e.lo) * 0.5 - pos;
    let (owner, shape) = match e.src {
        Src::Dynamic(i) => (cap.table.owner[i], Some((&cap.table.shape[i], cap.table.rot[i]))),
        Src::Static(i) => (None, Some((&cap.statics.shape[i], cap.statics.rot[i]))),
        Src::Terrain => (None, None),
    };
    let primitive = |s: &impact_core::geometry::Shape| {
        use impact_core::geometry::ShapeKind as K;
        matches!(s.kind(), K::Sphere | K::Capsule | K::Cuboid | K::Ellipsoid).then(|| s.to_spec())
    };
    let rotation = shape.map(|(_, r)| r).filter(|r| *r != glam::DQuat::IDENTITY).map(|r| r.as_quat().to_array());
    BodyInfo {
        entity: e.motion.0,
        class: class_name(cap, e).to_string(),
        owner,
        shape: shape.map_or(BodyShape::Terrain, |(s, _)| shape_of(s)),
        half_extents_m: f32x3(half),
        offset_m: f32x3(offset),
        fixed: !matches!(e.src, Src::Dynamic(_)),
        rotation,
        local_shape: shape.and_then(|(s, _)| primitive(s)),
        state: match e.src {
            Src::Dynamic(i) => GameState::clone(&cap.table.game[i]),
            _ => GameState::default(),
        },
        teleported: match e.src {
            Src::Dynamic(i) => cap.table.teleported[i],
            _ => None,
        },
    }
}

/// The avatar's whole core state at the capture's tick (PROTOCOL.md, "Prediction"): exact
/// position and velocity, its sleep state, and its contacts with static geometry (`touches`: the
/// indices into the capture's contacts of those that involve it, in order; see [`touches_of`]).
pub(super) fn avatar_state(cap: &Capture, avatar: EntityId, touches: &[(EntityId, u32)]) -> Option<AvatarState> {
    let i = cap.table.id.binary_search(&avatar).ok()?;
    let is_body = |e: EntityId| cap.table.id.binary_search(&e).is_ok();
    let from = touches.partition_point(|t| t.0 < avatar);
    let touching = touches[from..]
        .iter()
        .take_while(|t| t.0 == avatar)
        .filter_map(|&(_, k)| {
            let t = &cap.touching[k as usize];
            let other = if t.a == avatar { t.b } else { t.a };
            (!is_body(other)).then(|| AvatarTouch {
                other,
                normal: t.normal.to_array(),
                depth_m: t.depth,
                impulse: t.impulse,
                friction_impulse: t.friction_impulse.to_array(),
            })
        })
        .collect();
    Some(AvatarState {
        entity: avatar,
        position: cap.pos[i].to_array(),
        velocity: cap.vel[i].to_array(),
        asleep: cap.asleep[i],
        still_ticks: cap.still[i],
        touching,
        class: Some(cap.table.class[i].0),
        teleported: cap.table.teleported[i],
    })
}

/// The capture's contacts by body, once a frame: `(body, index)` for each side of each contact,
/// in body order and then contact order, so a watcher's are one search away rather than a pass
/// over every watcher's contacts.
pub(super) fn touches_of(cap: &Capture, out: &mut Vec<(EntityId, u32)>) {
    out.clear();
    for (k, t) in cap.touching.iter().enumerate() {
        out.push((t.a, k as u32));
        if t.b != t.a {
            out.push((t.b, k as u32));
        }
    }
    out.sort_unstable();
}

fn shape_of(s: &impact_core::geometry::Shape) -> BodyShape {
    use impact_core::geometry::ShapeKind as K;
    match s.kind() {
        K::Sphere => BodyShape::Sphere,
        K::Capsule => BodyShape::Capsule,
        K::Cuboid => BodyShape::Cuboid,
        K::Ellipsoid => BodyShape::Ellipsoid,
        K::Convex => BodyShape::Convex,
        K::TriMesh => BodyShape::Trimesh,
    }
}

/// A need's priority (a squared distance, less first) as an integer that orders the same: a
/// non-negative float's bits do (`+ 0.0` makes a negative zero positive).
fn rank(d: f64) -> u64 {
    debug_assert!(d >= 0.0, "a priority is a distance");
    (d + 0.0).to_bits()
}

/// No entry: a body gone since the last frame.
const GONE: u32 = u32::MAX;

/// Last frame's entry index of each body to this frame's (bodies are added and removed between
/// frames, so indices shift): made once a frame from both frames' ids, both in entity order.
#[derive(Debug, Default)]
pub(super) struct Remap {
    ids: Vec<EntityId>,
    to: Vec<u32>,
}

impl Remap {
    /// Moves on to the frame of `entries`.
    pub(super) fn advance(&mut self, entries: &[Entry]) {
        self.to.clear();
        self.to.resize(self.ids.len(), GONE);
        let mut k = 0;
        for (old, id) in self.ids.iter().enumerate() {
            while k < entries.len() && entries[k].motion.0 < *id {
                k += 1;
            }
            if k < entries.len() && entries[k].motion.0 == *id {
                self.to[old] = k as u32;
            }
        }
        self.ids.clear();
        self.ids.extend(entries.iter().map(|e| e.motion.0));
    }

    fn get(&self, old: u32) -> u32 {
        self.to.get(old as usize).copied().unwrap_or(GONE)
    }
}

/// What a frame is built with besides the receiver: stamps over the entries (which are near the
/// receiver, at what distance, and which it holds) and buffers kept between receivers.
#[derive(Debug, Default)]
pub(super) struct Marks {
    stamp: u32,
    /// Per entry, together: a receiver reads and writes all three of the entries near it, one
    /// cache line each rather than three.
    at: Vec<Mark>,
    wants: Vec<Need>,
    spare: Vec<HeldBody>,
}

/// An entry's marks: the stamp of the receiver it is near (and its squared distance to it), and
/// of the receiver that holds it.
#[derive(Clone, Copy, Debug, Default)]
struct Mark {
    near: u32,
    held: u32,
    dist2: f64,
}

impl Marks {
    /// A fresh stamp for `n` entries: no entry is marked with it.
    fn begin(&mut self, n: usize) -> u32 {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.at.fill(Mark::default());
            self.stamp = 1;
        }
        self.at.resize(n, Mark::default());
        self.stamp
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Want {
    /// New to the receiver (or everything, on a full frame).
    Enter,
    /// Held (at this index of what it keeps), its motion changed.
    Move(u32),
    /// Held (at this index), its info changed: sent whole again. Held back, it stays held with
    /// what the receiver has, so it is still said to leave if it leaves.
    Again(u32),
}

/// A body a receiver needs, packed in one integer that orders as the needs are served: by
/// priority ([`rank`], less first), then by entry (entries are in entity order, so a tie goes to
/// the lower id); the [`Want`] in the low bits. Sixteen bytes, compared as one number: choosing
/// and sorting the needs that fit the budget is a large share of a frame's work.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Need(u128);

impl Need {
    const INDEX: u32 = (1 << 30) - 1;

    fn new(d2: f64, i: u32, want: Want) -> Need {
        let w = match want {
            Want::Enter => 0,
            Want::Move(k) => 1 << 30 | k,
            Want::Again(k) => 2 << 30 | k,
        };
        debug_assert!(matches!(want, Want::Move(k) | Want::Again(k) if k <= Need::INDEX) || w == 0);
        Need(u128::from(rank(d2)) << 64 | u128::from(i) << 32 | u128::from(w))
    }

    /// Its entry and what it wants.
    fn get(self) -> (u32, Want) {
        let w = self.0 as u32;
        let k = w & Need::INDEX;
        let want = match w >> 30 {
            0 => Want::Enter,
            1 => Want::Move(k),
            _ => Want::Again(k),
        };
        ((self.0 >> 32) as u32, want)
    }
}

/// The frame that brings `held` to the bodies of `cands` (`(squared priority distance, entry)`,
/// in any order), spending at most `budget` estimated bytes; updates `held` to what it sends.
#[allow(clippy::too_many_arguments)]
pub(super) fn build(
    held: &mut Held,
    (entries, remap): (&[Entry], &Remap),
    marks: &mut Marks,
    cap: &Capture,
    cands: &[(f64, u32)],
    budget: Option<f64>,
    full: bool,
    centre: Option<DVec3>,
) -> StateFrame {
    let mut frame = StateFrame {
        tick: cap.tick,
        frame: held.frame,
        full,
        entered: Vec::new(),
        moved: Vec::new(),
        left: Vec::new(),
        deferred: 0,
        centre: centre.map(f32x3),
        avatar: None,
    };
    held.frame = held.frame.wrapping_add(1);
    let mut spend = FRAME_BYTES;
    let stamp = marks.begin(entries.len());
    for &(d2, i) in cands {
        let m = &mut marks.at[i as usize];
        (m.near, m.dist2) = (stamp, d2);
    }
    let mut wants = std::mem::take(&mut marks.wants);
    wants.clear();
    let mut keep = std::mem::take(&mut marks.spare);
    keep.clear();
    // What it holds: still near (sent again if changed) or gone from its area.
    let old = std::mem::take(&mut held.bodies);
    for b in &old {
        let i = remap.get(b.at);
        if i == GONE || marks.at[i as usize].near != stamp {
            if !full {
                frame.left.push(b.motion.0);
                spend += LEFT_BYTES;
            }
            continue;
        }
        let m = &mut marks.at[i as usize];
        m.held = stamp;
        let (e, d2) = (&entries[i as usize], m.dist2);
        let b = HeldBody { at: i, ..*b };
        if full {
            wants.push(Need::new(d2, i, Want::Enter));
        } else if b.info != e.info {
            // Its class or game state changed: its info again, from the budget first.
            wants.push(Need::new(0.0, i, Want::Again(keep.len() as u32)));
            keep.push(b);
        } else if changed(&b.motion, &e.motion, f64::from(cap.tick.0.wrapping_sub(b.sent.0)) * cap.config.dt) {
            // The distance over one plus the frames it waited, squared as the distance is.
            let wait = 1.0 + f64::from(b.waited);
            wants.push(Need::new(d2 / (wait * wait), i, Want::Move(keep.len() as u32)));
            keep.push(b);
        } else {
            keep.push(b);
        }
    }
    // What is near and it does not hold: new to it.
    for &(d2, i) in cands {
        if marks.at[i as usize].held != stamp {
            wants.push(Need::new(d2, i, Want::Enter));
        }
    }
    if full {
        keep.clear();
    }
    // Only as many as the budget could hold at the cheapest need ordering: pick them, sort them;
    // the rest wait (in any order: each just waits).
    let fit = budget.map_or(wants.len(), |b| ((b - spend as f64).max(0.0) / MOTION_BYTES as f64) as usize + 1);
    frame.moved.reserve(fit.min(wants.len()));
    if fit < wants.len() {
        wants.select_nth_unstable(fit);
        wants[..fit].sort_unstable();
    } else {
        wants.sort_unstable();
    }
    for (i, want) in wants.iter().map(|n| n.get()) {
        let e = &entries[i as usize];
        let cost = match want {
            Want::Enter | Want::Again(_) => e.info_bytes as usize + MOTION_BYTES,
            Want::Move(_) => MOTION_BYTES,
        };
        if let Some(b) = budget {
            if (spend + cost) as f64 > b {
                frame.deferred += 1;
                if let Want::Move(k) | Want::Again(k) = want {
                    keep[k as usize].waited = keep[k as usize].waited.saturating_add(1);
                }
                continue;
            }
        }
        spend += cost;
        frame.moved.push(e.motion);
        match want {
            Want::Move(k) => {
                keep[k as usize] = HeldBody { motion: e.motion, sent: cap.tick, waited: 0, ..keep[k as usize] }
            }
            Want::Again(k) => {
                frame.entered.push(info(cap, e));
                keep[k as usize] =
                    HeldBody { motion: e.motion, sent: cap.tick, info: e.info, waited: 0, ..keep[k as usize] };
            }
            Want::Enter => {
                frame.entered.push(info(cap, e));
                keep.push(HeldBody { at: i, motion: e.motion, sent: cap.tick, info: e.info, waited: 0 });
            }
        }
    }
    frame.moved.sort_unstable_by_key(|m| m.0);
    frame.entered.sort_unstable_by_key(|i| i.entity);
    frame.left.sort_unstable();
    held.bodies = keep;
    marks.spare = old;
    marks.wants = wants;
    frame
}

/// The bytes a body's info is budgeted at.
pub(super) fn info_bytes(cap: &Capture, e: &Entry) -> usize {
    let state = match e.src {
        Src::Dynamic(i) => state_bytes(&cap.table.game[i]),
        _ => 0,
    };
    INFO_BYTES + class_name(cap, e).len() + state
}

/// A game state's MessagePack size at most: each name's string and a float.
fn state_bytes(g: &GameState) -> usize {
    g.0.keys().map(|k| k.len() + 2 + 9).sum::<usize>() + 8
}

/// The budgeted size of a frame: at least its MessagePack size.
pub(super) fn estimate(f: &StateFrame) -> usize {
    let infos: usize = f.entered.iter().map(|i| INFO_BYTES + i.class.len() + state_bytes(&i.state)).sum();
    let avatar = f.avatar.as_ref().map_or(0, |a| AVATAR_BYTES + a.touching.len() * TOUCH_BYTES);
    FRAME_BYTES + infos + f.moved.len() * MOTION_BYTES + f.left.len() * LEFT_BYTES + avatar
}

/// The frame encoded for `key`, in a buffer of the frame's [`estimate`] (its MessagePack
/// size at most: written without growing), MessagePack by the frame's own writer
/// ([`StateFrame::encode_msgpack`], the bytes serde writes in a fraction of the time).
pub(super) fn publish(
    key: String,
    client: Option<ClientId>,
    frame: StateFrame,
    encoding: Encoding,
    keep: bool,
) -> Option<Publish> {
    let deferred = frame.deferred;
    let mut bytes = Vec::with_capacity(estimate(&frame));
    let frame = match encoding {
        Encoding::MsgPack => {
            frame.encode_msgpack(&mut bytes).ok()?;
            frame
        }
        Encoding::Json => {
            let msg = ServerMessage::State(frame);
            encode_into(&msg, encoding, &mut bytes).ok()?;
            let ServerMessage::State(frame) = msg else { return None };
            frame
        }
    };
    Some(Publish { key, bytes, encoding, client, deferred, frame: keep.then_some(frame) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Needs order by priority, then by entry, and give back the entry and want they were made of.
    #[test]
    fn needs_order_by_priority_then_entry() {
        let made = [
            (2.5, 1, Want::Enter),
            (0.0, 9, Want::Again(Need::INDEX)),
            (2.5, 0, Want::Move(0)),
            (1e-300, 3, Want::Move(7)),
            (f64::MAX, u32::MAX - 1, Want::Again(0)),
        ];
        let mut needs: Vec<Need> = made.iter().map(|&(d2, i, w)| Need::new(d2, i, w)).collect();
        for (n, &(_, i, w)) in needs.iter().zip(&made) {
            assert_eq!(n.get(), (i, w));
        }
        needs.sort_unstable();
        let order: Vec<u32> = needs.iter().map(|n| n.get().0).collect();
        assert_eq!(order, [9, 3, 0, 1, u32::MAX - 1]);
    }
}
