//! A regular height field: heights sampled on a grid in x and z, each cell split into two
//! triangles along the diagonal from its (x0, z0) corner to its (x1, z1) corner.
//!
//! The triangle under a point is found from the cell and the side of the diagonal; its plane
//! N = (P1 - P0) x (P2 - P0) gives the height Qy = (-Nx Qx - Nz Qz + N.P0) / Ny.

use crate::geometry::{floor_i64, Aabb};
use glam::DVec3;

/// Why a height field could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HeightFieldError {
    /// Fewer than 2 x 2 samples, or rows of different lengths.
    #[error("height field needs at least 2 x 2 samples in equal-length rows ({0})")]
    Shape(String),
    /// A non-finite height or a non-positive cell size.
    #[error("height field has an invalid value: {0}")]
    Value(String),
}

/// Heights on a grid. Sample `(ix, iz)` sits at `origin + (ix * cell_x, height, iz * cell_z)`.
#[derive(Clone, Debug)]
pub struct HeightField {
    origin: DVec3,
    cell_x: f64,
    cell_z: f64,
    nx: usize,
    nz: usize,
    /// Row-major by z: `heights[iz * nx + ix]`, metres above `origin.y`.
    heights: Vec<f64>,
    bounds: Aabb,
}

impl HeightField {
    /// Builds a height field from rows of heights (`rows[iz][ix]`, metres above `origin.y`).
    pub fn new(origin: DVec3, cell_x: f64, cell_z: f64, rows: &[Vec<f64>]) -> Result<HeightField, HeightFieldError> {
        let nz = rows.len();
        let nx = rows.first().map_or(0, Vec::len);
        if nz < 2 || nx < 2 || rows.iter().any(|r| r.len() != nx) {
            return Err(HeightFieldError::Shape(format!("{nz} rows, first has {nx}")));
        }
        if !(cell_x > 0.0 && cell_z > 0.0 && cell_x.is_finite() && cell_z.is_finite()) {
            return Err(HeightFieldError::Value(format!("cell size {cell_x} x {cell_z} m")));
        }
        let heights: Vec<f64> = rows.iter().flatten().copied().collect();
        if let Some(i) = heights.iter().position(|h| !h.is_finite()) {
            return Err(HeightFieldError::Value(format!(
                "height at row {}, column {} is {}",
                i / nx,
                i % nx,
                heights[i]
            )));
        }
        let lo = heights.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = heights.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let bounds = Aabb {
            min: origin + DVec3::new(0.0, lo, 0.0),
            max: origin + DVec3::new((nx - 1) as f64 * cell_x, hi, (nz - 1) as f64 * cell_z),
        };
        Ok(HeightField { origin, cell_x, cell_z, nx, nz, heights, bounds })
    }

    /// The position of sample `(0, 0)` at height 0, m.
    pub fn origin(&self) -> DVec3 {
        self.origin
    }

    /// Samples along x and z, and the heights, row-major by z (`heights[iz * nx + ix]`), m.
    pub fn samples(&self) -> (usize, usize, &[f64]) {
        (self.nx, self.nz, &self.heights)
    }

    /// Cell size `(x, z)`, m.
    pub fn cell_size(&self) -> (f64, f64) {
        (self.cell_x, self.cell_z)
    }

    /// The world-frame box around the surface.
    pub fn aabb(&self) -> Aabb {
        self.bounds
    }

    fn vertex(&self, ix: usize, iz: usize) -> DVec3 {
        self.origin + DVec3::new(ix as f64 * self.cell_x, self.heights[iz * self.nx + ix], iz as f64 * self.cell_z)
    }

    /// The two triangles of cell `(ix, iz)`, counter-clockwise seen from above (normals up).
    pub(crate) fn cell_triangles(&self, ix: usize, iz: usize) -> [[DVec3; 3]; 2] {
        let p00 = self.vertex(ix, iz);
        let p10 = self.vertex(ix + 1, iz);
        let p01 = self.vertex(ix, iz + 1);
        let p11 = self.vertex(ix + 1, iz + 1);
        // Upper-x triangle (u >= v) and upper-z triangle (u < v), both wound so that
        // (P1 - P0) x (P2 - P0) points up (+y).
        [[p00, p11, p10], [p00, p01, p11]]
    }

    /// The triangle under `(x, z)`, or `None` outside the field.
    pub(crate) fn triangle_at(&self, x: f64, z: f64) -> Option<[DVec3; 3]> {
        let u = (x - self.origin.x) / self.cell_x;
        let v = (z - self.origin.z) / self.cell_z;
        if !(u >= 0.0 && v >= 0.0 && u <= (self.nx - 1) as f64 && v <= (self.nz - 1) as f64) {
            return None;
        }
        // u, v >= 0 (checked above): the floor is the truncation.
        let ix = (u as usize).min(self.nx - 2);
        let iz = (v as usize).min(self.nz - 2);
        let (fu, fv) = (u - ix as f64, v - iz as f64);
        let [upper_x, upper_z] = self.cell_triangles(ix, iz);
        Some(if fu >= fv { upper_x } else { upper_z })
    }

    /// Unnormalised plane normal N = (P1 - P0) x (P2 - P0) of a triangle (points up here).
    pub(crate) fn plane_normal(t: &[DVec3; 3]) -> DVec3 {
        (t[1] - t[0]).cross(t[2] - t[0])
    }

