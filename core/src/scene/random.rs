//! A small seeded generator for scene placement (SplitMix64: fast, and the same on every
//! platform, so a seed always gives the same scene).

use super::format::ScatterDef;
use crate::geometry::Shape;
use glam::DVec3;

/// SplitMix64.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator from a seed.
    pub fn new(seed: u64) -> SplitMix64 {
        SplitMix64(seed)
    }

    /// The next 64 random bits.
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `[0, n)`.
    pub fn below(&mut self, n: u64) -> u64 {
        ((u128::from(self.next_u64()) * u128::from(n)) >> 64) as u64
    }
}

/// Places `count` bodies of `shape` on a jittered lattice in the scatter's box, so no two
/// overlap at the start, with random velocities. Returns `(position, velocity)` pairs.
pub fn scatter(s: &ScatterDef, shape: &Shape) -> Result<Vec<(DVec3, DVec3)>, String> {
    let min = DVec3::from_array(s.min);
    let max = DVec3::from_array(s.max);
    if !(min.is_finite() && max.is_finite()) || min.cmpgt(max).any() {
        return Err("min and max must be finite with min <= max on every axis".into());
    }
    let [lo, hi] = s.speed_mps;
    if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi) {
        return Err(format!("speed_mps [{lo}, {hi}] must be finite with 0 <= lo <= hi"));
    }
    let r = shape.bounding_radius();
    let cell = 2.0 * r * 1.05;
    let size = max - min;
    let dims = [0, 1, 2].map(|k| ((size[k] / cell).floor() as u64).max(1));
    // A lattice whose cell count overflows u64 would wrap the cell -> index arithmetic below
    // (found by fuzzing the scene loader): no scene needs one.
    let cells = dims.iter().try_fold(1u64, |acc, d| acc.checked_mul(*d)).ok_or_else(|| {
        format!(
            "the region is {} x {} x {} cells of {cell} m: too many; shrink it or scatter larger bodies",
            dims[0], dims[1], dims[2]
        )
    })?;
    let count = u64::from(s.count);
    if count > cells {
        return Err(format!(
            "the region fits only {cells} bodies of bounding radius {r} m without overlap, {count} asked"
        ));
    }
    let mut rng = SplitMix64::new(s.seed);
    // Choose distinct cells: a partial shuffle when the lattice is small, rejection otherwise.
    let chosen: Vec<u64> = if cells <= 4 * count.max(1) || cells <= 1 << 20 {
        let mut all: Vec<u64> = (0..cells).collect();
        for i in 0..count as usize {
            let j = i + rng.below(cells - i as u64) as usize;
            all.swap(i, j);
        }
        all.truncate(count as usize);
        all
    } else {
        let mut set = std::collections::BTreeSet::new();
        let mut order = Vec::with_capacity(count as usize);
        while (order.len() as u64) < count {
            let c = rng.below(cells);
            if set.insert(c) {
                order.push(c);
            }
        }
        order
    };
    let slack = (cell - 2.0 * r).max(0.0);
    let mut out = Vec::with_capacity(chosen.len());
    for c in chosen {
        let idx = [c % dims[0], (c / dims[0]) % dims[1], c / (dims[0] * dims[1])];
        let mut p = DVec3::ZERO;
        for k in 0..3 {
            // Thin axes (one cell) centre the body in the region.
            p[k] = if size[k] < cell {
                min[k] + 0.5 * size[k]
            } else {
                min[k] + (idx[k] as f64 + 0.5) * cell + (rng.unit() - 0.5) * slack
            };
        }
        let speed = lo + (hi - lo) * rng.unit();
        let dir = if s.planar {
            let a = std::f64::consts::TAU * rng.unit();
            DVec3::new(a.cos(), 0.0, a.sin())
        } else {
            let z = 2.0 * rng.unit() - 1.0;
            let a = std::f64::consts::TAU * rng.unit();
            let q = (1.0 - z * z).max(0.0).sqrt();
            DVec3::new(q * a.cos(), z, q * a.sin())
        };
        out.push((p, dir * speed));
    }
    Ok(out)
}
