//! A uniform grid hashed into a fixed table. The cell is as large as the largest box, and each
//! box is filed under the cell of its lower corner, so two overlapping boxes sit in the same or
//! adjacent cells. Each cell is compared with itself and 13 of its 26 neighbours (the ones that
//! come after it), so every pair of cells is visited once. A counting sort by bucket builds the
//! table in O(n) with no allocation once warm and no hash-map iteration order anywhere: buckets
//! are visited in index order and a bucket's entries are in body order.

use crate::sim::shape::Aabb;
use glam::DVec3;

#[derive(Clone, Copy, Debug)]
struct Entry {
    min: DVec3,
    max: DVec3,
    cell: [i64; 3],
    body: u32,
}

/// Grid state; the buffers are reused from tick to tick.
#[derive(Debug, Default)]
pub struct Grid {
    cell: f64,
    origin: DVec3,
    mask: usize,
    start: Vec<u32>,
    entries: Vec<Entry>,
    bucket_of: Vec<u32>,
    cursor: Vec<u32>,
}

/// The 13 neighbour offsets lexicographically after (0, 0, 0).
const FORWARD: [[i64; 3]; 13] = {
    let mut out = [[0i64; 3]; 13];
    let mut n = 0;
    let mut dx = -1;
    while dx <= 1 {
        let mut dy = -1;
        while dy <= 1 {
            let mut dz = -1;
            while dz <= 1 {
                if dx > 0 || (dx == 0 && (dy > 0 || (dy == 0 && dz > 0))) {
                    out[n] = [dx, dy, dz];
                    n += 1;
                }
                dz += 1;
            }
            dy += 1;
        }
        dx += 1;
    }
    out
};

#[inline]
fn hash(c: [i64; 3]) -> u64 {
    let h = (c[0] as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (c[1] as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (c[2] as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^ (h >> 29)
}

impl Grid {
    #[inline]
    fn cell_of(&self, p: DVec3) -> [i64; 3] {
        let q = (p - self.origin) / self.cell;
        [q.x.floor() as i64, q.y.floor() as i64, q.z.floor() as i64]
    }

    #[inline]
    fn bucket(&self, c: [i64; 3]) -> usize {
        hash(c) as usize & self.mask
    }

    fn build(&mut self, aabbs: &[Aabb]) {
        let n = aabbs.len();
        let mut origin = DVec3::splat(f64::INFINITY);
        let mut cell: f64 = 0.0;
        for b in aabbs {
            origin = origin.min(b.min);
            cell = cell.max(b.extents().max_element());
        }
        self.origin = origin;
        // A zero-size set of boxes still needs a positive cell.
        self.cell = if cell > 0.0 { cell } else { 1.0 };
        let table = (2 * n).next_power_of_two().max(2);
        self.mask = table - 1;
        self.start.clear();
        self.start.resize(table + 1, 0);
        self.bucket_of.clear();
        for b in aabbs {
            let k = self.bucket(self.cell_of(b.min));
            self.bucket_of.push(k as u32);
            self.start[k + 1] += 1;
        }
        for k in 0..table {
            self.start[k + 1] += self.start[k];
        }
        self.entries.clear();
        self.entries.resize(
            n,
            Entry {
                min: DVec3::ZERO,
                max: DVec3::ZERO,
                cell: [0; 3],
                body: 0,
            },
        );
        // Fill with a moving cursor per bucket (stable: ascending body index within a bucket).
        self.cursor.clear();
        self.cursor.extend_from_slice(&self.start[..table]);
        for (i, b) in aabbs.iter().enumerate() {
            let k = self.bucket_of[i] as usize;
            let at = self.cursor[k] as usize;
            self.cursor[k] += 1;
            self.entries[at] = Entry {
                min: b.min,
                max: b.max,
                cell: self.cell_of(b.min),
                body: i as u32,
            };
        }
    }

    /// Appends every overlapping pair `(i, j)`, `i < j`.
    pub fn pairs(&mut self, aabbs: &[Aabb], out: &mut Vec<(u32, u32)>) {
        self.build(aabbs);
        let overlap = |a: &Entry, b: &Entry| {
            a.min.x <= b.max.x
                && b.min.x <= a.max.x
                && a.min.y <= b.max.y
                && b.min.y <= a.max.y
                && a.min.z <= b.max.z
                && b.min.z <= a.max.z
        };
        for p in 0..self.entries.len() {
            let e = self.entries[p];
            let own = self.bucket(e.cell);
            let end = self.start[own + 1] as usize;
            for f in &self.entries[p + 1..end] {
                if f.cell == e.cell && overlap(&e, f) {
                    out.push((e.body.min(f.body), e.body.max(f.body)));
                }
            }
            for off in FORWARD {
                let c = [e.cell[0] + off[0], e.cell[1] + off[1], e.cell[2] + off[2]];
                let k = self.bucket(c);
                for f in &self.entries[self.start[k] as usize..self.start[k + 1] as usize] {
                    if f.cell == c && overlap(&e, f) {
                        out.push((e.body.min(f.body), e.body.max(f.body)));
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
        let lo = self.cell_of(query.min - DVec3::splat(self.cell));
        let hi = self.cell_of(query.max);
        let span = (0..3)
            .map(|k| (hi[k] - lo[k] + 1).max(0) as u128)
            .product::<u128>();
        if span > 4096 {
            return super::brute::query(aabbs, query, out);
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    let c = [x, y, z];
                    let k = self.bucket(c);
                    for f in &self.entries[self.start[k] as usize..self.start[k + 1] as usize] {
                        if f.cell == c
                            && (Aabb {
                                min: f.min,
                                max: f.max,
                            })
                            .overlaps(query)
                        {
                            out.push(f.body);
                        }
                    }
                }
            }
        }
    }
}
