//! The swept-sphere time of impact (DESIGN.md, "Intersection testing").
//!
//! Sphere P moves from P1 to P2 and sphere Q from Q1 to Q2 over one step. With A = P1 - Q1 and
//! B = (P2 - P1) - (Q2 - Q1), the squared distance at time t is |A + tB|^2, and the first
//! contact is the smaller root of |A + tB|^2 = (rP + rQ)^2:
//!
//! t = (-(A.B) - sqrt((A.B)^2 - B^2 (A^2 - r^2))) / B^2
//!
//! That form cancels catastrophically when the discriminant is small next to (A.B)^2 (grazing
//! or distant pairs), so it is evaluated as the algebraically equal
//! t = (A^2 - r^2) / (-(A.B) + sqrt(disc)), whose denominator is a sum of non-negative terms
//! for an approaching pair. Degenerate cases have defined answers: no relative motion
//! (B^2 = 0), moving apart, a negative discriminant (closest approach d^2 = A^2 - (A.B)^2 / B^2
//! exceeds r^2) and coincident centres.

use glam::DVec3;

/// Result of the swept-sphere test over `t` in `[0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum SweptSphere {
    /// Already overlapping at `t = 0` (`|A| < r`).
    Overlapping,
    /// First contact at this `t` in `[0, 1]`.
    Hit(f64),
    /// No contact during the step.
    Miss,
}

/// First time in `[0, 1]` at which spheres whose centres are `a = P1 - Q1` apart, with relative
/// displacement `b = (P2 - P1) - (Q2 - Q1)` over the step, come within `r = rP + rQ`.
pub(crate) fn swept_sphere(a: DVec3, b: DVec3, r: f64) -> SweptSphere {
    let a2 = a.length_squared();
    let c = a2 - r * r;
    if c < 0.0 {
        return SweptSphere::Overlapping;
    }
    let ab = a.dot(b);
    let b2 = b.length_squared();
    // Not approaching (this also covers B^2 = 0: no relative motion, ab = 0).
    if ab >= 0.0 || b2 == 0.0 {
        return SweptSphere::Miss;
    }
    let disc = ab * ab - b2 * c;
    if disc < 0.0 {
        return SweptSphere::Miss;
    }
    let t = c / (-ab + disc.sqrt());
    if t <= 1.0 {
        SweptSphere::Hit(t)
    } else {
        SweptSphere::Miss
    }
}

/// Squared closest-approach distance of the infinite relative path (`A^2 - (A.B)^2 / B^2`), or
/// `A^2` when there is no relative motion.
pub fn closest_approach_sq(a: DVec3, b: DVec3) -> f64 {
    let b2 = b.length_squared();
    if b2 == 0.0 {
        return a.length_squared();
    }
    let ab = a.dot(b);
    (a.length_squared() - ab * ab / b2).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn head_on_hand_computed() {
        // Centres 10 m apart closing at 20 m per step, radii sum 2: contact after 8 m, t = 0.4.
        let t = swept_sphere(DVec3::new(-10.0, 0.0, 0.0), DVec3::new(20.0, 0.0, 0.0), 2.0);
        assert_eq!(t, SweptSphere::Hit(0.4));
    }

    #[test]
    fn degenerate_cases() {
        // Equal velocities: B = 0.
        assert_eq!(swept_sphere(DVec3::new(5.0, 0.0, 0.0), DVec3::ZERO, 1.0), SweptSphere::Miss);
        // Coincident centres: overlapping.
        assert_eq!(swept_sphere(DVec3::ZERO, DVec3::X, 1.0), SweptSphere::Overlapping);
        // Negative discriminant: passes 3 m away with radius sum 2.
        assert_eq!(swept_sphere(DVec3::new(-5.0, 3.0, 0.0), DVec3::new(10.0, 0.0, 0.0), 2.0), SweptSphere::Miss);
        // Moving apart.
        assert_eq!(swept_sphere(DVec3::new(5.0, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0), 1.0), SweptSphere::Miss);
        // Grazing: closest approach exactly the radius sum is a touch at the closest point.
        match swept_sphere(DVec3::new(-5.0, 2.0, 0.0), DVec3::new(10.0, 0.0, 0.0), 2.0) {
            SweptSphere::Hit(t) => assert!((t - 0.5).abs() < 1e-12),
            other => panic!("{other:?}"),
        }
        // Stops short of contact.
        assert_eq!(swept_sphere(DVec3::new(-10.0, 0.0, 0.0), DVec3::new(5.0, 0.0, 0.0), 2.0), SweptSphere::Miss);
        assert_eq!(closest_approach_sq(DVec3::new(-5.0, 3.0, 0.0), DVec3::new(10.0, 0.0, 0.0)), 9.0);
    }

    proptest! {
        /// At the reported time the distance equals the radius sum, and before it the spheres
        /// never touched (checked on a fine grid).
        #[test]
        fn hit_time_is_first_contact(ax in -10.0..10.0f64, ay in -10.0..10.0f64, az in -10.0..10.0f64,
                                     bx in -30.0..30.0f64, by in -30.0..30.0f64, bz in -30.0..30.0f64, r in 0.01..3.0f64) {
            let a = DVec3::new(ax, ay, az);
            let b = DVec3::new(bx, by, bz);
            match swept_sphere(a, b, r) {
                SweptSphere::Hit(t) => {
                    prop_assert!((0.0..=1.0).contains(&t));
                    let d = (a + b * t).length();
                    prop_assert!((d - r).abs() <= 1e-9 * (1.0 + a.length() + b.length()), "d {d} r {r}");
                    for i in 0..200 {
                        let s = t * f64::from(i) / 200.0;
                        prop_assert!((a + b * s).length() >= r - 1e-9 * (1.0 + a.length() + b.length()));
                    }
                }
                SweptSphere::Miss => {
                    for i in 0..=200 {
                        let s = f64::from(i) / 200.0;
                        prop_assert!((a + b * s).length() >= r * (1.0 - 1e-9) - 1e-12);
                    }
                }
                SweptSphere::Overlapping => prop_assert!(a.length() < r),
            }
        }
    }
}
