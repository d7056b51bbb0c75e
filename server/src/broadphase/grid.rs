//! A uniform grid, as sorted cell keys. The cell is as large as the largest box, and each box is
//! filed under the cell of its lower corner, so two overlapping boxes sit in the same or
//! adjacent cells. Cells are numbered row by row (`x` fastest), and the boxes are kept sorted by
//! cell number with a radix sort, O(n) whatever the motion. (An insertion sort from the previous
//! tick's order was tried: a body changing cell along z moves a whole slab of entries, which
//! grows as n^(2/3).)
//!
//! Each cell is compared with itself and the 13 of its 26 neighbours that come after it, so each
//! pair of cells is visited once. Those 13 lie in five runs of consecutive cell numbers: the rest
//! of its own row (`x + 1`), and three cells (`x - 1 ..= x + 1`) in each of four later rows. As the
//! sweep walks the boxes in cell order, the start of each run only moves forward, so one cursor
//! per run finds it: the whole sweep is O(n + pairs) and walks memory in order. No table grows
//! with the volume of the world, so a sparse world costs what a dense one does.
//!
//! When the world is compact (at most [`DENSE_CELLS_PER_BODY`] cells per body) a table of where
//! each cell's entries start replaces both the radix sort (a counting sort fills it in one pass)
//! and the cursors (each run is two loads): the cursors walked every entry four times and their
//! loop exits were the sweep's main cost. The table's sweep also tests the first places of every
//! run together, without a branch (see `Grid::sweep_table`). Both paths give the same pairs, each
//! in an order of its own that depends on the boxes alone (the broadphase sorts them).

use crate::geometry::Aabb;
use crate::par::{Pool, MIN_PIECE, MIN_PIECE_HEAVY};
use glam::DVec3;

/// Above this many cells per body the cell-start table would cost more than the cursors save
/// (and would grow with the world's volume): the sorted keys and cursors serve instead.
pub const DENSE_CELLS_PER_BODY: u64 = 32;

/// A box in f32, relative to the grid's origin, laid out so that one overlap test is eight
/// independent comparisons (two SSE compares): `[min.x, min.y, min.z, -max.x, -max.y, -max.z, 0,
/// 0]`. Subtracting the origin and rounding to f32 are both monotone (never reverse `<=`), so two
/// boxes that overlap in f64 overlap here; the few pairs rounding adds are removed by the exact
/// f64 test that confirms each hit. So the pairs are exactly the f64 boxes' pairs, at half the
/// bytes and with no branch per test.
#[derive(Clone, Copy, Debug)]
#[repr(align(32))]
struct Near([f32; 8]);

