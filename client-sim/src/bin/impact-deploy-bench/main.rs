//! impact-deploy-bench: deployment benchmarks with real processes. zenohd routers (from
//! `scripts/zenohd`) and `impact-server` processes of this build, simulated clients in this
//! process. Each suite prints a table and one JSON object per line (`"suite"`, then its figures).
//!
//! - `router`: the same load through one router and directly, in alternating rounds.
//! - `mesh`: clients in separate sessions, half on each of two meshed routers.
//! - `failover`: a primary killed with SIGKILL under load, its standby taking over, N times.
//! - `replay`: a load test recorded with `--record`, replayed offline, every hash checked.
//! - `players`: what a watching player costs the server, the server on one CPU and the load on
//!   another (`players.rs`).
//! - `gateway`: what a browser player costs impact-gateway (on a CPU of its own) and what it adds
//!   to an input's round trip over Zenoh's path, measured side by side (`gateway.rs`).

mod gateway;
mod players;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use impact_client::netsim::Link;
use impact_client_sim::load::{self, Behaviour, LoadConfig};
use impact_client_sim::net::{self, Mode};
use impact_client_sim::process::{binary, zenohd, Proc};
use impact_client_sim::report::Report;
use impact_client_sim::timing::Timing;
use impact_protocol::{keys, Encoding, ServerMessage, Tick, WorldId};
use serde_json::json;
use std::process::Command;
use std::sync::mpsc::sync_channel;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// Deployment benchmarks for impact.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    #[command(subcommand)]
    suite: Suite,
}

#[derive(Subcommand, Debug)]
enum Suite {
    /// Clients through one zenohd router against connected to the server directly.
    Router {
        /// Clients.
        #[arg(long, default_value_t = 1000)]
        clients: u32,
        /// Seconds of load per run.
        #[arg(long, default_value_t = 30)]
        seconds: u64,
        /// Rounds (each runs direct, then through the router).
        #[arg(long, default_value_t = 3)]
        rounds: u32,
    },
    /// Matches on two meshed routers: `--worlds` arenas (`--balls` each) served by two server
    /// processes (one per router), their players in a Zenoh session each, every other world's
    /// players on the router its server is not on (crossing the mesh).
    Mesh {
        /// Clients in all.
        #[arg(long, default_value_t = 2000)]
        clients: u32,
        /// Worlds (matches), split between the two servers.
        #[arg(long, default_value_t = 4)]
        worlds: u32,
        /// Balls in each arena.
        #[arg(long, default_value_t = 250)]
        balls: u32,
        /// Seconds of load.
        #[arg(long, default_value_t = 30)]
        seconds: u64,
    },
    /// A primary killed with SIGKILL under load and its standby taking over, `--kills` times.
    Failover {
        /// Clients (through a router).
        #[arg(long, default_value_t = 500)]
        clients: u32,
        /// Kills (each with a fresh router, primary and standby).
        #[arg(long, default_value_t = 5)]
        kills: u32,
        /// Stop the primary with SIGSTOP instead (a host that stops answering with its sockets
        /// open): the router's lease decides when it is gone. It is killed after the run.
        #[arg(long)]
        hang: bool,
    },
    /// A load test recorded with `--record`, then replayed offline, every hash checked.
    Replay {
        /// Clients.
        #[arg(long, default_value_t = 1000)]
        clients: u32,
        /// Seconds of recorded load.
        #[arg(long, default_value_t = 60)]
        seconds: u64,
    },
    /// What a watching player costs: the server on one CPU, the load on another, by player count
    /// with and without state streams.
    Players(players::Players),
    /// What a browser player costs impact-gateway, on a CPU of its own, and what it adds to the
    /// input-to-ack round trip beside players on Zenoh directly.
    Gateway(gateway::GatewayBench),
}

fn main() -> Result<()> {
    match Args::parse().suite {
        Suite::Router { clients, seconds, rounds } => router(clients, seconds, rounds),
        Suite::Mesh { clients, worlds, balls, seconds } => mesh(clients, worlds, balls, seconds),
        Suite::Failover { clients, kills, hang } => failover(clients, kills, hang),
        Suite::Replay { clients, seconds } => replay(clients, seconds),
        Suite::Players(p) => players::players(&p),
        Suite::Gateway(g) => gateway::gateway(&g),
    }
}

