//! The impact server. `--offline` runs a scene through the core with no network, writes every
//! event as a JSON line and prints the plan and the time per stage.

use anyhow::{bail, Context, Result};
use clap::Parser;
use impact_server::offline;
use impact_server::scene::Scene;
use impact_server::sim::Plan;
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::Instant;

/// impact: an authoritative collision server for multiplayer games.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Scene file (TOML; see SCENES.md).
    #[arg(long)]
    scene: PathBuf,
    /// Run the core with no network, as fast as it goes.
    #[arg(long)]
    offline: bool,
    /// Ticks to run offline.
    #[arg(long, default_value_t = 640)]
    ticks: u32,
    /// Write every event as a JSON line here (offline).
    #[arg(long)]
    events_out: Option<PathBuf>,
    /// Inputs to apply (offline): one JSON `input` message per line, at its tick.
    #[arg(long)]
    inputs: Option<PathBuf>,
    /// Print the first N events to stdout (offline).
    #[arg(long, default_value_t = 12)]
    print_events: usize,
    /// Use the general path (GJK for every pair, no analytic kernels): for comparisons.
    #[arg(long)]
    general: bool,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let scene = Scene::load(&args.scene).map_err(anyhow::Error::msg)?;
    if !args.offline {
        bail!("the network runtime is not built yet: run with --offline (see README.md)");
    }
    let plan = if args.general { Plan::general(&scene.world) } else { Plan::for_world(&scene.world) };
    println!(
        "scene {} ({}): {} dynamic, {} static bodies{}",
        scene.name,
        args.scene.display(),
        scene.world.bodies.len(),
        scene.world.statics.id.len(),
        if scene.world.statics.terrain.is_some() { ", terrain" } else { "" }
    );
    println!("{plan}");
    let inputs = match &args.inputs {
        Some(p) => offline::read_inputs(p)?,
        None => offline::InputScript::new(),
    };
    let mut file = match &args.events_out {
        Some(p) => Some(std::io::BufWriter::new(
            std::fs::File::create(p).with_context(|| format!("creating {}", p.display()))?,
        )),
        None => None,
    };
    let mut printed = 0usize;
    let stdout = std::io::stdout();
    let tty = std::io::stderr().is_terminal();
    let mut last = Instant::now();
    let ticks = args.ticks;
    let report = offline::run(
        &scene,
        plan,
        ticks,
        &inputs,
        |e| {
            if printed < args.print_events {
                printed += 1;
                let mut o = stdout.lock();
                writeln!(o, "  tick {:>5} toi {:.4} {:>5} <-> {:<5} {:<5} {:<8} point [{:.3}, {:.3}, {:.3}] normal [{:.3}, {:.3}, {:.3}] depth {:.2e} m closing {:.3} m/s",
                    e.tick.0, e.toi, e.a.0, e.b.0, format!("{:?}", e.phase).to_lowercase(), format!("{:?}", e.response).to_lowercase(),
                    e.point[0], e.point[1], e.point[2], e.normal[0], e.normal[1], e.normal[2], e.depth_m, e.closing_speed_mps)?;
            }
            if let Some(f) = file.as_mut() {
                serde_json::to_writer(&mut *f, e)?;
                f.write_all(b"\n")?;
            }
            Ok(())
        },
        |done| {
            // Progress once a second: a live line on a terminal, plain lines otherwise.
            if last.elapsed().as_secs_f64() >= 1.0 || done == ticks {
                last = Instant::now();
                if tty {
                    eprint!("\r  tick {done}/{ticks} ({:.0} %)   ", f64::from(done) / f64::from(ticks.max(1)) * 100.0);
                    if done == ticks {
                        eprintln!();
                    }
                } else if done != ticks {
                    eprintln!("  tick {done}/{ticks}");
                }
            }
        },
    )?;
    if let Some(mut f) = file {
        f.flush()?;
    }
    offline::print_summary(&report, &mut std::io::stdout().lock())?;
    Ok(())
}
