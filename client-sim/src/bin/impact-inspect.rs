//! impact-inspect: tap a live event stream, record it, replay it, and query a server's history.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use impact_client_sim::net;
use impact_protocol::{keys, CollisionEvent, EntityId, EventStatus, Phase, ServerMessage, WorldId};
use std::io::{BufRead, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// Inspect an impact server's event stream.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Server (or router) endpoint(s).
    #[arg(long, default_value = "tcp/127.0.0.1:7447", global = true)]
    connect: Vec<String>,
    /// Zenoh user name, for a server started with `--users` (public streams and queries only).
    #[arg(long, global = true, requires = "password")]
    user: Option<String>,
    /// Password for --user.
    #[arg(long, global = true, requires = "user")]
    password: Option<String>,
    /// Zenoh session mode (`client` behind a router).
    #[arg(long, value_enum, global = true, default_value_t = net::Mode::Peer)]
    zenoh_mode: net::Mode,
    /// World name (default: every world).
    #[arg(long, global = true)]
    world: Option<String>,
    /// Only events involving this entity.
    #[arg(long, global = true)]
    entity: Option<u32>,
    /// Only this phase.
    #[arg(long, global = true, value_parser = ["begin", "end", "hit"])]
    kind: Option<String>,
    /// Only this status.
    #[arg(long, global = true, value_parser = ["provisional", "corrected", "confirmed"])]
    status: Option<String>,
    /// JSON lines instead of a table.
    #[arg(long, global = true)]
    json: bool,
    /// Tap: also write every message received to this file (JSON lines).
    #[arg(long)]
    record: Option<PathBuf>,
    /// Tap: stop after this many seconds.
    #[arg(long)]
    seconds: Option<f64>,
    #[command(subcommand)]
    cmd: Option<Cmd>,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Print a recorded stream with the same filters.
    Replay {
        /// The file `--record` wrote.
        file: PathBuf,
    },
    /// The world at a tick (default: now).
    State {
        /// Tick.
        #[arg(long)]
        tick: Option<u32>,
    },
    /// Events of a tick range.
    History {
        /// First tick.
        #[arg(long)]
        from: u32,
        /// Last tick.
        #[arg(long)]
        to: u32,
    },
    /// Serve a live view of a world in the browser (state, events, corrections, stats).
    Web {
        /// Where the page is served (`host:port`).
        #[arg(long, default_value = "127.0.0.1:8080")]
        listen: String,
    },
}

struct Filter {
    entity: Option<EntityId>,
    phase: Option<Phase>,
    status: Option<EventStatus>,
}

impl Filter {
    fn keep(&self, e: &CollisionEvent) -> bool {
        self.entity.is_none_or(|id| e.a == id || e.b == id)
            && self.phase.is_none_or(|p| e.phase == p)
            && self.status.is_none_or(|s| e.status == s)
    }
}

fn print_events(
    out: &mut impl Write,
    world: &str,
    what: &str,
    events: &[CollisionEvent],
    f: &Filter,
    json: bool,
) -> std::io::Result<()> {
    for e in events.iter().filter(|e| f.keep(e)) {
        if json {
            let v = serde_json::json!({"world": world, "message": what, "event": e});
            writeln!(out, "{v}")?;
        } else {
            writeln!(
                out,
                "{world:<10} {what:<11} tick {:>7} toi {:.4} {:>6} <-> {:<6} {:<5} {:<8} {:<11} point [{:9.3} {:9.3} {:9.3}] normal [{:6.3} {:6.3} {:6.3}] depth {:.2e} closing {:.3}",
                e.tick.0,
                e.toi,
                e.a.0,
                e.b.0,
                format!("{:?}", e.phase).to_lowercase(),
                format!("{:?}", e.response).to_lowercase(),
                format!("{:?}", e.status).to_lowercase(),
                e.point[0],
                e.point[1],
                e.point[2],
                e.normal[0],
                e.normal[1],
                e.normal[2],
                e.depth_m,
                e.closing_speed_mps
            )?;
        }
    }
    Ok(())
}

fn show(out: &mut impl Write, world: &str, msg: &ServerMessage, f: &Filter, json: bool) -> std::io::Result<()> {
    match msg {
        ServerMessage::Events(b) => print_events(out, world, "events", &b.events, f, json),
        ServerMessage::Confirmed(b) => print_events(out, world, "confirmed", &b.events, f, json),
        ServerMessage::Corrections(c) => {
            print_events(out, world, "retracted", &c.retracted, f, json)?;
            print_events(out, world, "amended", &c.amended, f, json)?;
            print_events(out, world, "added", &c.added, f, json)
        }
        other => {
            if json {
                writeln!(out, "{}", serde_json::json!({"world": world, "message": other}))
            } else {
                writeln!(out, "{world:<10} {other:?}")
            }
        }
    }
}

