//! Oriented box against a triangle (of a height field or a mesh): the separating-axis test in f64.
//!
//! A box and a triangle are convex polytopes, so the minimum translation that separates them lies
//! along a face normal (the box's three, the triangle's one) or along the cross product of an
//! edge of each (three by three): thirteen axes decide overlap and give the exact penetration
//! depth and normal, as in [`super::cuboid_cuboid`]. When they are apart, the separating-axis
//! gap is only a lower bound of the distance: a gap beyond the margin ends the query at once
//! (the common case: a crate well above the ground), and within it the distance is measured
//! exactly from the closest pair of features (a box corner and the triangle, a triangle corner
//! and the box, or an edge of each).
//!
//! This replaced parry's f32 GJK/EPA for boxes on terrain: a crate lying on a height field asks
//! for a handful of triangles every tick it is awake, and GJK/EPA was most of the yard scene's
//! time (`impact-bench rest`).
//!
//! The contact point follows `cuboid_cuboid`: the incident feature clipped to the reference face,
//! halfway to the reference plane, or the midpoint of two edges' closest points.

use super::capsule_capsule::closest_between_segments;
use super::cuboid_cuboid::{centroid, clip, Obb, Poly, EDGE_BIAS, FLAT};
use super::sphere_triangle::closest_on_triangle;
use super::Contact;
use glam::{DQuat, DVec3};

/// Which axis separates least.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Axis {
    /// The box's face normal `i` (its local axis).
    Box(usize),
    /// The triangle's normal.
    Triangle,
    /// Box axis `i` crossed with triangle edge `j` (from vertex `j` to vertex `j + 1`).
    Edges(usize, usize),
}

/// Contact between a box (half extents `half`, orientation `rot`) at the origin and the triangle
/// `tri` (vertices relative to the box's centre, world-oriented), or `None` when they are farther
/// apart than `margin`. The normal points from the box to the triangle.
pub fn contact(half: DVec3, rot: DQuat, tri: [DVec3; 3], margin: f64) -> Option<Contact> {
    // Everything in the box's frame: its axes are the unit axes there.
    let inv = rot.inverse();
    let v = tri.map(|p| inv * p);
    let edges = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    let h = half.to_array();
    // Separation along unit axis `l`, and whether the triangle lies on its positive side.
    let along = |l: DVec3| -> (f64, bool) {
        let p = [v[0].dot(l), v[1].dot(l), v[2].dot(l)];
        let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        let r = h[0] * l.x.abs() + h[1] * l.y.abs() + h[2] * l.z.abs();
        let (plus, minus) = (lo - r, -r - hi);
        (plus.max(minus), plus >= minus)
    };
    let signed = |l: DVec3, positive: bool| if positive { l } else { -l };

    let mut best = (f64::NEG_INFINITY, Axis::Box(0), DVec3::X);
    for (i, l) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
        let (s, pos) = along(l);
        if s > best.0 {
            best = (s, Axis::Box(i), signed(l, pos));
        }
    }
    let face = edges[0].cross(edges[1]);
    let face_len = face.length();
    if face_len > 0.0 {
        let l = face / face_len;
        let (s, pos) = along(l);
        if s > best.0 {
            best = (s, Axis::Triangle, signed(l, pos));
        }
    }
    if best.0 > margin {
        return None;
    }
    let face_best = best.0;
    for (j, e) in edges.iter().enumerate() {
        let e_len = e.length();
        for (i, u) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
            let l = u.cross(*e);
            let len = l.length();
            // Parallel: the face axes already cover this direction.
            if len < 1e-6 * e_len {
                continue;
            }
            let l = l / len;
            let (s, pos) = along(l);
            if s > margin {
                return None;
            }
            if s > best.0 && s > face_best + EDGE_BIAS * (1.0 + face_best.abs()) {
                best = (s, Axis::Edges(i, j), signed(l, pos));
            }
        }
    }
    let (sep, axis, n) = best;
    let local = if sep > 0.0 {
        // Apart, within the margin by the separating-axis bound: measure the distance exactly.
        let c = distance(half, &v, n);
        if -c.depth > margin {
            return None;
        }
        c
    } else {
        Contact { point: contact_point(half, &v, n, axis), normal: n, depth: -sep }
    };
    Some(Contact { point: rot * local.point, normal: rot * local.normal, depth: local.depth })
}

/// The box's twelve edges in its own frame.
fn box_edges(half: DVec3) -> [(DVec3, DVec3); 12] {
    std::array::from_fn(|k| {
        let axis = k / 4;
        let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
        let mut p = DVec3::ZERO;
        p[a] = if k & 1 == 0 { -half[a] } else { half[a] };
        p[b] = if k & 2 == 0 { -half[b] } else { half[b] };
        let (mut lo, mut hi) = (p, p);
        lo[axis] = -half[axis];
        hi[axis] = half[axis];
        (lo, hi)
    })
}

