//! `impact-bench rest`: bodies at rest under gravity, in impact's core and in rapier's full
//! `PhysicsPipeline` (solver, islands, sleeping on) built from the same world in the same
//! process: bodies standing on a floor, a pile of spheres in a box, and a yard of crates on
//! terrain with players and projectiles moving among them.
//!
//! Per scene and engine: mean and median ms/tick over the whole run and over its settled part
//! (the second half), bodies awake at the end, begin/end events per simulated second in the
//! settled part, and the deepest penetration sampled every 16 ticks. rapier's bodies have their
//! rotations locked, as impact's do (impact's orientations are fixed), and the scene's friction
//! and restitution.

use super::report::{json_line, mean_ms, median_ms, progress};
use anyhow::{Context, Result};
use clap::Args;
use impact_core::broadphase::{Broadphase, BroadphaseKind};
use impact_core::geometry::Shape;
use impact_core::narrow;
use impact_core::scene::Scene;
use impact_core::sim::world::Rule;
use impact_core::sim::{Plan, Stepper, TickOutput, World};
use impact_protocol::Phase;
use rapier3d::parry::utils::Array2;
use rapier3d::prelude::*;
use serde_json::json;
use std::time::{Duration, Instant};

/// Options for the rest suite.
#[derive(Args, Debug)]
pub struct RestArgs {
    /// Ticks per run (64 Hz: 640 is ten seconds).
    #[arg(long, default_value_t = 640)]
    ticks: u32,
    /// Bundled scenes to run (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "standing,pile,yard")]
    scenes: Vec<String>,
    /// Skip rapier.
    #[arg(long)]
    no_rapier: bool,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

/// Penetration is sampled every this many ticks (and at the last); it is not timed.
const PENETRATION_EVERY: u32 = 16;

/// One engine's run of one scene.
struct Run {
    samples: Vec<Duration>,
    /// Begin/end events in the settled part.
    events_settled: u64,
    awake_end: usize,
    penetration_max_m: f64,
}

impl Run {
    fn settled(&self) -> &[Duration] {
        &self.samples[self.samples.len() / 2..]
    }
}

fn run_impact(scene: &Scene, ticks: u32) -> Run {
    let mut w = scene.world.clone();
    let mut stepper = Stepper::new(Plan::for_world(&w), false);
    let mut out = TickOutput::default();
    let mut run =
        Run { samples: Vec::with_capacity(ticks as usize), events_settled: 0, awake_end: 0, penetration_max_m: 0.0 };
    for k in 0..ticks {
        let t = Instant::now();
        stepper.step(&mut w, &[], &mut out);
        run.samples.push(t.elapsed());
        if k >= ticks / 2 {
            run.events_settled +=
                out.events.iter().filter(|e| matches!(e.phase, Phase::Begin | Phase::End)).count() as u64;
        }
        if k % PENETRATION_EVERY == PENETRATION_EVERY - 1 || k + 1 == ticks {
            run.penetration_max_m = run.penetration_max_m.max(penetration(&w));
        }
    }
    run.awake_end = w.awake_asleep().0;
    run
}

/// The deepest overlap in `w`: every dynamic pair whose boxes overlap, every dynamic body
/// against the statics its box reaches and against the terrain, through impact's exact kernels.
fn penetration(w: &World) -> f64 {
    let b = &w.bodies;
    let boxes: Vec<_> = (0..b.len()).map(|i| b.shape[i].world_aabb(b.pos[i], b.rot[i])).collect();
    let mut pairs = Vec::new();
    Broadphase::new(BroadphaseKind::Grid).pairs(&boxes, &mut pairs, &impact_core::par::Pool::sequential());
    let mut worst = 0.0f64;
    for (i, j) in pairs {
        let (i, j) = (i as usize, j as usize);
        if let Some(c) = narrow::contact(&b.shape[i], b.rot[i], &b.shape[j], b.rot[j], b.pos[j] - b.pos[i], 0.0) {
            worst = worst.max(c.depth);
        }
    }
    let mut found = Vec::new();
    for (i, bounds) in boxes.iter().enumerate() {
        w.statics.index.query(bounds, &mut found);
        for &s in &found {
            let s = s as usize;
            let d = w.statics.pos[s] - b.pos[i];
            if let Some(c) = narrow::contact(&b.shape[i], b.rot[i], &w.statics.shape[s], w.statics.rot[s], d, 0.0) {
                worst = worst.max(c.depth);
            }
        }
        if let Some(t) = &w.statics.terrain {
            let rule = w.config.classes.rule(b.class[i], t.class);
            if rule != Rule::Ignore && t.field.aabb().overlaps(bounds) {
                if let Some(c) = narrow::terrain_contact(&b.shape[i], b.rot[i], b.pos[i], &t.field, 0.0) {
                    worst = worst.max(c.depth);
                }
            }
        }
    }
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

fn run_rapier(w: &World, ticks: u32) -> Result<Run> {
    let mut pw = PhysicsWorld::new();
    pw.gravity = w.config.gravity.as_vec3();
    pw.integration_parameters.dt = w.config.dt as f32;
    let friction = w.config.friction as f32;
    let s = &w.statics;
    for k in 0..s.id.len() {
        let c = collider(&s.shape[k])?
            .translation(s.pos[k].as_vec3())
            .rotation(s.rot[k].as_quat().to_scaled_axis())
            .friction(friction)
            .restitution(restitution(w, s.class[k]))
            .restitution_combine_rule(CoefficientCombineRule::Max);
        pw.insert_collider(c, None);
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
            .translation(centre.as_vec3())
            .friction(friction);
        pw.insert_collider(c, None);
    }
    let b = &w.bodies;
    for i in 0..b.len() {
        let props = &w.config.classes.props[b.class[i].0 as usize];
        let body = if b.inv_mass[i] > 0.0 { RigidBodyBuilder::dynamic() } else { RigidBodyBuilder::fixed() }
            .translation(b.pos[i].as_vec3())
            .rotation(b.rot[i].as_quat().to_scaled_axis())
            .linvel(b.vel[i].as_vec3())
            .gravity_scale(if props.gravity { 1.0 } else { 0.0 })
            .can_sleep(props.can_sleep)
            .lock_rotations();
        let mut c = collider(&b.shape[i])?
            .friction(friction)
            .restitution(restitution(w, b.class[i]))
            .restitution_combine_rule(CoefficientCombineRule::Max)
            .active_events(ActiveEvents::COLLISION_EVENTS);
        if b.inv_mass[i] > 0.0 {
            c = c.mass((1.0 / b.inv_mass[i]) as f32);
        }
        pw.insert(body, c);
    }
    let (collision_send, collision_recv) = std::sync::mpsc::channel();
    let (force_send, _force_recv) = std::sync::mpsc::channel();
    let (tear_send, _tear_recv) = std::sync::mpsc::channel();
    let events = ChannelEventCollector::new(collision_send, force_send, tear_send);
    let mut run =
        Run { samples: Vec::with_capacity(ticks as usize), events_settled: 0, awake_end: 0, penetration_max_m: 0.0 };
    for k in 0..ticks {
        let t = Instant::now();
        pw.step_with_events(&(), &events);
        run.samples.push(t.elapsed());
        let n = collision_recv.try_iter().count() as u64;
        if k >= ticks / 2 {
            run.events_settled += n;
        }
        if k % PENETRATION_EVERY == PENETRATION_EVERY - 1 || k + 1 == ticks {
            let deepest = pw
                .narrow_phase
                .contact_pairs()
                .flat_map(|p| p.manifolds().iter().flat_map(|m| m.points.iter().map(|c| -c.dist)))
                .fold(0.0f32, f32::max);
            run.penetration_max_m = run.penetration_max_m.max(f64::from(deepest));
        }
    }
    run.awake_end = pw.bodies.iter().filter(|(_, rb)| rb.is_dynamic() && !rb.is_sleeping()).count();
    Ok(run)
}

/// Runs the suite.
pub fn run(a: &RestArgs) -> Result<()> {
    println!(
        "{:<9} {:<7} {:>7} {:>9} {:>9} {:>10} {:>10} {:>7} {:>9} {:>10} {:>10}",
        "scene",
        "engine",
        "bodies",
        "ms mean",
        "ms p50",
        "settled",
        "settled50",
        "awake",
        "ev/s",
        "pen max m",
        "vs rapier"
    );
    for name in &a.scenes {
        let scene = Scene::load(&Scene::bundled_path(name)).with_context(|| format!("scene {name}"))?;
        let seconds = f64::from(a.ticks - a.ticks / 2) / f64::from(scene.world.config.tick_hz);
        progress(&format!("{name}: impact, {} ticks", a.ticks));
        let ours = run_impact(&scene, a.ticks);
        let peer = if a.no_rapier {
            None
        } else {
            progress(&format!("{name}: rapier, {} ticks", a.ticks));
            Some(run_rapier(&scene.world, a.ticks)?)
        };
        let bodies = scene.world.bodies.len();
        for (engine, r) in [("impact", Some(&ours)), ("rapier", peer.as_ref())] {
            let Some(r) = r else { continue };
            let mean = mean_ms(&r.samples);
            let median = median_ms(&mut r.samples.clone());
            let settled = mean_ms(r.settled());
            let settled_median = median_ms(&mut r.settled().to_vec());
            let events_per_s = r.events_settled as f64 / seconds;
            let ratio = match (&peer, engine) {
                (Some(p), "impact") => format!("{:.2}x", mean_ms(&p.samples) / mean),
                (Some(_), _) => "1.00x".to_string(),
                (None, _) => "-".to_string(),
            };
            println!(
                "{name:<9} {engine:<7} {bodies:>7} {mean:>9.4} {median:>9.4} {settled:>10.4} {settled_median:>10.4} {:>7} {events_per_s:>9.1} {:>10.2e} {ratio:>10}",
                r.awake_end, r.penetration_max_m
            );
            if a.json {
                json_line(&json!({
                    "suite": "rest", "scene": name, "engine": engine, "bodies": bodies, "ticks": a.ticks,
                    "ms_mean": mean, "ms_median": median, "ms_settled": settled, "ms_settled_median": settled_median,
                    "awake_end": r.awake_end, "events_per_s_settled": events_per_s,
                    "penetration_max_m": r.penetration_max_m,
                }));
            }
        }
    }
    println!("(vs rapier: rapier's mean ms/tick over impact's; settled: the second half of the run)");
    Ok(())
}
