//! Exact, slow reference answers for the kernels' property tests, and their shared inputs.

use glam::{DQuat, DVec3};
use proptest::prelude::*;

/// Any orientation: a rotation about a random axis by up to 3 rad either way.
pub fn rotation() -> impl Strategy<Value = DQuat> {
    (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -3.0..3.0f64)
        .prop_map(|(x, y, z, angle)| DQuat::from_axis_angle(DVec3::new(x, y, z + 1e-3).normalize(), angle))
}

/// The eight corners of a box (half extents `half`, orientation `rot`) centred at `centre`.
pub(crate) fn box_corners(half: DVec3, rot: DQuat, centre: DVec3) -> [DVec3; 8] {
    std::array::from_fn(|k| {
        let s = DVec3::new(
            if k & 1 == 0 { -1.0 } else { 1.0 },
            if k & 2 == 0 { -1.0 } else { 1.0 },
            if k & 4 == 0 { -1.0 } else { 1.0 },
        );
        centre + rot * (half * s)
    })
}

/// The facet of the convex hull of `points` nearest the origin (assumed inside), as (distance,
/// outward unit normal), found by trying the plane through every three points and keeping those
/// with all points on one side. For a Minkowski difference `A - B` of polytopes this is the
/// exact penetration depth, and the normal the direction that frees `B`.
pub(crate) fn nearest_facet(points: &[DVec3]) -> (f64, DVec3) {
    let mut best = (f64::INFINITY, DVec3::ZERO);
    for i in 0..points.len() {
        for j in i + 1..points.len() {
            for k in j + 1..points.len() {
                let n = (points[j] - points[i]).cross(points[k] - points[i]);
                if n.length_squared() < 1e-12 {
                    continue;
                }
                let n = n.normalize();
                let offset = n.dot(points[i]);
                let (lo, hi) = points.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    let x = n.dot(*p) - offset;
                    (lo.min(x), hi.max(x))
                });
                let facet = if hi <= 1e-9 {
                    (offset, n)
                } else if lo >= -1e-9 {
                    (-offset, -n)
                } else {
                    continue;
                };
                if facet.0 < best.0 {
                    best = facet;
                }
            }
        }
    }
    best
}