/// The exact distance between the box (its frame) and a triangle known to be apart from it, as
/// a contact with `depth = -distance`; `fallback` is the normal if the two touch exactly.
fn distance(half: DVec3, v: &[DVec3; 3], fallback: DVec3) -> Contact {
    let mut best = (f64::INFINITY, DVec3::ZERO, DVec3::ZERO); // (distance², on box, on triangle)
    let mut consider = |on_box: DVec3, on_tri: DVec3| {
        let d2 = (on_tri - on_box).length_squared();
        if d2 < best.0 {
            best = (d2, on_box, on_tri);
        }
    };
    for k in 0..8 {
        let c = DVec3::new(
            if k & 1 == 0 { -half.x } else { half.x },
            if k & 2 == 0 { -half.y } else { half.y },
            if k & 4 == 0 { -half.z } else { half.z },
        );
        consider(c, closest_on_triangle(c, v[0], v[1], v[2]));
    }
    for p in v {
        consider(p.clamp(-half, half), *p);
    }
    for (lo, hi) in box_edges(half) {
        for j in 0..3 {
            let (on_box, on_tri) = closest_between_segments(lo, hi, v[j], v[(j + 1) % 3]);
            consider(on_box, on_tri);
        }
    }
    let (d2, on_box, on_tri) = best;
    let d = d2.sqrt();
    let normal = if d > 0.0 { (on_tri - on_box) / d } else { fallback };
    Contact { point: (on_box + on_tri) * 0.5, normal, depth: -d }
}

