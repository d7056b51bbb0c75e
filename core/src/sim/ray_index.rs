//! The bodies of one world filed by cell for ray casts, so a ray tests the bodies in the cells it
//! crosses instead of every body.
//!
//! A tick's rewound shots look at a few past worlds, and each past world is looked at again by
//! later ticks' shots: the server builds a [`RayIndex`] once per past world it keeps and casts
//! every shot at that world through it ([`cast_many_indexed`]). The answers are the scan's
//! ([`super::ray::cast_many`]) bit for bit: a hit is a point inside the body's bounding sphere,
//! every body is filed in every cell its (slightly grown) sphere's box touches, the ray visits
//! its cells in order along its length and stops only at a cell that begins beyond its nearest
//! hit so far; the nearest hit is taken as the scan takes it (distance, then the lower id), so the
//! order bodies are met in does not matter. Bodies moved since the index was built
//! ([`RayIndex::moved`]) are tested by every ray where they are now, as bodies larger than a cell
//! are.

use super::ray::{body_hit, hit_of, static_hits, Best, Ray};
use super::world::World;
use crate::geometry::floor_i64;
use glam::DVec3;
use impact_protocol::RayHit;

/// Most cells along one axis: a wider world gets bigger cells.
const MAX_DIM: f64 = 128.0;

/// A world's dynamic bodies by cell (the static bodies and the terrain are few and tested as
/// the scan tests them).
#[derive(Clone, Debug, Default)]
pub struct RayIndex {
    /// The grid's lowest corner.
    origin: DVec3,
    cell: f64,
    dims: [i64; 3],
    /// `start[k]..start[k + 1]` are cell `k`'s bodies in `items`.
    start: Vec<u32>,
    items: Vec<u32>,
    /// Bodies larger than a cell, tested by every ray.
    large: Vec<u32>,
    /// Bodies (ascending) that moved since they were filed ([`RayIndex::moved`]): their cells
    /// are stale, so every ray tests them directly.
    moved: Vec<u32>,
    /// The bodies the world had when the index was built (a world changed since is scanned).
    bodies: usize,
}

/// How far a body's filed box reaches past its bounding sphere: far more than the rounding of
/// the walk (a few ulps of the coordinates), so a hit point on the sphere is inside a cell the
/// body is filed in even when it lies on a cell's face.
fn margin(p: DVec3) -> f64 {
    1e-6 + 1e-9 * p.abs().max_element()
}

