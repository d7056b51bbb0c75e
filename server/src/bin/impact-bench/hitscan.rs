//! `impact-bench hitscan`: what a lag-compensated shot costs when it is rewound rather than
//! re-simulated. The scene is the rollback suite's (the scale suite's moving spheres plus one
//! sphere owned by client 1, the shooter); the shot looks `--rewind` ticks back, and its cost
//! (casting the ray against the held world of that tick) is set beside the plain tick of the
//! same session. Target (issue: inputs on time): at most 5 % of a tick at 10,000 bodies.

use super::report::{json_line, median_ms, progress};
use anyhow::Result;
use clap::Args;
use impact_core::sim::{Plan, TickInput};
use impact_protocol::{Action, ClientId, Tick};
use impact_server::rollback::hitscan::rewind_rays;
use impact_server::rollback::{RollbackConfig, Session};
use serde_json::json;
use std::time::Instant;

/// Options for the hitscan suite.
#[derive(Args, Debug)]
pub struct HitscanArgs {
    /// Body counts.
    #[arg(long, value_delimiter = ',', default_value = "1000,10000")]
    bodies: Vec<u32>,
    /// How far back the shooter looks, ticks.
    #[arg(long, default_value_t = 8)]
    rewind: u32,
    /// Shots timed per body count (the median is reported).
    #[arg(long, default_value_t = 400)]
    shots: u32,
    /// Shots in one tick's batch, cast together against the same past world (a third of 1,000
    /// clients shooting at 7 shots a second is 36 a tick at 64 Hz).
    #[arg(long, default_value_t = 36)]
    batch: u32,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

/// Runs the suite.
pub fn run(a: &HitscanArgs) -> Result<()> {
    println!("hitscan: one shot rewound {} ticks (no re-simulation) against the plain tick; medians", a.rewind);
    println!(
        "{:>8} {:>10} {:>10} {:>12} {:>8} {:>14} {:>14}",
        "bodies", "tick_ms", "shot_ms", "% of tick", "target", "batch_ms", "per shot ms"
    );
    for &n in &a.bodies {
        let sc = super::rollback::scene(n)?;
        let b = &sc.world.bodies;
        let shooter = (0..b.len()).find(|&i| b.owner[i].is_some()).map(|i| b.id[i]).expect("an owned body");
        let mut cfg = RollbackConfig::for_world(&sc.world);
        cfg.window_ticks = cfg.window_ticks.max(a.rewind + 1);
        let mut s = Session::new(sc.world.clone(), Plan::for_world(&sc.world), cfg);
        progress(&format!("{n} bodies: warm-up"));
        let tick_ms = super::rollback::plain_tick_ms(&mut s, a.rewind + 30);
        progress(&format!("{n} bodies: {} shots", a.shots));
        let now = s.now();
        let view = Tick(now.0 - a.rewind);
        let oldest = s.oldest_accepted();
        let mut shots = Vec::with_capacity(a.shots as usize);
        let mut hits = 0u32;
        // Rays from the shooter's corner of the world in a fan of directions across it.
        let input = |k: u32| {
            let angle = f64::from(k) * 0.61803;
            let dir = [angle.cos(), 0.3 * (angle * 1.7).sin(), angle.sin().abs() + 0.2];
            let shot = Action::FireRay { shooter, origin: [-5.0, -5.0, -5.0], direction: dir, max_distance_m: 100.0 };
            TickInput { view_tick: Some(view), ..TickInput::new(ClientId(1), k, vec![shot]) }
        };
        let past = |t: Tick| s.frame(t).map(|f| (&f.state, f.ray_index()));
        for k in 0..a.shots {
            let mut one = vec![input(k)];
            let t = Instant::now();
            rewind_rays(now, &mut one, u32::MAX, oldest, None, s.world(), past);
            shots.push(t.elapsed());
            hits += u32::from(one[0].rewound.first().is_some_and(|r| r.hit.is_some()));
        }
        let shot_ms = median_ms(&mut shots);
        let mut batches = Vec::new();
        for b in 0..(a.shots / a.batch.max(1)).max(5) {
            let mut many: Vec<TickInput> = (0..a.batch).map(|k| input(b * a.batch + k)).collect();
            let t = Instant::now();
            rewind_rays(now, &mut many, u32::MAX, oldest, None, s.world(), past);
            batches.push(t.elapsed());
        }
        let batch_ms = median_ms(&mut batches);
        let per_shot = batch_ms / f64::from(a.batch.max(1));
        let pct = 100.0 * shot_ms / tick_ms;
        let target = if n < 10_000 {
            "-"
        } else if pct <= 5.0 {
            "met"
        } else {
            "MISSED"
        };
        println!("{n:>8} {tick_ms:>10.4} {shot_ms:>10.5} {pct:>11.2}% {target:>8} {batch_ms:>14.4} {per_shot:>14.5}");
        if a.json {
            json_line(&json!({
                "suite": "hitscan", "bodies": n, "rewind_ticks": a.rewind, "tick_ms": tick_ms,
                "shot_ms": shot_ms, "shot_pct_of_tick": pct, "shots": a.shots, "hits": hits,
                "batch": a.batch, "batch_ms": batch_ms, "batch_ms_per_shot": per_shot,
            }));
        }
    }
    Ok(())
}
