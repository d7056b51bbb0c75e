//! Seeded faults of a deployment ([`a_deployment_keeps_the_invariants`]), as `faults.rs` runs a
//! link's: a primary and a standby
//! behind a zenohd router, 24 game clients through it on 4 sessions, state streams on, and from
//! the seed: partitions of all clients and of one session's, sessions dropped and opened again
//! (back within the 2 s grace period or past it), the router restarted, the primary killed
//! (the standby takes over while the clients stay), the primary stalled under its lease.
//! Invariants after each: every input a client sent is answered, or known to it as lost
//! (none is still awaited); no input is answered or logged twice; every client's view of every
//! confirmed tick equals the confirmed batch, and no confirmed batch of a tick changes; a
//! returning client is welcomed again, to its avatar within the grace period, resumes its
//! inputs, and a drawing client gets a full state frame; one owner (no takeover without a
//! failover); the recordings of the primary and the standby, joined, replay every state hash;
//! no server panics, both exit cleanly. Real processes over real Zenoh do not replay exactly:
//! the seed fixes the schedule, not the threads' timing. Reproduce a seed with
//! `IMPACT_DEPLOY_SEEDS=5 cargo test -p impact-tests --test deploy_faults`; a long run
//! (BENCHMARKS.md, "Faults") sets a range: `IMPACT_DEPLOY_SEEDS=1-1000`.

mod common;

use common::process::{rss_mib, server_binary, Proc};
use common::seeded::{run_seeds, seeds, violations, RSS_BOUND_MIB};
use impact_client::netsim::Link;
use impact_client_sim::load::{self, Behaviour, Faults, LoadConfig};
use impact_client_sim::timing::Timing;
use impact_protocol::{Encoding, Epoch, WorldId};
use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;
use std::time::Duration;
use zenoh::Wait;

/// The deployment's seeds CI runs: router restarts in 1, 2, 4, 5, 7, 8, failovers in 2, 4, 6, 8;
/// and failures of the long runs: 18 (clients whose grace ran out just before the primary was
/// killed come back to the standby), 22 (clients that leave before their first welcome reached
/// them), 76 (a session dropped just before the router restarted: its clients came back while
/// the server itself was cut off), 251 (an input told lost while a stalled path held its
/// reject), 315 (a partition's backlog sent through a session dropped since), 596 (clients back
/// past their grace just before the failover: the log removed their old avatars after the
/// standby heard them return), 433 (a primary stopped as a healed partition's backlog came at
/// it: its link from the router stalled in TCP; BENCHMARKS.md) and 982 (a standby that took
/// over while the router was down).
const DEPLOY_SEEDS: [u64; 16] = [1, 2, 3, 4, 5, 6, 7, 8, 18, 22, 76, 251, 315, 433, 596, 982];

/// What the deployment's processes do to themselves in one seed: the router restarted (when
/// after the start, for how long) and the primary killed (when), each drawn from the seed.
#[derive(Clone, Copy, Debug)]
struct Outages {
    router: Option<(Duration, Duration)>,
    failover: Option<Duration>,
}

impl Outages {
    /// Runs them beside the load, timed from now (near enough to the load's start: it begins
    /// once its clients are connected); returns the router running at the end.
    fn run(self, seed: u64, mut router: Proc, at: String, primary: u32) -> std::thread::JoinHandle<Proc> {
        std::thread::spawn(move || {
            let start = std::time::Instant::now();
            let mut events: Vec<(Duration, u8)> = Vec::new();
            if let Some((when, down)) = self.router {
                events.extend([(when, 0), (when + down, 1)]);
            }
            if let Some(when) = self.failover {
                events.push((when, 2));
            }
            events.sort();
            for (k, (when, what)) in events.into_iter().enumerate() {
                std::thread::sleep(when.saturating_sub(start.elapsed()));
                match what {
                    0 => router.signal("KILL"),
                    1 => {
                        let _ = router.wait(Duration::from_secs(5));
                        router = Proc::router(&format!("dfault-router-{seed}-{k}"), &at, &[]);
                    }
                    _ => {
                        let _ = Command::new("kill").args(["-KILL", &primary.to_string()]).status();
                    }
                }
            }
            router
        })
    }

    fn from_seed(seed: u64, load: Duration) -> Outages {
        let mut rng = impact_client::netsim::Rng::new(seed ^ 0x0007_a6e5);
        let d = load.as_secs_f64();
        let router = (seed % 3 != 0).then(|| {
            let down = 0.3 + rng.unit() * 1.2;
            (Duration::from_secs_f64(2.0 + rng.unit() * (d - 5.0)), Duration::from_secs_f64(down))
        });
        let failover = (seed % 2 == 0).then(|| Duration::from_secs_f64(3.0 + rng.unit() * (d - 6.0)));
        Outages { router, failover }
    }
}

