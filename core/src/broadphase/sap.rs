//! Sweep and prune (the plane sweep): sort the boxes by their lower bound on one axis, then
//! sweep, testing each box only against those whose interval on that axis overlaps its own.
//! The order is kept between ticks and repaired with an insertion sort, which is near O(n) when
//! bodies move little per tick.

use crate::geometry::Aabb;

/// Sweep-and-prune state carried across ticks.
#[derive(Debug, Default)]
pub(crate) struct Sap {
    order: Vec<u32>,
    axis: usize,
}

impl Sap {
    /// Appends every overlapping pair `(i, j)`, `i < j`.
    pub fn pairs(&mut self, aabbs: &[Aabb], out: &mut Vec<(u32, u32)>) {
        let n = aabbs.len();
        if self.order.len() != n {
            // The body set changed: choose the axis with the widest spread of centres and sort
            // from scratch.
            self.axis = widest_axis(aabbs);
            self.order.clear();
            self.order.extend(0..n as u32);
            let axis = self.axis;
            self.order.sort_by(|&a, &b| aabbs[a as usize].min[axis].total_cmp(&aabbs[b as usize].min[axis]));
        } else {
            let axis = self.axis;
            let key = |i: u32| aabbs[i as usize].min[axis];
            for k in 1..n {
                let item = self.order[k];
                let v = key(item);
                let mut m = k;
                while m > 0 && key(self.order[m - 1]) > v {
                    self.order[m] = self.order[m - 1];
                    m -= 1;
                }
                self.order[m] = item;
            }
        }
        let axis = self.axis;
        for k in 0..n {
            let i = self.order[k];
            let a = &aabbs[i as usize];
            for &j in &self.order[k + 1..] {
                let b = &aabbs[j as usize];
                if b.min[axis] > a.max[axis] {
                    break;
                }
                if a.overlaps(b) {
                    out.push((i.min(j), i.max(j)));
                }
            }
        }
    }
}

fn widest_axis(aabbs: &[Aabb]) -> usize {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for b in aabbs {
        let c = (b.min + b.max) * 0.5;
        for k in 0..3 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0)
}
