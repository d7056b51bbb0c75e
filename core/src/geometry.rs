//! Collision shapes. Dynamic bodies are convex (sphere, capsule, box, ellipsoid, convex hull);
//! static geometry may also be a triangle mesh. Terrain is a separate height field
//! ([`crate::terrain`]).
//!
//! Shapes are defined in their local frame (centred on the body's position) and carried in f64.
//! Bodies keep a fixed orientation: impact is a collision server, not a rigid-body solver, so
//! rotation never changes during a step.

use glam::{DQuat, DVec3};
use impact_protocol::ShapeSpec;
use rapier3d::parry;
use std::sync::Arc;

/// Largest dimension (radius, half extent, distance of a point from the centre) a shape may
/// have, m.
pub const MAX_DIM_M: f64 = 1.0e6;

/// Why a [`ShapeSpec`] cannot become a [`Shape`].
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{field}: {detail}")]
pub struct ShapeError {
    /// The field, relative to the shape (`radius_m`, `points[3]`), or empty for the whole shape.
    pub field: String,
    /// What is wrong.
    pub detail: String,
}

fn shape_error(field: impl Into<String>, detail: impl Into<String>) -> ShapeError {
    ShapeError { field: field.into(), detail: detail.into() }
}

/// Whether `points` span a volume: four of them are not coplanar (to within a part in 10^9 of
/// their extent). A flat hull has no volume, so a dynamic body of it would have no mass; parry
/// builds one from three points all the same.
fn spans_volume(points: &[DVec3]) -> bool {
    let Some(&a) = points.first() else { return false };
    let farthest = |f: &dyn Fn(DVec3) -> f64| points.iter().copied().max_by(|p, q| f(*p).total_cmp(&f(*q)));
    let Some(b) = farthest(&|p| (p - a).length_squared()) else { return false };
    let scale = (b - a).length();
    let line = (b - a).normalize_or_zero();
    let off_line = |p: DVec3| (p - a).reject_from_normalized(line).length();
    let Some(c) = farthest(&off_line) else { return false };
    let normal = (b - a).cross(c - a).normalize_or_zero();
    let off_plane = |p: DVec3| (p - a).dot(normal).abs();
    let eps = 1e-9 * scale;
    scale > 0.0 && off_line(c) > eps && farthest(&off_plane).is_some_and(|d| off_plane(d) > eps)
}

/// A collision shape in its local frame, prepared for the tick. Lengths in metres.
///
/// Its own type beside the wire's [`ShapeSpec`] because it carries what is built once and kept:
/// a hull's parry polyhedron, a mesh's BVH. [`Shape::from_spec`] and [`Shape::to_spec`] are the
/// one conversion each way.
#[derive(Clone, Debug)]
pub enum Shape {
    /// A sphere centred on the origin.
    Sphere {
        /// Radius, m.
        radius: f64,
    },
    /// A capsule: the points within `radius` of the segment from `(0, -half_height, 0)` to
    /// `(0, half_height, 0)`.
    Capsule {
        /// Half the segment length, m.
        half_height: f64,
        /// Radius, m.
        radius: f64,
    },
    /// A box centred on the origin.
    Cuboid {
        /// Half extents along local x, y, z, m.
        half_extents: DVec3,
    },
    /// An axis-aligned (in local frame) ellipsoid, handled through its support function.
    Ellipsoid {
        /// Semi-axes along local x, y, z, m.
        radii: DVec3,
    },
    /// The convex hull of a point set.
    Convex(Arc<ConvexHull>),
    /// A static triangle mesh (never on a dynamic body).
    TriMesh(Arc<parry::shape::TriMesh>),
}

/// A convex hull: the points (f64, for bounds) and parry's polyhedron (for GJK and rays).
#[derive(Debug)]
pub struct ConvexHull {
    /// Hull vertices, local frame, m.
    pub points: Vec<DVec3>,
    /// The same hull as parry's shape (f32).
    pub parry: parry::shape::ConvexPolyhedron,
}

/// The shape families a plan chooses kernels by. The state stream's `BodyShape` names the same
/// families for drawing, plus terrain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ShapeKind {
    /// [`Shape::Sphere`].
    Sphere,
    /// [`Shape::Capsule`].
    Capsule,
    /// [`Shape::Cuboid`].
    Cuboid,
    /// [`Shape::Ellipsoid`].
    Ellipsoid,
    /// [`Shape::Convex`].
    Convex,
    /// [`Shape::TriMesh`].
    TriMesh,
}

