//! Sphere against sphere: the distance between centres.

use super::Contact;
use glam::DVec3;

/// Contact between a sphere of radius `r1` at the origin and one of radius `r2` at `d`.
/// Coincident centres get the normal `+y` (any unit vector is correct; this one is fixed so the
/// result is deterministic).
#[inline]
pub fn contact(r1: f64, r2: f64, d: DVec3) -> Option<Contact> {
    let dist = d.length();
    let normal = if dist > 0.0 { d / dist } else { DVec3::Y };
    let depth = r1 + r2 - dist;
    // Midpoint between the two surface points along the normal.
    let point = normal * (r1 - 0.5 * depth);
    Some(Contact { point, normal, depth })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_cases() {
        let c = contact(1.0, 0.5, DVec3::new(1.2, 0.0, 0.0)).unwrap();
        assert!((c.depth - 0.3).abs() < 1e-15);
        assert_eq!(c.normal, DVec3::X);
        assert!((c.point.x - 0.85).abs() < 1e-15, "{:?}", c.point);
        let apart = contact(1.0, 1.0, DVec3::new(0.0, 3.0, 0.0)).unwrap();
        assert!((apart.depth + 1.0).abs() < 1e-15);
        let same = contact(1.0, 1.0, DVec3::ZERO).unwrap();
        assert_eq!(same.normal, DVec3::Y);
        assert_eq!(same.depth, 2.0);
    }
}
