//! Bodies lying inside each other as the world stands: an inspection, not a stage of the tick.
//! The scene loader's `bodies_overlap` warning and the rest benchmark's penetration figure both
//! walk it.

use crate::broadphase::{Broadphase, BroadphaseKind};
use crate::narrow::{self, Contact};
use crate::par::Pool;
use crate::sim::world::World;

/// The other side of an overlap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Other {
    /// A dynamic body, by slot.
    Body(usize),
    /// Static geometry, by index into the static world.
    Static(usize),
    /// The terrain.
    Terrain,
}

/// Calls `f(slot, other, contact)` for every overlap (depth above zero) of a dynamic body: with
/// each other dynamic body whose box meets its own (each pair once, the lower slot first), with
/// the static geometry its box reaches, and with the terrain. Contacts are in the first body's
/// pair frame (its exact kernels); class rules are not consulted, that is the caller's choice.
pub fn each(w: &World, mut f: impl FnMut(usize, Other, Contact)) {
    let b = &w.bodies;
    let boxes: Vec<_> = (0..b.len()).map(|i| b.shape[i].world_aabb(b.pos[i], b.rot[i])).collect();
    let mut pairs = Vec::new();
    Broadphase::new(BroadphaseKind::Grid).pairs(&boxes, &mut pairs, &Pool::sequential());
    for (i, j) in pairs {
        let (i, j) = (i as usize, j as usize);
        if let Some(c) = narrow::contact(&b.shape[i], b.rot[i], &b.shape[j], b.rot[j], b.pos[j] - b.pos[i], 0.0) {
            f(i, Other::Body(j), c);
        }
    }
    let s = &w.statics;
    let mut found = Vec::new();
    for (i, bounds) in boxes.iter().enumerate() {
        s.index.query(bounds, &mut found);
        for &k in &found {
            let k = k as usize;
            if let Some(c) = narrow::contact(&b.shape[i], b.rot[i], &s.shape[k], s.rot[k], s.pos[k] - b.pos[i], 0.0) {
                f(i, Other::Static(k), c);
            }
        }
        if let Some(t) = s.terrain.as_ref().filter(|t| t.field.aabb().overlaps(bounds)) {
            if let Some(c) = narrow::terrain_contact(&b.shape[i], b.rot[i], b.pos[i], &t.field, 0.0) {
                f(i, Other::Terrain, c);
            }
        }
    }
}