/// `v.floor() as i64`, bit for bit (saturating; NaN gives 0), without `floor`: on the x86-64
/// baseline (no SSE4.1) `f64::floor` is a call into a software routine, and grids take a floor
/// per coordinate of every body they file (it was a fifth of building the ray index).
#[inline]
pub fn floor_i64(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// An axis-aligned bounding box in f64 (world frame unless said otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner, m.
    pub min: DVec3,
    /// Maximum corner, m.
    pub max: DVec3,
}

impl Aabb {
    /// The empty box (contains nothing; `union` with it is the identity).
    pub const EMPTY: Aabb = Aabb { min: DVec3::splat(f64::INFINITY), max: DVec3::splat(f64::NEG_INFINITY) };

    /// The smallest box containing both.
    #[inline]
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb { min: self.min.min(other.min), max: self.max.max(other.max) }
    }

    /// Closed-interval overlap on all three axes. All six comparisons are made (`&`, not `&&`):
    /// a broadphase asks this of neighbours that miss on any axis at random, and six compares
    /// cost less than the branch mispredictions of stopping at the first miss.
    #[inline]
    pub fn overlaps(&self, other: &Aabb) -> bool {
        (self.min.x <= other.max.x)
            & (other.min.x <= self.max.x)
            & (self.min.y <= other.max.y)
            & (other.min.y <= self.max.y)
            & (self.min.z <= other.max.z)
            & (other.min.z <= self.max.z)
    }

    /// Grown by `margin` on every side.
    #[inline]
    pub fn inflated(&self, margin: f64) -> Aabb {
        Aabb { min: self.min - DVec3::splat(margin), max: self.max + DVec3::splat(margin) }
    }

    /// Moved by `d`.
    #[inline]
    pub fn translated(&self, d: DVec3) -> Aabb {
        Aabb { min: self.min + d, max: self.max + d }
    }

    /// Size along each axis.
    #[inline]
    pub fn extents(&self) -> DVec3 {
        self.max - self.min
    }

    /// Whether the segment from `a` to `b` meets the box (closed, with `slack` m of tolerance
    /// on every side, so a caller can keep the test conservative against rounding): the slab
    /// test, exact where a box-box test against the segment's bounds is not (a long diagonal
    /// segment's bounds cover much that it never comes near).
    pub fn crosses_segment(&self, a: DVec3, b: DVec3, slack: f64) -> bool {
        let (min, max) = (self.min - DVec3::splat(slack), self.max + DVec3::splat(slack));
        let d = b - a;
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for axis in 0..3 {
            let (o, v, lo, hi) = (a[axis], d[axis], min[axis], max[axis]);
            if v == 0.0 {
                if o < lo || o > hi {
                    return false;
                }
                continue;
            }
            let (mut ta, mut tb) = ((lo - o) / v, (hi - o) / v);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            t0 = t0.max(ta);
            t1 = t1.min(tb);
            if t0 > t1 {
                return false;
            }
        }
        true
    }
}

