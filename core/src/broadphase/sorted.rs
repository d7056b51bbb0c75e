//! Boxes that do not move, sorted along x, for "does this box overlap any of them" in
//! O(log n + nearby): the selective re-simulation's reach set, tested against every body of
//! every tick it re-simulates.

use crate::geometry::Aabb;

/// Boxes sorted by their lower x bound.
#[derive(Clone, Debug, Default)]
pub struct SortedBoxes {
    boxes: Vec<Aabb>,
    /// The widest box along x: only boxes starting within it before a query can reach it.
    widest: f64,
}

impl SortedBoxes {
    /// The boxes, sorted along x.
    pub fn new(boxes: impl IntoIterator<Item = Aabb>) -> SortedBoxes {
        let mut boxes: Vec<Aabb> = boxes.into_iter().collect();
        boxes.sort_by(|a, b| a.min.x.total_cmp(&b.min.x));
        let widest = boxes.iter().map(|b| b.max.x - b.min.x).fold(0.0, f64::max);
        SortedBoxes { boxes, widest }
    }

    /// Whether any box overlaps `q`.
    pub fn hits(&self, q: &Aabb) -> bool {
        let first = self.boxes.partition_point(|b| b.min.x < q.min.x - self.widest);
        self.boxes[first..].iter().take_while(|b| b.min.x <= q.max.x).any(|b| b.overlaps(q))
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
        fn hits_equal_a_scan(set in proptest::collection::vec(aabb(), 0..60), probes in proptest::collection::vec(aabb(), 1..20)) {
            let index = SortedBoxes::new(set.iter().copied());
            for p in &probes {
                prop_assert_eq!(index.hits(p), set.iter().any(|b| b.overlaps(p)));
            }
        }
    }
}
