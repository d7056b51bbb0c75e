//! `gateway`: what a browser player costs `impact-gateway`, and what the gateway adds to an
//! input's round trip.
//!
//! The gateway runs on a CPU of its own (`taskset`); the server and this process share the
//! other. Here `--connections` players speak the WebSocket binding as a browser does (MessagePack
//! binary frames, a token in the hello, the state stream on), each a client library `Session` on
//! a Tokio task, and `--zenoh` players speak Zenoh to the server directly, each a `Session` on a
//! `Connection`, at the same time: the same server, tick and load, so the difference between the
//! two paths' input-to-ack round trips is the gateway's (and the WebSocket's) share. Both
//! measure an answer from the instant its input was handed to the socket or Zenoh to the
//! instant the answer arrived (the `Session`'s `Answer::round_trip`, stamped on arrival). The
//! gateway's CPU is read from the OS over the steady window, its memory per connection is its
//! resident memory under load less the same before anyone connected, and its drops come from its
//! `/stats`, as does its own share of the latency: how long answers and events stayed in it, from
//! their sample's arrival to their write to the socket ("in-gw", since it started). Each round starts a fresh server and gateway.

use super::{cpu_s, endpoint, median, progress, server_on};
use anyhow::{bail, Context, Result};
use futures_util::{SinkExt, StreamExt};
use impact_client::session::{Outcome, Session, SessionConfig, Status};
use impact_client::transport::{open_session, ConnectOptions, Connection, Mode};
use impact_client_sim::process::{binary, rss_mib, Proc};
use impact_gateway::token::{unix_now, Grant, Secret};
use impact_protocol::{Action, ClientId, Encoding, ServerMessage, WorldId};
use serde_json::json;
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

/// What the suite runs.
#[derive(clap::Args, Debug)]
pub struct GatewayBench {
    /// Players through the gateway (WebSocket).
    #[arg(long, default_value_t = 500)]
    connections: u32,
    /// Players on Zenoh directly, beside them, for the round trip without the gateway.
    #[arg(long, default_value_t = 50)]
    zenoh: u32,
    /// Rounds, each with a fresh server and gateway.
    #[arg(long, default_value_t = 3)]
    rounds: u32,
    /// Seconds of load per round.
    #[arg(long, default_value_t = 30)]
    seconds: u64,
    /// Seconds after the load starts before anything is counted (the players join and sync).
    #[arg(long, default_value_t = 10)]
    warmup: u64,
    /// Inputs a second per player.
    #[arg(long, default_value_t = 10.0)]
    input_hz: f64,
    /// The gateway's CPU.
    #[arg(long, default_value_t = 1)]
    gateway_cpu: usize,
    /// The CPU of the server and of this process (the players).
    #[arg(long, default_value_t = 0)]
    load_cpu: usize,
}

/// One round's figures.
struct Round {
    /// Input-to-ack round trips after the warm-up, ms: through the gateway, and on Zenoh.
    ws_ms: Vec<f64>,
    zenoh_ms: Vec<f64>,
    /// Players that played (welcomed and acked) on each path.
    ws_playing: u32,
    zenoh_playing: u32,
    /// The gateway's CPU over the steady window, cores.
    cores: f64,
    /// Its resident memory before anyone connected and at the end, MiB.
    rss_idle: f64,
    rss_loaded: f64,
    /// Its counters at the end (`/stats`).
    stats: serde_json::Value,
    /// How late the WebSocket players' loops ran (their input timers), p99 ms: a load generator that
    /// keeps up stays within a few ms, and its round trips are the path's.
    load_lag_ms_p99: f64,
    /// The same, median.
    load_lag_ms_p50: f64,
}

/// A microsecond count from the gateway's `/stats`.
fn us(v: &serde_json::Value) -> f64 {
    v.as_u64().map_or(f64::NAN, |x| x as f64)
}

/// Percentile `q` of `v` (sorted here), NaN when empty.
fn pct(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    v[((v.len() - 1) as f64 * q).round() as usize]
}

