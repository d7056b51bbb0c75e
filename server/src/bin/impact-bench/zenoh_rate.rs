//! `impact-bench zenoh`: raw Zenoh pub/sub throughput on loopback (the peer), beside the event
//! rate one subscriber receives from an impact server in the same run.
//!
//! Raw: one session publishes fixed-size payloads as fast as it can for a few seconds to a
//! subscriber in a second session connected over `tcp/127.0.0.1`; messages per second received.
//! impact: the server runs a busy arena (every ball bouncing), and one subscriber on `events`
//! counts event batches and events per second.

use super::report::{json_line, progress};
use anyhow::Result;
use clap::Args;
use impact_core::scene::Scene;
use impact_protocol::keys;
use impact_server::runtime::{self, ServerOptions};
use serde_json::json;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// Options.
#[derive(Args, Debug)]
pub struct ZenohArgs {
    /// Seconds per measurement.
    #[arg(long, default_value_t = 3.0)]
    seconds: f64,
    /// Balls in the server's arena for the event-rate run.
    #[arg(long, default_value_t = 20_000)]
    balls: u32,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

fn port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

fn peer(listen: Option<&str>, connect: Option<&str>) -> Result<zenoh::Session> {
    let l: Vec<String> = listen.map(|s| vec![s.to_string()]).unwrap_or_default();
    let c: Vec<String> = connect.map(|s| vec![s.to_string()]).unwrap_or_default();
    let cfg = impact_server::runtime::zenoh_config(None, &l, &c)?;
    zenoh::open(cfg).wait().map_err(|e| anyhow::anyhow!("{e}"))
}

fn raw(size: usize, seconds: f64) -> Result<f64> {
    let ep = format!("tcp/127.0.0.1:{}", port()?);
    let publisher_session = peer(Some(&ep), None)?;
    let subscriber_session = peer(None, Some(&ep))?;
    std::thread::sleep(Duration::from_millis(500));
    let count = Arc::new(AtomicU64::new(0));
    let c = count.clone();
    let _sub = subscriber_session
        .declare_subscriber("bench/raw")
        .callback(move |_| {
            c.fetch_add(1, Ordering::Relaxed);
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    std::thread::sleep(Duration::from_millis(500));
    let publisher = publisher_session.declare_publisher("bench/raw").wait().map_err(|e| anyhow::anyhow!("{e}"))?;
    let payload = vec![7u8; size];
    let start = Instant::now();
    let begin = count.load(Ordering::Relaxed);
    while start.elapsed().as_secs_f64() < seconds {
        for _ in 0..256 {
            let _ = publisher.put(payload.clone()).wait();
        }
    }
    std::thread::sleep(Duration::from_millis(200));
    let got = count.load(Ordering::Relaxed) - begin;
    Ok(got as f64 / start.elapsed().as_secs_f64())
}

fn events(balls: u32, seconds: f64) -> Result<(f64, f64, f64)> {
    let text = std::fs::read_to_string(Scene::bundled_path("arena"))?
        .replace("count = 2000", &format!("count = {balls}"))
        .replace("speed_mps = [1.0, 6.0]", "speed_mps = [4.0, 12.0]");
    let side = (f64::from(balls) * 8.0 / 20.0).sqrt() / 2.0;
    let text = text.replace("29.5", &format!("{:.1}", side.max(29.5) - 0.5));
    let scene = Scene::parse(&text, "arena-busy")?;
    let ep = format!("tcp/127.0.0.1:{}", port()?);
    let server = runtime::start(scene, ServerOptions { listen: vec![ep.clone()], ..ServerOptions::default() })?;
    let s = peer(None, Some(&ep))?;
    std::thread::sleep(Duration::from_millis(500));
    let msgs = Arc::new(AtomicU64::new(0));
    let evs = Arc::new(AtomicU64::new(0));
    let (m, e) = (msgs.clone(), evs.clone());
    let world = impact_protocol::WorldId::new("arena").map_err(anyhow::Error::msg)?;
    let _sub = s
        .declare_subscriber(keys::EVENTS.key(&world, None))
        .callback(move |sample| {
            m.fetch_add(1, Ordering::Relaxed);
            let enc = impact_protocol::Encoding::from_zenoh_tag(&sample.encoding().to_string()).unwrap_or_default();
            if let Ok(impact_protocol::ServerMessage::Events(b)) =
                impact_protocol::decode::<impact_protocol::ServerMessage>(
                    &sample.payload().to_bytes(),
                    enc,
                    impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES,
                )
            {
                e.fetch_add(b.events.len() as u64, Ordering::Relaxed);
            }
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    std::thread::sleep(Duration::from_secs(1));
    let (m0, e0) = (msgs.load(Ordering::Relaxed), evs.load(Ordering::Relaxed));
    let start = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let t = start.elapsed().as_secs_f64();
    let (m1, e1) = (msgs.load(Ordering::Relaxed), evs.load(Ordering::Relaxed));
    let summary = server.stop();
    Ok(((m1 - m0) as f64 / t, (e1 - e0) as f64 / t, summary.tick_ms_p99))
}

/// Runs the suite.
pub fn run(a: &ZenohArgs) -> Result<()> {
    println!("zenoh: raw pub/sub on loopback TCP beside impact's event stream, {} s each", a.seconds);
    println!("{:<44} {:>14} {:>14}", "measurement", "messages/s", "events/s");
    for size in [8usize, 64] {
        progress(&format!("raw {size} B"));
        let rate = raw(size, a.seconds)?;
        println!("{:<44} {:>14.0} {:>14}", format!("raw zenoh, {size} B payloads"), rate, "-");
        if a.json {
            json_line(&json!({"suite": "zenoh", "what": "raw", "payload_bytes": size, "msgs_per_s": rate}));
        }
    }
    progress(&format!("impact server, arena with {} balls", a.balls));
    let (msgs, evs, p99) = events(a.balls, a.seconds)?;
    println!("{:<44} {:>14.0} {:>14.0}", format!("impact events, one subscriber ({} balls)", a.balls), msgs, evs);
    println!("  (server tick p99 {p99:.2} ms during the run; events travel in one batch per tick)");
    if a.json {
        json_line(
            &json!({"suite": "zenoh", "what": "impact_events", "balls": a.balls, "msgs_per_s": msgs, "events_per_s": evs, "server_tick_ms_p99": p99}),
        );
    }
    Ok(())
}
