//! Sphere against capsule: the sphere against the closest point of the capsule's segment.

use super::{sphere_sphere, Contact};
use glam::{DQuat, DVec3};

/// Closest point to `p` on the segment `[a, b]`.
#[inline]
pub(crate) fn closest_on_segment(p: DVec3, a: DVec3, b: DVec3) -> DVec3 {
    let ab = b - a;
    let len2 = ab.length_squared();
    if len2 <= 0.0 {
        return a;
    }
    let t = ((p - a).dot(ab) / len2).clamp(0.0, 1.0);
    a + ab * t
}

/// Contact between a sphere of radius `r` at the origin and a capsule (segment half length
/// `half_height` along its local y, radius `rc`, orientation `rot`) centred at `d`.
#[inline]
pub fn contact(r: f64, half_height: f64, rc: f64, rot: DQuat, d: DVec3) -> Option<Contact> {
    let axis = rot * DVec3::new(0.0, half_height, 0.0);
    let q = closest_on_segment(DVec3::ZERO, d - axis, d + axis);
    sphere_sphere::contact(r, rc, q)
}
