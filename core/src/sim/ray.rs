//! Ray casts against the world: dynamic bodies, static bodies and the terrain. Analytic for
//! spheres and ellipsoids, parry's ray casts (in the body's local frame, so far-away bodies stay
//! accurate) for the other shapes, and a grid walk for the height field.

use crate::geometry::{Aabb, Shape};
use crate::sim::world::World;
use crate::terrain::heightfield::HeightField;
use glam::{DQuat, DVec3};
use impact_protocol::{EntityId, RayHit};
use rapier3d::parry;
use rapier3d::parry::query::RayCast;

/// A ray `origin + s * dir` (`dir` unit, `0 <= s <= max_m`) that never hits `exclude` (the
/// shooter).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Origin, world frame, m.
    pub origin: DVec3,
    /// Unit direction.
    pub dir: DVec3,
    /// Longest distance tested, m.
    pub max_m: f64,
    /// The entity the ray starts in, never hit.
    pub exclude: Option<EntityId>,
}

/// The nearest hit so far of one ray: `(distance, entity, normal)`.
pub(crate) type Best = Option<(f64, EntityId, DVec3)>;

/// The first hit of the ray `origin + s * dir` (`dir` unit, `0 <= s <= max_m`), skipping
/// `exclude` (the shooter).
pub fn cast(w: &World, origin: DVec3, dir: DVec3, max_m: f64, exclude: Option<EntityId>) -> Option<RayHit> {
    let ray = Ray { origin, dir, max_m, exclude };
    let mut best = [None];
    first_hits(w, std::slice::from_ref(&ray), &mut best);
    hit_of(&ray, best[0])
}

/// The first hit of each of `rays` against `w`, exactly as [`cast`] answers each, in one pass
/// over the bodies: each body is loaded once for all the rays instead of once per ray (a tick's
/// rewound shots against one past world). `out` is cleared first.
pub fn cast_many(w: &World, rays: &[Ray], out: &mut Vec<Option<RayHit>>) {
    let mut best = vec![None; rays.len()];
    first_hits(w, rays, &mut best);
    out.clear();
    out.extend(rays.iter().zip(best).map(|(r, b)| hit_of(r, b)));
}

pub(crate) fn hit_of(ray: &Ray, best: Best) -> Option<RayHit> {
    best.map(|(s, entity, normal)| RayHit {
        entity,
        point: (ray.origin + ray.dir * s).to_array(),
        normal: normal.to_array(),
        distance_m: s,
    })
}

/// Keeps the nearer of `best` and `hit` (ties: the lower id), so the answer does not depend on
/// the order bodies are visited in.
fn consider(best: &mut Best, hit: Option<(f64, DVec3)>, id: EntityId, max_m: f64) {
    if let Some((s, n)) = hit {
        if s <= max_m && best.is_none_or(|(bs, bid, _)| s < bs || (s == bs && id < bid)) {
            *best = Some((s, id, n));
        }
    }
}

/// The nearest hit of each ray, into `best` (one per ray, `None` to start).
fn first_hits(w: &World, rays: &[Ray], best: &mut [Best]) {
    let b = &w.bodies;
    for i in 0..b.len() {
        for (ray, best) in rays.iter().zip(best.iter_mut()) {
            body_hit(w, i, ray, best);
        }
    }
    for (ray, best) in rays.iter().zip(best.iter_mut()) {
        static_hits(w, ray, best);
    }
}

/// Dynamic body `i` against `ray`, kept in `best` if nearer.
///
/// Bodies are culled by their bounding spheres (centre and radius are at hand; a box would need
/// the orientation turned into a matrix per body per ray): a body a ray can hit first, at a
/// distance up to its nearest hit so far (ties included), has its sphere within reach of the
/// segment from the origin to that distance. One distance test per body and ray, and a branch
/// that is rarely taken. Culling only skips bodies a ray cannot hit first, so the answer is the
/// scan's.
#[inline]
pub(crate) fn body_hit(w: &World, i: usize, ray: &Ray, best: &mut Best) {
    let b = &w.bodies;
    let p = b.pos[i];
    // Conservative by a hair: rounding must never cull a grazing hit.
    let r = b.radius[i] * (1.0 + 1e-9) + 1e-9;
    let reach = best.map_or(ray.max_m, |(bs, _, _)| bs);
    let to = p - ray.origin;
    let d = to - ray.dir * to.dot(ray.dir).clamp(0.0, reach);
    if d.length_squared() > r * r || Some(b.id[i]) == ray.exclude {
        return;
    }
    let hit = cast_shape(&b.shape[i], p, b.rot[i], ray.origin, ray.dir, ray.max_m);
    consider(best, hit, b.id[i], ray.max_m);
}

