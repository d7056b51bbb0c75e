//! Sphere against triangle: the closest point of the triangle to the centre (Ericson 5.1.5).

use super::{sphere_sphere, Contact};
use glam::DVec3;

/// Closest point to `p` on triangle `abc`.
pub(crate) fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Contact between a sphere of radius `r` at the origin and the triangle `abc` (vertices relative
/// to the sphere centre). A centre exactly on the triangle gets the triangle's face normal.
pub fn contact(r: f64, a: DVec3, b: DVec3, c: DVec3) -> Option<Contact> {
    let q = closest_on_triangle(DVec3::ZERO, a, b, c);
    if q.length_squared() == 0.0 {
        let n = (b - a).cross(c - a).normalize_or(DVec3::Y);
        return Some(Contact { point: DVec3::ZERO, normal: -n, depth: r });
    }
    sphere_sphere::contact(r, 0.0, q)
}
