//! The impact server. `--offline` runs a scene through the core with no network, writes every
//! event as a JSON line and prints the plan and the time per stage; `--offline --replay FILE`
//! re-simulates a recording and checks every state hash.

use anyhow::{bail, Context, Result};
use clap::Parser;
use impact_core::scene::settings::{Setting, Source};
use impact_core::scene::Scene;
use impact_core::sim::{Plan, Pool};
use impact_protocol::{Encoding, WorldId};
use impact_server::rollback::{RollbackConfig, StalePolicy};
use impact_server::runtime::auth::Users;
use impact_server::runtime::{self, ServerOptions};
use impact_server::{offline, recording};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// impact: an authoritative collision server for multiplayer games.
#[derive(Parser, Debug, Clone)]
#[command(version, about)]
struct Args {
    /// Scene file (TOML; see SCENES.md). Repeat it to serve several worlds from one process (one
    /// tick thread each; the world names must differ).
    #[arg(long, required_unless_present = "print_acl")]
    scene: Vec<PathBuf>,
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
    /// With --offline: re-simulate this recording (from --record) and check every state hash.
    #[arg(long, requires = "offline")]
    replay: Option<PathBuf>,
    /// Write the input log to this file: a recording `--offline --replay` reproduces. With
    /// several worlds, the path must contain `{world}`.
    #[arg(long, conflicts_with = "offline")]
    record: Option<String>,
    /// Follow each world's primary server and take over when it dies (see README, "Failover").
    #[arg(long, conflicts_with_all = ["offline", "record"])]
    standby: bool,
    /// Use the general path (GJK for every pair, no analytic kernels): for comparisons.
    #[arg(long)]
    general: bool,
    /// Zenoh endpoints to listen on (repeatable). Default: tcp/127.0.0.1:7447; with `--connect`,
    /// an ephemeral loopback port (tcp/127.0.0.1:0), so several servers on one host can join a
    /// router; with `--zenoh-config`, what the file says.
    #[arg(long)]
    listen: Vec<String>,
    /// Zenoh endpoints to connect to, e.g. a router (repeatable).
    #[arg(long)]
    connect: Vec<String>,
    /// A Zenoh configuration file (JSON5) for anything else (a router, other transports).
    #[arg(long)]
    zenoh_config: Option<PathBuf>,
    /// World name (the `{world}` key segment); default: the scene's. Only with one --scene.
    #[arg(long)]
    world: Option<String>,
    /// Ticks per second; default: the scene's.
    #[arg(long)]
    tick_hz: Option<u32>,
    /// Rollback window in milliseconds; default: the scene's (250).
    #[arg(long)]
    rollback_ms: Option<u32>,
    /// Encoding of broadcast messages.
    #[arg(long, default_value = "msgpack")]
    encoding: Encoding,
    /// Stale inputs: reject them, or clamp them to the oldest tick in the window.
    #[arg(long, default_value = "reject", value_parser = ["reject", "clamp"])]
    stale: String,
    /// How a late input is re-simulated: `selective` re-simulates only the bodies it can reach,
    /// when that is provably what re-simulating everything gives (else everything); `full`
    /// always re-simulates every body. Results are the same; only the cost differs.
    #[arg(long, default_value = "selective", value_parser = ["selective", "full"])]
    resimulate: String,
    /// Self-check: re-simulate this many past ticks every tick and count desyncs.
    #[arg(long, default_value_t = 0)]
    self_check: u32,
    /// Inputs per second one client may send.
    #[arg(long, default_value_t = 120)]
    rate_limit: u32,
    /// The tick thread's nice value, ahead of other threads and processes when a core is
    /// contended (below 0 needs CAP_SYS_NICE or root; without it the server says so and goes on).
    /// 0 leaves its priority alone.
    #[arg(long, default_value_t = impact_server::runtime::DEFAULT_TICK_NICE, allow_negative_numbers = true)]
    tick_nice: i32,
    /// Stop after this many ticks (network mode).
    #[arg(long)]
    max_ticks: Option<u64>,
    /// No per-second status line.
    #[arg(long)]
    quiet: bool,
    /// Users file (TOML, `[[user]] name, password, client`, optional `role = "logic"`): turns on
    /// Zenoh user/password authentication and access control, so each user acts, listens and
    /// appears only as its own client. See README, "Users and access control".
    #[arg(long)]
    users: Option<PathBuf>,
    /// Print the Zenoh configuration (access control and dictionary path) a zenohd router needs
    /// to enforce `--users` at the edge, and exit.
    #[arg(long, requires = "users")]
    print_acl: bool,
    /// A client with the game-logic role (repeatable), beside the users file's `role = "logic"`
    /// users: its inputs act on any body and may teleport, spawn and change classes
    /// (PROTOCOL.md, "Game logic"). Without --users, anyone can claim the id: for development.
    #[arg(long = "logic-client", value_name = "CLIENT")]
    logic_clients: Vec<u32>,
    /// Game logic may open up to this many worlds at run time (a match starting), from the
    /// started scenes (by file name) and --scene-dir's; 0: none (game logic may still close
    /// one). Give it to one server process per deployment.
    #[arg(long, default_value_t = 0)]
    open_worlds: usize,
    /// A directory of scenes game logic may open by name (`{name}.toml`), with --open-worlds.
    #[arg(long, requires = "open_worlds")]
    scene_dir: Option<PathBuf>,
    /// With --print-acl: where the router's dictionary file (one `name:password` per line) is.
    #[arg(long, default_value = "users.dict")]
    dictionary_path: String,
    /// State stream frames per second: every body on `state`, and per client the bodies near
    /// its avatar on `client/{id}/state` (PROTOCOL.md, "State streams"). 0 turns them off.
    #[arg(long, default_value_t = 20)]
    state_hz: u32,
    /// Radius of a client's area of interest around its avatar, metres. Its cost grows with the
    /// bodies inside it (BENCHMARKS.md, "State streams").
    #[arg(long, default_value_t = 10.0)]
    aoi_m: f64,
    /// Bytes per second one client's state stream may use on average (the nearest bodies go
    /// first when a frame would exceed it).
    #[arg(long, default_value_t = 32 * 1024)]
    state_budget: u32,
    /// A full state frame every this many frames; deltas between.
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u32).range(1..))]
    state_full_every: u32,
    /// Serve Prometheus metrics at http://ADDR/metrics, e.g. 127.0.0.1:9898.
    #[arg(long)]
    metrics: Option<String>,
    /// Print every `[world]` value each scene runs with and where it came from (the scene, a
    /// default and why, or a flag), and exit.
    #[arg(long)]
    explain: bool,
    /// Threads for the core's parallel stages (bounds, broadphase, narrowphase, events), shared
    /// by the process's worlds. Results never depend on it. Default 1: on the 2-core machine
    /// measured, 2 threads were faster in some runs and slower in others (BENCHMARKS.md,
    /// "Threads"); measure on yours before raising it.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=256))]
    threads: Option<u16>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    // Zenoh's own log, when RUST_LOG asks for it (e.g. RUST_LOG=zenoh_transport=debug).
    zenoh::try_init_log_from_env();
    let users = args.users.as_deref().map(impact_server::runtime::auth::load).transpose()?;
    if args.print_acl {
        let users = users.context("--print-acl needs --users")?;
        println!("{}", users.router_config(&args.dictionary_path));
        return Ok(());
    }
    if args.world.is_some() && args.scene.len() > 1 {
        bail!("--world names one world: give it with a single --scene (each scene names its own world)");
    }
    let mut scenes = Vec::new();
    for path in &args.scene {
        scenes.push((load_scene(path, &args)?, path.clone()));
    }
    if args.explain {
        for (scene, path) in &scenes {
            println!("world {} ({}), [world] as it runs:", scene.name, path.display());
            for s in &scene.settings {
                println!("  {s}");
            }
            for w in &scene.warnings {
                println!("  {w}");
            }
        }
        return Ok(());
    }
    let threads = args.threads.map_or(1, usize::from);
    let pool = Pool::new(threads).map_err(anyhow::Error::msg)?;
    if !args.offline {
        return serve(scenes, &args, users, pool);
    }
    let [(scene, path)] = <[_; 1]>::try_from(scenes).map_err(|_| anyhow::anyhow!("--offline runs one --scene"))?;
    if let Some(rec) = &args.replay {
        // The world as the recording ran it: its [world] values, not this build's defaults.
        let scene = recording::scene_for(&path, rec).map_err(anyhow::Error::msg)?;
        return replay(&scene, &path, rec, &pool);
    }
    let plan = if args.general { Plan::general(&scene.world) } else { Plan::for_world(&scene.world) };
    println!("{}", describe(&scene, &path));
    println!("{plan}");
    println!("  core threads    {} (--threads; results do not depend on it)", pool.threads());
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
        &pool,
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

