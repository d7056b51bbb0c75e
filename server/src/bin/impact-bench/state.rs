//! `impact-bench state`: what the state streams cost, without the network. The arena with N
//! players (spawned as the server spawns them, wandering), stepped at 64 Hz; at each state frame
//! the tick thread's copy ([`Capture::of`]) and the state thread's work (areas of interest,
//! deltas, budgets, encoding: [`Streams::frames`]) are timed beside the tick itself. Publishing
//! (Zenoh puts) is not in these figures; the load test in BENCHMARKS.md has it.

use super::report::{json_line, median_ms, progress};
use anyhow::{Context, Result};
use clap::Args;
use impact_core::scene::{avatar_position, Scene};
use impact_core::sim::{Plan, Stepper, SystemAction, TickInput, TickOutput};
use impact_protocol::{Action, ClientId, Encoding, WorldId};
use impact_server::runtime::state::{Capture, StateOptions, Streams, Watcher};
use serde_json::json;
use std::time::{Duration, Instant};

/// Options for the state suite.
#[derive(Args, Debug)]
pub struct StateArgs {
    /// Players (comma-separated counts).
    #[arg(long, value_delimiter = ',', default_value = "100,1000")]
    clients: Vec<u32>,
    /// Areas of interest to compare, metres (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "10,20")]
    aoi_m: Vec<f64>,
    /// Byte budget per client per second.
    #[arg(long, default_value_t = StateOptions::default().bytes_per_s)]
    budget: u32,
    /// State frames per second.
    #[arg(long, default_value_t = 20)]
    hz: u32,
    /// Simulated seconds per run (64 ticks each).
    #[arg(long, default_value_t = 10)]
    seconds: u32,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

/// Runs the suite.
pub fn run(a: &StateArgs) -> Result<()> {
    println!(
        "{:>7} {:>5} | {:>9} {:>10} {:>11} {:>11} | {:>11} {:>9} {:>8} | {:>9}",
        "clients",
        "aoi m",
        "tick ms",
        "copy ms",
        "frame ms",
        "x core tick",
        "B/client/s",
        "in area",
        "deferred",
        "sent/frame"
    );
    for &clients in &a.clients {
        for &aoi in &a.aoi_m {
            let r = one(a, clients, aoi)?;
            println!(
                "{:>7} {:>5} | {:>9.3} {:>10.4} {:>11.3} {:>10.1}x | {:>11.0} {:>9.0} {:>8.0} | {:>9.1}",
                clients,
                aoi,
                r.tick_ms,
                r.copy_ms,
                r.frame_ms,
                r.share,
                r.bytes_per_client_s,
                r.in_area,
                r.deferred,
                r.sent
            );
            if a.json {
                json_line(&json!({
                    "suite": "state", "clients": clients, "aoi_m": aoi, "budget_bytes_per_s": a.budget, "hz": a.hz,
                    "tick_ms_median": r.tick_ms, "copy_ms_median": r.copy_ms, "frame_ms_median": r.frame_ms,
                    "state_work_over_core_tick": r.share, "bytes_per_client_s": r.bytes_per_client_s,
                    "bodies_in_area_mean": r.in_area, "deferred_per_frame_mean": r.deferred, "bodies_sent_per_frame_mean": r.sent,
                }));
            }
        }
    }
    Ok(())
}

struct Figures {
    tick_ms: f64,
    copy_ms: f64,
    frame_ms: f64,
    /// The state work (copy and frames) over the core's tick work, per simulated second.
    share: f64,
    bytes_per_client_s: f64,
    in_area: f64,
    deferred: f64,
    sent: f64,
}

fn one(a: &StateArgs, clients: u32, aoi: f64) -> Result<Figures> {
    progress(&format!("state: {clients} players, area {aoi} m"));
    let scene = Scene::load(&Scene::bundled_path("arena")).map_err(anyhow::Error::msg)?;
    let rule = scene.avatar.clone().context("the arena spawns avatars")?;
    let mut w = scene.world;
    let tick_hz = w.config.tick_hz;
    let mut stepper = Stepper::new(Plan::for_world(&w), false);
    let mut out = TickOutput::default();
    // Spawn the players as the server does, at tick 0.
    let spawns: Vec<SystemAction> = (0..clients)
        .map(|c| SystemAction::SpawnAvatar {
            client: ClientId(c),
            class: rule.class,
            shape: rule.shape.clone(),
            pos: avatar_position(&rule, c, 0),
        })
        .collect();
    stepper.step_with(&mut w, &spawns, &[], &mut out);
    let avatars: Vec<Watcher> = out
        .spawned
        .iter()
        .map(|(client, entity)| Watcher { client: *client, avatar: *entity, encoding: Encoding::MsgPack, full: false })
        .collect();
    let opts = StateOptions { hz: a.hz, aoi_m: aoi, bytes_per_s: a.budget, ..StateOptions::default() };
    let mut streams = Streams::new(WorldId::new("arena").map_err(anyhow::Error::msg)?, opts, Encoding::MsgPack);
    let (mut ticks, mut copies, mut frames) = (Vec::new(), Vec::new(), Vec::new());
    let (mut bytes, mut client_frames, mut deferred) = (0u64, 0u64, 0u64);
    let mut last_frame = None;
    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    for t in 1..=(a.seconds * tick_hz) {
        // Every player steers every 16 ticks (a wandering walk at up to 6 m/s).
        let inputs: Vec<TickInput> = if t % 16 == 0 {
            avatars
                .iter()
                .map(|v| {
                    let mut r = || {
                        rng ^= rng << 13;
                        rng ^= rng >> 7;
                        rng ^= rng << 17;
                        (rng >> 11) as f64 / (1u64 << 53) as f64 * 12.0 - 6.0
                    };
                    let velocity = [r(), r() * 0.3, r()];
                    TickInput::new(v.client, t, vec![Action::SetVelocity { entity: v.avatar, velocity }])
                })
                .collect()
        } else {
            Vec::new()
        };
        let t0 = Instant::now();
        stepper.step(&mut w, &inputs, &mut out);
        ticks.push(t0.elapsed());
        let frame = u64::from(t) * u64::from(a.hz) / u64::from(tick_hz);
        if last_frame == Some(frame) {
            continue;
        }
        last_frame = Some(frame);
        let t1 = Instant::now();
        let cap = Capture::of(&w, avatars.clone());
        copies.push(t1.elapsed());
        let t2 = Instant::now();
        let published = streams.frames(&cap, false, false);
        frames.push(t2.elapsed());
        for p in &published {
            bytes += p.bytes.len() as u64;
            client_frames += 1;
            deferred += u64::from(p.deferred);
        }
    }
    let tick_total: Duration = ticks.iter().sum();
    let state_total: Duration = copies.iter().chain(&frames).sum();
    let client_s = client_frames as f64 / f64::from(a.hz);
    let counts = streams.counts();
    let per_frame = |n: u64| n as f64 / counts.client_frames.max(1) as f64;
    Ok(Figures {
        tick_ms: median_ms(&mut ticks),
        copy_ms: median_ms(&mut copies),
        frame_ms: median_ms(&mut frames),
        share: state_total.as_secs_f64() / tick_total.as_secs_f64().max(1e-12),
        bytes_per_client_s: bytes as f64 / client_s.max(1e-9),
        in_area: per_frame(counts.in_area),
        deferred: deferred as f64 / client_frames.max(1) as f64,
        sent: per_frame(counts.sent),
    })
}
