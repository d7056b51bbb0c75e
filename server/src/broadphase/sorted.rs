//! Boxes that do not move, sorted along x, for "which of them overlap this box" in
//! O(log n + nearby): the selective re-simulation's reach set, tested against every body of
//! every tick it re-simulates.

use crate::sim::shape::Aabb;

/// Boxes with their ids, sorted by their lower x bound.
#[derive(Clone, Debug, Default)]
pub struct SortedBoxes {
    entries: Vec<(Aabb, u32)>,
    /// The widest box along x: only boxes starting within it before a query can reach it.
    widest: f64,
}

impl SortedBoxes {
    /// The boxes `(bounds, id)` sorted along x.
    pub fn new(entries: impl IntoIterator<Item = (Aabb, u32)>) -> SortedBoxes {
        let mut s = SortedBoxes::default();
        s.rebuild(entries);
        s
    }

    /// Replaces the boxes (reusing the buffer).
    pub fn rebuild(&mut self, entries: impl IntoIterator<Item = (Aabb, u32)>) {
        self.entries.clear();
        self.entries.extend(entries);
        // Ties in x broken by id: the order (and so every answer) is a function of the boxes.
        self.entries.sort_unstable_by(|a, b| a.0.min.x.total_cmp(&b.0.min.x).then(a.1.cmp(&b.1)));
        self.widest = self.entries.iter().map(|(b, _)| b.max.x - b.min.x).fold(0.0, f64::max);
    }

    /// The boxes that could overlap `q` along x.
    fn near(&self, q: &Aabb) -> impl Iterator<Item = &(Aabb, u32)> + '_ {
        let first = self.entries.partition_point(|(b, _)| b.min.x < q.min.x - self.widest);
        let max_x = q.max.x;
        self.entries[first..].iter().take_while(move |(b, _)| b.min.x <= max_x)
    }

    /// Appends the id of every box overlapping `q` (in x order, not sorted by id).
    pub fn query(&self, q: &Aabb, out: &mut Vec<u32>) {
        out.extend(self.near(q).filter(|(b, _)| b.overlaps(q)).map(|(_, id)| *id));
    }

    /// Whether any box overlaps `q`.
    pub fn hits(&self, q: &Aabb) -> bool {
        self.near(q).any(|(b, _)| b.overlaps(q))
    }

    /// Number of boxes.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use proptest::prelude::*;

    fn aabb() -> impl Strategy<Value = Aabb> {
        ((-20.0..20.0f64, -20.0..20.0f64, -20.0..20.0f64), (0.0..5.0f64, 0.0..5.0f64, 0.0..5.0f64))
            .prop_map(|((x, y, z), (w, h, d))| Aabb { min: DVec3::new(x, y, z), max: DVec3::new(x + w, y + h, z + d) })
    }

    proptest! {
        /// Every answer equals a scan of all the boxes.
        #[test]
        fn answers_equal_a_scan(set in proptest::collection::vec(aabb(), 0..60), probes in proptest::collection::vec(aabb(), 1..20)) {
            let index = SortedBoxes::new(set.iter().enumerate().map(|(k, b)| (*b, k as u32)));
            for p in &probes {
                let mut found = Vec::new();
                index.query(p, &mut found);
                found.sort_unstable();
                let scan: Vec<u32> = (0..set.len() as u32).filter(|&k| set[k as usize].overlaps(p)).collect();
                prop_assert_eq!(&found, &scan);
                prop_assert_eq!(index.hits(p), !scan.is_empty());
            }
        }
    }
}
