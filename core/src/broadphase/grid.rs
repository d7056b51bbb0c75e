//! A uniform grid, as sorted cell keys. The cell is as large as the largest box (and a hair larger:
//! `CELL_MARGIN`), and each box is filed under the cell of its lower corner, so two overlapping
//! boxes sit in the same or adjacent cells. Cells are numbered row by row (`x` fastest), and the
//! boxes are kept sorted by cell number with a radix sort, O(n) whatever the motion. (An insertion
//! sort from the previous tick's order was tried: a body changing cell along z moves a whole slab
//! of entries, which grows as n^(2/3).)
//!
//! Each cell is compared with itself and the 13 of its 26 neighbours that come after it, so each
//! pair of cells is visited once. Those 13 lie in five runs of consecutive cell numbers: the rest
//! of its own row (`x + 1`), and three cells (`x - 1 ..= x + 1`) in each of four later rows. As the
//! sweep walks the boxes in cell order, the start of each run only moves forward, so one cursor
//! per run finds it: the whole sweep is O(n + pairs) and walks memory in order. No table grows
//! with the volume of the world, so a sparse world costs what a dense one does.
//!
//! When the world is compact (at most `DENSE_CELLS_PER_BODY` cells per body) a table of where
//! each cell's entries start replaces both the radix sort (a counting sort fills it in one pass)
//! and the cursors (each run is two loads): the cursors walked every entry four times and their
//! loop exits were the sweep's main cost. Both paths give the same order and the same pairs.

use crate::geometry::{floor_i64, Aabb};
use crate::par::{Pool, MIN_PIECE, MIN_PIECE_HEAVY};
use glam::DVec3;

/// How much larger than the largest box a cell is, as a fraction. Two overlapping boxes' lower
/// corners are at most one box apart, and so, in cells, at most `1 / (1 + CELL_MARGIN)` apart
/// before rounding: the few ulps that computing cell coordinates can add (far less than this
/// margin while an axis has fewer than 2^32 cells) can never put them two cells apart. With the
/// cell exactly the largest box, two boxes one cell apart to the last digit could round into
/// cells two apart and their pair be missed.
const CELL_MARGIN: f64 = 1.0 / (1u64 << 20) as f64;

/// Above this many cells per body the cell-start table would cost more than the cursors save
/// (and would grow with the world's volume): the sorted keys and cursors serve instead.
pub(crate) const DENSE_CELLS_PER_BODY: u64 = 32;

/// Grid state, carried across ticks (the sort order) and reused (the buffers).
#[derive(Clone, Debug, Default)]
pub struct Grid {
    /// One over the cell's size: cell coordinates by a multiplication, not three divisions a box.
    inv_cell: f64,
    origin: DVec3,
    /// Cells per row and per slab (rows are padded by one cell at each end, slabs by one row).
    row: u64,
    slab: u64,
    /// Padded dimensions in cells.
    dims: [i64; 3],
    /// Body indices sorted by cell key.
    order: Vec<u32>,
    /// Cell key of `order[k]`.
    keys: Vec<u64>,
    /// Boxes in sorted order (for memory-order access in the sweep).
    boxes: Vec<Aabb>,
    /// Whether the last build succeeded (keys fit in 64 bits).
    built: bool,
    /// `key << 32 | body`, and the radix sort's scratch.
    packed: Vec<u64>,
    scratch: Vec<u64>,
    /// Always use the sorted keys and cursors (the tests compare both paths).
    pub sparse_only: bool,
    /// Compact worlds: `start[k]` is the index in `order` of cell `k`'s first entry (and
    /// `start[k + 1]` one past its last). Empty when the sorted-keys path is in use.
    start: Vec<u32>,
}