/// Loads a scene and applies the command line's overrides (world name, tick rate, window).
fn load_scene(path: &Path, args: &Args) -> Result<Scene> {
    if let Some(hz) = args.tick_hz {
        if !(1..=1000).contains(&hz) {
            bail!("--tick-hz {hz} must be in 1..=1000");
        }
    }
    // The flags go in before the keys are resolved: a default that follows the tick rate follows
    // the flag's, and the window (a duration) keeps its length when only the tick rate changes.
    let mut scene = Scene::load_with(path, |w| {
        w.tick_hz = args.tick_hz.or(w.tick_hz);
        w.rollback_ms = args.rollback_ms.or(w.rollback_ms);
    })
    .map_err(anyhow::Error::msg)?;
    for w in &scene.warnings {
        eprintln!("{}: {w}", path.display());
    }
    if let Some(name) = &args.world {
        scene.name = WorldId::new(name.clone()).map_err(anyhow::Error::msg)?;
    }
    if let Some(hz) = args.tick_hz {
        overridden(&mut scene.settings, "tick_hz", hz.to_string(), "--tick-hz");
    }
    if let Some(ms) = args.rollback_ms {
        overridden(&mut scene.settings, "rollback_ms", ms.to_string(), "--rollback-ms");
    }
    Ok(scene)
}

