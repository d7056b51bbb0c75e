//! Oriented box against oriented box: the separating-axis test in f64.
//!
//! For two convex polyhedra the minimum translation that separates them lies along a face
//! normal of either or along the cross product of an edge of each, so for boxes fifteen axes
//! decide overlap *and* give the exact penetration depth and normal. The test is symmetric by
//! construction (swapping the pair swaps the roles, not the numbers), which parry's f32 path is
//! not: on deep overlaps it can report depths that differ by tens of centimetres between the two
//! orders of the same pair.
//!
//! The contact point is the centre of the contact region: the incident feature (vertex, edge or
//! face of the other box) clipped to the reference face, each clipped vertex taken halfway to the
//! reference plane; for an edge/edge axis it is the midpoint of the two edges' closest points.
//!
//! Only overlap is decided here. For boxes that are apart, the separating-axis gap is a lower
//! bound of the distance, not the distance, so the caller measures the gap with GJK.

use super::capsule_capsule::closest_between_segments;
use super::Contact;
use glam::{DQuat, DVec3};

/// Below this `|u·n|` a box axis counts as lying in the plane of `n`: the box's support feature
/// extends along it (a face or an edge rather than a vertex).
pub(super) const FLAT: f64 = 1e-7;

/// An edge/edge axis must beat the best face axis by this (relative) margin to be chosen: on a
/// tie the face gives the larger, steadier contact region.
pub(super) const EDGE_BIAS: f64 = 1e-9;

/// A box in the pair frame: centre, unit axes and half extents.
#[derive(Clone, Copy)]
pub(super) struct Obb {
    centre: DVec3,
    axes: [DVec3; 3],
    half: DVec3,
}

impl Obb {
    pub(super) fn new(centre: DVec3, rot: DQuat, half: DVec3) -> Obb {
        Obb { centre, axes: [rot * DVec3::X, rot * DVec3::Y, rot * DVec3::Z], half }
    }

    /// The box's support feature in direction `n` as a convex polygon (1, 2 or 4 vertices, in
    /// order round the boundary).
    pub(super) fn support_feature(&self, n: DVec3) -> Poly {
        let mut fixed = self.centre;
        let mut free = Poly::default();
        for i in 0..3 {
            let along = self.axes[i] * self.half[i];
            let c = self.axes[i].dot(n);
            if c.abs() < FLAT {
                free.push(along);
            } else {
                fixed += along * c.signum();
            }
        }
        match free.as_slice() {
            [u] => Poly::of(&[fixed - *u, fixed + *u]),
            [u, v] => Poly::of(&[fixed + *u + *v, fixed - *u + *v, fixed - *u - *v, fixed + *u - *v]),
            // No free axis: a vertex. (Three cannot occur: the axes are an orthonormal basis.)
            _ => Poly::of(&[fixed]),
        }
    }

    /// The face whose outward normal is `n` (one of `±axes[axis]`) as its side planes
    /// `(unit normal, offset)`: a point is on the face's prism when `p·m <= offset` for each.
    fn face_sides(&self, axis: usize) -> [(DVec3, f64); 4] {
        let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
        let side = |k: usize, s: f64| {
            let m = self.axes[k] * s;
            (m, m.dot(self.centre) + self.half[k])
        };
        [side(i, 1.0), side(i, -1.0), side(j, 1.0), side(j, -1.0)]
    }
}

/// A convex polygon of at most eight vertices (a rectangle clipped by a rectangle), kept on
/// the stack: the kernel runs per pair per query and must not allocate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Poly {
    pts: [DVec3; 8],
    len: usize,
}

impl Poly {
    pub(super) fn of(points: &[DVec3]) -> Poly {
        let mut p = Poly::default();
        for &q in points {
            p.push(q);
        }
        p
    }

    pub(super) fn push(&mut self, p: DVec3) {
        self.pts[self.len] = p;
        self.len += 1;
    }

    pub(super) fn as_slice(&self) -> &[DVec3] {
        &self.pts[..self.len]
    }

    pub(super) fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// Which axis separates least.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Axis {
    /// Face normal `axes[i]` of box `a`.
    FaceA(usize),
    /// Face normal `axes[j]` of box `b`.
    FaceB(usize),
    /// `a.axes[i] × b.axes[j]`.
    Edges(usize, usize),
}

