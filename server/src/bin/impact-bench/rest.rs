//! `impact-bench rest`: bodies coming to rest under gravity, in impact's core and in rapier's
//! full `PhysicsPipeline` (solver, islands, sleeping on) built from the same bodies in the same
//! process. The scenes: `pile` (1,000 spheres dropped into a box), `stack` (100 stacks of ten
//! boxes), `ramp` (spheres and boxes sliding down a 40 degree ramp onto a floor) and `hillside`
//! (500 capsules standing on a height field) are written with no tuning keys, as a new user
//! would; `standing` and `yard` (crates on terrain with players and projectiles among them) are
//! the tuned scenes that came before.
//!
//! Each run is timed in two phases: falling (the ticks before `--settle-tick`, 600) and settled
//! (from it on), and over the whole run. Beside the cost: bodies awake at the settle tick and at
//! the end, events after the settle tick (impact: every event; rapier: its collision events), the
//! deepest penetration sampled every 16 ticks, and the final height (the highest point of a body
//! that falls). rapier's bodies have their rotations locked, as impact's do (impact's
//! orientations are fixed); a key the scene gives (friction, restitution) is given to rapier too,
//! a key it leaves out is rapier's own default.
//!
//! `--check` fails the run on a missed bound for the scenes with no tuning keys: every body
//! asleep at the settle tick and no event after it; for the pile, penetration under 1 % of the
//! radius and a height within 5 % of rapier's; and a cost over the whole run at most 0.5x
//! rapier's for the pile and 1.0x for the others (`--skip-cost` leaves the cost out:
//! CI checks the rest while the cost bounds are missed, see BENCHMARKS.md).

use super::report::{json_line, mean_ms, progress};
use anyhow::{Context, Result};
use clap::Args;
use impact_core::geometry::Shape;
use impact_core::scene::settings::Source;
use impact_core::scene::Scene;
use impact_core::sim::overlaps::{self, Other};
use impact_core::sim::world::Rule;
use impact_core::sim::{Plan, Stepper, TickOutput, World};
use rapier3d::parry::utils::Array2;
use rapier3d::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Options for the rest suite.
#[derive(Args, Debug)]
pub struct RestArgs {
    /// Ticks per run (64 Hz: 640 is ten seconds).
    #[arg(long, default_value_t = 640)]
    ticks: u32,
    /// The tick from which a scene should be settled: the falling phase is before it.
    #[arg(long, default_value_t = 600)]
    settle_tick: u32,
    /// Scenes to run (comma-separated): bundled names or paths to scene files.
    #[arg(long, value_delimiter = ',', default_value = "pile,stack,ramp,hillside,standing,yard")]
    scenes: Vec<String>,
    /// Skip rapier.
    #[arg(long)]
    no_rapier: bool,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
    /// Exit with an error when a scene with no tuning keys misses a bound (see the module docs).
    #[arg(long)]
    check: bool,
    /// Leave the cost bounds out of `--check`.
    #[arg(long)]
    skip_cost: bool,
    /// Also print, every this many ticks, where impact's time went (ms/tick per stage of the
    /// step, the work counted: pairs tested, impacts resolved, overlap tests) and rapier's time
    /// and awake bodies (this profiling costs a little time itself).
    #[arg(long, value_name = "TICKS")]
    stages: Option<u32>,
}

/// Penetration is sampled every this many ticks (and at the last); it is not timed.
const PENETRATION_EVERY: u32 = 16;

/// One engine's run of one scene.
struct Run {
    samples: Vec<Duration>,
    /// Events from the settle tick on.
    events_after_settle: u64,
    awake_at_settle: usize,
    awake_end: usize,
    penetration_max_m: f64,
    /// The highest point of a body that falls, at the end, m.
    height_m: f64,
}

impl Run {
    fn new(ticks: u32) -> Run {
        Run {
            samples: Vec::with_capacity(ticks as usize),
            events_after_settle: 0,
            awake_at_settle: 0,
            awake_end: 0,
            penetration_max_m: 0.0,
            height_m: f64::NAN,
        }
    }

    /// Mean ms/tick over a phase.
    fn phase_ms(&self, phase: Phase, settle: u32) -> f64 {
        let settle = (settle as usize).min(self.samples.len());
        mean_ms(match phase {
            Phase::Fall => &self.samples[..settle],
            Phase::Settled => &self.samples[settle..],
            Phase::All => &self.samples,
        })
    }
}

