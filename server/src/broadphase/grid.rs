//! A uniform grid. The cell is as large as the largest box, and each box is filed under the cell
//! of its lower corner, so two overlapping boxes sit in the same or adjacent cells. Each cell is
//! compared with itself and 13 of its 26 neighbours (those that come after it), so every pair of
//! cells is visited once.
//!
//! Two layouts, chosen per tick:
//! - **dense**: when the occupied region has at most a few cells per body (the common case, a
//!   populated arena), cells are indexed directly in a grid padded by one cell on every side, so
//!   a neighbour is a fixed offset away and needs neither a bounds check nor a hash;
//! - **hashed**: for sparse worlds (a few bodies spread over kilometres), cells hash into a table
//!   of twice the body count, and entries carry their cell to reject hash collisions.
//!
//! Both fill their table with a counting sort: O(n), no allocation once warm, and no hash-map
//! iteration order anywhere (buckets are visited in index order, a bucket's entries in body
//! order).

use crate::sim::shape::Aabb;
use glam::DVec3;

#[derive(Clone, Copy, Debug, Default)]
struct Entry {
    min: DVec3,
    max: DVec3,
    body: u32,
}

/// Grid state; the buffers are reused from tick to tick.
#[derive(Debug, Default)]
pub struct Grid {
    cell: f64,
    origin: DVec3,
    dense: bool,
    dims: [i64; 3],
    mask: usize,
    start: Vec<u32>,
    entries: Vec<Entry>,
    cells: Vec<[i64; 3]>,
    bucket_of: Vec<u32>,
    cursor: Vec<u32>,
}

/// The 13 neighbour offsets lexicographically after (0, 0, 0).
const FORWARD: [[i64; 3]; 13] = {
    let mut out = [[0i64; 3]; 13];
    let mut n = 0;
    let mut dz = -1;
    while dz <= 1 {
        let mut dy = -1;
        while dy <= 1 {
            let mut dx = -1;
            while dx <= 1 {
                if dz > 0 || (dz == 0 && (dy > 0 || (dy == 0 && dx > 0))) {
                    out[n] = [dx, dy, dz];
                    n += 1;
                }
                dx += 1;
            }
            dy += 1;
        }
        dz += 1;
    }
    out
};

/// Most cells per body for the dense layout.
const DENSE_CELLS_PER_BODY: i64 = 64;

