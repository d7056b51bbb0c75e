//! Broadphase: which pairs of dynamic bodies may touch during a step, from their swept bounds
//! (the box around the start and end poses), so fast movers are caught.
//!
//! Three interchangeable methods, each returning a superset of the truly overlapping pairs
//! (a property test checks each against [`brute`], the oracle):
//! - [`brute`]: every pair, O(n^2); the oracle, and fastest below a few dozen bodies.
//! - [`sap`]: sweep and prune on one axis, sorted incrementally across ticks (bodies barely move
//!   in one tick, so the insertion sort is near O(n)).
//! - [`grid`]: a uniform grid hashed into a fixed table, one cell per body; best for bodies of
//!   similar size, whatever their density.
//!
//! Static geometry lives in [`StaticIndex`], parry's BVH, built once. Sleeping bodies, which do
//! not move either, leave the method in use for a [`grid::Grid`] index that is rebuilt only when
//! the set of sleepers changes (the stepper keeps it).

pub mod brute;
pub mod grid;
pub mod sap;

use crate::geometry::Aabb;
use crate::par::Pool;
use rapier3d::parry;

/// Which broadphase the plan chose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BroadphaseKind {
    /// Every pair.
    BruteForce,
    /// Sweep and prune.
    SweepAndPrune,
    /// Uniform grid / spatial hash.
    Grid,
    /// parry's BVH, rebuilt every tick (for comparison: the plan never picks it for dynamic
    /// bodies; it serves static geometry).
    Bvh,
}

impl BroadphaseKind {
    /// The kind [`BroadphaseKind::name`] names.
    pub fn from_name(name: &str) -> Option<BroadphaseKind> {
        [BroadphaseKind::BruteForce, BroadphaseKind::SweepAndPrune, BroadphaseKind::Grid, BroadphaseKind::Bvh]
            .into_iter()
            .find(|k| k.name() == name)
    }

    /// Short name for plans and benchmarks.
    pub fn name(self) -> &'static str {
        match self {
            BroadphaseKind::BruteForce => "brute",
            BroadphaseKind::SweepAndPrune => "sap",
            BroadphaseKind::Grid => "grid",
            BroadphaseKind::Bvh => "bvh",
        }
    }
}

/// A broadphase with its reusable buffers (no allocation per tick once warm).
#[derive(Debug)]
pub struct Broadphase {
    kind: BroadphaseKind,
    sap: sap::Sap,
    grid: grid::Grid,
    /// The boxes of the last `pairs` call, for queries, when the grid does not hold them.
    boxes: Vec<Aabb>,
    /// The pair sort's buffers.
    scratch: [Vec<u64>; 2],
}

impl Broadphase {
    /// A broadphase of the given kind.
    pub fn new(kind: BroadphaseKind) -> Broadphase {
        Broadphase {
            kind,
            sap: sap::Sap::default(),
            grid: grid::Grid::default(),
            boxes: Vec::new(),
            scratch: Default::default(),
        }
    }

    /// The method in use.
    pub fn kind(&self) -> BroadphaseKind {
        self.kind
    }

    /// Every pair `(i, j)`, `i < j`, whose boxes overlap, ascending. `out` is cleared. The grid
    /// sweeps on `pool`'s threads.
    pub fn pairs(&mut self, aabbs: &[Aabb], out: &mut Vec<(u32, u32)>, pool: &Pool) {
        out.clear();
        match self.kind {
            BroadphaseKind::BruteForce => brute::pairs(aabbs, out),
            BroadphaseKind::SweepAndPrune => self.sap.pairs(aabbs, out),
            BroadphaseKind::Grid => self.grid.pairs(aabbs, out, pool),
            BroadphaseKind::Bvh => bvh_pairs(aabbs, out),
        }
        // Methods emit in their own order, and sweep and prune's depends on its history (a
        // rollback re-simulates with a later history). The settle pass is Gauss-Seidel over the
        // pairs, so their order reaches the result: one canonical order for every method.
        // (This comment used to say nothing downstream depended on the order; a pile run under
        // each method proved otherwise: `tests/determinism.rs`.)
        sort_pairs(out, aabbs.len(), &mut self.scratch);
        // Queries answer against these boxes, not whatever the caller holds later: the
        // stepper grows a body's box when its path changes mid-step, and a method that saw
        // the grown boxes would find other partners than one that did not.
        if !self.grid_holds_boxes(aabbs) {
            self.boxes.clear();
            self.boxes.extend_from_slice(aabbs);
        }
    }

    fn grid_holds_boxes(&self, aabbs: &[Aabb]) -> bool {
        self.kind == BroadphaseKind::Grid && self.grid.holds(aabbs.len())
    }

