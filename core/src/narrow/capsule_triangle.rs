//! Capsule against triangle: a sphere at the closest point of the capsule's segment to the
//! triangle (an endpoint against the face, or the segment against an edge), in f64. A segment
//! that meets the triangle (the capsule's core is inside it: the rare deep case) and a
//! degenerate triangle go to the general GJK/EPA path.

use super::{capsule_capsule::closest_between_segments, sphere_sphere, sphere_triangle::closest_on_triangle, Contact};
use glam::{DQuat, DVec3};

/// Contact between a capsule (segment half-length `h` along its local y, radius `r`,
/// orientation `rot`) at the origin and the triangle `tri` (vertices relative to the capsule's
/// centre), or `None` when they are farther apart than `margin`. `None` from the outer option
/// means "not handled here": the caller asks the general path.
pub(crate) fn contact(h: f64, r: f64, rot: DQuat, tri: [DVec3; 3], margin: f64) -> Option<Option<Contact>> {
    let axis = rot * DVec3::Y;
    let (p, q) = (-axis * h, axis * h);
    let [a, b, c] = tri;
    let n = (b - a).cross(c - a);
    if n.length_squared() < 1e-24 {
        return None;
    }
    let (sp, sq) = (n.dot(p - a), n.dot(q - a));
    // Both ends farther from the triangle's plane than the radius and margin, on one side: apart.
    let reach = (r + margin.max(0.0)) * n.length();
    if (sp > reach && sq > reach) || (sp < -reach && sq < -reach) {
        return Some(None);
    }
    if sp * sq <= 0.0 {
        // The segment reaches the triangle's plane: where it crosses, is that inside?
        if sp == sq {
            return None; // lies in the plane
        }
        let x = p + (q - p) * (sp / (sp - sq));
        if (closest_on_triangle(x, a, b, c) - x).length_squared() < 1e-24 {
            return None;
        }
    }
    // Apart from the segment: the closest pair is an endpoint against the face or the segment
    // against an edge. Ties keep the first, in this fixed order.
    let mut best = (p, closest_on_triangle(p, a, b, c));
    let mut best_d2 = (best.1 - best.0).length_squared();
    let mut take = |pair: (DVec3, DVec3)| {
        let d2 = (pair.1 - pair.0).length_squared();
        if d2 < best_d2 {
            best = pair;
            best_d2 = d2;
        }
    };
    take((q, closest_on_triangle(q, a, b, c)));
    for (e0, e1) in [(a, b), (b, c), (c, a)] {
        take(closest_between_segments(p, q, e0, e1));
    }
    if best_d2 == 0.0 {
        return None;
    }
    let reach = r + margin.max(0.0);
    if best_d2 > reach * reach {
        return Some(None);
    }
    let (on_segment, on_triangle) = best;
    let c = sphere_sphere::contact(r, 0.0, on_triangle - on_segment)?;
    Some(Some(Contact { point: c.point + on_segment, ..c }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Shape;
    use crate::narrow::{general, oracle::rotation};
    use proptest::prelude::*;

    fn flat(y: f64) -> [DVec3; 3] {
        [DVec3::new(-5.0, y, -5.0), DVec3::new(5.0, y, -5.0), DVec3::new(0.0, y, 5.0)]
    }

    #[test]
    fn an_upright_capsule_standing_on_a_triangle() {
        // Segment from y = -0.5 to 0.5, radius 0.3: the lower cap reaches y = -0.8.
        let c = contact(0.5, 0.3, DQuat::IDENTITY, flat(-0.79), 0.0).unwrap().unwrap();
        assert!((c.depth - 0.01).abs() < 1e-12 && (c.normal - DVec3::NEG_Y).length() < 1e-12, "{c:?}");
        assert!((c.point - DVec3::new(0.0, -0.795, 0.0)).length() < 1e-12, "{c:?}");
        // 2 cm below the cap: apart by 2 cm within a margin of 3, and nothing without one.
        let apart = contact(0.5, 0.3, DQuat::IDENTITY, flat(-0.82), 0.03).unwrap().unwrap();
        assert!((apart.depth + 0.02).abs() < 1e-12, "{apart:?}");
        assert_eq!(contact(0.5, 0.3, DQuat::IDENTITY, flat(-0.82), 0.0), Some(None));
        // The segment itself through the triangle: not handled here.
        assert_eq!(contact(0.5, 0.3, DQuat::IDENTITY, flat(0.1), 0.0), None);
    }

    #[test]
    fn a_lying_capsule_meets_an_edge_with_its_side() {
        // Lying along x; a triangle edge along z just under its middle.
        let rot = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2);
        let tri = [DVec3::new(0.0, -0.29, -1.0), DVec3::new(0.0, -0.29, 1.0), DVec3::new(0.0, -2.0, 0.0)];
        let c = contact(1.0, 0.3, rot, tri, 0.0).unwrap().unwrap();
        assert!((c.depth - 0.01).abs() < 1e-12 && (c.normal - DVec3::NEG_Y).length() < 1e-12, "{c:?}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]

        /// Where it answers, its distance is the segment's exact distance to the triangle (a
        /// dense search along the segment, each sample's nearest triangle point exact, brackets
        /// it: the distance is 1-Lipschitz along the segment), so its depth and normal are the
        /// penetration of a swept sphere whose core misses the triangle; and it agrees with the
        /// general path (GJK/EPA in f32, whose depths on curved shapes are only good to about a
        /// centimetre) on whether the pair overlaps, away from the boundary.
        #[test]
        fn is_the_exact_distance(
            h in 0.05..1.5f64, r in 0.05..1.0f64, rot in rotation(),
            p in proptest::array::uniform3((-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64)),
        ) {
            let tri = p.map(|(x, y, z)| DVec3::new(x, y, z));
            prop_assume!((tri[1] - tri[0]).cross(tri[2] - tri[0]).length() > 1e-2);
            let margin = 0.05;
            let Some(ours) = contact(h, r, rot, tri, margin) else { return Ok(()) };
            let axis = rot * DVec3::Y;
            let samples = 400;
            let nearest = (0..=samples)
                .map(|k| axis * h * (2.0 * f64::from(k) / f64::from(samples) - 1.0))
                .map(|x| (closest_on_triangle(x, tri[0], tri[1], tri[2]) - x).length())
                .fold(f64::INFINITY, f64::min);
            let spacing = 2.0 * h / f64::from(samples);
            match ours {
                None => prop_assert!(nearest > r + margin - 1e-9, "apart, but a sample is {nearest} away"),
                Some(c) => {
                    let dist = r - c.depth;
                    prop_assert!(dist <= nearest + 1e-12, "distance {dist} but a sample is {nearest} away");
                    prop_assert!(dist >= nearest - spacing / 2.0 - 1e-12, "distance {dist} below the search's {nearest}");
                    prop_assert!((c.normal.length() - 1.0).abs() < 1e-12);
                    if c.depth.abs() > 0.02 {
                        let shape = Shape::Capsule { half_height: h, radius: r };
                        let theirs = general::contact_triangle(&shape, rot, tri, margin).map_or(-1.0, |t| t.depth);
                        prop_assert_eq!(c.depth > 0.0, theirs > 0.0, "ours {} theirs {}", c.depth, theirs);
                    }
                }
            }
        }
    }
}