pub fn gateway(a: &GatewayBench) -> Result<()> {
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    if a.gateway_cpu == a.load_cpu || a.gateway_cpu.max(a.load_cpu) >= cpus {
        bail!("the gateway and the load need a CPU each (this machine has {cpus}): --gateway-cpu, --load-cpu");
    }
    impact_server::runtime::pin_to_cpu(a.load_cpu).map_err(anyhow::Error::msg)?;
    println!(
        "gateway: the arena at 64 Hz with state streams; {} players through impact-gateway (WebSocket) and {} on \
         Zenoh directly, {} inputs/s each; the gateway on CPU {}, the server and the players on CPU {}; {} s a \
         round, counted from {} s",
        a.connections, a.zenoh, a.input_hz, a.gateway_cpu, a.load_cpu, a.seconds, a.warmup
    );
    println!(
        "{:>5} {:>9} {:>9} {:>10} {:>10} {:>10} {:>10} {:>9} {:>7} {:>9} {:>10} {:>9} {:>8} {:>13}",
        "round",
        "ws play",
        "zen play",
        "ws p50 ms",
        "ws p99 ms",
        "zen p50",
        "zen p99",
        "added p99",
        "cores",
        "us/s/conn",
        "KiB/conn",
        "st drops",
        "lag p99",
        "in-gw p50/99"
    );
    let mut rounds = Vec::new();
    for round in 1..=a.rounds {
        progress(&format!("round {round}"));
        let r = one(a, round)?;
        let (mut ws, mut zn) = (r.ws_ms.clone(), r.zenoh_ms.clone());
        let (ws50, ws99, zn50, zn99) = (pct(&mut ws, 0.5), pct(&mut ws, 0.99), pct(&mut zn, 0.5), pct(&mut zn, 0.99));
        let n = f64::from(a.connections.max(1));
        let us_per_conn = r.cores * 1e6 / n;
        let kib_per_conn = (r.rss_loaded - r.rss_idle) * 1024.0 / n;
        let drops = r.stats["state_dropped"].as_u64().unwrap_or(0);
        println!(
            "{round:>5} {:>9} {:>9} {ws50:>10.2} {ws99:>10.2} {zn50:>10.2} {zn99:>10.2} {:>9.2} {:>7.3} {us_per_conn:>9.1} \
             {kib_per_conn:>10.1} {drops:>9} {:>8.1} {:>13}",
            r.ws_playing,
            r.zenoh_playing,
            ws99 - zn99,
            r.cores,
            r.load_lag_ms_p99,
            format!("{:.2}/{:.2}", us(&r.stats["relay_us_p50"]) / 1e3, us(&r.stats["relay_us_p99"]) / 1e3)
        );
        println!(
            "{}",
            json!({
                "suite": "gateway", "round": round, "connections": a.connections, "zenoh_players": a.zenoh,
                "ws_playing": r.ws_playing, "zenoh_playing": r.zenoh_playing,
                "ws_ack_ms_p50": ws50, "ws_ack_ms_p99": ws99, "zenoh_ack_ms_p50": zn50, "zenoh_ack_ms_p99": zn99,
                "added_ack_ms_p99": ws99 - zn99, "ws_acks": r.ws_ms.len(), "zenoh_acks": r.zenoh_ms.len(),
                "gateway_cores": r.cores, "gateway_us_per_s_per_connection": us_per_conn,
                "gateway_rss_idle_mib": r.rss_idle, "gateway_rss_loaded_mib": r.rss_loaded,
                "gateway_kib_per_connection": kib_per_conn, "gateway_stats": r.stats,
                "load_lag_ms_p50": r.load_lag_ms_p50, "load_lag_ms_p99": r.load_lag_ms_p99,
            })
        );
        rounds.push((ws99 - zn99, ws99, zn99, us_per_conn, kib_per_conn));
    }
    let col = |f: fn(&(f64, f64, f64, f64, f64)) -> f64| median(rounds.iter().map(f).collect());
    let (added, ws99, zn99, us, kib) = (col(|r| r.0), col(|r| r.1), col(|r| r.2), col(|r| r.3), col(|r| r.4));
    println!(
        "median of {} rounds: input-to-ack p99 {ws99:.2} ms through the gateway, {zn99:.2} ms on Zenoh: the gateway \
         adds {added:.2} ms (target at most 2); {us:.1} us of CPU a second and {kib:.1} KiB per connection",
        rounds.len()
    );
    println!(
        "{}",
        json!({"suite": "gateway", "summary": true, "rounds": rounds.len(), "connections": a.connections,
               "added_ack_ms_p99": added, "ws_ack_ms_p99": ws99, "zenoh_ack_ms_p99": zn99,
               "gateway_us_per_s_per_connection": us, "gateway_kib_per_connection": kib})
    );
    Ok(())
}

