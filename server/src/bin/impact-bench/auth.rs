//! `impact-bench auth`: what `--users` costs, against the same Zenoh sessions without it, in one
//! run.
//!
//! - **ACL size**: rules, subjects and policies generated for N users.
//! - **Server open**: time to open the server's Zenoh session with the dictionary and the ACL
//!   for N users compiled, against a plain session.
//! - **Connect**: time for a client to open a session to the server (handshake, with the
//!   user/password challenge when on), median and p99 of K sequential connects.
//! - **Round trip**: a client puts an input-sized payload on its own `input/{client}` key; the
//!   server's session answers on `client/{client}/ack`; the client times put to answer. Every
//!   message crosses the ACL twice (ingress put, egress put). Median and p99 of M round trips.
//!
//! Auth and plain runs alternate per round so the noisy machine treats both alike.

use super::report::{json_line, progress};
use anyhow::{anyhow, Result};
use clap::Args;
use impact_protocol::keys;
use impact_protocol::WorldId;
use impact_server::runtime::auth::{client_credentials, Users};
use serde_json::json;
use std::sync::mpsc::sync_channel;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// Options.
#[derive(Args, Debug)]
pub struct AuthArgs {
    /// Users in the generated file (and ACL).
    #[arg(long, default_value_t = 1000)]
    users: u32,
    /// Sequential client connects per mode and round.
    #[arg(long, default_value_t = 20)]
    connects: usize,
    /// Round trips per mode and round.
    #[arg(long, default_value_t = 2000)]
    round_trips: usize,
    /// Rounds (auth and plain alternate within each).
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// Print JSON lines.
    #[arg(long)]
    json: bool,
}

fn users(n: u32) -> Users {
    let text: String = (0..n)
        .map(|c| {
            format!("[[user]]\nname = \"player{c}\"\npassword = \"secret-{c}-{}\"\nclient = {c}\n", c * 7919 % 10007)
        })
        .collect();
    Users::parse(&text).expect("generated users file is valid")
}