fn endpoint() -> String {
    let port = std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).map(|a| a.port());
    format!("tcp/127.0.0.1:{}", port.expect("a free port"))
}

fn progress(msg: &str) {
    eprintln!("  .. {msg}");
}

/// The arena server on `listen`, connected to `connect` if given.
fn server(name: &str, listen: &str, connect: Option<&str>, extra: &[&str]) -> Result<Proc> {
    server_on(name, listen, connect, extra, None)
}

/// The same, kept on one CPU when `cpu` is given (`taskset`, as an operator would).
fn server_on(name: &str, listen: &str, connect: Option<&str>, extra: &[&str], cpu: Option<usize>) -> Result<Proc> {
    let mut cmd = match cpu {
        Some(c) => {
            let mut t = Command::new("taskset");
            t.args(["--cpu-list", &c.to_string()]).arg(binary("impact-server"));
            t
        }
        None => Command::new(binary("impact-server")),
    };
    cmd.arg("--scene").arg(impact_core::scene::Scene::bundled_path("arena")).args(["--listen", listen]);
    if let Some(c) = connect {
        cmd.args(["--connect", c]);
    }
    cmd.args(extra);
    let p = Proc::spawn(name, cmd);
    if !p.wait_for_output("listening on", Duration::from_secs(30)) {
        bail!("{name} did not start:\n{}", p.output());
    }
    Ok(p)
}

/// A router listening on `listen`, meshed with `connect`.
fn router_proc(name: &str, listen: &str, connect: &[String]) -> Proc {
    let p = Proc::router(name, listen, connect);
    std::thread::sleep(Duration::from_millis(400));
    p
}

/// Seconds of CPU (user + system) a process has used.
fn cpu_s(pid: u32) -> f64 {
    stat_cpu_s(&std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default())
}

/// Seconds of CPU (user + system) in a `/proc/.../stat` line (a process's or a thread's).
fn stat_cpu_s(stat: &str) -> f64 {
    // Fields after the command's closing parenthesis: utime is the 12th, stime the 13th.
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

/// The load every suite runs: the arena's mixed players, no simulated network (latency is the
/// real path's), ahead timing.
fn load_cfg(connect: &str, clients: u32, first: u32, sessions: u32, seconds: u64) -> LoadConfig {
    let link = Link { latency: Duration::ZERO, jitter: Duration::ZERO, loss: 0.0 };
    LoadConfig {
        connect: vec![connect.to_string()],
        zenoh_config: None,
        mode: Mode::Client,
        world: WorldId::new("arena").expect("name"),
        clients,
        first_client: first,
        sessions,
        users: None,
        duration: Duration::from_secs(seconds),
        uplink: link,
        downlink: link,
        behaviour: Behaviour::Mixed,
        timing: Timing::Ahead,
        input_hz: 10.0,
        encoding: Encoding::MsgPack,
        seed: u64::from(first),
        settle: Duration::from_secs(2),
        progress: false,
        faults: Default::default(),
        state: false,
        predict: 0,
        scene: None,
    }
}

fn row(name: &str, r: &Report, extra: &str) {
    println!(
        "{name:<28} {:>6} {:>9.2} {:>9.2} {:>9.0} {:>8} {:>9.2} {extra}",
        r.clients_welcomed,
        r.latency_ms_p50,
        r.latency_ms_p99,
        r.events_per_s,
        r.inputs_unanswered,
        r.server_tick_ms_p99
    );
}

fn header(extra: &str) {
    println!(
        "{:<28} {:>6} {:>9} {:>9} {:>9} {:>8} {:>9} {extra}",
        "run", "joined", "ack p50", "ack p99", "events/s", "unansw.", "tick p99"
    );
}

fn report_json(suite: &str, mode: &str, r: &Report, extra: serde_json::Value) {
    let mut v = json!({
        "suite": suite, "mode": mode, "clients": r.clients, "sessions": r.sessions, "welcomed": r.clients_welcomed,
        "ack_ms_p50": r.latency_ms_p50, "ack_ms_p99": r.latency_ms_p99, "ack_ms_max": r.latency_ms_max,
        "events_per_s": r.events_per_s, "acks": r.acks, "unanswered": r.inputs_unanswered,
        "views_matched": r.views_matched, "views_differed": r.views_mismatched,
        "server_tick_ms_p99": r.server_tick_ms_p99,
    });
    if let (Some(o), serde_json::Value::Object(e)) = (v.as_object_mut(), extra) {
        o.extend(e);
    }
    println!("{v}");
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => (v[n / 2 - 1] + v[n / 2]) / 2.0,
    }
}