/// A recording's entries by tick (the header apart), a cut-short last line left out.
fn recording(path: &std::path::Path) -> (String, BTreeMap<u32, String>) {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let mut lines = text.lines();
    let header = lines.next().unwrap_or_default().to_string();
    let mut ticks = BTreeMap::new();
    for line in lines {
        if let Ok(v) = serde_json::from_str::<serde_json::Value>(line) {
            if let Some(t) = v["tick"].as_u64() {
                ticks.insert(t as u32, line.to_string());
            }
        }
    }
    (header, ticks)
}

/// The primary's recording joined with the `log` entries a tap heard (from whichever server
/// owned the world: the standby's after a takeover), checked on the way: every version heard of
/// a tick is the same entry, ticks in both are the same entry, the ticks follow each other
/// without a gap, and no (client, seq) is logged twice. A killed primary's file may end with
/// ticks it wrote (the file is flushed first) but died before publishing: past the last tick it
/// was heard publishing, a tick only its successor published is the world's, and replaces the
/// file's (counted in `unpublished`). Returns the joined file's path.
fn join_log(
    primary: &std::path::Path,
    heard: BTreeMap<u32, Vec<(Option<Epoch>, String)>>,
    unpublished: &mut u32,
    wrong: &mut Vec<String>,
) -> std::path::PathBuf {
    let (header, mut ticks) = recording(primary);
    let first_owner = heard.values().flatten().map(|(e, _)| *e).min();
    let from_primary = |versions: &[(Option<Epoch>, String)]| versions.iter().any(|(e, _)| Some(*e) == first_owner);
    let last_from_primary = heard.iter().filter(|(_, v)| from_primary(v)).map(|(t, _)| *t).max();
    for (t, versions) in heard {
        let line = versions[0].1.clone();
        if versions.iter().any(|(_, l)| *l != line) {
            let owners: Vec<_> = versions.iter().map(|(e, _)| e.map(|e| e.0)).collect();
            wrong.push(format!("tick {t} was published differently by the owners of epochs {owners:?}"));
        }
        match ticks.get(&t) {
            Some(had) if *had != line && !from_primary(&versions) && last_from_primary.is_some_and(|l| t > l) => {
                *unpublished += 1;
                ticks.insert(t, line);
            }
            Some(had) if *had != line => wrong.push(format!("tick {t} was recorded and published differently")),
            Some(_) => {}
            None => {
                ticks.insert(t, line);
            }
        }
    }
    let mut seen = BTreeSet::new();
    let mut last: Option<u32> = None;
    for (t, line) in &ticks {
        if let Some(l) = last.filter(|l| *t != l + 1) {
            wrong.push(format!("the input log goes from tick {l} to {t}"));
        }
        last = Some(*t);
        let v: serde_json::Value = serde_json::from_str(line).unwrap_or_default();
        for i in v["inputs"].as_array().into_iter().flatten() {
            let key = (i["client"].as_u64(), i["seq"].as_u64());
            if !seen.insert(key) {
                wrong.push(format!("input {key:?} logged twice"));
            }
        }
    }
    let joined = primary.with_extension("joined.jsonl");
    let mut text = header;
    text.push('\n');
    for line in ticks.values() {
        text.push_str(line);
        text.push('\n');
    }
    std::fs::write(&joined, text).expect("writing the joined recording");
    joined
}