/// Running sums in place: each piece sums itself, then adds the total of the pieces before it.
fn prefix_sum(v: &mut [u32], pool: &Pool) {
    let pieces = std::sync::Mutex::new(Vec::new());
    pool.for_each_mut(v, MIN_PIECE * 8, |first, piece| {
        let mut sum = 0u32;
        for x in piece.iter_mut() {
            sum += *x;
            *x = sum;
        }
        pieces.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push((first, sum));
    });
    let mut pieces = pieces.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner);
    if pieces.len() < 2 {
        return;
    }
    pieces.sort_unstable();
    let mut before = 0;
    let offsets: Vec<(usize, u32)> = pieces
        .iter()
        .map(|&(first, total)| {
            let o = (first, before);
            before += total;
            o
        })
        .collect();
    pool.for_each_mut(v, MIN_PIECE * 8, |first, piece| {
        let add = offsets.iter().find(|o| o.0 == first).map_or(0, |o| o.1);
        piece.iter_mut().for_each(|x| *x += add);
    });
}

impl Grid {
    /// Cell coordinates of a point (may be negative or past the grid for query points).
    #[inline]
    fn coords(&self, p: DVec3) -> [i64; 3] {
        let q = (p - self.origin) * self.inv_cell;
        [floor_i64(q.x), floor_i64(q.y), floor_i64(q.z)]
    }

    /// Key of the cell holding `min`, the lower corner of a box this grid was built from: at or
    /// above the origin (the least corner of them all), so its cell coordinates are not negative
    /// and truncation is the floor. The same key as `self.key(self.coords(min))`, with no
    /// corrections for negative coordinates.
    #[inline]
    fn key_of_min(&self, min: DVec3) -> u64 {
        let q = (min - self.origin) * self.inv_cell;
        // Through i64 (a few instructions each on x86-64; u64 takes a dozen), as `coords` does:
        // below 2^63, as the build's bound on the cells keeps every coordinate.
        let c = |v: f64| v as i64 as u64 + 1;
        c(q.x) + self.row * c(q.y) + self.slab * c(q.z)
    }

    /// Key of in-grid cell coordinates (each shifted by one for the padding).
    #[inline]
    fn key(&self, c: [i64; 3]) -> u64 {
        (c[0] + 1) as u64 + self.row * (c[1] + 1) as u64 + self.slab * (c[2] + 1) as u64
    }

    /// Sorts the boxes by cell. Returns false when the world is too sparse for 64-bit keys
    /// (the caller then uses sweep and prune).
    fn build(&mut self, aabbs: &[Aabb], pool: &Pool) -> bool {
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
        let cell = if cell > 0.0 { cell * (1.0 + CELL_MARGIN) } else { 1.0 };
        self.inv_cell = 1.0 / cell;
        let span = if n == 0 { DVec3::ZERO } else { (top - origin) * self.inv_cell };
        // Padded dimensions: one empty cell (row, slab) on each side, so x - 1 and y - 1 never
        // wrap into the previous row or slab.
        let dims = [span.x, span.y, span.z].map(|s| s.floor() + 3.0);
        if dims[0] * dims[1] * dims[2] >= 1.8e19 {
            self.built = false;
            return false;
        }
        self.dims = dims.map(|d| d as i64);
        self.row = dims[0] as u64;
        self.slab = self.row * dims[1] as u64;
        // Sort (cell key, body) with an LSD radix sort on the key's used bits: O(n) whatever
        // the motion, and stable, so equal keys stay in body order.
        let cells = self.slab * dims[2] as u64;
        self.start.clear();
        if !self.sparse_only && cells <= DENSE_CELLS_PER_BODY * n as u64 + 4096 {
            self.counting_sort(aabbs, cells as usize, pool);
            self.built = true;
            return true;
        }
        let key_bits = 64 - cells.leading_zeros();
        let mut packed = std::mem::take(&mut self.packed);
        packed.clear();
        if key_bits <= 32 {
            packed.extend(aabbs.iter().enumerate().map(|(i, b)| self.key_of_min(b.min) << 32 | i as u64));
            super::radix_sort(&mut packed, &mut self.scratch, 32, key_bits);
        } else {
            // Keys too wide to pack with an index: a comparison sort on (key, body).
            let mut wide: Vec<(u64, u32)> =
                aabbs.iter().enumerate().map(|(i, b)| (self.key_of_min(b.min), i as u32)).collect();
            wide.sort_unstable();
            self.keys.clear();
            self.order.clear();
            self.keys.extend(wide.iter().map(|w| w.0));
            self.order.extend(wide.iter().map(|w| w.1));
        }
        if key_bits <= 32 {
            self.keys.clear();
            self.order.clear();
            self.keys.extend(packed.iter().map(|e| e >> 32));
            self.order.extend(packed.iter().map(|e| *e as u32));
        }
        self.packed = packed;
        self.boxes.clear();
        self.boxes.extend(self.order.iter().map(|&i| aabbs[i as usize]));
        self.built = true;
        true
    }