    /// Every body whose box as given to the last [`Broadphase::pairs`] overlaps `query`,
    /// ascending. Used to find new partners for a body whose path changed mid-step.
    pub fn query(&self, aabbs: &[Aabb], query: &Aabb, out: &mut Vec<u32>) {
        out.clear();
        if self.grid_holds_boxes(aabbs) {
            self.grid.query(aabbs, query, out);
        } else {
            brute::query(&self.boxes, query, out);
        }
        out.sort_unstable();
    }
}

/// Sorts pairs of indices below `n` ascending: packed into one integer of twice the bits an
/// index needs and radix sorted, a few linear passes where a comparison sort took a tenth of
/// the tick (pairs are unique, so any sort gives this order).
fn sort_pairs(pairs: &mut [(u32, u32)], n: usize, [packed, scratch]: &mut [Vec<u64>; 2]) {
    let bits = usize::BITS - n.leading_zeros();
    packed.clear();
    packed.extend(pairs.iter().map(|&(a, b)| u64::from(a) << bits | u64::from(b)));
    radix_sort(packed, scratch, 0, 2 * bits);
    let low = (1u64 << bits) - 1;
    for (p, &k) in pairs.iter_mut().zip(packed.iter()) {
        *p = ((k >> bits) as u32, (k & low) as u32);
    }
}

/// Stable LSD radix sort of `v` by bits `shift .. shift + bits` (11-bit digits).
pub(crate) fn radix_sort(v: &mut Vec<u64>, scratch: &mut Vec<u64>, shift: u32, bits: u32) {
    const DIGIT: u32 = 11;
    let mut at = shift;
    while at < shift + bits {
        let mut count = [0u32; 1 << DIGIT];
        for e in v.iter() {
            count[((e >> at) & ((1 << DIGIT) - 1)) as usize] += 1;
        }
        let mut sum = 0;
        for c in count.iter_mut() {
            let here = *c;
            *c = sum;
            sum += here;
        }
        scratch.clear();
        scratch.resize(v.len(), 0);
        for e in v.iter() {
            let d = ((e >> at) & ((1 << DIGIT) - 1)) as usize;
            scratch[count[d] as usize] = *e;
            count[d] += 1;
        }
        std::mem::swap(v, scratch);
        at += DIGIT;
    }
}

/// Every overlapping pair through a BVH built over the boxes: each box queries the tree.
fn bvh_pairs(aabbs: &[Aabb], out: &mut Vec<(u32, u32)>) {
    if aabbs.len() < 2 {
        return;
    }
    let leaves: Vec<_> = aabbs.iter().map(outward).collect();
    let bvh = parry::partitioning::Bvh::from_leaves(parry::partitioning::BvhBuildStrategy::Binned, &leaves);
    for (i, b) in aabbs.iter().enumerate() {
        let q = outward(b);
        for j in bvh.intersect_aabb(&q) {
            // The f32 boxes are rounded outwards: confirm in f64.
            if (j as usize) > i && aabbs[j as usize].overlaps(b) {
                out.push((i as u32, j));
            }
        }
    }
}

/// parry's BVH over the static bodies' bounds. Bounds are rounded outwards to f32, so a static
/// body far from the origin is never missed for want of precision.
///
/// With few static bodies (a handful of walls) a linear scan of their boxes beats any tree, so
/// the BVH is only built from `StaticIndex::BVH_MIN` bodies up.
#[derive(Debug)]
pub struct StaticIndex {
    bvh: Option<parry::partitioning::Bvh>,
    boxes: Vec<Aabb>,
}

fn outward(b: &Aabb) -> parry::bounding_volume::Aabb {
    let down = |x: f64| {
        let f = x as f32;
        if f64::from(f) > x {
            f.next_down()
        } else {
            f
        }
    };
    let up = |x: f64| {
        let f = x as f32;
        if f64::from(f) < x {
            f.next_up()
        } else {
            f
        }
    };
    parry::bounding_volume::Aabb::new(
        parry::math::Vector::new(down(b.min.x), down(b.min.y), down(b.min.z)),
        parry::math::Vector::new(up(b.max.x), up(b.max.y), up(b.max.z)),
    )
}

impl StaticIndex {
    /// Builds the BVH.
    pub fn new(aabbs: &[Aabb]) -> StaticIndex {
        let bvh = (aabbs.len() >= Self::BVH_MIN).then(|| {
            let leaves: Vec<_> = aabbs.iter().map(outward).collect();
            parry::partitioning::Bvh::from_leaves(parry::partitioning::BvhBuildStrategy::Binned, &leaves)
        });
        StaticIndex { bvh, boxes: aabbs.to_vec() }
    }

    /// Fewest static bodies for which the BVH is built.
    pub(crate) const BVH_MIN: usize = 32;