/// One deployment seed: returns what went wrong, if anything.
fn deployment_run(seed: u64) -> Result<String, String> {
    let router_at = format!("tcp/127.0.0.1:{}", common::free_port());
    let router = Proc::router(&format!("dfault-router-{seed}"), &router_at, &[]);
    std::thread::sleep(Duration::from_millis(500));
    let rec_p = std::env::temp_dir().join(format!("impact-dfault-{}-{seed}-primary.jsonl", std::process::id()));
    let server = |name: &str, extra: &[&str]| {
        let mut cmd = Command::new(server_binary());
        cmd.args(["--scene", &impact_core::scene::Scene::bundled_path("arena").to_string_lossy()])
            .args(["--connect", &router_at])
            .args(extra);
        Proc::spawn(&format!("dfault-{name}-{seed}"), cmd)
    };
    // Not quiet: a failing seed shows the primary's clients (those it knows, present or not)
    // and inputs accepted each second.
    let mut primary = server("primary", &["--record", &rec_p.to_string_lossy()]);
    if !primary.wait_for_output("listening on", Duration::from_secs(20)) {
        return Err(format!("seed {seed}: the primary did not start:\n{}", primary.output()));
    }
    std::thread::sleep(Duration::from_millis(500));
    let mut standby = server("standby", &["--standby"]);
    if !standby.wait_for_output("following from the checkpoint", Duration::from_secs(20)) {
        return Err(format!("seed {seed}: the standby did not follow:\n{}", standby.output()));
    }
    let (_tap, _log, heard) = log_tap(&router_at).map_err(|e| format!("seed {seed}: the log tap: {e}"))?;
    let duration = Duration::from_secs(12);
    let cfg = deployment_load(seed, &router_at, duration, primary.pid());
    let outages = Outages::from_seed(seed, duration);
    let plan = format!("seed {seed}: uplink {:?}, {outages:?}, faults {:?}", cfg.uplink, cfg.faults);
    let outages_thread = outages.run(seed, router, router_at.clone(), primary.pid());
    let report = load::run(&cfg);
    let router = outages_thread.join().expect("the outage thread");
    let report = report.map_err(|e| format!("{plan}\nload: {e}"))?;
    let rss = rss_mib(standby.pid()).max(rss_mib(primary.pid()));
    let mut wrong = Vec::new();
    let s_status = standby.stop();
    let p_status = if outages.failover.is_some() { primary.wait(Duration::from_secs(5)) } else { primary.stop() };
    let (p_out, s_out) = (primary.output(), standby.output());
    drop(router);
    for (name, out) in [("primary", &p_out), ("standby", &s_out)] {
        if out.contains("panicked") {
            wrong.push(format!("the {name} panicked:\n{out}"));
        }
    }
    if !s_status.is_some_and(|s| s.success()) {
        wrong.push(format!("the standby exited with {s_status:?}:\n{s_out}"));
    }
    match outages.failover {
        Some(_) if !s_out.contains("took over at tick") => wrong.push(format!("the standby never took over:\n{s_out}")),
        None if s_out.contains("took over") => {
            wrong.push(format!("the standby took over from a live primary:\n{s_out}"))
        }
        None if !p_status.is_some_and(|s| s.success()) => {
            wrong.push(format!("the primary exited with {p_status:?}:\n{p_out}"));
        }
        _ => {}
    }
    deployment_violations(&report, &mut wrong);
    if rss > RSS_BOUND_MIB {
        wrong.push(format!("server resident memory {rss:.0} MiB > {RSS_BOUND_MIB} MiB"));
    }
    // The input log: the primary's recording and what the tap heard, each input once, replayed
    // to every hash.
    std::thread::sleep(Duration::from_millis(300));
    let heard = std::mem::take(&mut *heard.lock().unwrap_or_else(|e| e.into_inner()));
    if heard.is_empty() {
        wrong.push("the log tap heard nothing".into());
    }
    let mut unpublished = 0;
    let joined = join_log(&rec_p, heard, &mut unpublished, &mut wrong);
    if unpublished > 0 && outages.failover.is_none() {
        wrong.push(format!("the primary recorded {unpublished} ticks it never published, and was not killed"));
    }
    let replayed = replay(&joined);
    if !replayed.contains("every recorded state hash reproduced") {
        wrong.push(format!("the input log did not replay:\n{replayed}"));
    }
    for f in [&rec_p, &joined] {
        let _ = std::fs::remove_file(f);
    }
    let summary = format!(
        "{plan}\n{report}\nserver rss {rss:.0} MiB; replay: {}; the killed primary's unpublished ticks: {unpublished}",
        replayed.lines().last().unwrap_or("")
    );
    if wrong.is_empty() {
        Ok(summary)
    } else {
        Err(format!(
            "{summary}\nthe primary said:\n{p_out}\nthe standby said:\n{s_out}\nFAILED:\n  {}",
            wrong.join("\n  ")
        ))
    }
}