    /// Stable counting sort by cell key into `start`, `keys`, `order` and `boxes` (compact
    /// worlds: `cells` is small enough to table).
    fn counting_sort(&mut self, aabbs: &[Aabb], cells: usize, pool: &Pool) {
        // `start[k + 2]` counts cell k; after the prefix sum `start[k + 1]` is where cell k
        // begins, and filling advances it to where cell k ends, which is `start[k + 1]`'s final
        // meaning shifted by one: so afterwards `start[k]` is where cell k begins. The maps
        // (keys, the gathers) and the prefix sum run on `pool`; integer sums in any grouping
        // are the same sums.
        self.start.resize(cells + 2, 0);
        let mut keys = std::mem::take(&mut self.scratch);
        keys.clear();
        pool.map_into(aabbs.len(), MIN_PIECE, &mut keys, |i| self.key_of_min(aabbs[i].min));
        for &k in &keys {
            self.start[k as usize + 2] += 1;
        }
        prefix_sum(&mut self.start, pool);
        self.order.clear();
        self.order.resize(aabbs.len(), 0);
        for (i, &k) in keys.iter().enumerate() {
            let slot = &mut self.start[k as usize + 1];
            self.order[*slot as usize] = i as u32;
            *slot += 1;
        }
        self.start.pop();
        // Keys and boxes in sorted order.
        let order = &self.order;
        self.keys.clear();
        pool.map_into(order.len(), MIN_PIECE, &mut self.keys, |k| keys[order[k] as usize]);
        self.scratch = keys; // keep the allocation
        self.boxes.clear();
        pool.map_into(order.len(), MIN_PIECE, &mut self.boxes, |k| aabbs[order[k] as usize]);
    }

    /// Appends every overlapping pair `(i, j)`, `i < j`, in the sweep's order: the boxes in
    /// cell order, each with the later boxes it overlaps. The sweep is cut into pieces of
    /// consecutive boxes on `pool`, joined in order (the same pairs in the same order as one
    /// thread's).
    pub fn pairs(&mut self, aabbs: &[Aabb], out: &mut Vec<(u32, u32)>, pool: &Pool) {
        if !self.build(aabbs, pool) {
            return super::brute::pairs(aabbs, out);
        }
        let this = &*self;
        pool.extend(self.keys.len(), MIN_PIECE_HEAVY, out, |range, out| this.sweep(range, out));
    }