/// Centre of the contact region for overlap along `n` (box to triangle), in the box's frame.
fn contact_point(half: DVec3, v: &[DVec3; 3], n: DVec3, axis: Axis) -> DVec3 {
    let b = Obb::new(DVec3::ZERO, DQuat::IDENTITY, half);
    match axis {
        Axis::Box(i) => {
            // Reference: the box face with outward normal n; incident: the triangle's feature
            // deepest along -n (a vertex, an edge or the whole triangle).
            let depth_of = |p: &DVec3| p.dot(n);
            let lowest = v.iter().map(depth_of).fold(f64::INFINITY, f64::min);
            let scale = 1.0 + v.iter().map(|p| p.abs().max_element()).fold(0.0, f64::max);
            let mut feature = Poly::default();
            for p in v {
                if depth_of(p) <= lowest + FLAT * scale {
                    feature.push(*p);
                }
            }
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            let mut region = feature;
            for (axis, s) in [(j, 1.0), (j, -1.0), (k, 1.0), (k, -1.0)] {
                let mut m = DVec3::ZERO;
                m[axis] = s;
                region = clip(region.as_slice(), m, half[axis]);
                if region.is_empty() {
                    break;
                }
            }
            // Clipping can only empty the region through rounding when the features barely meet.
            let region = if region.is_empty() { feature } else { region };
            let c = centroid(region.as_slice());
            c + n * ((half[i] - c.dot(n)) * 0.5)
        }
        Axis::Triangle => {
            // Reference: the triangle (its face towards the box has outward normal -n);
            // incident: the box's feature deepest along n, clipped to the triangle's prism.
            let feature = b.support_feature(n);
            let mut region = feature;
            for j in 0..3 {
                let (a, c, other) = (v[j], v[(j + 1) % 3], v[(j + 2) % 3]);
                let mut m = (c - a).cross(n);
                if m.dot(other - a) > 0.0 {
                    m = -m;
                }
                region = clip(region.as_slice(), m, m.dot(a));
                if region.is_empty() {
                    break;
                }
            }
            let region = if region.is_empty() { feature } else { region };
            let c = centroid(region.as_slice());
            c + n * ((n.dot(v[0]) - c.dot(n)) * 0.5)
        }
        Axis::Edges(_, j) => {
            let edge = b.support_feature(n);
            match edge.as_slice() {
                [p, q] => {
                    let (on_box, on_tri) = closest_between_segments(*p, *q, v[j], v[(j + 1) % 3]);
                    (on_box + on_tri) * 0.5
                }
                // A vertex or face here means the edge axis is (numerically) a face axis too.
                other => (centroid(other) + (v[j] + v[(j + 1) % 3]) * 0.5) * 0.5,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::narrow::oracle::{self, rotation};
    use proptest::prelude::*;

    fn flat_triangle(y: f64) -> [DVec3; 3] {
        [DVec3::new(-5.0, y, -5.0), DVec3::new(5.0, y, -5.0), DVec3::new(0.0, y, 5.0)]
    }

    #[test]
    fn box_sunk_into_a_wide_flat_triangle() {
        // A unit cube whose bottom face (y = -0.5) is 0.1 below a triangle at y = -0.4.
        let c = contact(DVec3::splat(0.5), DQuat::IDENTITY, flat_triangle(-0.4), 0.0).unwrap();
        assert!((c.depth - 0.1).abs() < 1e-12, "{c:?}");
        assert!((c.normal - DVec3::NEG_Y).length() < 1e-12, "{c:?}");
        // The whole bottom face lies over the triangle: its centre, halfway into the overlap.
        assert!((c.point - DVec3::new(0.0, -0.45, 0.0)).length() < 1e-12, "{c:?}");
    }

    #[test]
    fn box_just_above_a_triangle_is_apart_by_the_gap() {
        let c = contact(DVec3::splat(0.5), DQuat::IDENTITY, flat_triangle(-0.502), 0.01).unwrap();
        assert!((c.depth + 0.002).abs() < 1e-12, "{c:?}");
        assert!((c.normal - DVec3::NEG_Y).length() < 1e-12, "{c:?}");
        assert!(contact(DVec3::splat(0.5), DQuat::IDENTITY, flat_triangle(-0.502), 0.001).is_none());
        assert!(contact(DVec3::splat(0.5), DQuat::IDENTITY, flat_triangle(-0.502), 0.0).is_none());
    }

    #[test]
    fn corner_to_corner_distance_is_euclidean_not_the_axis_bound() {
        // A triangle whose nearest corner sits diagonally off the box's (+,+,+) corner: the
        // separating axes only bound the gap; the distance is the corner-to-corner length.
        let off = DVec3::splat(0.1);
        let corner = DVec3::splat(0.5) + off;
        let tri = [corner, corner + DVec3::new(1.0, 0.0, 0.0), corner + DVec3::new(0.0, 1.0, 1.0)];
        let c = contact(DVec3::splat(0.5), DQuat::IDENTITY, tri, 1.0).unwrap();
        assert!((c.depth + off.length()).abs() < 1e-12, "{c:?}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// Overlap, depth and normal agree with the Minkowski-difference oracle (the box's corners
        /// minus the triangle's), and the contact point lies in the box grown by the depth.
        #[test]
        fn matches_the_minkowski_difference(
            h in (0.05..2.0f64, 0.05..2.0f64, 0.05..2.0f64), rot in rotation(),
            p in proptest::array::uniform3((-2.5..2.5f64, -2.5..2.5f64, -2.5..2.5f64)),
        ) {
            let h = DVec3::new(h.0, h.1, h.2);
            let tri = p.map(|(x, y, z)| DVec3::new(x, y, z));
            prop_assume!((tri[1] - tri[0]).cross(tri[2] - tri[0]).length() > 1e-3);
            let diff: Vec<DVec3> = oracle::box_corners(h, rot, DVec3::ZERO)
                .iter().flat_map(|c| tri.iter().map(move |t| *c - *t)).collect();
            let (depth, _) = oracle::nearest_facet(&diff);
            match contact(h, rot, tri, 0.0) {
                None => prop_assert!(depth < 1e-9, "missed an overlap of {depth}"),
                Some(c) => {
                    prop_assert!((c.depth - depth).abs() < 1e-9, "depth {} oracle {depth}", c.depth);
                    if depth > 1e-6 {
                        // The depth along our normal is the oracle's (ties leave the normal free).
                        let l = rot.inverse() * c.normal;
                        let lo = tri.iter().map(|t| t.dot(c.normal)).fold(f64::INFINITY, f64::min);
                        let along = (h * l.abs()).element_sum() - lo;
                        prop_assert!((along - depth).abs() < 1e-9, "normal {:?}", c.normal);
                        let inside = (rot.inverse() * c.point).abs().cmple(h + DVec3::splat(depth + 1e-9)).all();
                        prop_assert!(inside, "point {:?}", c.point);
                    }
                }
            }
        }

        /// Apart, the distance is the true one: no point pair of box and triangle is closer
        /// (dense samples of both surfaces), and the pair reported is that far apart.
        #[test]
        fn apart_the_gap_is_the_distance(
            h in (0.05..2.0f64, 0.05..2.0f64, 0.05..2.0f64), rot in rotation(),
            p in proptest::array::uniform3((-3.0..3.0f64, -3.0..3.0f64, -3.0..3.0f64)),
        ) {
            let h = DVec3::new(h.0, h.1, h.2);
            let tri = p.map(|(x, y, z)| DVec3::new(x, y, z));
            prop_assume!((tri[1] - tri[0]).cross(tri[2] - tri[0]).length() > 1e-3);
            let Some(c) = contact(h, rot, tri, 10.0) else {
                prop_assert!(false, "within a 10 m margin there is always a contact");
                unreachable!()
            };
            prop_assume!(c.depth < -1e-6);
            let gap = -c.depth;
            // Brute force: triangle samples against the box (point-to-box distance is exact).
            let inv = rot.inverse();
            let mut nearest = f64::INFINITY;
            let n = 40;
            for a in 0..=n {
                for b in 0..=(n - a) {
                    let (s, t) = (a as f64 / n as f64, b as f64 / n as f64);
                    let q = inv * (tri[0] + (tri[1] - tri[0]) * s + (tri[2] - tri[0]) * t);
                    nearest = nearest.min((q - q.clamp(-h, h)).length());
                }
            }
            // Samples only over-estimate the distance, by at most the sample spacing.
            let spacing = (tri[1] - tri[0]).length().max((tri[2] - tri[0]).length()) / n as f64;
            prop_assert!(gap <= nearest + 1e-9, "gap {gap} but a sample is {nearest} away");
            prop_assert!(gap >= nearest - spacing - 1e-9, "gap {gap}, samples {nearest}");
        }
    }
}