/// The static bodies and the terrain against `ray`.
pub(crate) fn static_hits(w: &World, ray: &Ray, best: &mut Best) {
    let s = &w.statics;
    let end = ray.origin + ray.dir * ray.max_m;
    let ray_box = Aabb { min: ray.origin.min(end), max: ray.origin.max(end) };
    for k in 0..s.id.len() {
        if Some(s.id[k]) == ray.exclude || !s.aabb[k].overlaps(&ray_box) {
            continue;
        }
        let hit = cast_shape(&s.shape[k], s.pos[k], s.rot[k], ray.origin, ray.dir, ray.max_m);
        consider(best, hit, s.id[k], ray.max_m);
    }
    if let Some(t) = &s.terrain {
        consider(best, cast_heightfield(&t.field, ray.origin, ray.dir, ray.max_m), t.id, ray.max_m);
    }
}

/// Distance and unit normal (facing the ray) of the first hit on one shape.
pub(crate) fn cast_shape(
    shape: &Shape,
    pos: DVec3,
    rot: DQuat,
    origin: DVec3,
    dir: DVec3,
    max_m: f64,
) -> Option<(f64, DVec3)> {
    let inv = rot.inverse();
    let o = inv * (origin - pos);
    let d = inv * dir;
    let (s, n_local) = match shape {
        Shape::Sphere { radius } => ray_ellipsoid(o, d, DVec3::splat(*radius))?,
        Shape::Ellipsoid { radii } => ray_ellipsoid(o, d, *radii)?,
        _ => {
            let ray = parry::query::Ray::new(o.as_vec3(), d.as_vec3());
            let hit = match shape {
                Shape::Capsule { half_height, radius } => parry::shape::Capsule::new_y(
                    *half_height as f32,
                    *radius as f32,
                )
                .cast_local_ray_and_get_normal(&ray, max_m as f32, true),
                Shape::Cuboid { half_extents } => parry::shape::Cuboid::new(half_extents.as_vec3())
                    .cast_local_ray_and_get_normal(&ray, max_m as f32, true),
                Shape::Convex(hull) => hull.parry.cast_local_ray_and_get_normal(&ray, max_m as f32, true),
                Shape::TriMesh(mesh) => mesh.cast_local_ray_and_get_normal(&ray, max_m as f32, true),
                Shape::Sphere { .. } | Shape::Ellipsoid { .. } => {
                    unreachable!("handled analytically")
                }
            }?;
            (f64::from(hit.time_of_impact), hit.normal.as_dvec3())
        }
    };
    let mut n = (rot * n_local).normalize_or(-dir);
    if n.dot(dir) > 0.0 {
        n = -n; // a mesh hit from behind: face the shooter
    }
    Some((s, n))
}

