//! `impact-bench scale`: N spheres (radius 0.5 m, one per 8 m^3, speeds up to 5 m/s, 64 Hz)
//! moving straight through each other, in impact's core and in rapier's CollisionPipeline, same
//! positions every tick. Both answer the same question, which pairs overlap at the end of the
//! step, and the counts are checked equal. impact's response is `trigger`, so neither engine
//! changes a velocity and the two stay on the same trajectories (sleeping is off: a slow body
//! falling asleep would leave its trajectory, and the CollisionPipeline has no sleeping).
//! rapier runs on one thread, or, built with `--features rapier-parallel`, at every `--threads`
//! count with its own parallel pipeline.

use super::report::{json_line, mean_ms, median_ms, pools, progress};
use anyhow::{ensure, Result};
use clap::Args;
use impact_core::broadphase::BroadphaseKind;
use impact_core::scene::Scene;
use impact_core::sim::{Plan, Pool, Stepper, TickOutput, World};
use impact_server::plot::{svg_loglog, Series};
use rapier3d::prelude::*;
use serde_json::json;
use std::time::{Duration, Instant};

/// Options for the scale suite.
#[derive(Args, Debug)]
pub struct ScaleArgs {
    /// Body counts (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "1000,10000,50000")]
    bodies: Vec<u32>,
    /// Measured ticks (after warm-up); the median is reported.
    #[arg(long, default_value_t = 120)]
    ticks: u32,
    /// Warm-up ticks.
    #[arg(long, default_value_t = 20)]
    warmup: u32,
    /// Skip rapier (for body counts where it would take too long).
    #[arg(long)]
    no_rapier: bool,
    /// Also time each broadphase (brute force up to 20k bodies) and the general (GJK) path.
    #[arg(long)]
    variants: bool,
    /// Core threads to measure impact with (comma-separated; default: 1 and the available
    /// cores). Results are identical at every count; the pair counts are checked. Built with
    /// `--features rapier-parallel`, rapier's parallel pipeline runs at each count too.
    #[arg(long, value_delimiter = ',')]
    threads: Vec<u16>,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
    /// Write a log-log plot of ms/tick against bodies here (SVG).
    #[arg(long)]
    svg: Option<std::path::PathBuf>,
}

/// The scale scene for `n` bodies.
pub fn scene(n: u32) -> Result<Scene> {
    Ok(Scene::parse(&scene_text(n), "<scale>")?)
}

/// The scale scene's TOML for `n` bodies.
pub fn scene_text(n: u32) -> String {
    let side = (8.0 * f64::from(n)).cbrt();
    format!(
        r#"
[world]
name = "scale"
tick_hz = 64
default_response = "trigger"
contact_slop_m = 1e-9
max_bodies = 2000000
sleep_after_s = 0.0
[[class]]
name = "ball"
gravity = false
max_speed_mps = 5.0
[[scatter]]
class = "ball"
shape = {{ type = "sphere", radius_m = 0.5 }}
count = {n}
min = [0.0, 0.0, 0.0]
max = [{side}, {side}, {side}]
speed_mps = [0.0, 5.0]
seed = 1
"#
    )
}

/// Whether rapier was built with its parallel pipeline (`--features rapier-parallel`).
const RAPIER_PARALLEL: bool = cfg!(feature = "rapier-parallel");

struct Measured {
    ms: f64,
    /// Mean ms per tick: with the broadphase's pair cache, ticks that rebuild it cost more than
    /// the median one, so the mean is reported beside it.
    mean: f64,
    pairs: usize,
    /// The world's state hash at the end (impact): equal at every thread count.
    hash: u64,
}

