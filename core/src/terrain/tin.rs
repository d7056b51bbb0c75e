//! Triangulated irregular networks (TINs): terrain as arbitrary triangles. A point is located
//! by its barycentric weights in the x-z plane: it lies in a triangle when no weight is negative.

use glam::DVec3;

/// Barycentric weights `(w0, w1, w2)` of `(x, z)` with respect to triangle `t` projected on the
/// x-z plane, or `None` for a triangle that is degenerate in that projection.
pub(crate) fn barycentric_xz(x: f64, z: f64, t: &[DVec3; 3]) -> Option<[f64; 3]> {
    let (a, b, c) = (t[0], t[1], t[2]);
    let det = (b.z - c.z) * (a.x - c.x) + (c.x - b.x) * (a.z - c.z);
    if det == 0.0 {
        return None;
    }
    let w0 = ((b.z - c.z) * (x - c.x) + (c.x - b.x) * (z - c.z)) / det;
    let w1 = ((c.z - a.z) * (x - c.x) + (a.x - c.x) * (z - c.z)) / det;
    Some([w0, w1, 1.0 - w0 - w1])
}

/// A TIN: vertices and triangles (indices into `vertices`).
#[derive(Clone, Debug)]
pub struct Tin {
    vertices: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
}

impl Tin {
    /// Wraps vertices and triangles. Indices out of range are an error.
    pub fn new(vertices: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Result<Tin, String> {
        if let Some((i, t)) =
            triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&v| v as usize >= vertices.len()))
        {
            return Err(format!("triangle {i} {t:?} names a vertex past the {} given", vertices.len()));
        }
        Ok(Tin { vertices, triangles })
    }

    fn triangle(&self, i: usize) -> [DVec3; 3] {
        let t = self.triangles[i];
        [self.vertices[t[0] as usize], self.vertices[t[1] as usize], self.vertices[t[2] as usize]]
    }

    /// The first triangle containing `(x, z)` and the weights there. Weights within `-1e-12` of
    /// zero count as inside, so points on shared edges are found.
    pub(crate) fn locate(&self, x: f64, z: f64) -> Option<(usize, [f64; 3])> {
        (0..self.triangles.len()).find_map(|i| {
            let w = barycentric_xz(x, z, &self.triangle(i))?;
            w.iter().all(|&wi| wi >= -1e-12).then_some((i, w))
        })
    }

    /// Height at `(x, z)`: the weights applied to the triangle's vertex heights.
    pub fn height_at(&self, x: f64, z: f64) -> Option<f64> {
        let (i, w) = self.locate(x, z)?;
        let t = self.triangle(i);
        Some(w[0] * t[0].y + w[1] * t[1].y + w[2] * t[2].y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tin() -> Tin {
        // Two triangles over the square (0..4, 0..4) split along x = z, heights 0, 4, 8, 12.
        let v = vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(4.0, 4.0, 0.0),
            DVec3::new(4.0, 8.0, 4.0),
            DVec3::new(0.0, 12.0, 4.0),
        ];
        Tin::new(v, vec![[0, 1, 2], [0, 2, 3]]).unwrap()
    }

    #[test]
    fn barycentric_location_hand_computed() {
        let t = tin();
        // (3, 1) is in triangle 0: w = (1/4, 1/2, 1/4) -> height 0/4 + 4/2 + 8/4 = 4.
        let (i, w) = t.locate(3.0, 1.0).unwrap();
        assert_eq!(i, 0);
        for (got, want) in w.iter().zip([0.25, 0.5, 0.25]) {
            assert!((got - want).abs() < 1e-12, "{w:?}");
        }
        assert!((t.height_at(3.0, 1.0).unwrap() - 4.0).abs() < 1e-12);
        // (1, 3) is in triangle 1: w = (1/4, 1/4, 1/2) -> 0 + 2 + 6 = 8.
        let (i, _) = t.locate(1.0, 3.0).unwrap();
        assert_eq!(i, 1);
        assert!((t.height_at(1.0, 3.0).unwrap() - 8.0).abs() < 1e-12);
    }

    #[test]
    fn a_negative_weight_means_outside() {
        let t = tin();
        let tri0 = [DVec3::new(0.0, 0.0, 0.0), DVec3::new(4.0, 4.0, 0.0), DVec3::new(4.0, 8.0, 4.0)];
        let w = barycentric_xz(1.0, 3.0, &tri0).unwrap();
        assert!(w.iter().any(|&x| x < 0.0), "{w:?}");
        assert!(t.locate(5.0, 1.0).is_none());
        assert!(t.locate(-0.1, 0.0).is_none());
        assert!(Tin::new(vec![DVec3::ZERO], vec![[0, 1, 2]]).is_err());
    }
}
