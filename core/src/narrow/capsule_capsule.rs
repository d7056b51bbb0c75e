//! Capsule against capsule: spheres at the closest points of the two segments.

use super::{sphere_sphere, Contact};
use glam::{DQuat, DVec3};

/// Closest points `(on [p1, q1], on [p2, q2])` between two segments (Ericson, Real-Time
/// Collision Detection, 5.1.9), robust to degenerate and parallel segments.
pub(crate) fn closest_between_segments(p1: DVec3, q1: DVec3, p2: DVec3, q2: DVec3) -> (DVec3, DVec3) {
    let d1 = q1 - p1;
    let d2 = q2 - p2;
    let r = p1 - p2;
    let a = d1.length_squared();
    let e = d2.length_squared();
    let f = d2.dot(r);
    const EPS: f64 = 1e-300;
    let (s, t);
    if a <= EPS && e <= EPS {
        return (p1, p2);
    }
    if a <= EPS {
        s = 0.0;
        t = (f / e).clamp(0.0, 1.0);
    } else {
        let c = d1.dot(r);
        if e <= EPS {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else {
            let b = d1.dot(d2);
            let denom = a * e - b * b;
            let mut s0 = if denom > 1e-12 * a * e { ((b * f - c * e) / denom).clamp(0.0, 1.0) } else { 0.0 };
            let mut t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                t0 = 0.0;
                s0 = (-c / a).clamp(0.0, 1.0);
            } else if t0 > 1.0 {
                t0 = 1.0;
                s0 = ((b - c) / a).clamp(0.0, 1.0);
            }
            s = s0;
            t = t0;
        }
    }
    (p1 + d1 * s, p2 + d2 * t)
}

/// Contact between capsule 1 at the origin and capsule 2 at `d` (segments along local y).
pub fn contact(h1: f64, r1: f64, rot1: DQuat, h2: f64, r2: f64, rot2: DQuat, d: DVec3) -> Option<Contact> {
    let a1 = rot1 * DVec3::new(0.0, h1, 0.0);
    let a2 = rot2 * DVec3::new(0.0, h2, 0.0);
    let (c1, c2) = closest_between_segments(-a1, a1, d - a2, d + a2);
    sphere_sphere::contact(r1, r2, c2 - c1).map(|c| Contact { point: c.point + c1, ..c })
}