impl Shape {
    /// The shape `spec` describes, with its dimensions checked (positive, finite, at most
    /// [`MAX_DIM_M`]), a hull's points not degenerate and a mesh's triangles naming its vertices.
    pub fn from_spec(spec: &ShapeSpec) -> Result<Shape, ShapeError> {
        let dim = |x: f64, field: String| {
            if x.is_finite() && x > 0.0 && x <= MAX_DIM_M {
                Ok(x)
            } else {
                Err(shape_error(field, format!("{x} must be a positive finite length (m), at most {MAX_DIM_M:e}")))
            }
        };
        let dims = |v: &[f64; 3], name: &str| -> Result<DVec3, ShapeError> {
            for (k, x) in v.iter().enumerate() {
                dim(*x, format!("{name}[{k}]"))?;
            }
            Ok(DVec3::from_array(*v))
        };
        let points = |v: &[[f64; 3]], name: &str| -> Result<Vec<DVec3>, ShapeError> {
            v.iter()
                .enumerate()
                .map(|(k, p)| {
                    let p = DVec3::from_array(*p);
                    if p.is_finite() && p.length() <= MAX_DIM_M {
                        Ok(p)
                    } else {
                        Err(shape_error(format!("{name}[{k}]"), format!("not a finite point within {MAX_DIM_M:e} m")))
                    }
                })
                .collect()
        };
        Ok(match spec {
            ShapeSpec::Sphere { radius_m } => Shape::Sphere { radius: dim(*radius_m, "radius_m".into())? },
            ShapeSpec::Capsule { half_height_m, radius_m } => Shape::Capsule {
                half_height: dim(*half_height_m, "half_height_m".into())?,
                radius: dim(*radius_m, "radius_m".into())?,
            },
            ShapeSpec::Cuboid { half_extents_m } => {
                Shape::Cuboid { half_extents: dims(half_extents_m, "half_extents_m")? }
            }
            ShapeSpec::Ellipsoid { radii_m } => Shape::Ellipsoid { radii: dims(radii_m, "radii_m")? },
            ShapeSpec::Convex { points: p } => {
                let p = points(p, "points")?;
                let hull = spans_volume(&p).then(|| Shape::convex_hull(&p)).flatten();
                hull.ok_or_else(|| shape_error("points", "needs at least 4 points that are not coplanar"))?
            }
            ShapeSpec::Mesh { vertices, triangles } => {
                let v = points(vertices, "vertices")?;
                if let Some(k) = triangles.iter().position(|t| t.iter().any(|&i| i as usize >= v.len())) {
                    return Err(shape_error(
                        format!("triangles[{k}]"),
                        format!("names a vertex past the {} given", v.len()),
                    ));
                }
                let v = v.iter().map(|p| p.as_vec3()).collect();
                let mesh = parry::shape::TriMesh::new(v, triangles.clone())
                    .map_err(|e| shape_error("", format!("invalid mesh: {e:?}")))?;
                Shape::TriMesh(Arc::new(mesh))
            }
        })
    }

    /// The shape as data: [`Shape::from_spec`] of it gives this shape again (a mesh's vertices
    /// come back as the f32 the mesh holds).
    pub fn to_spec(&self) -> ShapeSpec {
        match self {
            Shape::Sphere { radius } => ShapeSpec::Sphere { radius_m: *radius },
            Shape::Capsule { half_height, radius } => {
                ShapeSpec::Capsule { half_height_m: *half_height, radius_m: *radius }
            }
            Shape::Cuboid { half_extents } => ShapeSpec::Cuboid { half_extents_m: half_extents.to_array() },
            Shape::Ellipsoid { radii } => ShapeSpec::Ellipsoid { radii_m: radii.to_array() },
            // The same points give the same hull: `convex_hull` keeps them as given.
            Shape::Convex(hull) => ShapeSpec::Convex { points: hull.points.iter().map(|p| p.to_array()).collect() },
            Shape::TriMesh(mesh) => ShapeSpec::Mesh {
                vertices: mesh.vertices().iter().map(|p| p.as_dvec3().to_array()).collect(),
                triangles: mesh.indices().to_vec(),
            },
        }
    }

    /// The family this shape belongs to.
    pub fn kind(&self) -> ShapeKind {
        match self {
            Shape::Sphere { .. } => ShapeKind::Sphere,
            Shape::Capsule { .. } => ShapeKind::Capsule,
            Shape::Cuboid { .. } => ShapeKind::Cuboid,
            Shape::Ellipsoid { .. } => ShapeKind::Ellipsoid,
            Shape::Convex(_) => ShapeKind::Convex,
            Shape::TriMesh(_) => ShapeKind::TriMesh,
        }
    }

    /// Whether the shape is convex (every shape but a triangle mesh).
    pub fn is_convex(&self) -> bool {
        !matches!(self, Shape::TriMesh(_))
    }

    /// Builds a convex hull shape. `None` when the points are degenerate (fewer than four
    /// non-coplanar points).
    pub fn convex_hull(points: &[DVec3]) -> Option<Shape> {
        let pts: Vec<parry::math::Vector> = points.iter().map(|p| p.as_vec3()).collect();
        let parry = parry::shape::ConvexPolyhedron::from_convex_hull(&pts)?;
        Some(Shape::Convex(Arc::new(ConvexHull { points: points.to_vec(), parry })))
    }

