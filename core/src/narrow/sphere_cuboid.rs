//! Sphere against oriented box: the closest point of the box to the sphere's centre, in the
//! box's frame.

use super::Contact;
use glam::{DQuat, DVec3};

/// Contact between a sphere of radius `r` at the origin and a box (half extents `half`,
/// orientation `rot`) centred at `d`. The normal points from the sphere to the box.
pub fn contact(r: f64, half: DVec3, rot: DQuat, d: DVec3) -> Option<Contact> {
    // Sphere centre in the box's local frame.
    let inv = rot.inverse();
    let c = inv * -d;
    let clamped = c.clamp(-half, half);
    let outside = c - clamped;
    let dist2 = outside.length_squared();
    let (local_point, local_normal_box_to_sphere, dist) = if dist2 > 0.0 {
        let dist = dist2.sqrt();
        (clamped, outside / dist, dist)
    } else {
        // Centre inside the box: push out through the nearest face (ties broken x, y, z so the
        // choice is deterministic).
        let gaps = half - c.abs();
        let (axis, gap) = if gaps.x <= gaps.y && gaps.x <= gaps.z {
            (0, gaps.x)
        } else if gaps.y <= gaps.z {
            (1, gaps.y)
        } else {
            (2, gaps.z)
        };
        let mut n = DVec3::ZERO;
        n[axis] = if c[axis] >= 0.0 { 1.0 } else { -1.0 };
        let mut p = c;
        p[axis] = half[axis] * n[axis];
        (p, n, -gap)
    };
    // Back to the pair frame: box point in world orientation relative to the sphere centre.
    let box_point = d + rot * local_point;
    let normal = -(rot * local_normal_box_to_sphere);
    let depth = r - dist;
    // Midpoint between the sphere surface point and the box surface point.
    let sphere_point = normal * r;
    Some(Contact { point: (box_point + sphere_point) * 0.5, normal, depth })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn face_edge_and_inside_cases() {
        let half = DVec3::new(1.0, 2.0, 3.0);
        // Sphere left of the +x face... the box is at +x from the sphere.
        let c = contact(0.5, half, DQuat::IDENTITY, DVec3::new(1.4, 0.0, 0.0)).unwrap();
        assert!((c.depth - 0.1).abs() < 1e-12);
        assert!((c.normal - DVec3::X).length() < 1e-12);
        // Edge: closest point is the box's edge at (-1, -2, z).
        let c = contact(1.0, half, DQuat::IDENTITY, DVec3::new(2.0, 3.0, 0.0)).unwrap();
        assert!((c.depth - (1.0 - 2f64.sqrt())).abs() < 1e-12);
        // Centre inside, nearest face is -x at distance 0.2 from the centre.
        let c = contact(0.5, half, DQuat::IDENTITY, DVec3::new(0.8, 0.0, 0.0)).unwrap();
        assert!((c.depth - 0.7).abs() < 1e-12, "{c:?}");
        assert!((c.normal - DVec3::X).length() < 1e-12);
        // A rotated box: 90 degrees about z swaps the x and y extents.
        let rot = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2);
        let c = contact(0.5, half, rot, DVec3::new(2.4, 0.0, 0.0)).unwrap();
        assert!((c.depth - 0.1).abs() < 1e-9, "{c:?}");
    }
}
