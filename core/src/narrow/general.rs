//! Any convex pair: parry's GJK (and EPA for penetration) on support maps.
//!
//! Every convex [`Shape`] answers [`Shape::local_support`], so one adapter lets parry's
//! `contact_support_map_support_map` handle ellipsoids and hulls as well as the primitives. The
//! query runs in f32 in the pair's local frame (`a` at the origin), which keeps it accurate far
//! from the world origin.

use super::Contact;
use crate::geometry::Shape;
use glam::{DQuat, DVec3};
use rapier3d::parry;
use rapier3d::parry::math::{Pose, Vector};
use rapier3d::parry::query::contact::contact_support_map_support_map;
use rapier3d::parry::query::QueryDispatcher;
use rapier3d::parry::shape::SupportMap;

/// Adapts a convex [`Shape`] to parry's support-map interface.
struct Support<'a>(&'a Shape);

impl SupportMap for Support<'_> {
    fn local_support_point(&self, dir: Vector) -> Vector {
        self.0.local_support(dir.as_dvec3()).as_vec3()
    }
}

/// Calls `f` with parry's own shape for `s`, built on the stack (no allocation), or `None`
/// for shapes parry does not have (the ellipsoid).
fn with_parry<R>(s: &Shape, f: impl FnOnce(&dyn parry::shape::Shape) -> R) -> Option<R> {
    Some(match s {
        Shape::Sphere { radius } => f(&parry::shape::Ball::new(*radius as f32)),
        Shape::Capsule { half_height, radius } => f(&parry::shape::Capsule::new_y(*half_height as f32, *radius as f32)),
        Shape::Cuboid { half_extents } => f(&parry::shape::Cuboid::new(half_extents.as_vec3())),
        Shape::Convex(hull) => f(&hull.parry),
        Shape::TriMesh(mesh) => f(mesh.as_ref()),
        Shape::Ellipsoid { .. } => return None,
    })
}

/// Contact between convex `a` (orientation `ra`) at the origin and convex `b` (orientation
/// `rb`) at `d`, or `None` when farther apart than `margin`. Shapes parry knows go through its
/// query dispatcher (which keeps spheres and capsules round: a point or segment plus a margin);
/// the ellipsoid goes through GJK/EPA on its support function.
pub fn contact(a: &Shape, ra: DQuat, b: &Shape, rb: DQuat, d: DVec3, margin: f64) -> Option<Contact> {
    let inv = ra.inverse();
    let pos12 = Pose::from_parts((inv * d).as_vec3(), (inv * rb).normalize().as_quat());
    let dispatched = with_parry(a, |pa| {
        with_parry(b, |pb| parry::query::DefaultQueryDispatcher.contact(&pos12, pa, pb, margin as f32).ok().flatten())
    })
    .flatten();
    let c = match dispatched {
        Some(result) => result?,
        None => contact_support_map_support_map(&pos12, &Support(a), &Support(b), margin as f32)?,
    };
    Some(from_parry(&c, &pos12, ra))
}

/// Contact between convex `a` (orientation `ra`) at the origin and the triangle `tri` (vertices
/// relative to `a`'s centre, world-oriented).
pub(crate) fn contact_triangle(a: &Shape, ra: DQuat, tri: [DVec3; 3], margin: f64) -> Option<Contact> {
    let inv = ra.inverse();
    let t = parry::shape::Triangle::new((inv * tri[0]).as_vec3(), (inv * tri[1]).as_vec3(), (inv * tri[2]).as_vec3());
    let pos12 = Pose::identity();
    let c = contact_support_map_support_map(&pos12, &Support(a), &t, margin as f32)?;
    Some(from_parry(&c, &pos12, ra))
}

fn from_parry(c: &parry::query::Contact, pos12: &Pose, ra: DQuat) -> Contact {
    let p1 = c.point1.as_dvec3();
    let p2 = pos12.transform_point(c.point2).as_dvec3();
    Contact {
        point: ra * ((p1 + p2) * 0.5),
        normal: (ra * c.normal1.as_dvec3()).normalize_or(DVec3::Y),
        depth: -(c.dist as f64),
    }
}