    /// The box bounding the shape in its local frame.
    pub fn local_aabb(&self) -> Aabb {
        let half = match self {
            Shape::Sphere { radius } => DVec3::splat(*radius),
            Shape::Capsule { half_height, radius } => DVec3::new(*radius, half_height + radius, *radius),
            Shape::Cuboid { half_extents } => *half_extents,
            Shape::Ellipsoid { radii } => *radii,
            Shape::Convex(hull) => {
                return hull
                    .points
                    .iter()
                    .fold(Aabb::EMPTY, |acc, p| Aabb { min: acc.min.min(*p), max: acc.max.max(*p) });
            }
            Shape::TriMesh(mesh) => {
                let a = mesh.local_aabb();
                return Aabb { min: a.mins.as_dvec3(), max: a.maxs.as_dvec3() };
            }
        };
        Aabb { min: -half, max: half }
    }

    /// The world-frame box bounding the shape at `pos` with orientation `rot`.
    pub fn world_aabb(&self, pos: DVec3, rot: DQuat) -> Aabb {
        if let Shape::Sphere { radius } = self {
            return Aabb { min: pos - DVec3::splat(*radius), max: pos + DVec3::splat(*radius) };
        }
        let local = self.local_aabb();
        let centre = (local.min + local.max) * 0.5;
        let half = (local.max - local.min) * 0.5;
        // |R| * half bounds the rotated box (Arvo's method).
        let m = glam::DMat3::from_quat(rot);
        let abs = glam::DMat3::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        let world_half = abs * half;
        let world_centre = pos + rot * centre;
        Aabb { min: world_centre - world_half, max: world_centre + world_half }
    }

    /// The smallest full dimension (diameter, thickness): the step a swept pair may take
    /// between two overlap samples without passing through this shape.
    pub fn min_extent(&self) -> f64 {
        match self {
            Shape::Sphere { radius } | Shape::Capsule { radius, .. } => 2.0 * radius,
            Shape::Cuboid { half_extents } => 2.0 * half_extents.min_element(),
            Shape::Ellipsoid { radii } => 2.0 * radii.min_element(),
            Shape::Convex(_) | Shape::TriMesh(_) => {
                let e = self.local_aabb().extents();
                // For a mesh, a thin wall may be a single sheet: its thickness is zero, but the
                // other shape's extent still bounds the sampling step.
                if matches!(self, Shape::TriMesh(_)) {
                    0.0
                } else {
                    e.min_element()
                }
            }
        }
    }

    /// Radius of the smallest origin-centred sphere that contains the shape.
    pub fn bounding_radius(&self) -> f64 {
        match self {
            Shape::Sphere { radius } => *radius,
            Shape::Capsule { half_height, radius } => half_height + radius,
            Shape::Cuboid { half_extents } => half_extents.length(),
            Shape::Ellipsoid { radii } => radii.max_element(),
            Shape::Convex(hull) => hull.points.iter().map(|p| p.length()).fold(0.0, f64::max),
            Shape::TriMesh(_) => {
                let a = self.local_aabb();
                a.min.length().max(a.max.length())
            }
        }
    }

    /// Volume in m^3 (used for default masses).
    pub fn volume(&self) -> f64 {
        use std::f64::consts::PI;
        match self {
            Shape::Sphere { radius } => 4.0 / 3.0 * PI * radius.powi(3),
            Shape::Capsule { half_height, radius } => PI * radius * radius * (2.0 * half_height + 4.0 / 3.0 * radius),
            Shape::Cuboid { half_extents } => 8.0 * half_extents.x * half_extents.y * half_extents.z,
            Shape::Ellipsoid { radii } => 4.0 / 3.0 * PI * radii.x * radii.y * radii.z,
            Shape::Convex(_) | Shape::TriMesh(_) => {
                let e = self.local_aabb().extents();
                e.x * e.y * e.z
            }
        }
    }