/// Contact between box `a` (half extents `ha`, orientation `ra`) at the origin and box `b` at
/// `d`, or `None` when the separating-axis test finds them apart. The normal points from `a` to
/// `b`; the depth is the exact penetration depth.
pub fn contact(ha: DVec3, ra: DQuat, hb: DVec3, rb: DQuat, d: DVec3) -> Option<Contact> {
    let a = Obb::new(DVec3::ZERO, ra, ha);
    let b = Obb::new(d, rb, hb);
    // Everything in a's frame (Gottschalk's OBB test): r[i][j] = a_i · b_j, t = d in a's axes.
    // Each axis's extents and the centres' distance along it are then a few products of these
    // numbers instead of fresh dot products with both boxes' axes.
    let r: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| a.axes[i].dot(b.axes[j])));
    let ar = r.map(|row| row.map(f64::abs));
    let t = [d.dot(a.axes[0]), d.dot(a.axes[1]), d.dot(a.axes[2])];
    let (ea, eb) = (ha.to_array(), hb.to_array());

    let mut best = (f64::NEG_INFINITY, Axis::FaceA(0));
    for i in 0..3 {
        let s = t[i].abs() - ea[i] - (eb[0] * ar[i][0] + eb[1] * ar[i][1] + eb[2] * ar[i][2]);
        if s > 0.0 {
            return None;
        }
        if s > best.0 {
            best = (s, Axis::FaceA(i));
        }
    }
    for j in 0..3 {
        let along = t[0] * r[0][j] + t[1] * r[1][j] + t[2] * r[2][j];
        let s = along.abs() - (ea[0] * ar[0][j] + ea[1] * ar[1][j] + ea[2] * ar[2][j]) - eb[j];
        if s > 0.0 {
            return None;
        }
        if s > best.0 {
            best = (s, Axis::FaceB(j));
        }
    }
    let face_best = best.0;
    for i in 0..3 {
        let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
        for j in 0..3 {
            let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
            // a_i × b_j in a's frame has components -r[i2][j] (along a_i1) and r[i1][j] (along
            // a_i2): its length without the cancellation of sqrt(1 - r[i][j]^2).
            let len = r[i1][j].hypot(r[i2][j]);
            // Parallel edges: the face axes already cover this direction.
            if len < 1e-6 {
                continue;
            }
            let along = (t[i2] * r[i1][j] - t[i1] * r[i2][j]).abs();
            let extent = ea[i1] * ar[i2][j] + ea[i2] * ar[i1][j] + eb[j1] * ar[i][j2] + eb[j2] * ar[i][j1];
            let s = (along - extent) / len;
            if s > 0.0 {
                return None;
            }
            if s > best.0 && s > face_best + EDGE_BIAS * (1.0 + face_best.abs()) {
                best = (s, Axis::Edges(i, j));
            }
        }
    }
    // The winning axis as a unit vector, turned to point from a to b.
    let toward_b = |n: DVec3| if n.dot(d) < 0.0 { -n } else { n };
    let n = match best.1 {
        Axis::FaceA(i) => toward_b(a.axes[i]),
        Axis::FaceB(j) => toward_b(b.axes[j]),
        Axis::Edges(i, j) => toward_b(a.axes[i].cross(b.axes[j]).normalize()),
    };
    let best = (best.0, n, best.1);

    let (sep, n, axis) = best;
    let depth = -sep;
    let point = match axis {
        Axis::FaceA(i) => face_contact_point(&a, i, &b, n),
        // Seen from b the reference normal is -n; the halfway points are the same.
        Axis::FaceB(j) => face_contact_point(&b, j, &a, -n),
        Axis::Edges(..) => {
            let ea = a.support_feature(n);
            let eb = b.support_feature(-n);
            let (pa, pb) = match (ea.as_slice(), eb.as_slice()) {
                ([p1, q1], [p2, q2]) => closest_between_segments(*p1, *q1, *p2, *q2),
                // A vertex or face here means the edge axis is (numerically) a face axis too.
                (fa, fb) => (centroid(fa), centroid(fb)),
            };
            (pa + pb) * 0.5
        }
    };
    Some(Contact { point, normal: n, depth })
}

/// Centre of the region where the incident box's support feature (towards the reference box
/// along `-n`) lies over the reference box's face `axis` (outward normal `n`), each point taken
/// halfway to the reference plane.
fn face_contact_point(reference: &Obb, axis: usize, incident: &Obb, n: DVec3) -> DVec3 {
    let plane = n.dot(reference.centre) + reference.half[axis];
    let feature = incident.support_feature(-n);
    let mut clipped = feature;
    for (m, offset) in reference.face_sides(axis) {
        clipped = clip(clipped.as_slice(), m, offset);
        if clipped.is_empty() {
            break;
        }
    }
    // Clipping can only empty the region through rounding when the features barely meet.
    let region = if clipped.is_empty() { feature } else { clipped };
    let c = centroid(region.as_slice());
    c + n * ((plane - c.dot(n)) * 0.5)
}