#[derive(Clone, Copy)]
enum Phase {
    Fall,
    Settled,
    All,
}

impl Phase {
    fn name(self) -> &'static str {
        match self {
            Phase::Fall => "fall",
            Phase::Settled => "settled",
            Phase::All => "all",
        }
    }
}

fn sample_tick(k: u32, ticks: u32) -> bool {
    k % PENETRATION_EVERY == PENETRATION_EVERY - 1 || k + 1 == ticks
}

fn run_impact(scene: &Scene, ticks: u32, settle: u32, stages: Option<u32>) -> Run {
    let mut w = scene.world.clone();
    let mut stepper = Stepper::new(Plan::for_world(&w), stages.is_some());
    let mut window = Window { every: stages.unwrap_or(64).max(1), ..Window::default() };
    let mut out = TickOutput::default();
    let mut run = Run::new(ticks);
    for k in 0..ticks {
        if k == settle {
            run.awake_at_settle = w.awake_asleep().0;
        }
        let t = Instant::now();
        stepper.step(&mut w, &[], &mut out);
        run.samples.push(t.elapsed());
        if k >= settle {
            run.events_after_settle += out.events.len() as u64;
        }
        if sample_tick(k, ticks) {
            run.penetration_max_m = run.penetration_max_m.max(penetration(&w));
        }
        if stages.is_some() {
            window.add(&stepper.stats, k, &w);
        }
    }
    run.awake_end = w.awake_asleep().0;
    let b = &w.bodies;
    run.height_m = height(
        (0..b.len())
            .filter(|&i| b.inv_mass[i] > 0.0 && w.config.classes.props[b.class[i].0 as usize].gravity)
            .map(|i| b.shape[i].world_aabb(b.pos[i], b.rot[i]).max.y)
            .collect(),
    );
    run
}

/// A pile's height from the tops of its bodies: the 95th percentile, so a few bodies perched on
/// the top (where the two engines' piles differ most by chance) do not decide it.
fn height(mut tops: Vec<f64>) -> f64 {
    if tops.is_empty() {
        return f64::NAN;
    }
    tops.sort_unstable_by(f64::total_cmp);
    let p = |q: f64| tops[((tops.len() - 1) as f64 * q).round() as usize];
    eprintln!("  heights: max {:.3} p95 {:.3} p50 {:.3}", p(1.0), p(0.95), p(0.5));
    p(0.95)
}

/// `--stages`: the step's stage times and work over windows of 64 ticks.
#[derive(Default)]
struct Window {
    every: u32,
    last: Vec<Duration>,
    pairs: u64,
    resolutions: u64,
    toi_tests: u64,
}

impl Window {
    fn add(&mut self, stats: &impact_core::sim::StageStats, k: u32, w: &World) {
        self.pairs += u64::from(stats.pairs_tested);
        self.resolutions += u64::from(stats.resolutions);
        self.toi_tests += u64::from(stats.toi_tests);
        if k % self.every != self.every - 1 {
            return;
        }
        let now: Vec<(&str, Duration)> = stats.stages().to_vec();
        if self.last.is_empty() {
            self.last = vec![Duration::ZERO; now.len()];
        }
        let per_tick = |d: Duration| d.as_secs_f64() * 1e3 / f64::from(self.every);
        let parts: Vec<String> =
            now.iter().zip(&self.last).map(|((name, d), l)| format!("{name} {:.3}", per_tick(*d - *l))).collect();
        let n = u64::from(self.every);
        let sleep = w.config.sleep_speed_mps;
        let speeds: Vec<f64> = w.bodies.vel.iter().map(|v| v.length()).collect();
        let moving = speeds.iter().filter(|s| **s > sleep).count();
        let fastest = speeds.iter().copied().fold(0.0, f64::max);
        eprintln!(
            "  ticks {:>4}-{:<4} ms/tick: {} | per tick: {} pairs, {} resolutions, {} overlap tests, {} awake, {moving} over the sleep speed (fastest {fastest:.3} m/s)",
            k + 1 - self.every,
            k,
            parts.join(", "),
            self.pairs / n,
            self.resolutions / n,
            self.toi_tests / n,
            stats.awake
        );
        self.last = now.iter().map(|(_, d)| *d).collect();
        (self.pairs, self.resolutions, self.toi_tests) = (0, 0, 0);
    }
}