    /// The support point in the local frame: the point of the shape farthest along `dir`.
    /// Defined for convex shapes; used by GJK through [`crate::narrow::general`].
    pub fn local_support(&self, dir: DVec3) -> DVec3 {
        match self {
            Shape::Sphere { radius } => dir.normalize_or(DVec3::Y) * *radius,
            Shape::Capsule { half_height, radius } => {
                let tip = DVec3::new(0.0, if dir.y >= 0.0 { *half_height } else { -half_height }, 0.0);
                tip + dir.normalize_or(DVec3::Y) * *radius
            }
            Shape::Cuboid { half_extents } => DVec3::new(
                half_extents.x.copysign(dir.x),
                half_extents.y.copysign(dir.y),
                half_extents.z.copysign(dir.z),
            ),
            Shape::Ellipsoid { radii } => {
                // p = R^2 d / |R d| for the ellipsoid x^T R^-2 x = 1.
                let rd = *radii * dir;
                let n = rd.length();
                if n > 0.0 {
                    *radii * rd / n
                } else {
                    DVec3::new(0.0, radii.y, 0.0)
                }
            }
            Shape::Convex(hull) => {
                let mut best = hull.points[0];
                let mut best_dot = best.dot(dir);
                for p in &hull.points[1..] {
                    let d = p.dot(dir);
                    if d > best_dot {
                        best = *p;
                        best_dot = d;
                    }
                }
                best
            }
            Shape::TriMesh(_) => DVec3::ZERO,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The floor without `floor` agrees with `floor` everywhere: around integers, at the ends of
    /// the i64 range and past them, for NaN and the infinities.
    #[test]
    fn floor_i64_is_floor_as_i64() {
        let edges = [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            1.0 - f64::EPSILON,
            -1.0 + f64::EPSILON,
            2.5e15,
            -2.5e15,
            4_503_599_627_370_495.5,
            -4_503_599_627_370_495.5,
            9.2e18,
            -9.2e18,
            9.3e18,
            -9.3e18,
            i64::MAX as f64,
            i64::MIN as f64,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
        ];
        for v in edges {
            assert_eq!(floor_i64(v), v.floor() as i64, "{v:e}");
        }
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = f64::from_bits(x);
            let scaled = (x as i64 as f64) * 1e-6;
            for v in [v, scaled, scaled.trunc(), scaled.trunc().next_up(), scaled.trunc().next_down()] {
                assert_eq!(floor_i64(v), v.floor() as i64, "{v:e}");
            }
        }
    }

    /// `to_spec` of `from_spec` is the spec again, for every kind of shape: the one conversion
    /// each way loses nothing (checkpoints rely on it for bit-identical restores).
    #[test]
    fn spec_round_trips_for_every_kind() {
        let cube: Vec<[f64; 3]> =
            (0..8).map(|k| [f64::from(k & 1), f64::from(k >> 1 & 1), f64::from(k >> 2)]).collect();
        let specs = [
            ShapeSpec::Sphere { radius_m: 0.5 },
            ShapeSpec::Capsule { half_height_m: 1.0, radius_m: 0.25 },
            ShapeSpec::Cuboid { half_extents_m: [1.0, 2.0, 3.0] },
            ShapeSpec::Ellipsoid { radii_m: [1.0, 0.5, 0.25] },
            ShapeSpec::Convex { points: cube },
            ShapeSpec::Mesh { vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], triangles: vec![[0, 1, 2]] },
        ];
        for spec in specs {
            let shape = Shape::from_spec(&spec).unwrap();
            assert_eq!(shape.to_spec(), spec);
        }
    }

    /// What cannot be a shape is refused, naming the field.
    #[test]
    fn bad_specs_name_the_field() {
        let field = |spec: ShapeSpec| Shape::from_spec(&spec).unwrap_err().field;
        assert_eq!(field(ShapeSpec::Sphere { radius_m: 0.0 }), "radius_m");
        assert_eq!(field(ShapeSpec::Capsule { half_height_m: f64::NAN, radius_m: 1.0 }), "half_height_m");
        assert_eq!(field(ShapeSpec::Cuboid { half_extents_m: [1.0, 2e6, 1.0] }), "half_extents_m[1]");
        assert_eq!(field(ShapeSpec::Convex { points: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] }), "points");
        // Flat: parry builds a hull of these, but it has no volume, so a body of it no mass.
        let square = vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.5, 0.5, 1e-12]];
        assert_eq!(field(ShapeSpec::Convex { points: square }), "points");
        assert_eq!(field(ShapeSpec::Convex { points: vec![[0.0, f64::INFINITY, 0.0]] }), "points[0]");
        let mesh = ShapeSpec::Mesh { vertices: vec![[0.0; 3], [1.0, 0.0, 0.0]], triangles: vec![[0, 1, 2]] };
        assert_eq!(field(mesh), "triangles[0]");
    }
}