#[inline]
fn hash(c: [i64; 3]) -> u64 {
    let h = (c[0] as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (c[1] as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (c[2] as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^ (h >> 29)
}

/// `floor` by truncation (a single instruction on every x86-64, where `f64::floor` is a libm
/// call without SSE4.1).
#[inline]
fn floor_i64(q: f64) -> i64 {
    let t = q as i64;
    if (t as f64) > q {
        t - 1
    } else {
        t
    }
}

#[inline]
fn overlap(a: &Entry, b: &Entry) -> bool {
    a.min.x <= b.max.x
        && b.min.x <= a.max.x
        && a.min.y <= b.max.y
        && b.min.y <= a.max.y
        && a.min.z <= b.max.z
        && b.min.z <= a.max.z
}

impl Grid {
    #[inline]
    fn cell_of(&self, p: DVec3) -> [i64; 3] {
        let q = (p - self.origin) / self.cell;
        [floor_i64(q.x), floor_i64(q.y), floor_i64(q.z)]
    }

    /// Table slot of a cell: its padded linear index (dense) or its hash (hashed).
    #[inline]
    fn slot(&self, c: [i64; 3]) -> usize {
        if self.dense {
            ((c[0] + 1) + self.dims[0] * ((c[1] + 1) + self.dims[1] * (c[2] + 1))) as usize
        } else {
            hash(c) as usize & self.mask
        }
    }

    fn build(&mut self, aabbs: &[Aabb]) {
        let n = aabbs.len();
        let mut origin = DVec3::splat(f64::INFINITY);
        let mut top = DVec3::splat(f64::NEG_INFINITY);
        let mut cell: f64 = 0.0;
        for b in aabbs {
            origin = origin.min(b.min);
            top = top.max(b.min);
            cell = cell.max(b.extents().max_element());
        }
        self.origin = origin;
        // A zero-size set of boxes still needs a positive cell.
        self.cell = if cell > 0.0 { cell } else { 1.0 };
        self.cells.clear();
        self.cells.extend(aabbs.iter().map(|b| {
            let q = (b.min - origin) / self.cell;
            [q.x as i64, q.y as i64, q.z as i64] // non-negative: truncation is floor
        }));
        let span = if n == 0 { DVec3::ZERO } else { (top - origin) / self.cell };
        // Padded dimensions; f64 so a huge sparse world cannot overflow the product.
        let dims = [span.x, span.y, span.z].map(|s| s.floor() + 3.0);
        let total = dims[0] * dims[1] * dims[2];
        self.dense = total <= (DENSE_CELLS_PER_BODY * (n as i64).max(64)) as f64;
        let table = if self.dense {
            self.dims = dims.map(|d| d as i64);
            total as usize
        } else {
            let t = (2 * n).next_power_of_two().max(2);
            self.mask = t - 1;
            t
        };
        self.start.clear();
        self.start.resize(table + 1, 0);
        self.bucket_of.clear();
        for k in 0..n {
            let s = self.slot(self.cells[k]);
            self.bucket_of.push(s as u32);
            self.start[s + 1] += 1;
        }
        for k in 0..table {
            self.start[k + 1] += self.start[k];
        }
        self.entries.clear();
        self.entries.resize(n, Entry::default());
        self.cursor.clear();
        self.cursor.extend_from_slice(&self.start[..table]);
        // Cells of the entries, in table order (needed by the hashed layout's collision check).
        let mut sorted_cells = std::mem::take(&mut self.cells);
        let unsorted = sorted_cells.clone();
        for (i, b) in aabbs.iter().enumerate() {
            let k = self.bucket_of[i] as usize;
            let at = self.cursor[k] as usize;
            self.cursor[k] += 1;
            self.entries[at] = Entry { min: b.min, max: b.max, body: i as u32 };
            sorted_cells[at] = unsorted[i];
        }
        self.cells = sorted_cells;
    }

    /// Appends every overlapping pair `(i, j)`, `i < j`.
    pub fn pairs(&mut self, aabbs: &[Aabb], out: &mut Vec<(u32, u32)>) {
        self.build(aabbs);
        if self.dense {
            let (dx, dy) = (self.dims[0], self.dims[0] * self.dims[1]);
            let offsets = FORWARD.map(|o| (o[0] + o[1] * dx + o[2] * dy) as isize);
            for p in 0..self.entries.len() {
                let e = self.entries[p];
                let own = self.bucket_of[e.body as usize] as usize;
                let end = self.start[own + 1] as usize;
                for f in &self.entries[p + 1..end] {
                    if overlap(&e, f) {
                        out.push((e.body.min(f.body), e.body.max(f.body)));
                    }
                }
                for off in offsets {
                    let k = (own as isize + off) as usize;
                    for f in &self.entries[self.start[k] as usize..self.start[k + 1] as usize] {
                        if overlap(&e, f) {
                            out.push((e.body.min(f.body), e.body.max(f.body)));
                        }
                    }
                }
            }
        } else {
            for p in 0..self.entries.len() {
                let e = self.entries[p];
                let c = self.cells[p];
                let own = self.slot(c);
                let end = self.start[own + 1] as usize;
                for q in p + 1..end {
                    let f = &self.entries[q];
                    if self.cells[q] == c && overlap(&e, f) {
                        out.push((e.body.min(f.body), e.body.max(f.body)));
                    }
                }
                for off in FORWARD {
                    let nc = [c[0] + off[0], c[1] + off[1], c[2] + off[2]];
                    let k = self.slot(nc);
                    for q in self.start[k] as usize..self.start[k + 1] as usize {
                        let f = &self.entries[q];
                        if self.cells[q] == nc && overlap(&e, f) {
                            out.push((e.body.min(f.body), e.body.max(f.body)));
                        }
                    }
                }
            }
        }
    }

    /// Appends every box (from the last build) overlapping `query`.
    pub fn query(&self, aabbs: &[Aabb], query: &Aabb, out: &mut Vec<u32>) {
        if self.entries.len() != aabbs.len() || self.entries.is_empty() {
            return super::brute::query(aabbs, query, out);
        }
        let mut lo = self.cell_of(query.min - DVec3::splat(self.cell));
        let mut hi = self.cell_of(query.max);
        if self.dense {
            // Clamp to the grid's occupied range (padding cells are empty).
            for k in 0..3 {
                lo[k] = lo[k].max(0);
                hi[k] = hi[k].min(self.dims[k] - 3);
            }
        }
        let span = (0..3).map(|k| (hi[k] - lo[k] + 1).max(0) as u128).product::<u128>();
        if span > 4096 {
            return super::brute::query(aabbs, query, out);
        }
        let q = Entry { min: query.min, max: query.max, body: 0 };
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    let c = [x, y, z];
                    let k = self.slot(c);
                    for p in self.start[k] as usize..self.start[k + 1] as usize {
                        if (self.dense || self.cells[p] == c) && overlap(&self.entries[p], &q) {
                            out.push(self.entries[p].body);
                        }
                    }
                }
            }
        }
    }
}