fn run_impact(world: &World, plan: Plan, pool: &Pool, warmup: u32, ticks: u32) -> Measured {
    let mut w = world.clone();
    let mut stepper = Stepper::new(plan, std::env::var_os("IMPACT_PROFILE").is_some());
    stepper.set_pool(pool.clone());
    let mut out = TickOutput::default();
    let mut samples = Vec::with_capacity(ticks as usize);
    for k in 0..warmup + ticks {
        let t = Instant::now();
        stepper.step(&mut w, &[], &mut out);
        if k >= warmup {
            samples.push(t.elapsed());
        }
    }
    if std::env::var_os("IMPACT_PROFILE").is_some() {
        for (name, d) in stepper.stats.stages() {
            eprintln!("    {name:<12} {:>9.4} ms/tick", d.as_secs_f64() * 1e3 / f64::from(warmup + ticks));
        }
        {
            eprintln!(
                "    last tick: {} pairs tested, {} resolved, {} toi tests",
                stepper.stats.pairs_tested, stepper.stats.resolutions, stepper.stats.toi_tests
            );
        }
    }
    let mean = mean_ms(&samples);
    Measured { ms: median_ms(&mut samples), mean, pairs: w.touching.len(), hash: w.state_hash() }
}

fn run_rapier(world: &World, warmup: u32, ticks: u32) -> Measured {
    let b = &world.bodies;
    let mut colliders = ColliderSet::new();
    let mut bodies = RigidBodySet::new();
    let handles: Vec<ColliderHandle> = (0..b.len())
        .map(|i| {
            let r = b.radius[i] as f32;
            // Parentless colliders are fixed; let fixed-fixed pairs be tested, since here every
            // collider moves (we set its position each tick).
            colliders.insert(
                ColliderBuilder::ball(r)
                    .translation(b.pos[i].as_vec3())
                    .active_collision_types(ActiveCollisionTypes::all())
                    .build(),
            )
        })
        .collect();
    let mut pipeline = CollisionPipeline::new();
    let mut broad = BroadPhaseBvh::new();
    let mut narrow = NarrowPhase::new();
    let mut islands = IslandManager::new();
    let dt = world.config.dt;
    let mut samples: Vec<Duration> = Vec::with_capacity(ticks as usize);
    for k in 0..warmup + ticks {
        let t = Instant::now();
        // Same kinematics as impact: constant velocity, positions at the end of tick k.
        let s = f64::from(k + 1) * dt;
        for (i, h) in handles.iter().enumerate() {
            let p = b.pos[i] + b.vel[i] * s;
            if let Some(c) = colliders.get_mut(*h) {
                c.set_translation(p.as_vec3());
            }
        }
        pipeline.step(0.0, &mut islands, &mut broad, &mut narrow, &mut bodies, &mut colliders, &(), &());
        if k >= warmup {
            samples.push(t.elapsed());
        }
    }
    let pairs =
        narrow.contact_pairs().filter(|p| p.manifolds().iter().any(|m| m.points.iter().any(|c| c.dist < 0.0))).count();
    let mean = mean_ms(&samples);
    Measured { ms: median_ms(&mut samples), mean, pairs, hash: 0 }
}

/// Runs the suite.
pub fn run(a: &ScaleArgs) -> Result<()> {
    let pools = pools(&a.threads)?;
    println!("scale: moving spheres r = 0.5 m, one per 8 m^3, speeds up to 5 m/s, 64 Hz; median of {} ticks after {} warm-up", a.ticks, a.warmup);
    if RAPIER_PARALLEL {
        println!("rapier built with its parallel pipeline: impact at N threads is compared with rapier at N threads");
    }
    println!(
        "{:>8} {:<22} {:>7} {:>12} {:>10} {:>10} {:>12} {:>10}",
        "bodies", "engine", "threads", "ms/tick", "mean", "pairs", "vs rapier", "vs 1 thr"
    );
    let mut growth: Vec<(f64, f64)> = Vec::new();
    let mut rapier_points: Vec<(f64, f64)> = Vec::new();
    let mut variant_points: Points = Points::new();
    for &n in &a.bodies {
        progress(&format!("{n} bodies: building"));
        let scene = scene(n)?;
        let world = &scene.world;
        let plan = Plan::for_world(world);
        let mut ours = Vec::new();
        for (threads, pool) in &pools {
            progress(&format!("{n} bodies: impact ({}, {threads} threads)", plan.broadphase.name()));
            ours.push((*threads, run_impact(world, plan.clone(), pool, a.warmup, a.ticks)));
        }
        // Same world, same ticks: every thread count must end in the same state.
        for (threads, m) in &ours[1..] {
            ensure!(m.hash == ours[0].1.hash, "{threads} threads ended in another state than {}", ours[0].0);
        }
        growth.push((f64::from(n), ours[0].1.ms));
        let peers = rapier_runs(a, n, world, &pools)?;
        report_impact(a, n, &plan, &ours, &peers);
        report_rapier(a, n, &ours, &peers, &mut rapier_points)?;
        if a.variants {
            run_variants(a, n, world, &plan, &pools, ours[0].1.ms, &mut variant_points);
        }
    }
    report_growth(a, &growth, &rapier_points, &variant_points)
}