    /// The pairs of the boxes at sorted positions `range` with the boxes after them.
    fn sweep(&self, range: std::ops::Range<usize>, out: &mut Vec<(u32, u32)>) {
        let n = self.keys.len();
        let (row, slab) = (self.row, self.slab);
        // The four later rows: (y + 1, z), and (y - 1 ..= y + 1, z + 1), as offsets of their
        // x - 1 cell from the current cell.
        let runs = [row - 1, slab - row - 1, slab - 1, slab + row - 1];
        let push = |out: &mut Vec<(u32, u32)>, a: u32, b: u32| out.push((a.min(b), a.max(b)));
        if !self.start.is_empty() {
            let start = &self.start;
            let run = |out: &mut Vec<(u32, u32)>, a: &Aabb, body: u32, from: u32, to: u32| {
                for c in from as usize..to as usize {
                    if a.overlaps(&self.boxes[c]) {
                        push(out, body, self.order[c]);
                    }
                }
            };
            for p in range {
                let key = self.keys[p] as usize;
                let (a, body) = (self.boxes[p], self.order[p]);
                // Own cell (later entries) and the next cell of the row.
                run(out, &a, body, p as u32 + 1, start[key + 2]);
                for r in runs {
                    let lo = key + r as usize;
                    run(out, &a, body, start[lo], start[lo + 3]);
                }
            }
            return;
        }
        // Each run's first entry only moves forward as the sweep goes: a cursor per run, which a
        // piece starting mid-sweep places by binary search where the sweep would have it.
        let mut cursor = [0usize; 4];
        if let Some(&first) = self.keys.get(range.start) {
            for r in 0..4 {
                cursor[r] = self.keys.partition_point(|&k| k < first + runs[r]);
            }
        }
        for p in range {
            let key = self.keys[p];
            let a = self.boxes[p];
            let body = self.order[p];
            // Own cell (later entries) and the next cell of the row.
            let mut q = p + 1;
            while q < n && self.keys[q] <= key + 1 {
                if a.overlaps(&self.boxes[q]) {
                    push(out, body, self.order[q]);
                }
                q += 1;
            }
            for r in 0..4 {
                let lo = key + runs[r];
                let hi = lo + 2;
                let mut c = cursor[r];
                while c < n && self.keys[c] < lo {
                    c += 1;
                }
                cursor[r] = c;
                while c < n && self.keys[c] <= hi {
                    if a.overlaps(&self.boxes[c]) {
                        push(out, body, self.order[c]);
                    }
                    c += 1;
                }
            }
        }
    }

    /// Files `aabbs` for [`Grid::query`] without looking for pairs: an index over boxes that
    /// stay put (the sleeping bodies), built once and queried many times.
    pub fn index(&mut self, aabbs: &[Aabb]) {
        self.build(aabbs, &Pool::sequential());
    }

    /// Whether the last build succeeded for `n` boxes (then [`Grid::query`] answers from it).
    pub fn holds(&self, n: usize) -> bool {
        self.built && self.keys.len() == n && n > 0
    }