fn router(clients: u32, seconds: u64, rounds: u32) -> Result<()> {
    let zenohd = zenohd();
    progress(&format!("zenohd: {}", zenohd.display()));
    println!("router: {clients} clients ({} sessions), {seconds} s per run, {rounds} rounds", clients.div_ceil(100));
    header("router cpu");
    let (mut direct, mut routed) = (Vec::new(), Vec::new());
    for round in 1..=rounds {
        for via_router in [false, true] {
            let name = if via_router { "router" } else { "direct" };
            progress(&format!("round {round}: {name}"));
            let listen = endpoint();
            let (router, connect) = if via_router {
                let r = endpoint();
                (Some(router_proc("bench-router", &r, &[])), r)
            } else {
                (None, listen.clone())
            };
            let mut srv = server("bench-server", &listen, via_router.then_some(connect.as_str()), &["--quiet"])?;
            let cpu0 = router.as_ref().map_or(0.0, |r| cpu_s(r.pid()));
            let t0 = Instant::now();
            let r = load::run(&load_cfg(&connect, clients, 1000, clients.div_ceil(100), seconds))?;
            let cpu = router.as_ref().map(|p| (cpu_s(p.pid()) - cpu0) / t0.elapsed().as_secs_f64() * 100.0);
            srv.stop();
            let extra = cpu.map_or(String::new(), |c| format!("{c:.0} %"));
            row(&format!("{name} (round {round})"), &r, &extra);
            report_json("router", name, &r, json!({ "round": round, "router_cpu_pct": cpu }));
            if via_router {
                routed.push((r, cpu.unwrap_or(0.0)));
            } else {
                direct.push(r);
            }
        }
    }
    let p99 = |v: &[&Report]| median(v.iter().map(|r| r.latency_ms_p99).collect());
    let p50 = |v: &[&Report]| median(v.iter().map(|r| r.latency_ms_p50).collect());
    let d: Vec<&Report> = direct.iter().collect();
    let rt: Vec<&Report> = routed.iter().map(|(r, _)| r).collect();
    let cpu = median(routed.iter().map(|(_, c)| *c).collect());
    println!(
        "median of {rounds}: ack p50 {:.2} -> {:.2} ms, p99 {:.2} -> {:.2} ms (router adds {:+.2} ms at p99; target <= 2 ms), router cpu {cpu:.0} %",
        p50(&d),
        p50(&rt),
        p99(&d),
        p99(&rt),
        p99(&rt) - p99(&d)
    );
    println!(
        "{}",
        json!({ "suite": "router", "summary": true, "clients": clients, "rounds": rounds,
            "direct_ack_ms_p50": p50(&d), "router_ack_ms_p50": p50(&rt),
            "direct_ack_ms_p99": p99(&d), "router_ack_ms_p99": p99(&rt),
            "router_p99_added_ms": p99(&rt) - p99(&d), "router_cpu_pct": cpu })
    );
    Ok(())
}