/// Clips a convex polygon (or a segment, or a point) to the half-space `p·m <= offset`.
pub(super) fn clip(poly: &[DVec3], m: DVec3, offset: f64) -> Poly {
    let inside = |p: DVec3| p.dot(m) <= offset;
    let cut = |p: DVec3, q: DVec3| {
        let (dp, dq) = (p.dot(m) - offset, q.dot(m) - offset);
        p + (q - p) * (dp / (dp - dq))
    };
    let mut out = Poly::default();
    match poly {
        [] => {}
        [p] => {
            if inside(*p) {
                out.push(*p);
            }
        }
        [p, q] => match (inside(*p), inside(*q)) {
            (true, true) => out = Poly::of(&[*p, *q]),
            (true, false) => out = Poly::of(&[*p, cut(*p, *q)]),
            (false, true) => out = Poly::of(&[cut(*p, *q), *q]),
            (false, false) => {}
        },
        _ => {
            // Sutherland–Hodgman against one plane: each plane adds at most one vertex, and a
            // rectangle meets four planes, so eight is enough.
            for k in 0..poly.len() {
                let (p, q) = (poly[k], poly[(k + 1) % poly.len()]);
                match (inside(p), inside(q)) {
                    (true, true) => out.push(q),
                    (true, false) => out.push(cut(p, q)),
                    (false, true) => {
                        out.push(cut(p, q));
                        out.push(q);
                    }
                    (false, false) => {}
                }
            }
        }
    }
    out
}

