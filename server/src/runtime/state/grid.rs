//! The area grid: the bodies filed by cell, so a client's area is a few rows of cells.

use glam::DVec3;
use impact_core::geometry::floor_i64;

/// A body filed in a grid cell: its bounds beside its index, so a search reads cells in order.
#[derive(Clone, Copy, Debug)]
pub(super) struct Filed {
    pub(super) lo: DVec3,
    pub(super) hi: DVec3,
    pub(super) i: u32,
}

/// The bodies filed by the cell their centre is in, in a dense grid over the centres' bounds:
/// cells in (x, y, z) order, z fastest, each cell's bodies together, so a search reads each
/// (x, y) row of cells as one slice (no hashing, no pointer chasing).
#[derive(Debug, Default)]
pub(super) struct AreaGrid {
    pub(super) origin: DVec3,
    pub(super) size: f64,
    pub(super) dims: [i64; 3],
    /// `start[k]..start[k + 1]` are cell `k`'s bodies in `items`.
    pub(super) start: Vec<u32>,
    pub(super) items: Vec<Filed>,
}

/// Most cells a grid has; a world wider than this many cells of the asked size gets bigger cells.
const MAX_CELLS: i64 = 1 << 20;

impl AreaGrid {
    pub(super) fn cell_of(&self, p: DVec3) -> [i64; 3] {
        let q = (p - self.origin) / self.size;
        [floor_i64(q.x), floor_i64(q.y), floor_i64(q.z)]
    }

    pub(super) fn index(&self, c: [i64; 3]) -> usize {
        ((c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]) as usize
    }

    /// Files `bodies` in cells of (at least) `size`.
    pub(super) fn build(&mut self, size: f64, bodies: &[Filed]) {
        self.items.clear();
        self.start.clear();
        if bodies.is_empty() {
            self.dims = [0; 3];
            return;
        }
        let centre = |f: &Filed| (f.lo + f.hi) * 0.5;
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for f in bodies {
            lo = lo.min(centre(f));
            hi = hi.max(centre(f));
        }
        self.origin = lo;
        self.size = size;
        loop {
            let d = ((hi - lo) / self.size).floor() + DVec3::ONE;
            self.dims = [d.x as i64, d.y as i64, d.z as i64];
            if d.x * d.y * d.z <= MAX_CELLS as f64 {
                break;
            }
            self.size *= 2.0;
        }
        let cells = (self.dims[0] * self.dims[1] * self.dims[2]) as usize;
        self.start.resize(cells + 1, 0);
        let keys: Vec<usize> = bodies.iter().map(|f| self.index(self.cell_of(centre(f)))).collect();
        for &k in &keys {
            self.start[k + 1] += 1;
        }
        for k in 0..cells {
            self.start[k + 1] += self.start[k];
        }
        let mut at: Vec<u32> = self.start[..cells].to_vec();
        self.items.resize(bodies.len(), bodies[0]);
        for (f, &k) in bodies.iter().zip(&keys) {
            self.items[at[k] as usize] = *f;
            at[k] += 1;
        }
    }
}