/// Times per broadphase variant: (bodies, ms) by variant name.
type Points = std::collections::BTreeMap<&'static str, Vec<(f64, f64)>>;

/// rapier at 1 thread, and with its parallel pipeline built in, at each thread count, in a rayon
/// pool of that many threads (its stages use the pool they are called from).
fn rapier_runs(a: &ScaleArgs, n: u32, world: &World, pools: &[(usize, Pool)]) -> Result<Vec<(usize, Measured)>> {
    let mut peers: Vec<(usize, Measured)> = Vec::new();
    if !a.no_rapier {
        let counts: Vec<usize> = if RAPIER_PARALLEL { pools.iter().map(|(t, _)| *t).collect() } else { vec![1] };
        for t in counts {
            progress(&format!("{n} bodies: rapier ({t} threads)"));
            let m = if RAPIER_PARALLEL {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build()?;
                pool.install(|| run_rapier(world, a.warmup, a.ticks))
            } else {
                run_rapier(world, a.warmup, a.ticks)
            };
            peers.push((t, m));
        }
    }
    Ok(peers)
}

/// impact's rows, each against rapier on as many threads when its parallel pipeline ran, else on one.
fn report_impact(a: &ScaleArgs, n: u32, plan: &Plan, ours: &[(usize, Measured)], peers: &[(usize, Measured)]) {
    let single = ours[0].1.ms;
    for (threads, m) in ours {
        // Against rapier on as many threads when its parallel pipeline ran, else on one.
        let peer = peers.iter().find(|(t, _)| t == threads).or(peers.first());
        let ratio = peer.map(|(_, p)| p.ms / m.ms);
        println!(
            "{n:>8} {:<22} {threads:>7} {:>12.4} {:>10.4} {:>10} {:>12} {:>10}",
            format!("impact ({})", plan.broadphase.name()),
            m.ms,
            m.mean,
            m.pairs,
            ratio.map_or("-".into(), |r| format!("{r:.1}x faster")),
            format!("{:.2}x", single / m.ms)
        );
        if a.json {
            json_line(&json!({"suite": "scale", "engine": "impact", "bodies": n, "threads": threads,
                "ms_per_tick": m.ms, "mean_ms_per_tick": m.mean, "pairs": m.pairs,
                "broadphase": plan.broadphase.name(), "speedup_vs_1_thread": single / m.ms,
                "vs_rapier": ratio, "vs_rapier_threads": peer.map(|(t, _)| t)}));
        }
    }
}

/// rapier's rows, each checked to have found as many touching pairs as impact.
fn report_rapier(
    a: &ScaleArgs,
    n: u32,
    ours: &[(usize, Measured)],
    peers: &[(usize, Measured)],
    rapier_points: &mut Vec<(f64, f64)>,
) -> Result<()> {
    for (threads, p) in peers {
        let one = peers[0].1.ms;
        if *threads == 1 {
            rapier_points.push((f64::from(n), p.ms));
        }
        let name = if RAPIER_PARALLEL { "rapier (parallel)" } else { "rapier" };
        println!(
            "{n:>8} {name:<22} {threads:>7} {:>12.4} {:>10.4} {:>10} {:>12} {:>10}",
            p.ms,
            p.mean,
            p.pairs,
            format!("{:.1}x", one / p.ms),
            format!("{:.2}x", one / p.ms)
        );
        if a.json {
            json_line(&json!({"suite": "scale", "engine": "rapier", "bodies": n, "threads": threads,
                "parallel_pipeline": RAPIER_PARALLEL, "ms_per_tick": p.ms, "mean_ms_per_tick": p.mean,
                "pairs": p.pairs, "speedup_vs_1_thread": one / p.ms}));
        }
        // Same question, same answer: a mismatch means one engine is wrong.
        let ours = &ours[0].1;
        let diff = (p.pairs as f64 - ours.pairs as f64).abs();
        ensure!(
            diff <= 1.0 + 1e-3 * p.pairs as f64,
            "pair counts differ: impact {} rapier ({threads} threads) {}",
            ours.pairs,
            p.pairs
        );
    }
    Ok(())
}