/// The deepest overlap in `w`: dynamic pairs, dynamic bodies against static geometry, and
/// against the terrain where their classes meet it, through impact's exact kernels.
fn penetration(w: &World) -> f64 {
    let mut worst = 0.0f64;
    overlaps::each(w, |i, other, c| {
        let meets = match (other, &w.statics.terrain) {
            (Other::Terrain, Some(t)) => w.config.classes.rule(w.bodies.class[i], t.class) != Rule::Ignore,
            _ => true,
        };
        if meets {
            worst = worst.max(c.depth);
        }
    });
    worst
}

/// rapier's collider for one of impact's shapes (sphere, capsule, cuboid: what the rest scenes
/// use).
fn collider(shape: &Shape) -> Result<ColliderBuilder> {
    Ok(match *shape {
        Shape::Sphere { radius } => ColliderBuilder::ball(radius as f32),
        Shape::Capsule { half_height, radius } => ColliderBuilder::capsule_y(half_height as f32, radius as f32),
        Shape::Cuboid { half_extents } => {
            let h = half_extents.as_vec3();
            ColliderBuilder::cuboid(h.x, h.y, h.z)
        }
        ref other => anyhow::bail!("the rest suite has no rapier collider for {:?}", other.kind()),
    })
}

/// The restitution a class bounces with against its own kind (or the world's default).
fn restitution(w: &World, class: impact_core::sim::world::ClassId) -> f32 {
    match w.config.classes.rule(class, class) {
        Rule::Bounce { restitution } => restitution as f32,
        _ => 0.0,
    }
}

/// What rapier is given of the scene's keys: a key the scene writes, rapier gets too; a key it
/// leaves out, rapier keeps its own default (friction 0.5, restitution 0).
struct Given {
    friction: bool,
    restitution: bool,
}

impl Given {
    fn of(scene: &Scene) -> Given {
        let from_scene = |key: &str| scene.settings.iter().any(|s| s.key == key && s.source == Source::Scene);
        // A [[response]] entry with its own restitution is a key the scene writes.
        Given {
            friction: from_scene("friction"),
            restitution: from_scene("restitution") || from_scene("default_response"),
        }
    }

    fn apply(&self, c: ColliderBuilder, w: &World, class: impact_core::sim::world::ClassId) -> ColliderBuilder {
        let c = if self.friction { c.friction(w.config.friction as f32) } else { c };
        if self.restitution {
            c.restitution(restitution(w, class)).restitution_combine_rule(CoefficientCombineRule::Max)
        } else {
            c
        }
    }
}