    /// Static bodies whose bounds overlap `query`, ascending by index.
    pub fn query(&self, query: &Aabb, out: &mut Vec<u32>) {
        out.clear();
        match &self.bvh {
            Some(bvh) => {
                let q = outward(query);
                out.extend(bvh.intersect_aabb(&q));
                out.sort_unstable();
            }
            None => brute::query(&self.boxes, query, out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use proptest::prelude::*;

    /// The radix sort of pairs gives the comparison sort's order, for index widths from one
    /// bit to 32 (where the packed pair needs all 64 bits).
    #[test]
    fn pair_sort_equals_comparison_sort() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for n in [1usize, 2, 3, 1000, 65_536, 70_000, 1 << 31] {
            let mut pairs: Vec<(u32, u32)> = (0..3000)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    let (a, b) = ((x % n as u64) as u32, ((x >> 32) % n as u64) as u32);
                    (a.min(b), a.max(b))
                })
                .collect();
            pairs.sort_unstable();
            pairs.dedup();
            let want = pairs.clone();
            pairs.reverse();
            let third = pairs.len() / 3;
            pairs.rotate_left(third);
            sort_pairs(&mut pairs, n, &mut Default::default());
            assert_eq!(pairs, want, "n = {n}");
        }
    }

    fn boxes() -> impl Strategy<Value = Vec<Aabb>> {
        proptest::collection::vec(
            ((-50.0..50.0f64, -50.0..50.0f64, -50.0..50.0f64), (0.01..6.0f64, 0.01..6.0f64, 0.01..6.0f64)),
            0..120,
        )
        .prop_map(|v| {
            v.into_iter()
                .map(|((x, y, z), (w, h, d))| {
                    let min = DVec3::new(x, y, z);
                    Aabb { min, max: min + DVec3::new(w, h, d) }
                })
                .collect()
        })
    }

    proptest! {
        /// Each method returns exactly the brute-force set (a superset is required; all three
        /// test exact box overlap, so they must be equal), over several ticks of motion so the
        /// incremental sweep and prune is exercised.
        #[test]
        fn every_method_finds_every_overlapping_pair(frames in proptest::collection::vec(boxes(), 1..4)) {
            let mut sap = Broadphase::new(BroadphaseKind::SweepAndPrune);
            let mut grid = Broadphase::new(BroadphaseKind::Grid);
            let mut brute = Broadphase::new(BroadphaseKind::BruteForce);
            let mut bvh = Broadphase::new(BroadphaseKind::Bvh);
            let mut cursors = grid::Grid::default();
            cursors.sparse_only = true;
            let (mut a, mut b, mut c, mut d, mut e) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
            // The grids sweep in pieces on two threads, cut as finely as the pool allows.
            let (one, two) = (Pool::sequential(), Pool::new(2).unwrap().cut_finely());
            for aabbs in &frames {
                brute.pairs(aabbs, &mut a, &one);
                sap.pairs(aabbs, &mut b, &one);
                grid.pairs(aabbs, &mut c, &two);
                bvh.pairs(aabbs, &mut d, &one);
                e.clear();
                cursors.pairs(aabbs, &mut e, &two);
                // Each method has its own order; the sets must be equal.
                a.sort_unstable();
                b.sort_unstable();
                c.sort_unstable();
                d.sort_unstable();
                e.sort_unstable();
                prop_assert_eq!(&a, &b, "sap");
                prop_assert_eq!(&a, &e, "grid (cursors)");
                prop_assert_eq!(&a, &c, "grid");
                prop_assert_eq!(&a, &d, "bvh");
                if let Some(q) = aabbs.first() {
                    let q = q.inflated(3.0);
                    let (mut qa, mut qc) = (Vec::new(), Vec::new());
                    brute.query(aabbs, &q, &mut qa);
                    grid.query(aabbs, &q, &mut qc);
                    prop_assert_eq!(&qa, &qc, "grid query");
                    let mut qe = Vec::new();
                    cursors.query(aabbs, &q, &mut qe);
                    qe.sort_unstable();
                    prop_assert_eq!(&qa, &qe, "grid query (sorted keys)");
                }
            }
        }

        /// The static BVH finds every static box that overlaps a query, far from the origin too.
        #[test]
        fn static_bvh_finds_every_overlap(aabbs in boxes(), offset in prop_oneof![Just(0.0), Just(1.0e6), Just(-3.0e7)]) {
            let shifted: Vec<Aabb> = aabbs.iter().map(|b| b.translated(DVec3::splat(offset))).collect();
            let index = StaticIndex::new(&shifted);
            for q in shifted.iter().take(10) {
                let mut got = Vec::new();
                index.query(q, &mut got);
                let mut want = Vec::new();
                brute::query(&shifted, q, &mut want);
                for w in want {
                    prop_assert!(got.contains(&w), "missed {w}");
                }
            }
        }
    }
}