/// Every broadphase, and the general (GJK) path, on the same world, against the plan's choice.
fn run_variants(
    a: &ScaleArgs,
    n: u32,
    world: &World,
    plan: &Plan,
    pools: &[(usize, Pool)],
    single: f64,
    variant_points: &mut Points,
) {
    if a.variants {
        let mut kinds = vec![BroadphaseKind::SweepAndPrune, BroadphaseKind::Grid, BroadphaseKind::Bvh];
        // Brute force is O(n^2): 10^10 box tests a tick at 100k bodies. Run it to 20k.
        if n <= 20_000 {
            kinds.push(BroadphaseKind::BruteForce);
        }
        for kind in kinds {
            progress(&format!("{n} bodies: broadphase {}", kind.name()));
            let m = run_impact(
                world,
                Plan { broadphase: kind, ..plan.clone() },
                &pools[0].1,
                a.warmup.min(5),
                a.ticks.min(30),
            );
            variant_points.entry(kind.name()).or_default().push((f64::from(n), m.ms));
            println!("{n:>8} {:<22} {:>12.4} {:>10}", format!("impact broadphase={}", kind.name()), m.ms, m.pairs);
            if a.json {
                json_line(
                    &json!({"suite": "scale", "engine": "impact", "variant": format!("broadphase={}", kind.name()), "bodies": n, "ms_per_tick": m.ms, "pairs": m.pairs}),
                );
            }
        }
        progress(&format!("{n} bodies: general path"));
        let m = run_impact(world, Plan::general(world), &pools[0].1, a.warmup.min(5), a.ticks.min(30));
        println!(
            "{n:>8} {:<22} {:>12.4} {:>10} {:>12}",
            "impact general (GJK)",
            m.ms,
            m.pairs,
            format!("plan {:.1}x faster", m.ms / single)
        );
        if a.json {
            json_line(
                &json!({"suite": "scale", "engine": "impact", "variant": "general", "bodies": n, "ms_per_tick": m.ms, "pairs": m.pairs}),
            );
        }
    }
}

/// Growth exponents over the sizes, and the plot.
fn report_growth(
    a: &ScaleArgs,
    growth: &[(f64, f64)],
    rapier_points: &[(f64, f64)],
    variant_points: &Points,
) -> Result<()> {
    for (name, pts) in variant_points {
        if pts.len() >= 2 {
            let k = growth_exponent(pts);
            println!("broadphase {name}: growth exponent k = {k:.2} over {} sizes", pts.len());
            if a.json {
                json_line(
                    &json!({"suite": "scale", "engine": "impact", "variant": format!("broadphase={name}"), "growth_exponent": k}),
                );
            }
        }
    }
    if growth.len() >= 2 {
        let slope = growth_exponent(growth);
        println!("growth exponent (ms ~ n^k, least squares): k = {slope:.2}");
        if let Some(path) = &a.svg {
            let mut series = vec![Series { name: "impact".into(), points: growth.to_vec() }];
            if !rapier_points.is_empty() {
                series.push(Series { name: "rapier".into(), points: rapier_points.to_vec() });
            }
            std::fs::write(
                path,
                svg_loglog("scale: moving spheres, 64 Hz", "bodies", "ms per tick (median)", &series),
            )?;
            println!("plot: {}", path.display());
        }
        if a.json {
            json_line(&json!({"suite": "scale", "engine": "impact", "growth_exponent": slope}));
        }
    }
    Ok(())
}

/// Least-squares slope of log(ms) on log(n): 1 is linear.
fn growth_exponent(points: &[(f64, f64)]) -> f64 {
    let pts: Vec<(f64, f64)> = points.iter().map(|(n, ms)| (n.ln(), ms.ln())).collect();
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / pts.len() as f64;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / pts.len() as f64;
    pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>() / pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>()
}
