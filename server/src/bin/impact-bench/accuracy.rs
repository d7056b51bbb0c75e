//! `impact-bench accuracy`: run time against error. Known-answer scenes (sphere pairs, sphere
//! against rotated boxes, sphere against a height field, bullets against 1 cm walls) through each
//! method (discrete overlap, bisection with 1..24 halvings, the default tolerance, the analytic
//! swept sphere) at 30, 64, 120 and 240 Hz, and rapier's continuous collision (PhysicsPipeline
//! with CCD) on the head-on bullet and sphere-box scenes in the same run.

use super::report::{json_line, progress};
use anyhow::Result;
use clap::Args;
use impact_server::plot::{svg_loglog, Series};
use impact_server::trials::{self, Errors, Kind, Method, Setup};
use rapier3d::prelude::*;
use serde_json::json;
use std::collections::BTreeMap;
use std::time::Instant;

/// Options.
#[derive(Args, Debug)]
pub struct AccuracyArgs {
    /// Trials per scene.
    #[arg(long, default_value_t = 400)]
    trials: u32,
    /// Repeats per measurement (median time).
    #[arg(long, default_value_t = 5)]
    repeats: u32,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
    /// Write the Pareto plot (time per tick against the largest time-of-impact error) here.
    #[arg(long)]
    svg: Option<std::path::PathBuf>,
}

fn row(a: &AccuracyArgs, scene: &str, method: &str, setting: &str, hz: u32, e: &Errors) {
    println!(
        "{scene:<15} {method:<10} {setting:<18} {hz:>4} {:>9.4} {:>11.3e} {:>11.3e} {:>10.2e} {:>10.2e} {:>7.2} {:>7.2}",
        e.ms_per_tick, e.toi_err_max_s, e.toi_err_mean_s, e.point_err_max_m, e.normal_err_max_rad, e.missed_pct, e.false_pct
    );
    if a.json {
        json_line(&json!({"suite": "accuracy", "scene": scene, "method": method, "setting": setting, "tick_hz": hz,
            "ms_per_tick": e.ms_per_tick, "toi_err_max_s": e.toi_err_max_s, "toi_err_mean_s": e.toi_err_mean_s,
            "point_err_max_m": e.point_err_max_m, "normal_err_max_rad": e.normal_err_max_rad, "missed_pct": e.missed_pct, "false_pct": e.false_pct}));
    }
}

/// rapier's CCD on the same trial set (sphere against a wall, head on or oblique): one physics
/// step with restitution 0; the sphere stops at the contact, so the distance it travelled gives
/// rapier's time of impact. Missed: it ended past the wall's face.
fn rapier_ccd(set: &trials::TrialSet, repeats: u32) -> Errors {
    let w = &set.world;
    let dt = w.config.dt;
    let mut times = Vec::new();
    let mut e = Errors::default();
    for _ in 0..repeats.max(1) {
        let mut bodies = RigidBodySet::new();
        let mut colliders = ColliderSet::new();
        for k in 0..w.statics.id.len() {
            let Some(half) = (match &w.statics.shape[k] {
                impact_core::geometry::Shape::Cuboid { half_extents } => Some(*half_extents),
                _ => None,
            }) else {
                continue;
            };
            let pose = Pose::from_parts(w.statics.pos[k].as_vec3(), w.statics.rot[k].as_quat());
            colliders.insert(
                ColliderBuilder::cuboid(half.x as f32, half.y as f32, half.z as f32)
                    .position(pose)
                    .restitution(0.0)
                    .friction(0.0)
                    .build(),
            );
        }
        let mut handles = Vec::new();
        for i in 0..w.bodies.len() {
            let rb = RigidBodyBuilder::dynamic()
                .translation(w.bodies.pos[i].as_vec3())
                .linvel(w.bodies.vel[i].as_vec3())
                .ccd_enabled(true)
                .build();
            let h = bodies.insert(rb);
            colliders.insert_with_parent(
                ColliderBuilder::ball(w.bodies.radius[i] as f32).restitution(0.0).friction(0.0).build(),
                h,
                &mut bodies,
            );
            handles.push(h);
        }
        let mut pipeline = PhysicsPipeline::new();
        let params = IntegrationParameters { dt: dt as f32, ..IntegrationParameters::default() };
        let (mut islands, mut broad, mut narrow) = (IslandManager::new(), BroadPhaseBvh::new(), NarrowPhase::new());
        let (mut ij, mut mj, mut ccd) = (ImpulseJointSet::new(), MultibodyJointSet::new(), CCDSolver::new());
        let mut soft = SoftBodySet::default();
        let t = Instant::now();
        pipeline.step(
            Vector::ZERO,
            &params,
            &mut islands,
            &mut broad,
            &mut narrow,
            &mut bodies,
            &mut colliders,
            &mut ij,
            &mut mj,
            &mut soft,
            &mut ccd,
            &(),
            &(),
        );
        times.push(t.elapsed().as_secs_f64() * 1e3);
        // Score against the truths (sphere i is truth i: one sphere per wall).
        let (mut sum, mut hits, mut missed) = (0.0, 0u32, 0u32);
        e.toi_err_max_s = 0.0;
        for (i, truth) in set.truths.iter().enumerate() {
            let Some(tc) = truth.toi else { continue };
            let p0 = w.bodies.pos[i];
            let v = w.bodies.vel[i];
            let p1 = bodies[handles[i]].translation().as_dvec3();
            // Signed distance of the centre from the face plane at the end: the truth's point
            // is on the face and its normal points out of it.
            let n = truth.normal;
            let n = if n.dot(v) > 0.0 { -n } else { n };
            let end_gap = (p1 - truth.point).dot(n) - w.bodies.radius[i];
            if end_gap < -w.bodies.radius[i] {
                missed += 1;
                continue;
            }
            hits += 1;
            let travelled = (p1 - p0).dot(v.normalize());
            let toi = (travelled / v.length() / dt).clamp(0.0, 1.0);
            let err = (toi - tc).abs() * dt;
            sum += err;
            e.toi_err_max_s = e.toi_err_max_s.max(err);
        }
        e.toi_err_mean_s = if hits > 0 { sum / f64::from(hits) } else { 0.0 };
        e.missed_pct = 100.0 * f64::from(missed) / f64::from((hits + missed).max(1));
    }
    times.sort_by(f64::total_cmp);
    e.ms_per_tick = times[times.len() / 2];
    e.point_err_max_m = f64::NAN;
    e.normal_err_max_rad = f64::NAN;
    e
}