/// Records that `flag` set `key` to `value`, for `--explain`.
fn overridden(settings: &mut [Setting], key: &str, value: String, flag: &'static str) {
    if let Some(s) = settings.iter_mut().find(|s| s.key == key) {
        *s = Setting { key: s.key, value, source: Source::Flag, why: flag.into() };
    }
}

/// `--offline --replay FILE`: re-simulates a recording and checks every state hash; fails on the
/// first tick that differs.
fn replay(scene: &Scene, path: &Path, rec: &Path, pool: &Pool) -> Result<()> {
    println!("{}", describe(scene, path));
    println!("replaying {}", rec.display());
    let tty = std::io::stderr().is_terminal();
    let mut last = Instant::now();
    let report = recording::replay(scene, rec, pool, |done| {
        if last.elapsed().as_secs_f64() >= 1.0 {
            last = Instant::now();
            if tty {
                eprint!("\r  tick {done}   ");
            } else {
                eprintln!("  tick {done}");
            }
        }
    })
    .map_err(anyhow::Error::msg)?;
    if tty {
        eprintln!();
    }
    println!("{report}");
    if report.first_mismatch.is_some() {
        bail!("the replay differs from the recording");
    }
    Ok(())
}

fn serve(scenes: Vec<(Scene, PathBuf)>, args: &Args, users: Option<Users>, pool: Pool) -> Result<()> {
    if let Some(r) = &args.record {
        if scenes.len() > 1 && !r.contains("{world}") {
            bail!("--record {r}: with several worlds the path must contain {{world}}");
        }
    }
    if !(args.aoi_m.is_finite() && args.aoi_m > 0.0) {
        bail!("--aoi-m {} must be a positive number of metres", args.aoi_m);
    }
    let state = runtime::StateOptions {
        hz: args.state_hz,
        aoi_m: args.aoi_m,
        bytes_per_s: args.state_budget,
        full_every: args.state_full_every,
    };
    let metrics = args.metrics.as_ref().map(|_| runtime::Metrics::new());
    let _metrics_server = match (&metrics, &args.metrics) {
        (Some(m), Some(addr)) => {
            let server = m.serve(addr).with_context(|| format!("--metrics {addr}: cannot listen there"))?;
            println!("metrics: http://{}/metrics", server.addr());
            Some(server)
        }
        _ => None,
    };
    // The options of a world, started now or opened by game logic later.
    let opts_for = {
        let (a, users, pool, metrics) = (args.clone(), users.clone(), pool.clone(), metrics.clone());
        move |scene: &Scene| {
            let mut rollback = RollbackConfig::for_world(&scene.world);
            rollback.selective = a.resimulate == "selective";
            rollback.self_check_ticks = a.self_check;
            rollback.stale = if a.stale == "clamp" { StalePolicy::Clamp } else { StalePolicy::Reject };
            ServerOptions {
                listen: listen_endpoints(&a),
                connect: a.connect.clone(),
                zenoh_config: a.zenoh_config.clone(),
                encoding: a.encoding,
                rollback: Some(rollback),
                inputs_per_client_per_s: a.rate_limit,
                tick_nice: a.tick_nice,
                max_ticks: a.max_ticks,
                verbose: !a.quiet,
                users: users.clone(),
                logic_clients: a.logic_clients.iter().map(|&c| impact_protocol::ClientId(c)).collect(),
                record: a.record.as_ref().map(|r| PathBuf::from(r.replace("{world}", scene.name.as_str()))),
                standby: a.standby,
                state: state.clone(),
                metrics: metrics.clone(),
                pool: pool.clone(),
                ..ServerOptions::default()
            }
        }
    };
    let mut worlds = Vec::new();
    let mut named = std::collections::BTreeMap::new();
    for (scene, path) in scenes {
        let plan = Plan::for_world(&scene.world);
        println!("impact-server: {}{}", describe(&scene, &path), if args.standby { " (standby)" } else { "" });
        println!("{plan}");
        println!("  core threads    {} (--threads; results do not depend on it)", pool.threads());
        if let Some(stem) = path.file_stem().and_then(|s| s.to_str()) {
            named.insert(stem.to_string(), path.clone());
        }
        let opts = opts_for(&scene);
        worlds.push((scene, opts));
    }
    if args.open_worlds > 0 && args.record.as_ref().is_some_and(|r| !r.contains("{world}")) {
        bail!("--record with --open-worlds: the path must contain {{world}} (each world records its own)");
    }
    let names: Vec<String> = worlds.iter().map(|(s, _)| s.name.to_string()).collect();
    let listen = match worlds.first().map(|(_, o)| o.listen.join(", ")).unwrap_or_default() {
        l if !l.is_empty() => l,
        _ => "what the Zenoh configuration file says".to_string(),
    };
    let loader_args = args.clone();
    let host = runtime::HostOptions {
        open_worlds: args.open_worlds,
        scenes: named,
        scene_dir: args.scene_dir.clone(),
        load: std::sync::Arc::new(move |p: &Path| load_scene(p, &loader_args).map_err(|e| format!("{e:#}"))),
        options: std::sync::Arc::new(opts_for),
    };
    let host = runtime::Host::start(worlds, host)?;
    let keys: Vec<String> = names.iter().map(|n| format!("impact/v1/{n}/...")).collect();
    println!("listening on {listen} as {}  (Ctrl-C or SIGTERM to stop)", keys.join(", "));
    if args.open_worlds > 0 {
        let dir = args.scene_dir.as_ref().map_or(String::new(), |d| format!(" and {}/*.toml", d.display()));
        println!("game logic may open up to {} worlds from the scenes above{dir}", args.open_worlds);
    }
    if !args.connect.is_empty() {
        println!("connecting to {}", args.connect.join(", "));
    }
    if let Some(u) = &users {
        println!("access control: {} users, default deny (user/password authentication required)", u.users.len());
    }
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    let mut fenced = Vec::new();
    for (world, summary) in host.run_until(&stop) {
        if summary.fenced_by.is_some() {
            println!("world {world} stopped: another server owns it\n{summary}");
            fenced.push(world.to_string());
        } else {
            println!("world {world} stopped: final confirmed events published\n{summary}");
        }
    }
    if !fenced.is_empty() {
        // For a supervisor: this process lost its worlds to a newer owner (a standby that took
        // over while it stood still); restart it with --standby.
        eprintln!("impact-server: exiting with status 3: another server owns {}", fenced.join(", "));
        std::process::exit(3);
    }
    Ok(())
}

