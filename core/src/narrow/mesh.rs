//! A convex shape against a static triangle mesh: parry's BVH finds the triangles under the
//! shape's bounds, then each triangle is tested with its kernel (`narrow::triangle_contact`), and the
//! deepest contact is the pair's contact.

use super::Contact;
use crate::geometry::Shape;
use glam::{DQuat, DVec3};
use rapier3d::parry;

/// Contact between convex `a` (orientation `ra`) at the origin and `mesh` (orientation `rm`) at
/// `d`, or `None` when no triangle is within `margin`.
pub fn contact(
    a: &Shape,
    ra: DQuat,
    mesh: &parry::shape::TriMesh,
    rm: DQuat,
    d: DVec3,
    margin: f64,
) -> Option<Contact> {
    let inv = rm.inverse();
    // `a`'s bounds in the mesh frame.
    let centre_in_mesh = inv * -d;
    let bounds = a.world_aabb(centre_in_mesh, inv * ra).inflated(margin.max(0.0));
    let query = parry::bounding_volume::Aabb::new(bounds.min.as_vec3(), bounds.max.as_vec3());
    let mut best: Option<Contact> = None;
    for i in mesh.bvh().intersect_aabb(&query) {
        let t = mesh.triangle(i);
        let tri = [d + rm * t.a.as_dvec3(), d + rm * t.b.as_dvec3(), d + rm * t.c.as_dvec3()];
        let c = super::triangle_contact(a, ra, tri, margin);
        if let Some(c) = c.filter(|c| c.depth > -margin) {
            // Deepest wins; ties keep the lower triangle index (the BVH order is fixed for a
            // given mesh, so this is deterministic).
            if best.is_none_or(|b| c.depth > b.depth) {
                best = Some(c);
            }
        }
    }
    best
}
