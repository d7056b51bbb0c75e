//! `impact-bench rollback`: the cost of one rollback of depth d (rewind, re-simulate d ticks,
//! reconcile their events) beside the plain tick in the same session, for full and selective
//! re-simulation. The scene is the scale suite's (moving spheres) plus one sphere owned by client
//! 1, whose late velocity change is the rollback's cause.

use super::report::{json_line, median_ms, pools, progress};
use anyhow::Result;
use clap::Args;
use impact_core::scene::Scene;
use impact_core::sim::Plan;
use impact_protocol::{Action, ClientId, ClientInput, Tick};
use impact_server::rollback::{RollbackConfig, Session};
use serde_json::json;
use std::time::Instant;

/// Options for the rollback suite.
#[derive(Args, Debug)]
pub struct RollbackArgs {
    /// Body counts.
    #[arg(long, value_delimiter = ',', default_value = "1000,10000")]
    bodies: Vec<u32>,
    /// Rollback depths, ticks.
    #[arg(long, value_delimiter = ',', default_value = "1,4,8,16")]
    depths: Vec<u32>,
    /// Rollbacks measured per (bodies, depth, mode); the median is reported.
    #[arg(long, default_value_t = 15)]
    repeats: u32,
    /// Core threads (comma-separated; default: 1 and the available cores). Re-simulation runs
    /// on the same threads as the tick.
    #[arg(long, value_delimiter = ',')]
    threads: Vec<u16>,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

pub fn scene(n: u32) -> Result<Scene> {
    let base = super::scale::scene_text(n);
    let text = format!("{base}\n[[body]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = 0.5 }}\nposition = [-5.0, -5.0, -5.0]\nvelocity = [1.0, 0.0, 0.0]\nowner = 1\n");
    Ok(Scene::parse(&text, "<rollback>")?)
}

/// Advances `s` by `warm_up` ticks, then times 40 plain ticks (no late input): their median, ms.
pub fn plain_tick_ms(s: &mut Session, warm_up: u32) -> f64 {
    for _ in 0..warm_up {
        s.advance();
    }
    let mut plain = Vec::new();
    for _ in 0..40 {
        let t = Instant::now();
        s.advance();
        plain.push(t.elapsed());
    }
    median_ms(&mut plain)
}

/// Runs the suite.
pub fn run(a: &RollbackArgs) -> Result<()> {
    println!(
        "rollback: one late input from one client; ms = rewind + re-simulate d ticks; median of {} rollbacks",
        a.repeats
    );
    println!(
        "{:>8} {:>7} {:>6} {:<10} {:>10} {:>10} {:>14} {:>8} {:>9}",
        "bodies", "threads", "depth", "mode", "ms", "tick_ms", "ms/(d*tick)", "target", "vs 1 thr"
    );
    let pools = pools(&a.threads)?;
    // One thread's rollback time per (bodies, mode, depth), for the speed-up.
    let mut single: std::collections::BTreeMap<(u32, bool, u32), f64> = std::collections::BTreeMap::new();
    for &n in &a.bodies {
        let sc = scene(n)?;
        let owned = *sc
            .world
            .bodies
            .id
            .iter()
            .zip(&sc.world.bodies.owner)
            .find(|(_, o)| o.is_some())
            .map(|(id, _)| id)
            .expect("owned body");
        for (selective, (threads, pool)) in
            [false, true].into_iter().flat_map(|sel| pools.iter().map(move |p| (sel, p)))
        {
            let mode = if selective { "selective" } else { "full" };
            let mut cfg = RollbackConfig::for_world(&sc.world);
            cfg.window_ticks = a.depths.iter().copied().max().unwrap_or(16).max(1);
            cfg.selective = selective;
            let mut s = Session::new(sc.world.clone(), Plan::for_world(&sc.world), cfg);
            s.set_pool(pool.clone());
            progress(&format!("{n} bodies, {mode}, {threads} threads: warm-up"));
            let tick_ms = plain_tick_ms(&mut s, 30);
            let snapshot_ms = s.stats.snapshot_time.as_secs_f64() * 1e3 / s.stats.ticks.max(1) as f64;
            let mut seq = 0;
            for &d in &a.depths {
                progress(&format!("{n} bodies, {mode}, {threads} threads: depth {d}"));
                let mut samples = Vec::new();
                for r in 0..a.repeats {
                    seq += 1;
                    let now = s.now().0;
                    let v = if r % 2 == 0 { [2.0, 0.5, -1.0] } else { [-1.5, 0.0, 1.0] };
                    let input = ClientInput {
                        aim_tick: None,
                        view_tick: None,
                        client: ClientId(1),
                        seq,
                        tick: Tick(now - d),
                        actions: vec![Action::SetVelocity { entity: owned, velocity: v }],
                    };
                    s.submit(input).map_err(|e| anyhow::anyhow!("input refused: {}", e.detail))?;
                    let adv = s.advance();
                    assert_eq!(adv.rollback_depth, d);
                    samples.push(s.stats.last_rollback);
                }
                let ms = median_ms(&mut samples);
                let ratio = ms / (f64::from(d) * tick_ms);
                let target: &str = if selective {
                    if d == 16 && n >= 10_000 {
                        if ms <= 2.0 * tick_ms {
                            "ok"
                        } else {
                            "MISS"
                        }
                    } else {
                        "-"
                    }
                } else if ratio <= 1.1 {
                    "ok"
                } else {
                    "MISS"
                };
                let one = *single.entry((n, selective, d)).or_insert(ms);
                let speedup = one / ms;
                println!("{n:>8} {threads:>7} {d:>6} {mode:<10} {ms:>10.4} {tick_ms:>10.4} {ratio:>14.3} {target:>8} {speedup:>8.2}x");
                if a.json {
                    json_line(&json!({"suite": "rollback", "bodies": n, "threads": threads, "depth": d, "mode": mode,
                        "ms": ms, "tick_ms": tick_ms, "speedup_vs_1_thread": speedup}));
                }
            }
            println!(
                "{:>8} {threads:>7} {:>6} {:<10} snapshot per tick {snapshot_ms:.4} ms ({:.1} % of the tick)",
                "",
                "",
                "",
                snapshot_ms / tick_ms * 100.0
            );
            if selective {
                println!(
                    "{:>8} {threads:>7} {:>6} {:<10} selective used in {} of {} rollbacks",
                    "", "", "", s.stats.selective_rollbacks, s.stats.rollbacks
                );
            }
        }
    }
    Ok(())
}