impl Near {
    /// Meets nothing (NaN compares false): what a sweep slot with no box in it points at.
    const NOTHING: Near = Near([f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);

    #[inline]
    fn of(b: &Aabb, origin: DVec3) -> Near {
        let (lo, hi) = ((b.min - origin).as_vec3(), (b.max - origin).as_vec3());
        Near([lo.x, lo.y, lo.z, -hi.x, -hi.y, -hi.z, 0.0, 0.0])
    }

    /// The other side of the test for this box: `[max.x, max.y, max.z, -min.x, -min.y, -min.z,
    /// 0, 0]`, so that `other` overlaps this box when each of its lanes is at most this one's.
    #[inline]
    fn query(&self) -> [f32; 8] {
        let b = &self.0;
        [-b[3], -b[4], -b[5], -b[0], -b[1], -b[2], 0.0, 0.0]
    }

    /// Whether this box overlaps the box whose [`Near::query`] is `q` (or may: see the type).
    #[inline]
    fn meets(&self, q: &[f32; 8]) -> bool {
        let mut all = true;
        for (a, b) in self.0.iter().zip(q) {
            all &= a <= b;
        }
        all
    }
}

/// Places a table sweep tests in every run without a branch; a run with more entries (rare:
/// a box has about 0.2 neighbours per cell in a scene as dense as the scale benchmark's) takes a
/// loop for the rest.
const FIXED_PER_RUN: usize = 2;

/// Grid state, carried across ticks (the sort order) and reused (the buffers).
#[derive(Debug, Default)]
pub struct Grid {
    cell: f64,
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
    /// Compact worlds: the boxes in sorted order as [`Near`], then [`Near::NOTHING`].
    near: Vec<Near>,
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
        let q = (p - self.origin) / self.cell;
        let f = |v: f64| {
            let t = v as i64;
            if (t as f64) > v {
                t - 1
            } else {
                t
            }
        };
        [f(q.x), f(q.y), f(q.z)]
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
        self.cell = if cell > 0.0 { cell } else { 1.0 };
        let span = if n == 0 { DVec3::ZERO } else { (top - origin) / self.cell };
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
            packed.extend(aabbs.iter().enumerate().map(|(i, b)| self.key(self.coords(b.min)) << 32 | i as u64));
            super::radix_sort(&mut packed, &mut self.scratch, 32, key_bits);
        } else {
            // Keys too wide to pack with an index: a comparison sort on (key, body).
            let mut wide: Vec<(u64, u32)> =
                aabbs.iter().enumerate().map(|(i, b)| (self.key(self.coords(b.min)), i as u32)).collect();
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
        pool.map_into(aabbs.len(), MIN_PIECE, &mut keys, |i| self.key(self.coords(aabbs[i].min)));
        for &k in &keys {
            self.start[k as usize + 2] += 1;
        }
        prefix_sum(&mut self.start, pool);
        // Each body and its key to its place (the key is at hand: one pass, not a gather after).
        self.order.clear();
        self.order.resize(aabbs.len(), 0);
        self.keys.clear();
        self.keys.resize(aabbs.len(), 0);
        for (i, &k) in keys.iter().enumerate() {
            let slot = &mut self.start[k as usize + 1];
            self.order[*slot as usize] = i as u32;
            self.keys[*slot as usize] = k;
            *slot += 1;
        }
        self.start.pop();
        self.scratch = keys; // keep the allocation
                             // Boxes in sorted order.
        let order = &self.order;
        self.boxes.clear();
        pool.map_into(order.len(), MIN_PIECE, &mut self.boxes, |k| aabbs[order[k] as usize]);
        let (boxes, origin) = (&self.boxes, self.origin);
        self.near.clear();
        pool.map_into(boxes.len(), MIN_PIECE, &mut self.near, |k| Near::of(&boxes[k], origin));
        self.near.push(Near::NOTHING);
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
            self.sweep_table(range, runs, out);
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

    /// [`Grid::sweep`] with the cell-start table. A box's five runs (its own cell's later
    /// entries and the next cell, then three cells in each of four later rows) hold about one
    /// box between them, and whether a run ends after zero, one or two entries is a branch the
    /// processor cannot predict: it was most of the sweep's time. So the first
    /// [`FIXED_PER_RUN`] places of every run are tested together, without a branch (a place
    /// past its run's end points at [`Near::NOTHING`]), as f32 [`Near`] boxes; a hit is
    /// confirmed in f64, and only runs longer than that take a loop.
    fn sweep_table(&self, range: std::ops::Range<usize>, runs: [u64; 4], out: &mut Vec<(u32, u32)>) {
        const PLACES: usize = 5 * FIXED_PER_RUN;
        let (start, near) = (&self.start, &self.near);
        let nothing = (near.len() - 1) as u32;
        let confirm = |out: &mut Vec<(u32, u32)>, p: usize, c: usize| {
            if self.boxes[p].overlaps(&self.boxes[c]) {
                let (a, b) = (self.order[p], self.order[c]);
                out.push((a.min(b), a.max(b)));
            }
        };
        for p in range {
            let key = self.keys[p] as usize;
            let q = near[p].query();
            // (first, end) of each run: own cell after p and the next cell, then the rows.
            let mut bounds = [(p as u32 + 1, start[key + 2]); 5];
            for (b, r) in bounds[1..].iter_mut().zip(runs) {
                let lo = key + r as usize;
                *b = (start[lo], start[lo + 3]);
            }
            let mut places = [nothing; PLACES];
            let mut long = false;
            for (k, &(first, end)) in bounds.iter().enumerate() {
                for j in 0..FIXED_PER_RUN as u32 {
                    places[k * FIXED_PER_RUN + j as usize] = if first + j < end { first + j } else { nothing };
                }
                long |= end > first + FIXED_PER_RUN as u32;
            }
            let mut hits = 0u32;
            for (k, &c) in places.iter().enumerate() {
                hits |= u32::from(near[c as usize].meets(&q)) << k;
            }
            while hits != 0 {
                let k = hits.trailing_zeros() as usize;
                hits &= hits - 1;
                confirm(out, p, places[k] as usize);
            }
            if long {
                for &(first, end) in &bounds {
                    for c in first as usize + FIXED_PER_RUN..end as usize {
                        if near[c].meets(&q) {
                            confirm(out, p, c);
                        }
                    }
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
        // Cells outside the padded grid hold nothing; clamping keeps keys from wrapping.
        let lo = self.coords(query.min - DVec3::splat(self.cell));
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

    fn far_boxes() -> impl Strategy<Value = Vec<Aabb>> {
        // Near-touching boxes a long way from the origin, where f32 cannot tell them apart:
        // a corner shared exactly (closed boxes overlap), or a gap of a few f64 ulps.
        let offset = prop_oneof![Just(0.0), Just(1.0e6), Just(-3.0e7), Just(1.0e12)];
        (offset, proptest::collection::vec((0..6i32, 0..6i32, 0..6i32, 0..3u8, 0..4u32), 2..200)).prop_map(
            |(offset, v)| {
                v.into_iter()
                    .map(|(x, y, z, size, nudge)| {
                        let unit = 1.0e-3;
                        let min = DVec3::new(offset + f64::from(x) * unit, f64::from(y) * unit, f64::from(z) * unit);
                        let mut max = min + DVec3::splat(f64::from(size) * unit);
                        // Shrink by a few ulps: now it misses a neighbour it would have touched.
                        for _ in 0..nudge {
                            max.x = max.x.next_down();
                        }
                        Aabb { min, max: max.max(min) }
                    })
                    .collect()
            },
        )
    }

    proptest! {
        /// The f32 first test may only ever add pairs that the f64 test then removes: the table's
        /// sweep finds exactly the brute-force pairs on boxes that touch, or miss by a few f64
        /// ulps (which f32 cannot see), near and far from the origin.
        #[test]
        fn table_sweep_is_exact_far_from_the_origin(aabbs in far_boxes()) {
            let mut want = Vec::new();
            super::super::brute::pairs(&aabbs, &mut want);
            want.sort_unstable();
            let mut grid = Grid::default();
            let mut got = Vec::new();
            grid.pairs(&aabbs, &mut got, &Pool::sequential());
            prop_assert!(!grid.start.is_empty(), "the table's sweep was taken");
            got.sort_unstable();
            prop_assert_eq!(got, want);
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
        // Cut over threads, each path gives the pairs of one thread, in the same order.
        let pool = Pool::new(3).unwrap().cut_finely();
        for (grid, one) in [(&mut table, &a), (&mut cursors, &b)] {
            let mut c = Vec::new();
            grid.pairs(&aabbs, &mut c, &pool);
            assert_eq!(one, &c, "the same order on any number of threads");
        }
        // The two paths emit in their own orders (the caller sorts); the same set, each once.
        for mut pairs in [a, b] {
            pairs.sort_unstable();
            assert_eq!(pairs, want);
        }
    }
}