/// The load of a deployment seed: 24 game clients on 4 client-mode sessions through the router,
/// state streams on, a network path and faults drawn from the seed (`primary` is stalled).
fn deployment_load(seed: u64, router_at: &str, duration: Duration, primary: u32) -> LoadConfig {
    let sessions = 4;
    let mut rng = impact_client::netsim::Rng::new(seed);
    let latency = Duration::from_millis(10 + (rng.unit() * 50.0) as u64);
    let jitter = Duration::from_millis((rng.unit() * 20.0) as u64);
    let uplink = Link { latency, jitter, loss: rng.unit() * 0.03 };
    LoadConfig {
        mode: impact_client_sim::net::Mode::Client,
        connect: vec![router_at.to_string()],
        zenoh_config: None,
        world: WorldId::new("arena").expect("a world name"),
        clients: 24,
        first_client: 6000,
        sessions: sessions as u32,
        users: None,
        duration,
        uplink,
        downlink: Link { loss: 0.0, ..uplink },
        behaviour: Behaviour::Mixed,
        timing: Timing::Ahead,
        input_hz: 10.0,
        encoding: if seed % 3 == 0 { Encoding::Json } else { Encoding::MsgPack },
        seed,
        settle: Duration::from_secs(4),
        progress: false,
        faults: Faults::deployment(seed, duration, sessions, Some(primary)),
        state: true,
        predict: 24,
        scene: None,
    }
}

/// `impact-server --offline --replay` of `recording`: what it printed (what went wrong, if it
/// could not run).
fn replay(recording: &std::path::Path) -> String {
    let out = Command::new(server_binary())
        .args(["--scene", &impact_core::scene::Scene::bundled_path("arena").to_string_lossy()])
        .args(["--offline", "--replay", &recording.to_string_lossy()])
        .output();
    match out {
        Ok(o) => String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr),
        Err(e) => format!("could not run the replay: {e}"),
    }
}

/// What the log tap heard of `impact/v1/arena/log`, by tick, as the recording's lines: every
/// version, with the owner epoch that published it.
type Heard = std::sync::Arc<std::sync::Mutex<BTreeMap<u32, Vec<(Option<Epoch>, String)>>>>;

/// The log tap: a peer session, linked to each server directly as the standby is (so a router
/// restart does not cut it off; the log is published with `block`), and its subscriber.
fn log_tap(router_at: &str) -> anyhow::Result<(zenoh::Session, zenoh::pubsub::Subscriber<()>, Heard)> {
    let tap = impact_client_sim::net::open(&[router_at.to_string()], None, None, impact_client_sim::net::Mode::Peer)?;
    let heard: Heard = Heard::default();
    let into = heard.clone();
    let world = WorldId::new("arena").expect("a world name");
    let sub = tap
        .declare_subscriber(impact_protocol::keys::LOG.key(&world, None))
        .callback(move |sample| {
            if let Ok(impact_protocol::ServerMessage::Log(l)) = impact_client_sim::net::decode_server(&sample) {
                let line = serde_json::to_string(&l).unwrap_or_default();
                let epoch = impact_client::transport::epoch_of(&sample);
                let mut heard = into.lock().unwrap_or_else(|e| e.into_inner());
                let versions = heard.entry(l.tick.0).or_default();
                if !versions.contains(&(epoch, line.clone())) {
                    versions.push((epoch, line));
                }
            }
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok((tap, sub, heard))
}

/// What a deployment run's report shows wrong, beyond [`violations`].
fn deployment_violations(r: &impact_client_sim::report::Report, wrong: &mut Vec<String>) {
    violations(r, wrong);
    if r.inputs_awaited > 0 {
        wrong.push(format!("{} inputs still awaited an answer: neither answered nor known lost", r.inputs_awaited));
    }
    if r.session_drops == 0 || r.returns == 0 {
        wrong.push("no session was dropped and came back: the run tested less than it says".into());
    }
    let short = |n: u64, of: u64, what: &str| (n < of).then(|| format!("{} of {of} {what}", of - n));
    wrong.extend(short(r.returns_welcomed, r.returns, "returning clients were never welcomed again"));
    wrong.extend(short(
        r.returns_kept_avatar,
        r.returns_in_grace,
        "clients back within the grace period lost their avatar",
    ));
    wrong.extend(short(r.returns_full_frame, r.returns_drawing, "returning clients got no full state frame"));
    if r.returns_full_frame < r.returns_drawing {
        wrong.extend(r.unframed.iter().map(|u| format!("    {u}")));
    }
    wrong.extend(short(r.returns_resumed, r.returns, "returning clients had no input accepted after"));
    if r.returns_resumed < r.returns {
        wrong.extend(r.unresumed.iter().map(|u| format!("    {u}")));
    }
}

#[test]
fn a_deployment_keeps_the_invariants() {
    let seeds = seeds("IMPACT_DEPLOY_SEEDS", DEPLOY_SEEDS.into_iter());
    run_seeds("deployment", "IMPACT_DEPLOY_SEEDS", seeds, deployment_run, "deploy_faults");
}
