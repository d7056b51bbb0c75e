//! [`ShapeSpec`]: a collision shape as data, the one vocabulary the scene file, the spawn action
//! and the standby checkpoint share. The core turns it into its prepared shape (hulls and meshes
//! built once, in f64) in one place, `impact_core::geometry::Shape::from_spec`, and back with
//! `Shape::to_spec`.
//!
//! What each user may carry differs, and is checked where it is used rather than by a type of its
//! own: a client spawns only a sphere, a capsule or a cuboid ([`ShapeSpec::spawnable`]); a mesh
//! belongs to a static class in a scene and never to a dynamic body in a checkpoint.

use serde::{Deserialize, Serialize};

/// A collision shape in its local frame, centred on the body's position. Lengths in metres.
///
/// Internally tagged by `type`. Unknown fields are refused (a misspelt key in a scene file is an
/// error, not a default). A checkpoint written before the shapes were one type named the
/// dimensions without the `_m` suffix (`radius`, `half_height`, `half_extents`, `radii`): those
/// names are still read.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ShapeSpec {
    /// A sphere.
    Sphere {
        /// Radius, metres.
        #[serde(alias = "radius")]
        radius_m: f64,
    },
    /// A capsule along the local y axis: the points within `radius_m` of the segment from
    /// `(0, -half_height_m, 0)` to `(0, half_height_m, 0)`.
    Capsule {
        /// Half the length of the segment between the two cap centres, metres.
        #[serde(alias = "half_height")]
        half_height_m: f64,
        /// Radius, metres.
        #[serde(alias = "radius")]
        radius_m: f64,
    },
    /// A box, axis-aligned in its local frame.
    Cuboid {
        /// Half extents along local x, y, z, metres.
        #[serde(alias = "half_extents")]
        half_extents_m: [f64; 3],
    },
    /// An ellipsoid, axis-aligned in its local frame.
    Ellipsoid {
        /// Semi-axes along local x, y, z, metres.
        #[serde(alias = "radii")]
        radii_m: [f64; 3],
    },
    /// The convex hull of points (local frame, metres): at least 4 that are not coplanar.
    Convex {
        /// The points.
        points: Vec<[f64; 3]>,
    },
    /// A triangle mesh (static bodies only).
    Mesh {
        /// Vertices, local frame, metres.
        vertices: Vec<[f64; 3]>,
        /// Triangles as vertex index triples.
        triangles: Vec<[u32; 3]>,
    },
}

impl ShapeSpec {
    /// Whether a client may spawn a body of this shape (a sphere, a capsule or a cuboid: shapes
    /// whose size the server checks in constant time).
    pub fn spawnable(&self) -> bool {
        matches!(self, ShapeSpec::Sphere { .. } | ShapeSpec::Capsule { .. } | ShapeSpec::Cuboid { .. })
    }
}