impl RayIndex {
    /// Files `w`'s dynamic bodies.
    pub fn build(w: &World) -> RayIndex {
        let b = &w.bodies;
        let n = b.len();
        let mut index = RayIndex { bodies: n, ..RayIndex::default() };
        if n == 0 {
            return index;
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in &b.pos {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        // About eight bodies' worth of space a cell, at most MAX_DIM cells an axis.
        let extent = (hi - lo).max(DVec3::ONE);
        let mut cell = (extent.x * extent.y * extent.z / n as f64).cbrt() * 2.0;
        cell = cell.max(extent.max_element() / MAX_DIM).max(1e-3);
        // Bodies no larger than a cell reach at most one cell past the centres' bounds.
        index.origin = lo - DVec3::splat(cell);
        index.cell = cell;
        let dims = ((hi - index.origin) / cell).floor() + DVec3::splat(2.0);
        index.dims = [dims.x as i64, dims.y as i64, dims.z as i64];
        let cells = (index.dims[0] * index.dims[1] * index.dims[2]) as usize;
        // Each small body's cells: a box of at most 3 x 3 x 3.
        let mut spans: Vec<([i64; 3], [i64; 3])> = Vec::with_capacity(n);
        index.start = vec![0; cells + 1];
        for i in 0..n {
            let grow = b.radius[i] * (1.0 + 1e-9) + margin(b.pos[i]);
            if grow > cell {
                index.large.push(i as u32);
                spans.push(([0; 3], [-1; 3]));
                continue;
            }
            let (c0, c1) = (index.cell_of(b.pos[i] - DVec3::splat(grow)), index.cell_of(b.pos[i] + DVec3::splat(grow)));
            let mut start = std::mem::take(&mut index.start);
            for_cells(c0, c1, |c| start[index.at(c) + 1] += 1);
            index.start = start;
            spans.push((c0, c1));
        }
        for k in 0..cells {
            index.start[k + 1] += index.start[k];
        }
        let mut fill: Vec<u32> = index.start[..cells].to_vec();
        let mut items = vec![0; index.start[cells] as usize];
        for (i, (c0, c1)) in spans.into_iter().enumerate() {
            for_cells(c0, c1, |c| {
                let k = index.at(c);
                items[fill[k] as usize] = i as u32;
                fill[k] += 1;
            });
        }
        index.items = items;
        index
    }

    /// Notes that the bodies in `slots` moved (the world's bodies are otherwise as filed, and as
    /// many): rays test them directly from now on, wherever they are. Returns false once more than
    /// a sixteenth of the bodies have moved: the index is then better built again.
    ///
    /// A rollback that re-simulates a few bodies changes only their motion in the past worlds it
    /// writes back; their indices stay, and a later shot at those ticks casts through them.
    pub fn moved(&mut self, slots: impl IntoIterator<Item = usize>) -> bool {
        for slot in slots {
            let slot = slot as u32;
            if let Err(at) = self.moved.binary_search(&slot) {
                self.moved.insert(at, slot);
            }
        }
        self.moved.len() * 16 <= self.bodies
    }

    /// The cell `p` is in, clamped to the grid.
    fn cell_of(&self, p: DVec3) -> [i64; 3] {
        let q = (p - self.origin) / self.cell;
        [0, 1, 2].map(|k| floor_i64(q[k]).clamp(0, self.dims[k] - 1))
    }

    fn at(&self, c: [i64; 3]) -> usize {
        ((c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]) as usize
    }

    /// Calls `visit` with the bodies of each cell `ray` crosses, in order along it, with the
    /// distance at which the ray enters the cell; `visit` returns `false` to stop.
    fn walk(&self, ray: &Ray, mut visit: impl FnMut(f64, &[u32]) -> bool) {
        let lo = self.origin;
        let hi = self.origin + DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64) * self.cell;
        // The part of the segment inside the grid (slabs).
        let (mut t0, mut t1) = (0.0f64, ray.max_m);
        for k in 0..3 {
            let (o, d) = (ray.origin[k], ray.dir[k]);
            if d == 0.0 {
                if o < lo[k] || o > hi[k] {
                    return;
                }
                continue;
            }
            let (a, b) = ((lo[k] - o) / d, (hi[k] - o) / d);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        if t0 > t1 {
            return;
        }
        let mut c = self.cell_of(ray.origin + ray.dir * t0);
        let mut step = [0i64; 3];
        let mut next = [f64::INFINITY; 3];
        let mut delta = [f64::INFINITY; 3];
        for k in 0..3 {
            let d = ray.dir[k];
            if d > 0.0 {
                step[k] = 1;
                next[k] = (lo[k] + (c[k] + 1) as f64 * self.cell - ray.origin[k]) / d;
                delta[k] = self.cell / d;
            } else if d < 0.0 {
                step[k] = -1;
                next[k] = (lo[k] + c[k] as f64 * self.cell - ray.origin[k]) / d;
                delta[k] = -self.cell / d;
            }
        }
        let mut enter = t0;
        loop {
            let k = self.at(c);
            if !visit(enter, &self.items[self.start[k] as usize..self.start[k + 1] as usize]) {
                return;
            }
            let axis = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            enter = next[axis];
            if enter > t1 {
                return;
            }
            c[axis] += step[axis];
            if c[axis] < 0 || c[axis] >= self.dims[axis] {
                return;
            }
            next[axis] += delta[axis];
        }
    }
}

/// Calls `f` for every cell from `c0` to `c1` inclusive.
fn for_cells(c0: [i64; 3], c1: [i64; 3], mut f: impl FnMut([i64; 3])) {
    for x in c0[0]..=c1[0] {
        for y in c0[1]..=c1[1] {
            for z in c0[2]..=c1[2] {
                f([x, y, z]);
            }
        }
    }
}

/// The first hit of each of `rays` against `w`, exactly as [`super::ray::cast_many`] answers
/// them, through `index` (built from `w`; an index of another body count is not used and every
/// body is scanned). `out` is cleared first.
pub fn cast_many_indexed(w: &World, index: &RayIndex, rays: &[Ray], out: &mut Vec<Option<RayHit>>) {
    if index.bodies != w.bodies.len() {
        return super::ray::cast_many(w, rays, out);
    }
    // Each body once per ray, however many cells it is filed in.
    let mut seen = vec![u32::MAX; w.bodies.len()];
    out.clear();
    for (r, ray) in rays.iter().enumerate() {
        let mut best: Best = None;
        for &i in &index.large {
            body_hit(w, i as usize, ray, &mut best);
        }
        // Moved bodies where they are now; the cells they were filed in skip them.
        for &i in &index.moved {
            seen[i as usize] = r as u32;
            body_hit(w, i as usize, ray, &mut best);
        }
        index.walk(ray, |enter, bodies| {
            // A cell that begins past the nearest hit holds nothing nearer (ties included; the
            // walk's rounding is far below the margin bodies are filed with).
            if best.is_some_and(|(s, _, _)| enter > s + margin(ray.origin + ray.dir * s)) {
                return false;
            }
            for &i in bodies {
                if std::mem::replace(&mut seen[i as usize], r as u32) != r as u32 {
                    body_hit(w, i as usize, ray, &mut best);
                }
            }
            true
        });
        static_hits(w, ray, &mut best);
        out.push(hit_of(ray, best));
    }
}