fn mesh(clients: u32, worlds: u32, balls: u32, seconds: u64) -> Result<()> {
    let _ = zenohd();
    let (r1, r2) = (endpoint(), endpoint());
    let router1 = router_proc("mesh-r1", &r1, &[]);
    let router2 = router_proc("mesh-r2", &r2, std::slice::from_ref(&r1));
    let routers = [&r1, &r2];
    // The matches: the arena with its name and ball count changed.
    let arena = std::fs::read_to_string(impact_core::scene::Scene::bundled_path("arena"))?;
    let dir = std::env::temp_dir().join(format!("impact-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let mut files = [Vec::new(), Vec::new()];
    for w in 0..worlds {
        let text = arena.replacen("name = \"arena\"", &format!("name = \"match{w}\""), 1).replacen(
            "count = 2000",
            &format!("count = {balls}"),
            1,
        );
        let f = dir.join(format!("match{w}.toml"));
        std::fs::write(&f, text)?;
        files[(w % 2) as usize].push(f);
    }
    let mut servers = Vec::new();
    for (k, list) in files.iter().enumerate() {
        let mut cmd = Command::new(binary("impact-server"));
        for f in list {
            cmd.arg("--scene").arg(f);
        }
        cmd.args(["--listen", &endpoint(), "--connect", routers[k], "--quiet"]);
        let p = Proc::spawn(&format!("mesh-server{k}"), cmd);
        if !p.wait_for_output("listening on", Duration::from_secs(30)) {
            bail!("a server did not start:\n{}", p.output());
        }
        servers.push(p);
    }
    let per = clients / worlds.max(1);
    println!(
        "mesh: {clients} clients in a session each, {worlds} worlds of {balls} balls and {per} players on two servers, one per router"
    );
    progress(&format!("opening {clients} sessions"));
    let cpu0 = (cpu_s(router1.pid()), cpu_s(router2.pid()));
    let t0 = Instant::now();
    let runs: Vec<_> = (0..worlds)
        .map(|w| {
            // World w is served on router w % 2; odd and even players cross the mesh by turns.
            let router = routers[((w / 2 + w) % 2) as usize].clone();
            let mut cfg = load_cfg(&router, per, 1000 + w * per, per, seconds);
            cfg.world = WorldId::new(format!("match{w}")).expect("name");
            let crosses = ((w / 2 + w) % 2) != w % 2;
            (w, crosses, std::thread::spawn(move || load::run(&cfg)))
        })
        .collect();
    let mut results = Vec::new();
    for (w, crosses, h) in runs {
        let r = h.join().map_err(|_| anyhow::anyhow!("world {w}'s clients panicked"))??;
        results.push((w, crosses, r));
    }
    let wall = t0.elapsed().as_secs_f64();
    let cpu = ((cpu_s(router1.pid()) - cpu0.0) / wall * 100.0, (cpu_s(router2.pid()) - cpu0.1) / wall * 100.0);
    for s in &mut servers {
        s.stop();
    }
    let _ = std::fs::remove_dir_all(&dir);
    header("");
    for (w, crosses, r) in &results {
        let how = if *crosses { "across the mesh" } else { "its server's router" };
        row(&format!("match{w} ({how})"), r, "");
        report_json("mesh", &format!("match{w}"), r, json!({ "crosses_mesh": crosses, "balls": balls }));
    }
    println!("router cpu: {:.0} % and {:.0} %", cpu.0, cpu.1);
    let all: Vec<&Report> = results.iter().map(|(_, _, r)| r).collect();
    println!(
        "{}",
        json!({ "suite": "mesh", "summary": true, "clients": clients, "sessions": clients, "worlds": worlds,
            "welcomed": all.iter().map(|r| r.clients_welcomed).sum::<u32>(),
            "ack_ms_p99_worst": all.iter().map(|r| r.latency_ms_p99).fold(0.0, f64::max),
            "unanswered": all.iter().map(|r| r.inputs_unanswered).sum::<u64>(),
            "router1_cpu_pct": cpu.0, "router2_cpu_pct": cpu.1 })
    );
    Ok(())
}

/// What a failover run saw on the log stream: `(tick, when, inputs as (client, seq))` of every
/// entry, in arrival order.
type Seen = Vec<(Tick, Instant, Vec<(u32, u32)>)>;

fn failover(clients: u32, kills: u32, hang: bool) -> Result<()> {
    let _ = zenohd();
    let how =
        if hang { "stopped with SIGSTOP (a hung host: the router's lease decides)" } else { "killed with SIGKILL" };
    println!("failover: {clients} clients through a router, primary {how} 8 s into the load, {kills} times");
    println!(
        "{:<6} {:>9} {:>11} {:>9} {:>11} {:>11} {:>9} {:>10} {:>9}",
        "kill", "gap ms", "ticks lost", "repeated", "re-applied", "acked lost", "unansw.", "views bad", "ack p99"
    );
    let mut gaps = Vec::new();
    for k in 1..=kills {
        let r = endpoint();
        let _router = router_proc("failover-router", &r, &[]);
        let primary = server("failover-primary", &endpoint(), Some(&r), &["--quiet"])?;
        let mut standby = server("failover-standby", &endpoint(), Some(&r), &["--standby"])?;
        if !standby.wait_for_output("following from the checkpoint", Duration::from_secs(20)) {
            bail!("the standby never followed:\n{}", standby.output());
        }
        // The log, seen from a session of its own.
        let s = net::open(std::slice::from_ref(&r), None, None, Mode::Client)?;
        let (tx, rx) = sync_channel(1_000_000);
        let _sub = s
            .declare_subscriber(keys::LOG.key(&WorldId::new("arena")?, None))
            .callback(move |sample| {
                if let Ok(ServerMessage::Log(l)) = net::decode_server(&sample) {
                    let inputs = l.inputs.iter().map(|i| (i.client.0, i.seq)).collect();
                    let _ = tx.try_send((l.tick, Instant::now(), inputs));
                }
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let cfg = load_cfg(&r, clients, 1000, clients.div_ceil(100), 16);
        let load = std::thread::spawn(move || load::run(&cfg));
        std::thread::sleep(Duration::from_secs(8));
        primary.signal(if hang { "STOP" } else { "KILL" });
        let killed = Instant::now();
        // A stopped primary resumes 4 s later, under the load, after its standby took over: it
        // must hold, hear the newer owner and exit with status 3, publishing nothing.
        let mut primary = primary;
        let resumed = if hang {
            std::thread::sleep(Duration::from_secs(4));
            primary.signal("CONT");
            Some(Instant::now())
        } else {
            None
        };
        let report = load.join().map_err(|_| anyhow::anyhow!("load panicked"))??;
        let old_exit = primary.wait(Duration::from_secs(5)).and_then(|x| x.code());
        primary.signal("KILL");
        standby.stop();
        let out = standby.output();
        std::thread::sleep(Duration::from_millis(300));
        let seen: Seen = rx.try_iter().collect();
        let gap = seen.iter().find(|(_, at, _)| *at > killed).map(|(_, at, _)| (*at - killed).as_secs_f64() * 1e3);
        let Some(gap) = gap else { bail!("kill {k}: no tick after the kill:\n{out}") };
        let (mut lost, mut repeated) = (0u64, 0u64);
        for w in seen.windows(2) {
            let (a, b) = (w[0].0 .0, w[1].0 .0);
            if b <= a {
                repeated += 1;
                eprintln!("  kill {k}: log tick {b} came after {a}");
            } else if b > a + 1 {
                lost += u64::from(b - a - 1);
                eprintln!(
                    "  kill {k}: log ticks {}..{} never came ({:.0} ms after the kill)",
                    a + 1,
                    b - 1,
                    w[1].1.saturating_duration_since(killed).as_secs_f64() * 1e3
                );
            }
        }
        let reapplied = out
            .lines()
            .find(|l| l.contains("acked inputs re-applied"))
            .and_then(|l| l.split(" acked inputs re-applied").next())
            .and_then(|l| l.rsplit(' ').next())
            .and_then(|n| n.parse::<u64>().ok())
            .context("the standby did not take over")?;
        let differed = out.contains("(0 hashes differed)");
        if let Some(at) = resumed {
            let after = seen.iter().filter(|(_, t, _)| *t > at).count();
            let old = primary.output();
            let fenced = old.contains("another server owns it now");
            eprintln!(
                "  kill {k}: the primary resumed: {} (exit status {old_exit:?}); {after} log entries after it, {} \
                 messages of the old owner dropped by the players",
                if fenced { "fenced" } else { "NOT fenced" },
                report.stale_owner
            );
        }
        // Every acked input is in the confirmed log once: the log holds only acked inputs, so
        // as many distinct ones as acks, and none twice.
        let logged: Vec<(u32, u32)> = seen.iter().flat_map(|(_, _, i)| i.iter().copied()).collect();
        let distinct: std::collections::BTreeSet<(u32, u32)> = logged.iter().copied().collect();
        let unaccounted = report.acks.saturating_sub(distinct.len() as u64);
        let logged_twice = logged.len() - distinct.len();
        println!(
            "{k:<6} {gap:>9.1} {lost:>11} {repeated:>9} {reapplied:>11} {unaccounted:>11} {:>9} {:>10} {:>9.2}",
            report.inputs_unanswered, report.views_mismatched, report.latency_ms_p99
        );
        println!(
            "{}",
            json!({ "suite": "failover", "kill": k, "clients": clients, "gap_ms": gap, "confirmed_ticks_lost": lost,
                "confirmed_ticks_repeated": repeated, "hang": hang, "acked_inputs_reapplied": reapplied,
                "acks": report.acks, "acked_inputs_unaccounted": unaccounted, "inputs_logged_twice": logged_twice,
                "inputs_unanswered": report.inputs_unanswered, "views_matched": report.views_matched,
                "views_differed": report.views_mismatched, "standby_hashes_equal": differed,
                "ack_ms_p99": report.latency_ms_p99, "resumed_primary_exit": old_exit,
                "stale_owner_dropped": report.stale_owner })
        );
        gaps.push(gap);
    }
    let m = median(gaps.clone());
    println!(
        "median gap from the {} to the standby's first tick: {m:.1} ms over {kills} runs (target < 2000 ms)",
        if hang { "SIGSTOP" } else { "SIGKILL" }
    );
    println!(
        "{}",
        json!({ "suite": "failover", "summary": true, "kills": kills, "gap_ms_median": m, "gap_ms_max": gaps.iter().cloned().fold(0.0, f64::max) })
    );
    Ok(())
}

fn replay(clients: u32, seconds: u64) -> Result<()> {
    let file = std::env::temp_dir().join(format!("impact-bench-recording-{}.jsonl", std::process::id()));
    let listen = endpoint();
    let rec = file.to_string_lossy().to_string();
    let mut srv = server("replay-server", &listen, None, &["--quiet", "--record", &rec])?;
    progress(&format!("recording {seconds} s of {clients} clients into {rec}"));
    let r = load::run(&load_cfg(&listen, clients, 1000, clients.div_ceil(100), seconds))?;
    srv.stop();
    let size = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
    progress("replaying");
    let t0 = Instant::now();
    let out = Command::new(binary("impact-server"))
        .arg("--scene")
        .arg(impact_core::scene::Scene::bundled_path("arena"))
        .args(["--offline", "--replay", &rec])
        .output()?;
    let secs = t0.elapsed().as_secs_f64();
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let _ = std::fs::remove_file(&file);
    let line = text.lines().find(|l| l.starts_with("replayed world")).unwrap_or("").to_string();
    let verdict = text.lines().find(|l| l.contains("state hash")).unwrap_or("").to_string();
    println!("replay: {clients} clients for {seconds} s, {} acks; recording {:.1} MB", r.acks, size as f64 / 1e6);
    println!("{line}\n{verdict}");
    let ok = out.status.success() && verdict.starts_with("every recorded state hash reproduced");
    println!(
        "{}",
        json!({ "suite": "replay", "clients": clients, "seconds": seconds, "acks": r.acks, "recording_bytes": size,
            "replay_s": secs, "summary": line, "all_hashes_reproduced": ok })
    );
    if !ok {
        bail!("the replay did not reproduce every hash:\n{text}");
    }
    Ok(())
}