/// Mean of the vertices (the polygons here are at most octagons from clipping a rectangle by a
/// rectangle; the vertex mean lies inside and is stable, which is all the event needs).
pub(super) fn centroid(points: &[DVec3]) -> DVec3 {
    points.iter().copied().sum::<DVec3>() / points.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::narrow::oracle::{self, rotation};

    #[test]
    fn box_resting_on_a_wider_box_touches_at_the_centre_of_the_overlap() {
        // a: a 10 x 1 x 10 floor slab; b: a unit cube sunk 0.1 into it, off-centre in x.
        let c = contact(
            DVec3::new(5.0, 0.5, 5.0),
            DQuat::IDENTITY,
            DVec3::splat(0.5),
            DQuat::IDENTITY,
            DVec3::new(3.0, 0.9, 0.0),
        )
        .unwrap();
        assert!((c.depth - 0.1).abs() < 1e-12, "{c:?}");
        assert!((c.normal - DVec3::Y).length() < 1e-12, "{c:?}");
        // The region is b's whole bottom face; its centre is under b, halfway into the overlap.
        assert!((c.point - DVec3::new(3.0, 0.45, 0.0)).length() < 1e-12, "{c:?}");
    }

    #[test]
    fn overhanging_box_touches_at_the_centre_of_the_shared_part() {
        // b hangs over a's +x edge: its bottom face spans x in [4.5, 5.5], a's top ends at 5.
        let c = contact(
            DVec3::new(5.0, 0.5, 5.0),
            DQuat::IDENTITY,
            DVec3::splat(0.5),
            DQuat::IDENTITY,
            DVec3::new(5.0, 0.9, 0.0),
        )
        .unwrap();
        assert!((c.depth - 0.1).abs() < 1e-12, "{c:?}");
        assert!((c.point - DVec3::new(4.75, 0.45, 0.0)).length() < 1e-12, "{c:?}");
    }

    #[test]
    fn edge_against_edge_hand_computed() {
        // Two unit cubes, a turned 45 degrees about z and b about y: a's edge along z (at x = s)
        // meets b's edge along y (at x = d - s) crosswise, and they overlap by 2s - d along x.
        let s = std::f64::consts::SQRT_2 * 0.5;
        let ra = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_4);
        let rb = DQuat::from_rotation_y(std::f64::consts::FRAC_PI_4);
        let d = DVec3::new(2.0 * s - 0.05, 0.0, 0.0);
        let c = contact(DVec3::splat(0.5), ra, DVec3::splat(0.5), rb, d).unwrap();
        assert!((c.depth - 0.05).abs() < 1e-12, "{c:?}");
        assert!((c.normal - DVec3::X).length() < 1e-12, "{c:?}");
        // Midway between (s, 0, 0) on a's edge and (d - s, 0, 0) on b's.
        assert!((c.point - DVec3::new(s - 0.025, 0.0, 0.0)).length() < 1e-12, "{c:?}");
        // Pulled apart by more than the overlap, that axis separates them.
        assert!(contact(DVec3::splat(0.5), ra, DVec3::splat(0.5), rb, d + DVec3::new(0.06, 0.0, 0.0)).is_none());
    }

    #[test]
    fn edge_against_face_hand_computed() {
        // a's edge along z (a turned 45 degrees about z) against b's -x face (b turned about x,
        // which leaves its x axis alone).
        let s = std::f64::consts::SQRT_2 * 0.5;
        let ra = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_4);
        let rb = DQuat::from_rotation_x(std::f64::consts::FRAC_PI_4);
        let d = DVec3::new(s + 0.5 - 0.05, 0.0, 0.0);
        let c = contact(DVec3::splat(0.5), ra, DVec3::splat(0.5), rb, d).unwrap();
        assert!((c.depth - 0.05).abs() < 1e-12, "{c:?}");
        assert!((c.normal - DVec3::X).length() < 1e-12, "{c:?}");
        // The whole edge lies over b's face: its centre, halfway to the face plane.
        assert!((c.point - DVec3::new(s - 0.025, 0.0, 0.0)).length() < 1e-12, "{c:?}");
    }

    #[test]
    fn clip_handles_points_segments_and_polygons() {
        let m = DVec3::X;
        assert!(clip(&[DVec3::new(2.0, 0.0, 0.0)], m, 1.0).is_empty());
        assert_eq!(clip(&[DVec3::ZERO, DVec3::new(2.0, 0.0, 0.0)], m, 1.0).as_slice(), &[DVec3::ZERO, DVec3::X]);
        let square = [DVec3::new(2.0, 1.0, 0.0), DVec3::new(0.0, 1.0, 0.0), DVec3::ZERO, DVec3::new(2.0, 0.0, 0.0)];
        let half = clip(&square, m, 1.0);
        assert_eq!(half.as_slice().len(), 4);
        assert!((centroid(half.as_slice()) - DVec3::new(0.5, 0.5, 0.0)).length() < 1e-12);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(150))]

        /// Overlap, depth and normal agree with the Minkowski-difference oracle, and the
        /// contact point lies inside both boxes grown by the depth.
        #[test]
        fn matches_the_minkowski_difference(
            ha in (0.05..2.0f64, 0.05..2.0f64, 0.05..2.0f64), hb in (0.05..2.0f64, 0.05..2.0f64, 0.05..2.0f64),
            ra in rotation(), rb in rotation(), d in (-3.0..3.0f64, -3.0..3.0f64, -3.0..3.0f64),
        ) {
            let (ha, hb, d) = (DVec3::new(ha.0, ha.1, ha.2), DVec3::new(hb.0, hb.1, hb.2), DVec3::new(d.0, d.1, d.2));
            // The exact depth by another road: the nearest facet of the Minkowski difference.
            let corners_b = oracle::box_corners(hb, rb, d);
            let diff: Vec<DVec3> =
                oracle::box_corners(ha, ra, DVec3::ZERO).iter().flat_map(|pa| corners_b.iter().map(move |pb| *pa - *pb)).collect();
            let (depth, normal) = oracle::nearest_facet(&diff);
            match contact(ha, ra, hb, rb, d) {
                None => proptest::prop_assert!(depth < 1e-9, "missed an overlap of {depth}"),
                Some(c) => {
                    proptest::prop_assert!((c.depth - depth).abs() < 1e-9, "depth {} oracle {depth}", c.depth);
                    if depth > 1e-6 {
                        // Ties between facets leave the normal free; the depth along ours must match.
                        let along = (ha * (ra.inverse() * c.normal).abs()).element_sum()
                            + (hb * (rb.inverse() * c.normal).abs()).element_sum() - d.dot(c.normal);
                        proptest::prop_assert!((along - depth).abs() < 1e-9, "normal {:?} oracle {normal:?}", c.normal);
                        let inside = |h: DVec3, r: DQuat, centre: DVec3| {
                            (r.inverse() * (c.point - centre)).abs().cmple(h + DVec3::splat(depth + 1e-9)).all()
                        };
                        proptest::prop_assert!(inside(ha, ra, DVec3::ZERO) && inside(hb, rb, d), "point {:?}", c.point);
                    }
                }
            }
        }
    }
}
