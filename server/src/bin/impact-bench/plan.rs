//! `impact-bench plan`: what the plan saves. The arena scene three ways in one run: as bundled;
//! with a terrain declared that no body can reach (the terrain pass runs and finds nothing:
//! it must cost next to nothing); and on the general path (GJK for every pair, bisection instead
//! of the swept-sphere formula, sampling always on), which is what a plan-less engine runs.

use super::report::{json_line, median_ms, progress};
use anyhow::Result;
use clap::Args;
use impact_core::scene::Scene;
use impact_core::sim::{Plan, Stepper, TickOutput};
use serde_json::json;
use std::time::Instant;

/// Options for the plan suite.
#[derive(Args, Debug)]
pub struct PlanArgs {
    /// Measured ticks; the median is reported.
    #[arg(long, default_value_t = 200)]
    ticks: u32,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

fn time(scene: &Scene, plan: Plan, ticks: u32) -> (f64, u64) {
    let mut w = scene.world.clone();
    let mut st = Stepper::new(plan, false);
    let mut out = TickOutput::default();
    let mut samples = Vec::new();
    let mut events = 0;
    for _ in 0..ticks {
        let t = Instant::now();
        st.step(&mut w, &[], &mut out);
        samples.push(t.elapsed());
        events += out.events.len() as u64;
    }
    (median_ms(&mut samples), events)
}

/// Runs the suite.
pub fn run(a: &PlanArgs) -> Result<()> {
    let path = Scene::bundled_path("arena");
    let text = std::fs::read_to_string(&path)?;
    let arena = Scene::parse(&text, "arena")?;
    // The same arena with a 200 x 200 m terrain 1 km below: declared, never reached.
    let with_terrain = Scene::parse(
        &format!(
            "{text}\n[[class]]\nname = \"ground\"\nstatic = true\n[terrain]\nclass = \"ground\"\norigin = [-100.0, -1000.0, -100.0]\ncell_m = [2.0, 2.0]\nhills = {{ nx = 101, nz = 101, amplitude_m = 1.0, wavelength_m = 20.0 }}\n"
        ),
        "arena+terrain",
    )?;
    println!("plan: arena ({} balls, 6 walls), median of {} ticks", arena.world.bodies.len(), a.ticks);
    println!("{:<34} {:>10} {:>10} {:>10}", "variant", "ms/tick", "vs plan", "events");
    progress("arena, planned");
    let (base, base_events) = time(&arena, Plan::for_world(&arena.world), a.ticks);
    let rows = [
        ("planned (sphere kernels, no terrain)", base, base_events, "planned"),
        {
            progress("arena with unused terrain");
            let (ms, ev) = time(&with_terrain, Plan::for_world(&with_terrain.world), a.ticks);
            ("unused terrain declared", ms, ev, "unused_terrain")
        },
        {
            progress("arena on the general path");
            let (ms, ev) = time(&arena, Plan::general(&arena.world), a.ticks);
            ("general path (GJK, bisection)", ms, ev, "general")
        },
    ];
    for (name, ms, events, key) in rows {
        println!("{name:<34} {ms:>10.4} {:>9.2}x {events:>10}", ms / base);
        if a.json {
            json_line(
                &json!({"suite": "plan", "variant": key, "ms_per_tick": ms, "ratio_to_planned": ms / base, "events": events}),
            );
        }
    }
    Ok(())
}