fn main() -> Result<()> {
    let a = Args::parse();
    let f = Filter {
        entity: a.entity.map(EntityId),
        phase: a.kind.as_deref().map(|k| match k {
            "begin" => Phase::Begin,
            "end" => Phase::End,
            _ => Phase::Hit,
        }),
        status: a.status.as_deref().map(|s| match s {
            "provisional" => EventStatus::Provisional,
            "corrected" => EventStatus::Corrected,
            _ => EventStatus::Confirmed,
        }),
    };
    let world = a.world.as_deref().map(|w| WorldId::new(w.to_string())).transpose().map_err(anyhow::Error::msg)?;
    let stdout = std::io::stdout();
    match &a.cmd {
        Some(Cmd::Replay { file }) => {
            let r = std::io::BufReader::new(
                std::fs::File::open(file).with_context(|| format!("opening {}", file.display()))?,
            );
            let mut out = stdout.lock();
            for (k, line) in r.lines().enumerate() {
                let line = line?;
                let v: serde_json::Value =
                    serde_json::from_str(&line).with_context(|| format!("{}:{}", file.display(), k + 1))?;
                let w = v["world"].as_str().unwrap_or("?").to_string();
                if world.as_ref().is_some_and(|x| x.as_str() != w) {
                    continue;
                }
                let msg: ServerMessage = serde_json::from_value(v["message"].clone())
                    .with_context(|| format!("{}:{}", file.display(), k + 1))?;
                show(&mut out, &w, &msg, &f, a.json)?;
            }
            Ok(())
        }
        Some(Cmd::State { tick }) => {
            query(&a, world, keys::QUERY_STATE, &tick.map(|t| format!("tick={t}")).unwrap_or_default(), &f)
        }
        Some(Cmd::History { from, to }) => query(&a, world, keys::QUERY_HISTORY, &format!("from={from};to={to}"), &f),
        Some(Cmd::Web { listen }) => web(&a, world, listen),
        None => tap(&a, world, &f),
    }
}

/// Serves the viewer until Ctrl-C.
fn web(a: &Args, world: Option<WorldId>, listen: &str) -> Result<()> {
    let session = open(a)?;
    let world = match world {
        Some(w) => w,
        None => only_world(&session, &a.connect)?,
    };
    let viewer = impact_client_sim::web::Viewer::start(&session, &world, listen)?;
    println!("impact-inspect: viewer of world {world} at {}  (Ctrl-C to stop)", viewer.url());
    let (tx, rx) = std::sync::mpsc::channel();
    ctrlc::set_handler(move || {
        let _ = tx.send(());
    })
    .context("installing the Ctrl-C handler")?;
    let _ = rx.recv();
    if viewer.dropped() > 0 {
        println!("{} messages were dropped for pages that fell behind", viewer.dropped());
    }
    Ok(())
}

/// The one world served where we are connected (each server declares a liveliness token per
/// world); an error naming them when there are several, or none.
fn only_world(session: &zenoh::Session, connect: &[String]) -> Result<WorldId> {
    let replies = session
        .liveliness()
        .get(keys::SERVER.any_world())
        .timeout(Duration::from_secs(3))
        .wait()
        .map_err(|e| anyhow::anyhow!("looking for servers: {e}"))?;
    let mut worlds = std::collections::BTreeSet::new();
    while let Ok(reply) = replies.recv() {
        if let Ok(sample) = reply.result() {
            if let Ok((w, _)) = keys::SERVER.parse(sample.key_expr().as_str()) {
                worlds.insert(w);
            }
        }
    }
    let names: Vec<String> = worlds.iter().map(ToString::to_string).collect();
    match worlds.len() {
        1 => Ok(worlds.into_iter().next().expect("one world")),
        0 => bail!("no impact server answered at {}: start one, or give --world", connect.join(", ")),
        _ => bail!("several worlds are served there ({}): pick one with --world", names.join(", ")),
    }
}

/// A session to the server, authenticated when --user is given.
fn open(a: &Args) -> Result<zenoh::Session> {
    let creds = a.user.clone().zip(a.password.clone()).map(|(user, password)| net::Credentials { user, password });
    net::open(&a.connect, None, creds.as_ref(), a.zenoh_mode)
}