fn run_rapier(scene: &Scene, ticks: u32, settle: u32, stages: Option<u32>) -> Result<Run> {
    let w = &scene.world;
    let given = Given::of(scene);
    let mut pw = PhysicsWorld::new();
    pw.gravity = w.config.gravity.as_vec3();
    pw.integration_parameters.dt = w.config.dt as f32;
    let s = &w.statics;
    for k in 0..s.id.len() {
        let c = collider(&s.shape[k])?.translation(s.pos[k].as_vec3()).rotation(s.rot[k].as_quat().to_scaled_axis());
        pw.insert_collider(given.apply(c, w, s.class[k]), None);
    }
    if let Some(t) = &s.terrain {
        let (nx, nz, heights) = t.field.samples();
        // parry's height field: rows along z, columns along x, column-major, centred on its
        // origin and scaled to the field's extent.
        let mut data = vec![0.0f32; nx * nz];
        for iz in 0..nz {
            for ix in 0..nx {
                data[iz + ix * nz] = heights[iz * nx + ix] as f32;
            }
        }
        let (cx, cz) = t.field.cell_size();
        let (wx, wz) = (cx * (nx - 1) as f64, cz * (nz - 1) as f64);
        let centre = t.field.origin() + glam::DVec3::new(wx / 2.0, 0.0, wz / 2.0);
        let c = ColliderBuilder::heightfield(Array2::new(nz, nx, data), Vector::new(wx as f32, 1.0, wz as f32))
            .translation(centre.as_vec3());
        pw.insert_collider(given.apply(c, w, t.class), None);
    }
    let b = &w.bodies;
    let mut falls = Vec::new();
    for i in 0..b.len() {
        let props = &w.config.classes.props[b.class[i].0 as usize];
        let body = if b.inv_mass[i] > 0.0 { RigidBodyBuilder::dynamic() } else { RigidBodyBuilder::fixed() }
            .translation(b.pos[i].as_vec3())
            .rotation(b.rot[i].as_quat().to_scaled_axis())
            .linvel(b.vel[i].as_vec3())
            .gravity_scale(if props.gravity { 1.0 } else { 0.0 })
            .can_sleep(props.can_sleep)
            .lock_rotations();
        let mut c = given.apply(collider(&b.shape[i])?, w, b.class[i]).active_events(ActiveEvents::COLLISION_EVENTS);
        if b.inv_mass[i] > 0.0 {
            c = c.mass((1.0 / b.inv_mass[i]) as f32);
        }
        let (handle, _) = pw.insert(body, c);
        if b.inv_mass[i] > 0.0 && props.gravity {
            falls.push(handle);
        }
    }
    let (collision_send, collision_recv) = std::sync::mpsc::channel();
    let (force_send, _force_recv) = std::sync::mpsc::channel();
    let (tear_send, _tear_recv) = std::sync::mpsc::channel();
    let events = ChannelEventCollector::new(collision_send, force_send, tear_send);
    let awake = |pw: &PhysicsWorld| pw.bodies.iter().filter(|(_, rb)| rb.is_dynamic() && !rb.is_sleeping()).count();
    let mut run = Run::new(ticks);
    for k in 0..ticks {
        if k == settle {
            run.awake_at_settle = awake(&pw);
        }
        let t = Instant::now();
        pw.step_with_events(&(), &events);
        run.samples.push(t.elapsed());
        let n = collision_recv.try_iter().count() as u64;
        if k >= settle {
            run.events_after_settle += n;
        }
        if sample_tick(k, ticks) {
            let deepest = pw
                .narrow_phase
                .contact_pairs()
                .flat_map(|p| p.manifolds().iter().flat_map(|m| m.points.iter().map(|c| -c.dist)))
                .fold(0.0f32, f32::max);
            run.penetration_max_m = run.penetration_max_m.max(f64::from(deepest));
        }
        if let Some(every) = stages.map(|e| e.max(1)).filter(|e| k % e == e - 1) {
            let last = &run.samples[run.samples.len() - every as usize..];
            eprintln!(
                "  rapier ticks {:>4}-{:<4} ms/tick {:.3}, {} awake",
                k + 1 - every,
                k,
                mean_ms(last),
                awake(&pw)
            );
        }
    }
    run.awake_end = awake(&pw);
    run.height_m = height(
        falls
            .iter()
            .flat_map(|h| pw.bodies[*h].colliders().iter().map(|c| f64::from(pw.colliders[*c].compute_aabb().maxs.y)))
            .collect(),
    );
    Ok(run)
}

/// A scene by bundled name or path.
fn scene_path(name: &str) -> PathBuf {
    if name.ends_with(".toml") || name.contains('/') {
        Path::new(name).to_path_buf()
    } else {
        Scene::bundled_path(name)
    }
}

/// Whether a scene writes none of the keys that decide resting behaviour: the scenes the bounds
/// of `--check` hold.
fn untuned(scene: &Scene) -> bool {
    const TUNING: [&str; 8] = [
        "default_response",
        "restitution",
        "friction",
        "contact_slop_m",
        "bounce_threshold_mps",
        "sleep_speed_mps",
        "sleep_after_s",
        "partial_sleep",
    ];
    !scene.settings.iter().any(|s| TUNING.contains(&s.key) && s.source == Source::Scene)
}

/// The bounds a scene with no tuning keys misses, as sentences (empty: it holds them all).
fn missed(name: &str, scene: &Scene, ours: &Run, peer: Option<&Run>, a: &RestArgs) -> Vec<String> {
    let settle = a.settle_tick;
    let mut out = Vec::new();
    if ours.awake_at_settle > 0 {
        out.push(format!("{name}: {} bodies awake at tick {settle} (bound: 0)", ours.awake_at_settle));
    }
    if ours.events_after_settle > 0 {
        out.push(format!("{name}: {} events after tick {settle} (bound: 0)", ours.events_after_settle));
    }
    let pile = scene.name.as_str() == "pile";
    // The pile's penetration bound is relative to its spheres' radius.
    if let (true, Some(radius)) = (pile, scene.facts.thinnest_falling_m) {
        if ours.penetration_max_m >= 0.01 * radius {
            out.push(format!(
                "{name}: penetration {:.2e} m, not under 1 % of the radius ({:.2e} m)",
                ours.penetration_max_m,
                0.01 * radius
            ));
        }
    }
    if let Some(p) = peer {
        if pile && (ours.height_m - p.height_m).abs() > 0.05 * p.height_m {
            out.push(format!("{name}: height {:.3} m, not within 5 % of rapier's {:.3} m", ours.height_m, p.height_m));
        }
        let bound = if pile { 0.5 } else { 1.0 };
        let ratio = ours.phase_ms(Phase::All, settle) / p.phase_ms(Phase::All, settle);
        if ratio > bound && !a.skip_cost {
            out.push(format!("{name}: costs {ratio:.2}x rapier over the run (bound: {bound}x)"));
        }
    }
    out
}