/// One round: a fresh server and gateway, both kinds of player at once.
fn one(a: &GatewayBench, round: u32) -> Result<Round> {
    let listen = endpoint();
    let mut srv = server_on("gateway-server", &listen, None, &["--quiet", "--state-hz", "20"], Some(a.load_cpu))?;
    let dir = std::env::temp_dir().join(format!("impact-gateway-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let secret_file = dir.join("secret");
    let secret_bytes = format!("impact-deploy-bench gateway round {round} secret of 32+ bytes");
    std::fs::write(&secret_file, &secret_bytes)?;
    let secret = Secret::new(secret_bytes.as_bytes()).map_err(anyhow::Error::msg)?;
    let mut cmd = Command::new("taskset");
    cmd.args(["--cpu-list", &a.gateway_cpu.to_string()]).arg(binary("impact-gateway"));
    cmd.args(["--listen", "127.0.0.1:0", "--connect", &listen, "--threads", "1", "--report-s", "0"])
        .arg("--token-secret")
        .arg(&secret_file)
        .args(["--max-connections", &(a.connections + 16).to_string()]);
    let mut gw = Proc::spawn("gateway", cmd);
    if !gw.wait_for_output("listening on http://", Duration::from_secs(30)) {
        bail!("the gateway did not start:\n{}", gw.output());
    }
    let out = gw.output();
    let addr = out
        .split("listening on http://")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .context("the gateway's address")?
        .to_string();
    std::thread::sleep(Duration::from_millis(500));
    let rss_idle = rss_mib(gw.pid());

    let started = Instant::now();
    let (warm, end) = (started + Duration::from_secs(a.warmup), started + Duration::from_secs(a.seconds));
    let world = WorldId::new("arena")?;
    let every = Duration::from_secs_f64(1.0 / a.input_hz.max(0.1));
    // The Zenoh players, on a thread of their own.
    let zenoh = {
        let (listen, world, n) = (listen.clone(), world.clone(), a.zenoh);
        std::thread::spawn(move || zenoh_players(&listen, &world, n, every, warm, end))
    };
    // The gateway's CPU over the steady window.
    let pid = gw.pid();
    let cpu = std::thread::spawn(move || {
        std::thread::sleep(warm.saturating_duration_since(Instant::now()));
        let c0 = cpu_s(pid);
        let t0 = Instant::now();
        std::thread::sleep(end.saturating_duration_since(Instant::now()));
        (cpu_s(pid) - c0) / t0.elapsed().as_secs_f64()
    });
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    let samples = Arc::new(Mutex::new((Vec::new(), Vec::new())));
    let playing = Arc::new(std::sync::atomic::AtomicU32::new(0));
    rt.block_on(async {
        let mut tasks = Vec::new();
        for k in 0..a.connections {
            let client = ClientId(10_000 + k);
            let token = secret.issue(&Grant { client, world: world.clone(), expires: unix_now() + 3600 });
            let (addr, samples, playing) = (addr.clone(), samples.clone(), playing.clone());
            tasks.push(tokio::spawn(async move {
                let _ = ws_player(&addr, &token, client, every, warm, end, &samples, &playing).await;
            }));
            // Joins spread over the first seconds, as players arrive.
            tokio::time::sleep(Duration::from_millis(4)).await;
        }
        for t in tasks {
            let _ = t.await;
        }
    });
    let cores = cpu.join().map_err(|_| anyhow::anyhow!("the CPU sampler panicked"))?;
    let rss_loaded = rss_mib(gw.pid());
    let stats: serde_json::Value = serde_json::from_str(&http_get(&addr, "/stats")).unwrap_or_default();
    let (zenoh_ms, zenoh_playing) = zenoh.join().map_err(|_| anyhow::anyhow!("the Zenoh players panicked"))??;
    gw.stop();
    srv.stop();
    let _ = std::fs::remove_dir_all(&dir);
    let (ws_ms, mut lags) = std::mem::take(&mut *samples.lock().unwrap_or_else(|e| e.into_inner()));
    let (load_lag_ms_p50, load_lag_ms_p99) = (pct(&mut lags, 0.5), pct(&mut lags, 0.99));
    Ok(Round {
        load_lag_ms_p50,
        load_lag_ms_p99,
        ws_ms,
        zenoh_ms,
        ws_playing: playing.load(std::sync::atomic::Ordering::Relaxed),
        zenoh_playing,
        cores,
        rss_idle,
        rss_loaded,
        stats,
    })
}

/// Whether a MessagePack server message is a state frame, from its first bytes (the `type` key
/// comes first: a map's header, `"type"`, then `"state"`).
fn is_state(b: &[u8]) -> bool {
    b.get(..16).is_some_and(|head| head.windows(11).any(|w| w == b"\xa4type\xa5state"))
}

/// The input a player sends: a velocity that turns with time, so the avatars move.
fn walk(s: &Session, now: Instant, started: Instant) -> Option<Vec<Action>> {
    let entity = s.avatar()?;
    let a = now.duration_since(started).as_secs_f64() * 0.7 + f64::from(entity.0);
    Some(vec![Action::SetVelocity { entity, velocity: [3.0 * a.cos(), 0.0, 3.0 * a.sin()] }])
}

/// Answers accepted after `warm`, as round trips in ms; whether any was.
fn take_round_trips(s: &mut Session, warm: Instant, into: &mut Vec<f64>) -> bool {
    let mut any = false;
    for a in s.take_answers() {
        if let Outcome::Accepted { .. } = a.outcome {
            any = true;
            if a.sent >= warm {
                into.push(a.round_trip.as_secs_f64() * 1e3);
            }
        }
    }
    s.take_event_news().for_each(drop);
    any
}

/// One player through the gateway, as the TypeScript client plays: the hello, then a `Session`
/// fed with what arrives (stamped on arrival) and sending what it gives at once.
#[allow(clippy::too_many_arguments)]
async fn ws_player(
    addr: &str,
    token: &str,
    client: ClientId,
    every: Duration,
    warm: Instant,
    end: Instant,
    samples: &Mutex<(Vec<f64>, Vec<f64>)>,
    playing: &std::sync::atomic::AtomicU32,
) -> Result<()> {
    // Without Nagle's algorithm, as browsers open their sockets (an input is not held back for
    // the previous one's TCP acknowledgement).
    let (mut ws, _) = tokio_tungstenite::connect_async_with_config(format!("ws://{addr}/ws"), None, true).await?;
    let hello = rmp_serde::to_vec_named(&json!({"type": "hello", "token": token}))?;
    ws.send(Message::Binary(hello.into())).await?;
    let mut s = Session::new(SessionConfig::new(client));
    let started = Instant::now();
    let mut next_input = started;
    let mut mine = Vec::new();
    let mut counted = false;
    // Woken by what arrives, and by a timer for the inputs (and the session's own timeouts): at
    // 500 players every wake-up counts on a core shared with the server.
    let mut timer = tokio::time::interval(every.min(Duration::from_millis(50)));
    timer.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut lags = Vec::new();
    loop {
        tokio::select! {
            m = ws.next() => match m {
                Some(Ok(Message::Binary(b))) => {
                    let at = Instant::now();
                    // State frames are the bulk (the gateway's load), taken and not decoded: the
                    // players' CPU is the server's and the Zenoh players' too. Gateway notices
                    // (ready, link_restored) are not server messages: skipped.
                    if !is_state(&b) {
                        if let Ok(m) = impact_protocol::decode::<ServerMessage>(&b, Encoding::MsgPack, usize::MAX) {
                            s.receive(m, at);
                        }
                    }
                }
                Some(Ok(_)) => {}
                _ => break,
            },
            due = timer.tick() => {
                // How late this player's loop runs: the load generator keeping up, or not.
                let late = due.into_std().elapsed().as_secs_f64() * 1e3;
                if due.into_std() >= warm {
                    lags.push(late);
                }
            }
        }
        let now = Instant::now();
        if now >= end {
            break;
        }
        if s.status() == Status::Playing && now >= next_input {
            next_input = now + every;
            if let Some(actions) = walk(&s, now, started) {
                let _ = s.input(actions, now);
            }
        }
        while let Some(m) = s.poll_transmit(now) {
            ws.send(Message::Binary(impact_protocol::encode(&m, Encoding::MsgPack)?.into())).await?;
        }
        if take_round_trips(&mut s, warm, &mut mine) && !counted {
            counted = true;
            playing.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    }
    let _ = ws.close(None).await;
    let mut all = samples.lock().unwrap_or_else(|e| e.into_inner());
    all.0.extend(mine);
    all.1.extend(lags);
    Ok(())
}

/// `n` players on Zenoh directly (one session, a `Connection` each, as the deploy tests' players),
/// pumped every 2 ms: their round trips after `warm`, and how many played.
fn zenoh_players(
    listen: &str,
    world: &WorldId,
    n: u32,
    every: Duration,
    warm: Instant,
    end: Instant,
) -> Result<(Vec<f64>, u32)> {
    let session = open_session(&[listen.to_string()], None, None, Mode::Peer).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut players = Vec::new();
    for k in 0..n {
        let client = ClientId(1 + k);
        // As the WebSocket players: the state stream, no scene (no prediction with the core).
        let opts =
            ConnectOptions { scene: false, ..ConnectOptions::new(vec![listen.to_string()], world.clone(), client) };
        let conn = Connection::on(session.clone(), &opts).map_err(|e| anyhow::anyhow!("{e}"))?;
        players.push((conn, Session::new(SessionConfig::new(client)), Instant::now(), false));
    }
    let started = Instant::now();
    let mut out = Vec::new();
    let mut played = 0;
    while Instant::now() < end {
        for (conn, s, next_input, counted) in &mut players {
            let now = Instant::now();
            if s.status() == Status::Playing && now >= *next_input {
                *next_input = now + every;
                if let Some(actions) = walk(s, now, started) {
                    let _ = s.input(actions, now);
                }
            }
            conn.pump(s, now).map_err(|e| anyhow::anyhow!("{e}"))?;
            if take_round_trips(s, warm, &mut out) && !*counted {
                *counted = true;
                played += 1;
            }
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    Ok((out, played))
}

/// A plain HTTP GET on loopback: the body.
fn http_get(host: &str, path: &str) -> String {
    use std::io::{Read, Write};
    let Ok(mut c) = std::net::TcpStream::connect(host) else { return String::new() };
    let _ = c.set_read_timeout(Some(Duration::from_secs(5)));
    let _ = write!(c, "GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n");
    let mut text = String::new();
    let _ = c.read_to_string(&mut text);
    text.split_once("\r\n\r\n").map(|(_, body)| body.to_string()).unwrap_or_default()
}