/// Ray against the ellipsoid `x^2/a^2 + y^2/b^2 + z^2/c^2 = 1` (a sphere when all equal), in its
/// frame. A ray starting inside hits at distance 0 with the normal facing back along the ray.
fn ray_ellipsoid(o: DVec3, d: DVec3, radii: DVec3) -> Option<(f64, DVec3)> {
    let os = o / radii;
    let ds = d / radii;
    let a = ds.length_squared();
    let b = os.dot(ds);
    let c = os.length_squared() - 1.0;
    if c <= 0.0 {
        return Some((0.0, -d));
    }
    if b >= 0.0 || a == 0.0 {
        return None;
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    // Stable smaller root (see toi::analytic for the same form).
    let s = c / (-b + disc.sqrt());
    let p = o + d * s;
    Some((s, (p / (radii * radii)).normalize_or(-d)))
}

/// Moller-Trumbore: distance along the ray to triangle `t`, if hit from either side.
fn ray_triangle(o: DVec3, d: DVec3, t: &[DVec3; 3]) -> Option<f64> {
    let e1 = t[1] - t[0];
    let e2 = t[2] - t[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - t[0];
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let dist = e2.dot(q) * inv;
    (dist >= 0.0).then_some(dist)
}

/// Walks the cells the ray crosses in x-z, in order, and returns the first triangle hit.
fn cast_heightfield(field: &HeightField, origin: DVec3, dir: DVec3, max_m: f64) -> Option<(f64, DVec3)> {
    let bounds = field.aabb();
    // Clip the ray to the field's box.
    let (mut s0, mut s1) = (0.0f64, max_m);
    for k in 0..3 {
        if dir[k].abs() < 1e-300 {
            if origin[k] < bounds.min[k] || origin[k] > bounds.max[k] {
                return None;
            }
        } else {
            let a = (bounds.min[k] - origin[k]) / dir[k];
            let b = (bounds.max[k] - origin[k]) / dir[k];
            s0 = s0.max(a.min(b));
            s1 = s1.min(a.max(b));
        }
    }
    if s0 > s1 {
        return None;
    }
    // Sample the clipped segment finely enough to visit every cell it crosses: a step of
    // half the smaller cell side in x-z, then test the cells around each sample.
    let ext = bounds.extents();
    let cell = field.cell_size();
    let step = 0.5 * cell.0.min(cell.1);
    let horizontal = (dir.x * dir.x + dir.z * dir.z).sqrt();
    let steps = if horizontal > 0.0 { (((s1 - s0) * horizontal) / step).ceil() as usize + 1 } else { 1 };
    let steps = steps.min(4 * (ext.x / cell.0 + ext.z / cell.1) as usize + 8);
    let mut best: Option<(f64, DVec3)> = None;
    for k in 0..=steps {
        let s = if steps == 0 { s0 } else { s0 + (s1 - s0) * k as f64 / steps as f64 };
        let p = origin + dir * s;
        let probe = Aabb { min: p - DVec3::new(step, 0.0, step), max: p + DVec3::new(step, 0.0, step) };
        let probe = Aabb {
            min: DVec3::new(probe.min.x, bounds.min.y, probe.min.z),
            max: DVec3::new(probe.max.x, bounds.max.y, probe.max.z),
        };
        field.for_each_triangle_in(&probe, |t| {
            if let Some(dist) = ray_triangle(origin, dir, &t) {
                if dist <= max_m && best.is_none_or(|(b, _)| dist < b) {
                    best = Some((dist, HeightField::plane_normal(&t).normalize()));
                }
            }
        });
        // Cells are visited in ray order: a hit before the next sample's reach is final.
        if let Some((b, _)) = best {
            if b <= s {
                break;
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_and_box_hits_hand_computed() {
        let s = Shape::Sphere { radius: 1.0 };
        let (d, n) = cast_shape(&s, DVec3::new(10.0, 0.0, 0.0), DQuat::IDENTITY, DVec3::ZERO, DVec3::X, 100.0).unwrap();
        assert!((d - 9.0).abs() < 1e-12);
        assert!((n + DVec3::X).length() < 1e-12);
        assert!(cast_shape(&s, DVec3::new(10.0, 1.5, 0.0), DQuat::IDENTITY, DVec3::ZERO, DVec3::X, 100.0).is_none());
        assert!(
            cast_shape(&s, DVec3::new(10.0, 0.0, 0.0), DQuat::IDENTITY, DVec3::ZERO, DVec3::X, 8.0).is_none()
                || cast_shape(&s, DVec3::new(10.0, 0.0, 0.0), DQuat::IDENTITY, DVec3::ZERO, DVec3::X, 8.0).unwrap().0
                    > 8.0
        );
        let b = Shape::Cuboid { half_extents: DVec3::new(0.5, 2.0, 2.0) };
        let (d, n) = cast_shape(&b, DVec3::new(0.0, 0.0, 5.0), DQuat::IDENTITY, DVec3::ZERO, DVec3::Z, 100.0).unwrap();
        assert!((d - 3.0).abs() < 1e-5, "{d}");
        assert!((n + DVec3::Z).length() < 1e-5);
        // Far from the origin the local frame keeps it exact.
        let far = DVec3::new(1.0e7, 0.0, 0.0);
        let (d, _) = cast_shape(&s, far + DVec3::new(10.0, 0.0, 0.0), DQuat::IDENTITY, far, DVec3::X, 100.0).unwrap();
        assert!((d - 9.0).abs() < 1e-9);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(200))]

        /// The culled cast answers exactly what a scan of every body answers (same entity, same
        /// distance, bit for bit), rotated boxes and capsules included.
        #[test]
        fn culled_cast_equals_the_scan(
            bodies in proptest::collection::vec(
                ((-20.0..20.0f64, -20.0..20.0f64, -20.0..20.0f64), 0..3u8, (0.1..3.0f64, 0.1..3.0f64), crate::narrow::oracle::rotation()),
                1..60),
            origin in (-25.0..25.0f64, -25.0..25.0f64, -25.0..25.0f64),
            dir in (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64),
            max_m in 1.0..80.0f64,
        ) {
            let dir = DVec3::new(dir.0, dir.1, dir.2 + 1e-3).normalize();
            let origin = DVec3::new(origin.0, origin.1, origin.2);
            let text = "[world]\nname = \"r\"\n[[class]]\nname = \"c\"\n";
            let mut w = crate::scene::Scene::parse(text, "<rays>").unwrap().world;
            for (k, ((x, y, z), kind, (a, c), rot)) in bodies.iter().enumerate() {
                let shape = match kind {
                    0 => Shape::Sphere { radius: *a },
                    1 => Shape::Capsule { half_height: *a, radius: c.min(1.0) },
                    _ => Shape::Cuboid { half_extents: DVec3::new(*a, *c, 0.5 * (a + c)) },
                };
                let body = crate::sim::world::NewBody {
                    class: crate::sim::world::ClassId(0),
                    shape,
                    pos: DVec3::new(*x, *y, *z),
                    vel: DVec3::ZERO,
                    rot: *rot,
                    inv_mass: 1.0,
                    owner: None,
                };
                w.spawn(body).unwrap();
                let _ = k;
            }
            let exclude = Some(w.bodies.id[0]);
            let fast = cast(&w, origin, dir, max_m, exclude);
            // The scan: every body, nearest first, ties to the lower id.
            let b = &w.bodies;
            let scan = (0..b.len())
                .filter(|&i| Some(b.id[i]) != exclude)
                .filter_map(|i| cast_shape(&b.shape[i], b.pos[i], b.rot[i], origin, dir, max_m).map(|(s, _)| (s, b.id[i])))
                .filter(|(s, _)| *s <= max_m)
                .min_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            proptest::prop_assert_eq!(fast.clone().map(|h| (h.distance_m, h.entity)), scan);
            // The batch answers each ray as the single cast does (a second ray from the far side
            // shares the pass).
            let rays = [
                Ray { origin, dir, max_m, exclude },
                Ray { origin: -origin, dir: -dir, max_m, exclude: None },
            ];
            let mut many = Vec::new();
            cast_many(&w, &rays, &mut many);
            proptest::prop_assert_eq!(&many[0], &fast);
            proptest::prop_assert_eq!(&many[1], &cast(&w, -origin, -dir, max_m, None));
            // Through the world's index: the same answers, bit for bit.
            let index = crate::sim::ray_index::RayIndex::build(&w);
            let mut indexed = Vec::new();
            crate::sim::ray_index::cast_many_indexed(&w, &index, &rays, &mut indexed);
            proptest::prop_assert_eq!(&indexed, &many);
        }

        /// Many small bodies, so the index has many cells and a ray crosses many: its answers are
        /// the scan's, for rays from inside and outside the bodies' bounds, along axes and not.
        #[test]
        fn indexed_cast_equals_the_scan_in_a_crowd(
            seed in 0..u64::MAX,
            count in 1..800usize,
            spread in 1.0..200.0f64,
            rays in proptest::collection::vec(
                ((-1.5..1.5f64, -1.5..1.5f64, -1.5..1.5f64), (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64), 0..4u8, 0.5..400.0f64),
                1..12),
        ) {
            let text = "[world]\nname = \"r\"\n[[class]]\nname = \"c\"\n";
            let mut w = crate::scene::Scene::parse(text, "<rays>").unwrap().world;
            let mut x = seed | 1;
            let mut unit = move || {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 11) as f64 / (1u64 << 53) as f64
            };
            for _ in 0..count {
                let pos = DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5) * spread;
                // Mostly small, now and then one larger than a cell.
                let radius = if unit() < 0.02 { 0.5 * spread * unit() + 0.1 } else { 0.05 + 1.5 * unit() };
                let shape = if unit() < 0.5 {
                    Shape::Sphere { radius }
                } else {
                    Shape::Cuboid { half_extents: DVec3::new(radius, 0.5 * radius, 0.8 * radius) }
                };
                let rot = DQuat::from_rotation_y(6.0 * unit());
                let body = crate::sim::world::NewBody {
                    class: crate::sim::world::ClassId(0), shape, pos, vel: DVec3::ZERO, rot, inv_mass: 1.0, owner: None,
                };
                w.spawn(body).unwrap();
            }
            let rays: Vec<Ray> = rays
                .iter()
                .enumerate()
                .map(|(k, (o, d, axis, max_m))| {
                    let mut dir = DVec3::new(d.0, d.1, d.2 + 1e-3);
                    if *axis < 3 {
                        // Along an axis: the walk's zero steps.
                        dir = DVec3::ZERO;
                        dir[*axis as usize] = if d.0 < 0.0 { -1.0 } else { 1.0 };
                    }
                    Ray {
                        origin: DVec3::new(o.0, o.1, o.2) * spread,
                        dir: dir.normalize(),
                        max_m: *max_m,
                        exclude: (k % 2 == 0).then(|| w.bodies.id[k % w.bodies.len()]),
                    }
                })
                .collect();
            let (mut scan, mut indexed) = (Vec::new(), Vec::new());
            cast_many(&w, &rays, &mut scan);
            let mut index = crate::sim::ray_index::RayIndex::build(&w);
            crate::sim::ray_index::cast_many_indexed(&w, &index, &rays, &mut indexed);
            proptest::prop_assert_eq!(&indexed, &scan);
            // A few bodies move after the index was built (as a rollback writes back the bodies
            // it re-simulated): noted as moved, the answers are still the scan's of the world
            // as it is now, though their cells say where they were.
            let n = w.bodies.len();
            let moved: Vec<usize> = (0..n).filter(|_| unit() < 0.05).take((n / 16).max(1)).collect();
            for &i in &moved {
                w.bodies.pos[i] = DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5) * spread;
            }
            proptest::prop_assert!(index.moved(moved.iter().copied()) || moved.len() * 16 > n);
            cast_many(&w, &rays, &mut scan);
            crate::sim::ray_index::cast_many_indexed(&w, &index, &rays, &mut indexed);
            proptest::prop_assert_eq!(indexed, scan);
        }
    }

    #[test]
    fn heightfield_ray_hits_the_plane_under_it() {
        let rows = vec![vec![0.0; 11]; 11];
        let f = HeightField::new(DVec3::ZERO, 1.0, 1.0, &rows).unwrap();
        // Straight down onto a flat field at (3.3, 10, 4.7).
        let (d, n) = cast_heightfield(&f, DVec3::new(3.3, 10.0, 4.7), -DVec3::Y, 100.0).unwrap();
        assert!((d - 10.0).abs() < 1e-12);
        assert!((n - DVec3::Y).length() < 1e-12);
        // A shallow ray from outside the field reaching it far away.
        let dir = DVec3::new(1.0, -0.1, 0.0).normalize();
        let (d, _) = cast_heightfield(&f, DVec3::new(-5.0, 1.0, 5.0), dir, 100.0).unwrap();
        let hit = DVec3::new(-5.0, 1.0, 5.0) + dir * d;
        assert!((hit.y).abs() < 1e-9 && (hit.x - 5.0).abs() < 1e-9, "{hit:?}");
        assert!(cast_heightfield(&f, DVec3::new(3.0, 1.0, 3.0), DVec3::Y, 100.0).is_none());
    }
}