/// Runs the suite.
pub fn run(a: &AccuracyArgs) -> Result<()> {
    println!(
        "accuracy: {} trials per scene, median of {} ticks; errors against the exact contact",
        a.trials, a.repeats
    );
    println!(
        "{:<15} {:<10} {:<18} {:>4} {:>9} {:>11} {:>11} {:>10} {:>10} {:>7} {:>7}",
        "scene",
        "method",
        "setting",
        "hz",
        "ms/tick",
        "toi err max",
        "toi err avg",
        "point err",
        "normal err",
        "miss %",
        "false %"
    );
    let mut methods = vec![Method::Discrete];
    methods.extend([1, 2, 4, 8, 12, 16, 20, 24].map(Method::Bisect));
    methods.push(Method::Default);
    let mut pareto: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for kind in [Kind::SpherePairs, Kind::SphereBox, Kind::SphereTerrain, Kind::BulletWall] {
        for hz in [30, 64, 120, 240] {
            progress(&format!("{} at {hz} Hz", kind.name()));
            let (radius, speed) = match kind {
                Kind::BulletWall => ((0.05, 0.05), (10.0, 1000.0)),
                Kind::SpherePairs => ((0.1, 0.1), (1.0, 200.0)),
                _ => ((0.1, 0.5), (1.0, 50.0)),
            };
            let set = trials::build(&Setup {
                kind,
                count: a.trials,
                tick_hz: hz,
                radius,
                speed,
                seed: u64::from(hz),
                ..Setup::default()
            });
            let mut ms = methods.clone();
            if kind == Kind::SpherePairs {
                ms.push(Method::Analytic);
            }
            for m in ms {
                let e = trials::measure(&set, m, a.repeats);
                let (name, setting) = m.label();
                row(a, kind.name(), name, &setting, hz, &e);
                if hz == 64 && kind == Kind::SpherePairs {
                    let key = if matches!(m, Method::Bisect(_)) {
                        "bisection (1..24)".to_string()
                    } else {
                        format!("{name} {setting}").trim_end_matches(" -").to_string()
                    };
                    pareto.entry(key).or_default().push((e.ms_per_tick, e.toi_err_max_s.max(1e-12)));
                }
            }
            if matches!(kind, Kind::BulletWall | Kind::SphereBox) {
                let e = rapier_ccd(&set, a.repeats);
                row(a, kind.name(), "rapier_ccd", "PhysicsPipeline", hz, &e);
            }
        }
    }
    // The cost of accuracy on a real scene: the arena (2,000 balls, walls) with the default
    // method against discrete overlap testing, median tick over 200 ticks each.
    progress("arena: default against discrete");
    let arena = impact_core::scene::Scene::load(&impact_core::scene::Scene::bundled_path("arena"))?;
    let mut arena_ms = Vec::new();
    for m in [Method::Discrete, Method::Default] {
        let mut w = arena.world.clone();
        let plan = m.apply(&mut w);
        let mut st = impact_core::sim::Stepper::new(plan, false);
        let mut out = impact_core::sim::TickOutput::default();
        let mut times = Vec::new();
        for _ in 0..200 {
            let t = Instant::now();
            st.step(&mut w, &[], &mut out);
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        times.sort_by(f64::total_cmp);
        arena_ms.push(times[times.len() / 2]);
    }
    let ratio = arena_ms[1] / arena_ms[0];
    println!(
        "arena: discrete {:.4} ms/tick, default {:.4} ms/tick: {ratio:.2}x (target <= 1.3x)",
        arena_ms[0], arena_ms[1]
    );
    if a.json {
        json_line(
            &json!({"suite": "accuracy", "scene": "arena", "discrete_ms_per_tick": arena_ms[0], "default_ms_per_tick": arena_ms[1], "ratio": ratio}),
        );
    }
    if let Some(path) = &a.svg {
        let series: Vec<Series> = pareto.into_iter().map(|(name, points)| Series { name, points }).collect();
        std::fs::write(
            path,
            svg_loglog(
                "sphere pairs at 64 Hz: time per tick against error",
                "ms per tick",
                "largest TOI error (s)",
                &series,
            ),
        )?;
        println!("plot: {}", path.display());
    }
    Ok(())
}