    /// Appends every box (from the last build) overlapping `query`.
    pub fn query(&self, aabbs: &[Aabb], query: &Aabb, out: &mut Vec<u32>) {
        if !self.built || self.keys.len() != aabbs.len() || self.keys.is_empty() {
            return super::brute::query(aabbs, query, out);
        }
        // A box that reaches the query starts at most one cell below the query's own lower
        // corner (in cell coordinates, where the margin absorbs rounding; subtracting a cell
        // from a corner far from the origin would round by more than the margin). Cells outside
        // the padded grid hold nothing; clamping keeps keys from wrapping.
        let lo = self.coords(query.min).map(|c| c.saturating_sub(1));
        let hi = self.coords(query.max);
        let lo: [i64; 3] = std::array::from_fn(|k| lo[k].clamp(-1, self.dims[k] - 2));
        let hi: [i64; 3] = std::array::from_fn(|k| hi[k].clamp(-1, self.dims[k] - 2));
        let rows = (hi[1] - lo[1] + 1).max(0) as u128 * (hi[2] - lo[2] + 1).max(0) as u128;
        if rows > 1024 {
            return super::brute::query(aabbs, query, out);
        }
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let first = self.key([lo[0], y, z]);
                let last = self.key([hi[0], y, z]);
                // The row's entries: from the cell-start table when there is one, else by
                // binary search in the sorted keys.
                let (from, to) = if self.start.is_empty() {
                    (self.keys.partition_point(|&k| k < first), self.keys.partition_point(|&k| k <= last))
                } else {
                    (self.start[first as usize] as usize, self.start[last as usize + 1] as usize)
                };
                for c in from..to {
                    if self.boxes[c].overlaps(query) {
                        out.push(self.order[c]);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Chains of boxes of one size, each starting exactly where the one before it ends (so
    /// every neighbour touches, and the lower corners are exactly one box, the cell's size
    /// before its margin, apart), at an offset near or far from the origin; and the same chain
    /// among a crowd of other boxes on a lattice, so the table's runs have every length.
    fn chains() -> impl Strategy<Value = Vec<Aabb>> {
        let offset = prop_oneof![Just(0.0), -1.0e3..1.0e3f64, Just(1.0e6), Just(-3.0e7), 1.0e9..1.0e12f64];
        let size = prop_oneof![Just(1.0), Just(0.1), 1.0e-3..10.0f64];
        (offset, size, 2..60usize, proptest::collection::vec((0..6i32, 0..6i32, 0..6i32), 0..120)).prop_map(
            |(offset, size, links, crowd)| {
                let mut boxes = Vec::new();
                let mut min = DVec3::new(offset, offset * 0.5, -offset);
                for k in 0..links {
                    let max = min + DVec3::splat(size);
                    boxes.push(Aabb { min, max });
                    // The next starts where this one ends: on x, then on y, then on z, in turn.
                    min[k % 3] = max[k % 3];
                }
                let base = boxes[0].min;
                boxes.extend(crowd.into_iter().map(|(x, y, z)| {
                    let min = base + DVec3::new(f64::from(x), f64::from(y), f64::from(z)) * (0.5 * size);
                    Aabb { min, max: min + DVec3::splat(size) }
                }));
                boxes
            },
        )
    }

    proptest! {
        /// Boxes exactly one box apart are never filed two cells apart, however the cell
        /// coordinates round: the table's sweep and the cursors both find exactly the
        /// brute-force pairs on touching chains, near and far from the origin, and a query
        /// with any of the boxes finds exactly the boxes it touches.
        #[test]
        fn touching_chains_are_found_whole(aabbs in chains()) {
            let mut want = Vec::new();
            super::super::brute::pairs(&aabbs, &mut want);
            want.sort_unstable();
            let (mut table, mut cursors) = (Grid::default(), Grid { sparse_only: true, ..Grid::default() });
            for grid in [&mut table, &mut cursors] {
                let mut got = Vec::new();
                grid.pairs(&aabbs, &mut got, &Pool::sequential());
                got.sort_unstable();
                prop_assert_eq!(&got, &want);
                // Queries with each box find what brute force finds (its touching neighbours).
                for q in aabbs.iter().take(24) {
                    let (mut hits, mut truth) = (Vec::new(), Vec::new());
                    grid.query(&aabbs, q, &mut hits);
                    hits.sort_unstable();
                    super::super::brute::query(&aabbs, q, &mut truth);
                    prop_assert_eq!(&hits, &truth);
                }
            }
        }
    }

    /// A compact world takes the cell-start table, a forced grid the cursors; both find exactly
    /// the brute-force pairs, in the same order.
    #[test]
    fn table_and_cursors_agree_with_brute_force() {
        // 3,000 boxes of up to 1.5 m in a 25 m cube (a deterministic generator: no seed drift).
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let aabbs: Vec<Aabb> = (0..3000)
            .map(|_| {
                let min = DVec3::new(next(), next(), next()) * 25.0;
                Aabb { min, max: min + DVec3::new(next(), next(), next()) * 1.5 }
            })
            .collect();
        let mut want = Vec::new();
        super::super::brute::pairs(&aabbs, &mut want);
        want.sort_unstable();
        assert!(want.len() > 500, "the world should be crowded: {} pairs", want.len());
        let (mut table, mut cursors) = (Grid::default(), Grid { sparse_only: true, ..Grid::default() });
        let (mut a, mut b) = (Vec::new(), Vec::new());
        table.pairs(&aabbs, &mut a, &Pool::sequential());
        cursors.pairs(&aabbs, &mut b, &Pool::sequential());
        assert!(!table.start.is_empty() && cursors.start.is_empty(), "each path taken");
        assert_eq!(a, b, "same pairs in the same order");
        // Cut over threads, each path gives the pairs of one thread, in the same order.
        let pool = Pool::new(3).unwrap().cut_finely();
        for grid in [&mut table, &mut cursors] {
            let mut c = Vec::new();
            grid.pairs(&aabbs, &mut c, &pool);
            assert_eq!(a, c);
        }
        a.sort_unstable();
        assert_eq!(a, want);
    }
}
