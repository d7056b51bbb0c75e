//! Every pair: the oracle the other methods are tested against.

use crate::geometry::Aabb;

/// Appends every overlapping pair `(i, j)`, `i < j`.
pub fn pairs(aabbs: &[Aabb], out: &mut Vec<(u32, u32)>) {
    for i in 0..aabbs.len() {
        for j in i + 1..aabbs.len() {
            if aabbs[i].overlaps(&aabbs[j]) {
                out.push((i as u32, j as u32));
            }
        }
    }
}

/// Appends every box overlapping `query`.
pub fn query(aabbs: &[Aabb], query: &Aabb, out: &mut Vec<u32>) {
    out.extend((0..aabbs.len() as u32).filter(|&i| aabbs[i as usize].overlaps(query)));
}