fn query(a: &Args, world: Option<WorldId>, pattern: keys::KeyPattern, params: &str, f: &Filter) -> Result<()> {
    let Some(world) = world else { bail!("--world is required for queries") };
    let session = open(a)?;
    let key = pattern.key(&world, None);
    let replies = session
        .get(format!("{key}?{params}"))
        .timeout(Duration::from_secs(5))
        .wait()
        .map_err(|e| anyhow::anyhow!("query: {e}"))?;
    let mut out = std::io::stdout().lock();
    let mut any = false;
    while let Ok(reply) = replies.recv() {
        any = true;
        match reply.result() {
            Ok(sample) => match net::decode_server(sample)? {
                ServerMessage::History(h) => print_events(&mut out, world.as_str(), "history", &h.events, f, a.json)?,
                ServerMessage::Snapshot(s) => {
                    if a.json {
                        writeln!(out, "{}", serde_json::to_string(&s)?)?;
                    } else {
                        writeln!(out, "tick {} state hash {:016x}, {} bodies", s.tick.0, s.state_hash, s.bodies.len())?;
                        for b in s.bodies.iter().filter(|b| f.entity.is_none_or(|e| e == b.entity)) {
                            writeln!(
                                out,
                                "  {:>6} {:<10} owner {:<6} pos [{:9.3} {:9.3} {:9.3}] vel [{:7.3} {:7.3} {:7.3}]",
                                b.entity.0,
                                b.class,
                                b.owner.map_or("-".into(), |c| c.0.to_string()),
                                b.position[0],
                                b.position[1],
                                b.position[2],
                                b.velocity[0],
                                b.velocity[1],
                                b.velocity[2]
                            )?;
                        }
                    }
                }
                ServerMessage::QueryError(e) => bail!("the server says: {}", e.detail),
                other => writeln!(out, "{other:?}")?,
            },
            Err(e) => bail!("query failed: {e:?}"),
        }
    }
    if !any {
        bail!("no server answered {key} (is it running, and is the world name right?)");
    }
    Ok(())
}

fn tap(a: &Args, world: Option<WorldId>, f: &Filter) -> Result<()> {
    let session = open(a)?;
    let (tx, rx) = std::sync::mpsc::sync_channel::<(String, Vec<u8>, String)>(65_536);
    let mut subs = Vec::new();
    for p in [keys::EVENTS, keys::CORRECTIONS, keys::CONFIRMED] {
        let key = match &world {
            Some(w) => p.key(w, None),
            None => p.any_world(),
        };
        let tx = tx.clone();
        let sub = session
            .declare_subscriber(key)
            .callback(move |s| {
                let _ = tx.try_send((
                    s.key_expr().as_str().to_string(),
                    s.payload().to_bytes().to_vec(),
                    s.encoding().to_string(),
                ));
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("subscribing: {e}"))?;
        subs.push(sub);
    }
    drop(tx);
    let mut record = match &a.record {
        Some(p) => Some(std::io::BufWriter::new(
            std::fs::File::create(p).with_context(|| format!("creating {}", p.display()))?,
        )),
        None => None,
    };
    // Ctrl-C ends the tap like `--seconds` does, so a recording is flushed and whole.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    let started = Instant::now();
    let mut out = std::io::stdout().lock();
    let mut stdout_open = true;
    loop {
        if stop.load(std::sync::atomic::Ordering::SeqCst)
            || a.seconds.is_some_and(|s| started.elapsed().as_secs_f64() >= s)
        {
            break;
        }
        let Ok((key, bytes, tag)) = rx.recv_timeout(Duration::from_millis(200)) else { continue };
        let enc = impact_protocol::Encoding::from_zenoh_tag(&tag).unwrap_or_default();
        let Ok(msg) =
            impact_protocol::decode::<ServerMessage>(&bytes, enc, impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES)
        else {
            continue;
        };
        let w = key.split('/').nth(2).unwrap_or("?").to_string();
        if let Some(r) = record.as_mut() {
            writeln!(r, "{}", serde_json::json!({"world": w, "message": msg}))?;
        }
        if stdout_open {
            match show(&mut out, &w, &msg, f, a.json) {
                Ok(()) => {}
                // The reader went away (`| head`): a recording carries on without it, like
                // `tee -p`; a plain tap has nothing left to do.
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                    stdout_open = false;
                    if record.is_none() {
                        break;
                    }
                }
                Err(e) => return Err(e.into()),
            }
        }
    }
    if let Some(mut r) = record {
        r.flush().context("writing the recording")?;
    }
    drop(subs);
    let _ = session.close().wait();
    Ok(())
}
