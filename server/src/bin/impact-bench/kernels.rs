//! `impact-bench kernels`: each analytic pair kernel against parry's general path (GJK/EPA in
//! f32, through its query dispatcher) on the same random poses: time per query, how far the two
//! disagree on depth, how far each disagrees with itself when the pair is swapped, and how often
//! parry finds no contact for a pair the analytic kernel sees overlapping.

use super::report::{json_line, progress};
use anyhow::Result;
use clap::Args;
use glam::{DQuat, DVec3};
use impact_core::geometry::Shape;
use impact_core::narrow::{self, general};
use impact_core::scene::random::SplitMix64;
use serde_json::json;
use std::hint::black_box;
use std::time::Instant;

/// Options for the kernels suite.
#[derive(Args, Debug)]
pub struct KernelsArgs {
    /// Random poses per pair family (half or so overlapping).
    #[arg(long, default_value_t = 20_000)]
    poses: u32,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

struct Pose {
    a: Shape,
    ra: DQuat,
    b: Shape,
    rb: DQuat,
    d: DVec3,
}

fn rotation(rng: &mut SplitMix64) -> DQuat {
    let axis = DVec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5 + 1e-3).normalize();
    DQuat::from_axis_angle(axis, (rng.unit() - 0.5) * 6.0)
}

fn shape(kind: &str, rng: &mut SplitMix64) -> Shape {
    let mut len = || 0.05 + 1.95 * rng.unit();
    match kind {
        "sphere" => Shape::Sphere { radius: len() },
        "capsule" => Shape::Capsule { half_height: len(), radius: 0.5 * len() },
        _ => Shape::Cuboid { half_extents: DVec3::new(len(), len(), len()) },
    }
}

fn poses(a: &str, b: &str, n: u32, seed: u64) -> Vec<Pose> {
    let mut rng = SplitMix64::new(seed);
    (0..n)
        .map(|_| Pose {
            a: shape(a, &mut rng),
            ra: rotation(&mut rng),
            b: shape(b, &mut rng),
            rb: rotation(&mut rng),
            d: DVec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5) * 6.0,
        })
        .collect()
}

/// Nanoseconds per overlap query (margin 0, the question the tick asks most), best of three.
fn time(poses: &[Pose], f: impl Fn(&Pose) -> Option<narrow::Contact>) -> f64 {
    (0..3)
        .map(|_| {
            let t = Instant::now();
            for p in poses {
                black_box(f(black_box(p)));
            }
            t.elapsed().as_secs_f64() * 1e9 / poses.len() as f64
        })
        .fold(f64::INFINITY, f64::min)
}

/// Runs the suite.
pub fn run(a: &KernelsArgs) -> Result<()> {
    let families = [
        ("sphere", "sphere"),
        ("sphere", "capsule"),
        ("capsule", "capsule"),
        ("sphere", "box"),
        ("capsule", "box"),
        ("box", "box"),
    ];
    println!("kernels: {} random poses per pair (centres within 3 m on each axis, sizes 0.05-2 m)", a.poses);
    println!(
        "{:<16} {:>12} {:>12} {:>8} {:>16} {:>16} {:>16} {:>12}",
        "pair", "analytic ns", "parry ns", "speedup", "depth diff max", "parry swap max", "ours swap max", "parry none"
    );
    for (seed, (ka, kb)) in families.iter().enumerate() {
        let name = format!("{ka}/{kb}");
        progress(&name);
        let ps = poses(ka, kb, a.poses, 17 + seed as u64);
        let ours = |p: &Pose| narrow::contact(&p.a, p.ra, &p.b, p.rb, p.d, 0.0);
        let parry = |p: &Pose| general::contact(&p.a, p.ra, &p.b, p.rb, p.d, 0.0);
        let (t_ours, t_parry) = (time(&ps, ours), time(&ps, parry));
        // Agreement, on the pairs the analytic kernel finds overlapping by more than 1 mm.
        let (mut diff, mut swap_parry, mut swap_ours, mut none) = (0.0f64, 0.0f64, 0.0f64, 0u32);
        for p in &ps {
            let Some(c) = ours(p).filter(|c| c.depth > 1e-3) else { continue };
            let swapped = |f: &dyn Fn(&Pose) -> Option<narrow::Contact>| {
                f(&Pose { a: p.b.clone(), ra: p.rb, b: p.a.clone(), rb: p.ra, d: -p.d }).map_or(0.0, |s| s.depth)
            };
            swap_ours = swap_ours.max((c.depth - swapped(&ours)).abs());
            match parry(p) {
                Some(g) => {
                    diff = diff.max((c.depth - g.depth).abs());
                    swap_parry = swap_parry.max((g.depth - swapped(&parry)).abs());
                }
                None => none += 1,
            }
        }
        println!(
            "{name:<16} {t_ours:>12.1} {t_parry:>12.1} {:>7.1}x {diff:>14.2e} m {swap_parry:>14.2e} m {swap_ours:>14.2e} m {none:>12}",
            t_parry / t_ours
        );
        if a.json {
            json_line(&json!({
                "suite": "kernels", "pair": name, "analytic_ns": t_ours, "parry_ns": t_parry,
                "speedup": t_parry / t_ours, "max_depth_diff_m": diff, "parry_swap_asymmetry_max_m": swap_parry,
                "analytic_swap_asymmetry_max_m": swap_ours, "parry_no_contact": none,
            }));
        }
    }
    Ok(())
}