fn port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// The `q` quantile of sorted samples.
fn quantile(v: &[f64], q: f64) -> f64 {
    v.get(((v.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN)
}

struct Mode {
    open_ms: Vec<f64>,
    connect_ms: Vec<f64>,
    rtt_us: Vec<f64>,
}

/// One round of one mode: open a server session, connect clients, time round trips.
fn round(users: Option<&Users>, a: &AuthArgs, m: &mut Mode) -> Result<()> {
    let ep = format!("tcp/127.0.0.1:{}", port()?);
    let mut cfg = impact_server::runtime::zenoh_config(None, std::slice::from_ref(&ep), &[])?;
    let t = Instant::now();
    let dict = users.map(|u| impact_server::runtime::auth::apply(u, &mut cfg)).transpose()?;
    let server = zenoh::open(cfg).wait().map_err(|e| anyhow!("server session: {e}"))?;
    m.open_ms.push(t.elapsed().as_secs_f64() * 1e3);
    drop(dict);
    let world = WorldId::new("bench").map_err(|e| anyhow!("{e}"))?;
    let creds = |c: u32| users.and_then(|u| u.for_client(c)).map(|u| (u.name.clone(), u.password.clone()));
    let client = |c: u32| -> Result<zenoh::Session> {
        let mut cfg = impact_server::runtime::zenoh_config(None, &[], std::slice::from_ref(&ep))?;
        cfg.insert_json5("listen/endpoints", "[]").map_err(|e| anyhow!("{e}"))?;
        if let Some((u, p)) = creds(c) {
            client_credentials(&mut cfg, &u, &p)?;
        }
        zenoh::open(cfg).wait().map_err(|e| anyhow!("client session: {e}"))
    };
    for k in 0..a.connects {
        let t = Instant::now();
        let s = client(k as u32 % a.users)?;
        m.connect_ms.push(t.elapsed().as_secs_f64() * 1e3);
        s.close().wait().map_err(|e| anyhow!("{e}"))?;
    }
    // The echo: the server's session answers every input on the sender's ack key.
    let me = a.users - 1;
    let echo_world = world.clone();
    let echo_session = server.clone();
    let _echo = server
        .declare_subscriber(keys::INPUT.any_client(&world))
        .callback(move |s| {
            let Ok((_, Some(c))) = keys::INPUT.parse(s.key_expr().as_str()) else { return };
            let _ = echo_session.put(keys::CLIENT_ACK.key(&echo_world, Some(c)), s.payload().clone()).wait();
        })
        .wait()
        .map_err(|e| anyhow!("{e}"))?;
    let player = client(me)?;
    let (tx, rx) = sync_channel::<()>(16);
    let _ack = player
        .declare_subscriber(keys::CLIENT_ACK.key(&world, Some(impact_protocol::ClientId(me))))
        .callback(move |_| {
            let _ = tx.try_send(());
        })
        .wait()
        .map_err(|e| anyhow!("{e}"))?;
    std::thread::sleep(Duration::from_millis(300));
    let input_key = keys::INPUT.key(&world, Some(impact_protocol::ClientId(me)));
    let payload = vec![0x5au8; 96]; // about one input with one action, as MessagePack
    for k in 0..a.round_trips + 50 {
        let t = Instant::now();
        player.put(&input_key, payload.clone()).wait().map_err(|e| anyhow!("{e}"))?;
        rx.recv_timeout(Duration::from_secs(2))
            .map_err(|_| anyhow!("no answer within 2 s: is the ACL blocking it?"))?;
        if k >= 50 {
            m.rtt_us.push(t.elapsed().as_secs_f64() * 1e6);
        }
    }
    Ok(())
}

/// Runs the suite.
pub fn run(a: &AuthArgs) -> Result<()> {
    let u = users(a.users);
    let acl = u.acl();
    let count = |k: &str| acl[k].as_array().map_or(0, Vec::len);
    let (rules, subjects, policies) = (count("rules"), count("subjects"), count("policies"));
    let acl_bytes = acl.to_string().len();
    let mut with = Mode { open_ms: vec![], connect_ms: vec![], rtt_us: vec![] };
    let mut without = Mode { open_ms: vec![], connect_ms: vec![], rtt_us: vec![] };
    for r in 0..a.rounds {
        progress(&format!("round {} of {}: with --users ({} users)", r + 1, a.rounds, a.users));
        round(Some(&u), a, &mut with)?;
        progress(&format!("round {} of {}: plain", r + 1, a.rounds));
        round(None, a, &mut without)?;
    }
    println!(
        "impact-bench auth: {} users -> {rules} rules, {subjects} subjects, {policies} policies ({} KiB of ACL)",
        a.users,
        acl_bytes / 1024
    );
    for v in [
        &mut with.open_ms,
        &mut with.connect_ms,
        &mut with.rtt_us,
        &mut without.open_ms,
        &mut without.connect_ms,
        &mut without.rtt_us,
    ] {
        v.sort_by(f64::total_cmp);
    }
    println!("{:<34}{:>12}{:>12}{:>10}", "", "--users", "plain", "ratio");
    let mut rows = Vec::new();
    for (name, q, unit, w, p) in [
        ("server session open, median", 0.5, "ms", &with.open_ms, &without.open_ms),
        ("client connect, median", 0.5, "ms", &with.connect_ms, &without.connect_ms),
        ("client connect, p99", 0.99, "ms", &with.connect_ms, &without.connect_ms),
        ("input round trip, median", 0.5, "us", &with.rtt_us, &without.rtt_us),
        ("input round trip, p99", 0.99, "us", &with.rtt_us, &without.rtt_us),
    ] {
        let (x, y) = (quantile(w, q), quantile(p, q));
        println!("{:<34}{:>10.2}{unit}{:>10.2}{unit}{:>9.2}x", name, x, y, x / y);
        rows.push((name, unit, x, y));
    }
    if a.json {
        for (name, unit, x, y) in rows {
            json_line(&json!({
                "suite": "auth", "metric": name, "unit": unit, "users": a.users, "rules": rules,
                "with_users": x, "plain": y, "ratio": x / y,
            }));
        }
    }
    Ok(())
}