    /// Surface height at `(x, z)` from the plane equation of the triangle under it.
    pub fn height_at(&self, x: f64, z: f64) -> Option<f64> {
        let t = self.triangle_at(x, z)?;
        let n = Self::plane_normal(&t);
        Some((-n.x * x - n.z * z + n.dot(t[0])) / n.y)
    }

    /// Unit surface normal at `(x, z)` (pointing up).
    pub fn normal_at(&self, x: f64, z: f64) -> Option<DVec3> {
        self.triangle_at(x, z).map(|t| Self::plane_normal(&t).normalize())
    }

    /// Calls `f` with every triangle whose cell overlaps `bounds` in x and z and whose heights
    /// reach its y range (a triangle wholly above or below the box cannot touch what it bounds).
    pub(crate) fn for_each_triangle_in(&self, bounds: &Aabb, mut f: impl FnMut([DVec3; 3])) {
        if !bounds.overlaps(&self.bounds) {
            return;
        }
        let cell = |v: f64, o: f64, c: f64, n: usize| (floor_i64((v - o) / c).max(0) as usize).min(n - 2);
        let x0 = cell(bounds.min.x, self.origin.x, self.cell_x, self.nx);
        let x1 = cell(bounds.max.x, self.origin.x, self.cell_x, self.nx);
        let z0 = cell(bounds.min.z, self.origin.z, self.cell_z, self.nz);
        let z1 = cell(bounds.max.z, self.origin.z, self.cell_z, self.nz);
        for iz in z0..=z1 {
            for ix in x0..=x1 {
                for t in self.cell_triangles(ix, iz) {
                    let (lo, hi) = (t[0].y.min(t[1].y).min(t[2].y), t[0].y.max(t[1].y).max(t[2].y));
                    if hi >= bounds.min.y && lo <= bounds.max.y {
                        f(t);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 x 2-cell field with hand-picked heights.
    fn field() -> HeightField {
        let rows = vec![vec![0.0, 1.0, 2.0], vec![0.0, 2.0, 4.0], vec![0.0, 0.0, 0.0]];
        HeightField::new(DVec3::new(10.0, 5.0, 20.0), 2.0, 2.0, &rows).unwrap()
    }

    #[test]
    fn triangle_under_a_point_and_its_plane() {
        let f = field();
        // (x, z) = (11, 20.5): cell (0, 0), u = 0.5 >= v = 0.25 -> the upper-x triangle
        // P00 = (10, 5, 20), P11 = (12, 7, 22), P10 = (12, 6, 20).
        let t = f.triangle_at(11.0, 20.5).unwrap();
        assert_eq!(t, [DVec3::new(10.0, 5.0, 20.0), DVec3::new(12.0, 7.0, 22.0), DVec3::new(12.0, 6.0, 20.0)]);
        // N = (P1 - P0) x (P2 - P0) = (2, 2, 2) x (2, 1, 0) = (2*0 - 2*1, 2*2 - 2*0, 2*1 - 2*2) = (-2, 4, -2).
        assert_eq!(HeightField::plane_normal(&t), DVec3::new(-2.0, 4.0, -2.0));
        // Qy = (-Nx Qx - Nz Qz + N.P0) / Ny = (2*11 + 2*20.5 + (-20 + 20 - 40)) / 4 = 5.75.
        assert!((f.height_at(11.0, 20.5).unwrap() - 5.75).abs() < 1e-12);
        // The other side of the diagonal: (10.5, 21.5), u = 0.25 < v = 0.75 -> P00, P01, P11 with
        // P01 = (10, 5, 22): N = (0, 0, 2) x (2, 2, 2) = (0*2 - 2*2, 2*2 - 0*2, 0*2 - 0*2) = (-4, 4, 0).
        let t = f.triangle_at(10.5, 21.5).unwrap();
        assert_eq!(HeightField::plane_normal(&t), DVec3::new(-4.0, 4.0, 0.0));
        // Qy = (4*10.5 + 0 + (-40 + 20)) / 4 = 5.5.
        assert!((f.height_at(10.5, 21.5).unwrap() - 5.5).abs() < 1e-12);
        let n = f.normal_at(10.5, 21.5).unwrap();
        assert!((n - DVec3::new(-1.0, 1.0, 0.0).normalize()).length() < 1e-12);
    }

    #[test]
    fn heights_match_samples_at_vertices_and_outside_is_none() {
        let f = field();
        assert!((f.height_at(12.0, 22.0).unwrap() - 7.0).abs() < 1e-12);
        assert!((f.height_at(14.0, 22.0).unwrap() - 9.0).abs() < 1e-12);
        assert!(f.height_at(9.99, 21.0).is_none());
        assert!(f.height_at(11.0, 24.01).is_none());
    }

    #[test]
    fn bad_fields_are_refused() {
        assert!(HeightField::new(DVec3::ZERO, 1.0, 1.0, &[vec![0.0, 1.0]]).is_err());
        assert!(HeightField::new(DVec3::ZERO, 1.0, 1.0, &[vec![0.0, 1.0], vec![0.0]]).is_err());
        assert!(HeightField::new(DVec3::ZERO, 0.0, 1.0, &[vec![0.0, 1.0], vec![0.0, 1.0]]).is_err());
        assert!(HeightField::new(DVec3::ZERO, 1.0, 1.0, &[vec![0.0, f64::NAN], vec![0.0, 1.0]]).is_err());
    }
}