/// Where the server listens: `--listen` if given; what the configuration file says with
/// `--zenoh-config`; with `--connect`, an ephemeral port on loopback, so that several servers on
/// one host join one router without fighting over a port, while the peers on that host (a
/// standby, a tool) still reach it directly, as Zenoh peers expect to (a router does not relay
/// between two peers; a peer that listened nowhere could not be followed); otherwise the default,
/// tcp/127.0.0.1:7447.
fn listen_endpoints(args: &Args) -> Vec<String> {
    if !args.listen.is_empty() {
        args.listen.clone()
    } else if args.zenoh_config.is_some() {
        Vec::new()
    } else if !args.connect.is_empty() {
        vec!["tcp/127.0.0.1:0".to_string()]
    } else {
        vec!["tcp/127.0.0.1:7447".to_string()]
    }
}

/// One line about the scene: name, file, bodies, tick rate and rollback window.
fn describe(scene: &Scene, path: &Path) -> String {
    let w = &scene.world;
    format!(
        "world {} ({}): {} dynamic and {} static bodies{}, {} Hz, rollback window {} ticks",
        scene.name,
        path.display(),
        w.bodies.len(),
        w.statics.id.len(),
        if w.statics.terrain.is_some() { ", terrain" } else { "" },
        w.config.tick_hz,
        w.config.window_ticks
    )
}