/// Runs the suite.
pub fn run(a: &RestArgs) -> Result<()> {
    anyhow::ensure!(a.settle_tick < a.ticks, "--settle-tick {} must be before --ticks {}", a.settle_tick, a.ticks);
    println!(
        "{:<9} {:<8} {:>6} {:>10} {:>10} {:>8} {:>11} {:>11} {:>19} {:>15}",
        "scene",
        "phase",
        "bodies",
        "impact ms",
        "rapier ms",
        "i/r",
        "awake i/r",
        "events i/r",
        "penetration m i/r",
        "height m i/r"
    );
    let mut failures = Vec::new();
    for name in &a.scenes {
        let scene = Scene::load(&scene_path(name)).with_context(|| format!("scene {name}"))?;
        progress(&format!("{name}: impact, {} ticks", a.ticks));
        let ours = run_impact(&scene, a.ticks, a.settle_tick, a.stages);
        let peer = if a.no_rapier {
            None
        } else {
            progress(&format!("{name}: rapier, {} ticks", a.ticks));
            Some(run_rapier(&scene, a.ticks, a.settle_tick, a.stages)?)
        };
        let bodies = scene.world.bodies.len();
        for phase in [Phase::Fall, Phase::Settled, Phase::All] {
            let impact_ms = ours.phase_ms(phase, a.settle_tick);
            let rapier_ms = peer.as_ref().map(|p| p.phase_ms(phase, a.settle_tick));
            let ratio = rapier_ms.map(|r| impact_ms / r);
            let pair = |x: String, y: Option<String>| format!("{x}/{}", y.unwrap_or_else(|| "-".into()));
            println!(
                "{:<9} {:<8} {bodies:>6} {impact_ms:>10.4} {:>10} {:>8} {:>11} {:>11} {:>19} {:>15}",
                name,
                phase.name(),
                rapier_ms.map_or("-".into(), |r| format!("{r:.4}")),
                ratio.map_or("-".into(), |r| format!("{r:.2}x")),
                pair(ours.awake_end.to_string(), peer.as_ref().map(|p| p.awake_end.to_string())),
                pair(ours.events_after_settle.to_string(), peer.as_ref().map(|p| p.events_after_settle.to_string())),
                pair(
                    format!("{:.1e}", ours.penetration_max_m),
                    peer.as_ref().map(|p| format!("{:.1e}", p.penetration_max_m))
                ),
                pair(format!("{:.3}", ours.height_m), peer.as_ref().map(|p| format!("{:.3}", p.height_m))),
            );
            if a.json {
                json_line(&json!({
                    "suite": "rest", "scene": name, "phase": phase.name(), "bodies": bodies, "ticks": a.ticks,
                    "settle_tick": a.settle_tick, "untuned": untuned(&scene),
                    "impact_ms": impact_ms, "rapier_ms": rapier_ms, "impact_over_rapier": ratio,
                    "awake_at_settle": ours.awake_at_settle, "awake_end": ours.awake_end,
                    "rapier_awake_end": peer.as_ref().map(|p| p.awake_end),
                    "events_after_settle": ours.events_after_settle,
                    "rapier_events_after_settle": peer.as_ref().map(|p| p.events_after_settle),
                    "max_penetration_m": ours.penetration_max_m,
                    "rapier_max_penetration_m": peer.as_ref().map(|p| p.penetration_max_m),
                    "height_m": ours.height_m, "rapier_height_m": peer.as_ref().map(|p| p.height_m),
                }));
            }
        }
        if a.check && untuned(&scene) {
            failures.extend(missed(name, &scene, &ours, peer.as_ref(), a));
        }
    }
    println!(
        "(i/r: impact over rapier, mean ms/tick in the phase; fall: ticks before {}, settled: from it; awake at the end; events from tick {} on)",
        a.settle_tick, a.settle_tick
    );
    if !failures.is_empty() {
        anyhow::bail!("missed bounds:\n  {}", failures.join("\n  "));
    }
    Ok(())
}
