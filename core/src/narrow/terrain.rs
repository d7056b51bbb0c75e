//! A convex shape against the height field: the triangles under the shape's bounds, each tested
//! with its kernel (`narrow::triangle_contact`); the deepest wins. The field is solid below its
//! surface, so a sphere whose centre has sunk under the triangle beneath it still gets a
//! contact pushing it back up.

use super::Contact;
use crate::geometry::Shape;
use crate::terrain::heightfield::HeightField;
use glam::{DQuat, DVec3};

/// Contact between `shape` (orientation `rot`) centred at world position `pos` and the field,
/// in the shape's pair frame (shape at the origin, normal pointing from the shape into the
/// terrain), or `None` when nothing is within `margin`.
pub fn terrain_contact(shape: &Shape, rot: DQuat, pos: DVec3, field: &HeightField, margin: f64) -> Option<Contact> {
    let bounds = shape.world_aabb(pos, rot).inflated(margin.max(0.0));
    let mut best: Option<Contact> = None;
    let mut consider = |c: Option<Contact>| {
        if let Some(c) = c.filter(|c| c.depth > -margin) {
            if best.is_none_or(|b| c.depth > b.depth) {
                best = Some(c);
            }
        }
    };
    field.for_each_triangle_in(&bounds, |t| {
        let tri = [t[0] - pos, t[1] - pos, t[2] - pos];
        consider(super::triangle_contact(shape, rot, tri, margin));
    });
    if let Shape::Sphere { radius } = shape {
        // Solid below: the signed distance to the plane of the triangle under the centre.
        if let Some(t) = field.triangle_at(pos.x, pos.z) {
            let up = HeightField::plane_normal(&t).normalize();
            let s = up.dot(pos - t[0]);
            if s < 0.0 {
                consider(Some(Contact {
                    point: -up * (*radius + s) * 0.5 - up * (-s) * 0.5,
                    normal: -up,
                    depth: radius - s,
                }));
            }
        }
    }
    best
}
