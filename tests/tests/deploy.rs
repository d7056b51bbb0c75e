//! Deployment, end to end, with real processes: zenohd routers (installed by `scripts/zenohd`),
//! `impact-server` processes owning several worlds, a standby taking over from a primary killed
//! with SIGKILL, and (where the machine allows) routers, servers and clients in separate network
//! namespaces.

mod common;

use common::process::{server_binary, Proc};
use common::{answers, free_port, join, query_all};
use impact_client_sim::net::{self, Mode};
use impact_protocol::{
    encode, keys, ClientId, ClientInput, ClientMessage, Encoding, Epoch, ServerMessage, Tick, WorldId,
};
use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::{Duration, Instant};
use zenoh::Wait;

/// A message as a tap received it: its key, the owner epoch it carried, when it came.
struct Tapped {
    key: String,
    msg: ServerMessage,
    epoch: Option<Epoch>,
    at: Instant,
}

/// Messages with the key they came on.
struct Tap {
    rx: Receiver<Tapped>,
    _sub: zenoh::pubsub::Subscriber<()>,
}

impl Tap {
    fn new(s: &zenoh::Session, key: &str) -> Tap {
        let (tx, rx) = sync_channel(1_000_000);
        let sub = s
            .declare_subscriber(key.to_string())
            .callback(move |sample| {
                if let Ok(msg) = net::decode_server(&sample) {
                    let key = sample.key_expr().as_str().to_string();
                    let epoch = impact_client::transport::epoch_of(&sample);
                    let _ = tx.try_send(Tapped { key, msg, epoch, at: Instant::now() });
                }
            })
            .wait()
            .expect("subscriber");
        Tap { rx, _sub: sub }
    }

    /// Everything received so far.
    fn drain(&self) -> Vec<(String, ServerMessage, Instant)> {
        self.rx.try_iter().map(|t| (t.key, t.msg, t.at)).collect()
    }

    /// Everything received so far, with the epochs.
    fn drain_tapped(&self) -> Vec<Tapped> {
        self.rx.try_iter().collect()
    }

    /// The first message within `timeout` for which `f` says something.
    fn wait_for<T>(
        &self,
        timeout: Duration,
        mut f: impl FnMut(&str, &ServerMessage, Instant) -> Option<T>,
    ) -> Option<T> {
        let end = Instant::now() + timeout;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            let t = self.rx.recv_timeout(left).ok()?;
            if let Some(t) = f(&t.key, &t.msg, t.at) {
                return Some(t);
            }
        }
        None
    }
}

fn endpoint() -> String {
    format!("tcp/127.0.0.1:{}", free_port())
}

/// A client-mode session through `router` (it talks to nothing else).
fn through(router: &str) -> zenoh::Session {
    let s = net::open(&[router.to_string()], None, None, Mode::Client).expect("client session through the router");
    std::thread::sleep(Duration::from_millis(200));
    s
}

/// An `impact-server` process for `scenes`, connected to `router` with no other network flag, as
/// the README's router topology starts them: it listens on an ephemeral loopback port, so several
/// on one host (two on one router in the mesh test) never fight over a port (they did, over 7447,
/// before), and the standby still reaches its primary.
fn server(name: &str, scenes: &[&str], router: &str, extra: &[&str]) -> Proc {
    let mut cmd = Command::new(server_binary());
    for s in scenes {
        cmd.arg("--scene").arg(impact_core::scene::Scene::bundled_path(s));
    }
    cmd.args(["--connect", router]).args(extra);
    Proc::spawn(name, cmd)
}

fn send(s: &zenoh::Session, world: &WorldId, input: &ClientInput) {
    let bytes = encode(&ClientMessage::Input(input.clone()), Encoding::MsgPack).expect("encodes");
    s.put(keys::INPUT.key(world, Some(input.client)), bytes)
        .encoding(Encoding::MsgPack.zenoh_tag())
        .wait()
        .expect("put");
}

fn world_of(key: &str) -> String {
    key.split('/').nth(2).unwrap_or("").to_string()
}

/// Two routers meshed, three server processes, four worlds; a client of each world on either
/// router. Each client is welcomed and answered by its own world only, and every world's stats
/// reach every client across the mesh, from exactly one server each.
#[test]
fn worlds_across_processes_on_a_router_mesh() {
    let (r1, r2) = (endpoint(), endpoint());
    let _router1 = Proc::router("mesh-r1", &r1, &[]);
    std::thread::sleep(Duration::from_millis(300));
    let _router2 = Proc::router("mesh-r2", &r2, std::slice::from_ref(&r1));
    std::thread::sleep(Duration::from_millis(500));
    // Two worlds in one process (one tick thread each), one each in two more, on both routers.
    let mut servers = [
        server("mesh-s1", &["corridor", "breakout"], &r1, &["--quiet"]),
        server("mesh-s2", &["bullets"], &r2, &["--quiet"]),
        server("mesh-s3", &["arena"], &r2, &["--quiet"]),
    ];
    let worlds = ["corridor", "breakout", "bullets", "arena"];
    for s in &servers {
        assert!(s.wait_for_output("listening on", Duration::from_secs(20)), "a server did not start:\n{}", s.output());
    }
    let mut clients = Vec::new();
    for (k, w) in worlds.iter().enumerate() {
        let router = if k % 2 == 0 { &r1 } else { &r2 };
        let s = through(router);
        let me = ClientId(100 + k as u32);
        let mine = Tap::new(&s, &format!("impact/v1/*/client/{}/**", me.0));
        let stats = Tap::new(&s, "impact/v1/*/stats");
        let world = WorldId::new(*w).unwrap();
        let token = join(&s, &world, me);
        clients.push((s, me, world, mine, stats, token));
    }
    for (s, me, world, mine, _, _) in &clients {
        let (tick, at) = mine
            .wait_for(Duration::from_secs(20), |key, m, at| match m {
                ServerMessage::Welcome(w) => {
                    assert_eq!(world_of(key), world.as_str(), "client {me} welcomed by another world");
                    Some((w.tick, at))
                }
                _ => None,
            })
            .unwrap_or_else(|| panic!("client {me} of world {world} was never welcomed"));
        // The world's tick now: the welcome's, plus the ticks since it came (64 Hz).
        let now = tick.0 + (at.elapsed().as_secs_f64() * 64.0) as u32;
        let input = ClientInput {
            aim_tick: None,
            client: *me,
            seq: 0,
            tick: Tick(now + 2),
            view_tick: None,
            actions: Vec::new(),
        };
        send(s, world, &input);
        let answer = mine.wait_for(Duration::from_secs(10), |key, m, _| match m {
            ServerMessage::Ack(a) if a.seq == 0 => Some((world_of(key), Ok(a.applied_tick))),
            ServerMessage::Reject(r) => Some((world_of(key), Err(r.clone()))),
            _ => None,
        });
        match answer {
            Some((w, Ok(_))) => assert_eq!(w, world.as_str(), "client {me}'s input answered by world {w}"),
            other => panic!("client {me} of world {world}: no ack for its input: {other:?}"),
        }
    }
    std::thread::sleep(Duration::from_millis(2500));
    for (_, me, world, mine, stats, _) in &clients {
        for (key, m, _) in mine.drain() {
            assert_eq!(world_of(&key), world.as_str(), "client {me} of world {world} received {m:?} on {key}");
        }
        // Every world's stats reached this client, whichever router it is on, from one server
        // each: its ticks only go up (two servers of one world would interleave).
        let mut seen: BTreeMap<String, Vec<u32>> = BTreeMap::new();
        for (key, m, _) in stats.drain() {
            if let ServerMessage::Stats(s) = m {
                seen.entry(world_of(&key)).or_default().push(s.tick.0);
            }
        }
        for w in worlds {
            let t = seen.get(w).unwrap_or_else(|| panic!("client {me} never heard world {w}'s stats: {seen:?}"));
            assert!(t.windows(2).all(|p| p[0] < p[1]), "world {w}'s stats ticks {t:?}: more than one server?");
        }
    }
    drop(clients);
    for s in &mut servers {
        let status = s.stop();
        assert!(status.is_some_and(|x| x.success()), "a server did not stop cleanly:\n{}", s.output());
        assert!(!s.output().contains("panicked"), "{}", s.output());
    }
}

/// One client of the failover test: its avatar, its acked seqs and its clock.
struct Player {
    id: ClientId,
    avatar: Option<impact_protocol::EntityId>,
    tick: Option<(Tick, Instant)>,
    welcomes: u32,
    next_seq: u32,
    acked: BTreeSet<u32>,
    ack_ticks: BTreeMap<u32, Tick>,
}

/// What the failover test saw on the log and confirmed streams.
#[derive(Default)]
struct Published {
    log_ticks: Vec<(Tick, Instant)>,
    logged_inputs: BTreeMap<(u32, u32), u32>,
    confirmed_ticks: Vec<Tick>,
    /// The confirmed batches heard, by tick.
    confirmed: BTreeMap<u32, impact_protocol::EventBatch>,
}

impl Published {
    fn take(&mut self, log: &Tap, confirmed: &Tap) {
        for (_, m, at) in log.drain() {
            if let ServerMessage::Log(l) = m {
                for i in &l.inputs {
                    *self.logged_inputs.entry((i.client.0, i.seq)).or_default() += 1;
                }
                self.log_ticks.push((l.tick, at));
            }
        }
        for (_, m, _) in confirmed.drain() {
            if let ServerMessage::Confirmed(b) = m {
                self.confirmed_ticks.push(b.tick);
                self.confirmed.insert(b.tick.0, b);
            }
        }
    }
}

/// A primary and a standby for one world behind a router; clients keep playing while the
/// primary is killed with SIGKILL. The standby takes over within 2 s; the confirmed stream and
/// the input log have every tick exactly once, with no gap; every acked input is in the log,
/// once; the standby's state hashes equal the primary's; the clients are welcomed again; and
/// the primary's recording replays to the same hashes.
#[test]
fn a_standby_takes_over_from_a_killed_primary() {
    let router = endpoint();
    let _router = Proc::router("failover-router", &router, &[]);
    std::thread::sleep(Duration::from_millis(500));
    let record = std::env::temp_dir().join(format!("impact-failover-{}.jsonl", std::process::id()));
    let record_arg = record.to_string_lossy().to_string();
    let mut primary = server("failover-primary", &["arena"], &router, &["--quiet", "--record", &record_arg]);
    assert!(primary.wait_for_output("listening on", Duration::from_secs(20)), "{}", primary.output());
    let world = WorldId::new("arena").unwrap();
    let s = through(&router);
    let log = Tap::new(&s, &keys::LOG.key(&world, None));
    let confirmed = Tap::new(&s, &keys::CONFIRMED.key(&world, None));
    let acks = Tap::new(&s, &format!("impact/v1/{world}/client/*/ack"));
    let mut players: Vec<Player> = (0..8)
        .map(|k| Player {
            id: ClientId(300 + k),
            avatar: None,
            tick: None,
            welcomes: 0,
            next_seq: 0,
            acked: BTreeSet::new(),
            ack_ticks: BTreeMap::new(),
        })
        .collect();
    let _tokens: Vec<_> = players.iter().map(|p| join(&s, &world, p.id)).collect();
    // The standby starts after the primary has confirmed ticks: it joins late, from a checkpoint.
    std::thread::sleep(Duration::from_secs(1));
    let mut standby = server("failover-standby", &["arena"], &router, &["--standby"]);
    assert!(
        standby.wait_for_output("following from the checkpoint", Duration::from_secs(20)),
        "the standby never restored a checkpoint:\n{}",
        standby.output()
    );

    let started = Instant::now();
    let mut killed: Option<Instant> = None;
    let mut seen = Published::default();
    let mut kill_tick = None;
    let mut rng = 7u64;
    let mut rejects = Vec::new();
    while started.elapsed() < Duration::from_secs(9) {
        if killed.is_none() && started.elapsed() > Duration::from_secs(4) {
            primary.signal("KILL");
            killed = Some(Instant::now());
            kill_tick = seen.confirmed_ticks.last().copied();
            let _ = primary.wait(Duration::from_secs(5));
        }
        for (key, m, at) in acks.drain() {
            let Some(p) = players.iter_mut().find(|p| keys::CLIENT_ACK.key(&world, Some(p.id)) == key) else {
                continue;
            };
            match m {
                ServerMessage::Welcome(w) => {
                    p.avatar = w.avatar;
                    p.tick = Some((w.tick, at));
                    p.welcomes += 1;
                    p.next_seq = p.next_seq.max(w.next_seq);
                }
                ServerMessage::Ack(a) => {
                    assert!(p.acked.insert(a.seq), "client {} seq {} acked twice", p.id, a.seq);
                    p.ack_ticks.insert(a.seq, a.applied_tick);
                    p.tick = Some((a.server_tick, at));
                }
                ServerMessage::Reject(r) => rejects.push(format!("{:?}: {}", r.reason, r.detail)),
                _ => {}
            }
        }
        seen.take(&log, &confirmed);
        // Each player moves its avatar five times a second, stamped a few ticks ahead.
        for p in &mut players {
            let (Some(avatar), Some((tick, at))) = (p.avatar, p.tick) else { continue };
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            if rng >> 61 != 0 {
                continue;
            }
            let now = tick.0 + (at.elapsed().as_secs_f64() * 64.0) as u32 + 2;
            let v = ((rng >> 33) % 7) as f64 - 3.0;
            let input = ClientInput {
                aim_tick: None,
                client: p.id,
                seq: p.next_seq,
                tick: Tick(now),
                view_tick: None,
                actions: vec![impact_protocol::Action::SetVelocity { entity: avatar, velocity: [v, 0.0, -v] }],
            };
            p.next_seq += 1;
            send(&s, &world, &input);
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    seen.take(&log, &confirmed);
    recovers_confirmed_batches(&s, &world, &seen, kill_tick.expect("ticks were confirmed before the kill"), &players);
    // Stop the standby: it confirms what is left in its window, once.
    let status = standby.stop();
    let out = standby.output();
    assert!(status.is_some_and(|x| x.success()), "the standby did not stop cleanly:\n{out}");
    std::thread::sleep(Duration::from_millis(500));
    seen.take(&log, &confirmed);
    let killed = killed.expect("the primary was killed");

    // The takeover: logged, hashes equal, quick.
    assert!(out.contains("the primary is gone; took over at tick"), "the standby never took over:\n{out}");
    assert!(out.contains("(0 hashes differed)"), "the standby's state differed from the primary's:\n{out}");
    let first_after = seen.log_ticks.iter().find(|(_, at)| *at > killed).map(|(_, at)| *at - killed);
    let gap = first_after.expect("no tick was published after the kill");
    eprintln!("failover: first tick from the standby {:.0} ms after SIGKILL", gap.as_secs_f64() * 1e3);
    assert!(gap < Duration::from_secs(2), "the standby published its first tick {gap:?} after the kill");

    // Every confirmed tick exactly once, with no gap, across the takeover.
    for (name, ticks) in
        [("log", seen.log_ticks.iter().map(|(t, _)| *t).collect::<Vec<_>>()), ("confirmed", seen.confirmed_ticks)]
    {
        assert!(ticks.len() > 400, "only {} {name} ticks", ticks.len());
        for w in ticks.windows(2) {
            assert_eq!(w[1].0, w[0].0 + 1, "{name} went from tick {} to {}", w[0].0, w[1].0);
        }
    }
    // Every acked input is in the log exactly once (acks of ticks the log covered).
    let last_logged = seen.log_ticks.last().map(|(t, _)| *t).expect("log");
    let mut acked = 0;
    for p in &players {
        assert!(p.welcomes >= 2, "client {} was welcomed {} times: no re-anchor after the takeover", p.id, p.welcomes);
        for seq in &p.acked {
            if p.ack_ticks[seq] <= last_logged {
                acked += 1;
                assert_eq!(
                    seen.logged_inputs.get(&(p.id.0, *seq)),
                    Some(&1),
                    "client {} seq {seq}: acked but logged {:?} times",
                    p.id,
                    seen.logged_inputs.get(&(p.id.0, *seq))
                );
            }
        }
    }
    assert!(acked > 100, "only {acked} acked inputs: the run tested little");
    // A few inputs sent in the moment no server owned the world may go unanswered; none is
    // refused (the clock the clients keep is the server's).
    assert!(rejects.is_empty(), "inputs were refused: {rejects:?}");
    let line = out.lines().find(|l| l.contains("acked inputs re-applied")).unwrap_or_default().to_string();
    eprintln!("failover: {acked} acked inputs all in the log once; {line}");
    // Inputs acked by the primary for ticks it never confirmed were applied by the standby.
    let reapplied: u32 = line
        .split(" acked inputs re-applied")
        .next()
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(reapplied > 0, "the takeover re-applied no acked input: the test did not reach that path");

    // The primary's recording (up to its death) replays to every hash it recorded.
    let replay = Command::new(server_binary())
        .arg("--scene")
        .arg(impact_core::scene::Scene::bundled_path("arena"))
        .args(["--offline", "--replay", &record_arg])
        .output()
        .expect("replay");
    let text = String::from_utf8_lossy(&replay.stdout);
    let _ = std::fs::remove_file(&record);
    assert!(replay.status.success() && text.contains("every recorded state hash reproduced"), "replay:\n{text}");
}

/// A subscriber that missed a confirmed batch asks for it again (`query/confirmed`): the standby
/// that took over answers for 2 s of ticks around the kill, those its primary confirmed (as it
/// heard them) and its own, each as the stream carried it; for one client, the batch its own
/// stream carries (the events of its avatar), an empty one for a tick without.
fn recovers_confirmed_batches(s: &zenoh::Session, world: &WorldId, seen: &Published, kill: Tick, players: &[Player]) {
    let (from, to) = (kill.0 - 64, kill.0 + 64);
    let key = keys::QUERY_CONFIRMED.key(world, None);
    let answered: BTreeMap<u32, impact_protocol::EventBatch> =
        query_all(s, key.clone(), &format!("from={from};to={to}"))
            .into_iter()
            .filter_map(|m| match m {
                ServerMessage::Confirmed(b) => Some((b.tick.0, b)),
                _ => None,
            })
            .collect();
    assert_eq!(answered.keys().copied().collect::<Vec<_>>(), (from..=to).collect::<Vec<_>>(), "ticks answered");
    let mut events = 0;
    for t in from..=to {
        assert_eq!(
            answered.get(&t),
            seen.confirmed.get(&t),
            "tick {t}: the answer is not the batch the stream carried"
        );
        events += answered[&t].events.len();
    }
    assert!(events > 0, "no events around the kill: the per-client answer is not tested");
    let p = players.iter().find(|p| p.avatar.is_some()).expect("a player with an avatar");
    let avatar = p.avatar.expect("checked");
    let mine = query_all(s, key, &format!("from={from};to={to};client={}", p.id.0));
    assert_eq!(mine.len(), answered.len(), "one batch per tick for client {}", p.id);
    let mut own = 0;
    for m in mine {
        let ServerMessage::Confirmed(b) = m else { panic!("not a confirmed batch: {m:?}") };
        let expected: Vec<_> =
            answered[&b.tick.0].events.iter().filter(|e| e.a == avatar || e.b == avatar).cloned().collect();
        own += expected.len();
        assert_eq!(b.events, expected, "tick {}: client {}'s batch", b.tick.0, p.id);
    }
    eprintln!(
        "failover: query/confirmed answered ticks {from}..={to} ({events} events, {own} of client {}) as the stream had them",
        p.id
    );
}

/// What one owner of a world published, as a tap through the router saw it.
#[derive(Default)]
struct Owners {
    /// Every world-wide message (events, corrections, confirmed, owner notices): its epoch and
    /// when it came.
    seen: Vec<(Option<Epoch>, Instant)>,
    /// The confirmed batches, in arrival order: tick and epoch.
    confirmed: Vec<(Tick, Option<Epoch>)>,
}

impl Owners {
    fn take(&mut self, taps: &[&Tap]) {
        for tap in taps {
            for t in tap.drain_tapped() {
                if let ServerMessage::Confirmed(b) = &t.msg {
                    self.confirmed.push((b.tick, t.epoch));
                }
                self.seen.push((t.epoch, t.at));
            }
        }
    }

    /// The epochs heard from `from` on.
    fn epochs_since(&self, from: Instant) -> BTreeMap<Option<Epoch>, usize> {
        let mut n = BTreeMap::new();
        for (e, at) in &self.seen {
            if *at >= from {
                *n.entry(*e).or_default() += 1;
            }
        }
        n
    }

    /// Each tick confirmed once, in order, without a gap; `servers` (what they printed) is
    /// shown if not.
    fn confirmed_once(&self, servers: &str) {
        assert!(self.confirmed.len() > 300, "only {} confirmed ticks:\n{servers}", self.confirmed.len());
        for w in self.confirmed.windows(2) {
            assert_eq!(w[1].0 .0, w[0].0 .0 + 1, "confirmed went from tick {:?} to {:?}:\n{servers}", w[0], w[1]);
        }
    }
}

/// The taps a fencing test listens with: every world-wide stream, the owner's notices included.
fn world_taps(s: &zenoh::Session, world: &WorldId) -> Vec<Tap> {
    [keys::EVENTS, keys::CORRECTIONS, keys::CONFIRMED, keys::OWNER]
        .iter()
        .map(|k| Tap::new(s, &k.key(world, None)))
        .collect()
}

/// A primary and a standby behind a router, and the primary stands still for 4 s (SIGSTOP, then
/// SIGCONT: a hung host, a long pause) with its sockets open. Its lease runs out, the standby
/// takes over as epoch 2, and when the primary resumes it publishes nothing more: it holds its
/// messages, hears the newer owner, ends the world and exits with status 3. Through the router,
/// every tick is confirmed exactly once across the takeover, nothing of epoch 1 arrives after the
/// resume, and the world ends with one owner.
#[test]
fn a_stalled_primary_comes_back_fenced() {
    let router = endpoint();
    let _router = Proc::router("fence-router", &router, &[]);
    std::thread::sleep(Duration::from_millis(500));
    let mut primary = server("fence-primary", &["arena"], &router, &["--quiet"]);
    assert!(primary.wait_for_output("listening on", Duration::from_secs(20)), "{}", primary.output());
    let world = WorldId::new("arena").unwrap();
    let s = through(&router);
    let taps = world_taps(&s, &world);
    let _tokens: Vec<_> = (0..4).map(|k| join(&s, &world, ClientId(400 + k))).collect();
    std::thread::sleep(Duration::from_secs(1));
    let mut standby = server("fence-standby", &["arena"], &router, &["--standby"]);
    assert!(
        standby.wait_for_output("following from the checkpoint", Duration::from_secs(20)),
        "the standby never restored a checkpoint:\n{}",
        standby.output()
    );
    let mut seen = Owners::default();
    let pause = |d: Duration, seen: &mut Owners| {
        let end = Instant::now() + d;
        while Instant::now() < end {
            seen.take(&taps.iter().collect::<Vec<_>>());
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    pause(Duration::from_secs(2), &mut seen);
    primary.signal("STOP");
    pause(Duration::from_secs(4), &mut seen);
    primary.signal("CONT");
    let resumed = Instant::now();
    pause(Duration::from_secs(6), &mut seen);
    let exit = primary.wait(Duration::from_secs(5));
    let status = standby.stop();
    std::thread::sleep(Duration::from_millis(500));
    seen.take(&taps.iter().collect::<Vec<_>>());
    let (p_out, s_out) = (primary.output(), standby.output());
    assert!(status.is_some_and(|x| x.success()), "the standby did not stop cleanly:\n{s_out}");
    assert!(s_out.contains("took over at tick") && s_out.contains("as epoch 2"), "no takeover at epoch 2:\n{s_out}");
    assert!(p_out.contains("stood still for"), "the primary never saw it stood still:\n{p_out}");
    assert!(p_out.contains("another server owns it now (epoch 2"), "the primary was not fenced:\n{p_out}");
    assert_eq!(exit.and_then(|x| x.code()), Some(3), "the fenced primary did not exit with status 3:\n{p_out}");
    // Nothing from the old owner once it resumed; the new owner's messages all carry its epoch.
    let after = seen.epochs_since(resumed);
    eprintln!("fence: epochs heard after the resume: {after:?}");
    assert_eq!(after.get(&Some(Epoch(1))), None, "the primary published after it resumed: {after:?}");
    assert_eq!(after.get(&None), None, "messages without an epoch: {after:?}");
    assert!(after.get(&Some(Epoch(2))).is_some_and(|n| *n > 100), "the new owner was not heard: {after:?}");
    seen.confirmed_once(&format!("{p_out}\n{s_out}"));
    let epochs: BTreeSet<_> = seen.confirmed.iter().map(|(_, e)| *e).collect();
    assert_eq!(epochs, BTreeSet::from([Some(Epoch(1)), Some(Epoch(2))]), "confirmed by {epochs:?}");
}

/// A primary alone behind a router stands still past its lease (SIGSTOP for 2.5 s, then SIGCONT):
/// it holds its messages until it knows no other server took the world over, goes on, and
/// welcomes its clients again on its present (PROTOCOL.md, "The server hangs and comes back"):
/// their clocks follow it at once, and each can tell which inputs it sent into the silence never
/// arrived. (The clients' presence, declared anew through the router after the stall, welcomes
/// them too here; the hold's own welcome makes it not depend on Zenoh doing so.)
#[test]
fn a_primary_that_held_past_its_lease_welcomes_its_clients_again() {
    let router = endpoint();
    let _router = Proc::router("hold-router", &router, &[]);
    std::thread::sleep(Duration::from_millis(500));
    let mut primary = server("hold-primary", &["arena"], &router, &["--quiet"]);
    assert!(primary.wait_for_output("listening on", Duration::from_secs(20)), "{}", primary.output());
    let world = WorldId::new("arena").unwrap();
    let s = through(&router);
    let ids = [ClientId(450), ClientId(451)];
    let taps: Vec<Tap> = ids.iter().map(|c| Tap::new(&s, &keys::CLIENT_ACK.key(&world, Some(*c)))).collect();
    let _tokens: Vec<_> = ids.iter().map(|c| join(&s, &world, *c)).collect();
    let welcomed = |tap: &Tap| {
        tap.wait_for(Duration::from_secs(10), |_, m, at| match m {
            ServerMessage::Welcome(w) => Some((w.tick, at)),
            _ => None,
        })
    };
    let first: Vec<_> = taps.iter().map(|t| welcomed(t).expect("a first welcome")).collect();
    std::thread::sleep(Duration::from_millis(500));
    primary.signal("STOP");
    std::thread::sleep(Duration::from_millis(2500));
    primary.signal("CONT");
    let resumed = Instant::now();
    for (k, tap) in taps.iter().enumerate() {
        let Some((tick, at)) = welcomed(tap) else {
            panic!("client {} was not welcomed again:\n{}", ids[k].0, primary.output());
        };
        let after = at.duration_since(resumed);
        eprintln!(
            "hold: client {} welcomed again {:.2} s after the resume, at tick {}",
            ids[k].0,
            after.as_secs_f64(),
            tick.0
        );
        assert!(after >= Duration::from_millis(1500), "welcomed during the hold ({after:?})");
        assert!(tick > first[k].0, "the second welcome names tick {} after {}", tick.0, first[k].0 .0);
    }
    let status = primary.stop();
    let out = primary.output();
    assert!(out.contains("holding its messages") && out.contains("publishing again"), "no hold:\n{out}");
    assert!(status.is_some_and(|x| x.success()), "the primary did not stop cleanly:\n{out}");
}

/// The only router restarts under a primary and a standby that reach each other through it
/// alone (Zenoh clients of the router, as servers in separate network segments are): the standby
/// sees the primary's token go with the router, and must not take over a world whose primary is
/// alive. After the restart one owner publishes, at epoch 1, and no tick is confirmed twice.
#[test]
fn a_router_restart_leaves_one_owner() {
    let router = endpoint();
    let mut r = Proc::router("restart-router", &router, &[]);
    std::thread::sleep(Duration::from_millis(500));
    // Clients of the router: no direct link between the two servers that would carry the token.
    let config = std::env::temp_dir().join(format!("impact-restart-{}.json5", std::process::id()));
    std::fs::write(
        &config,
        r#"{ mode: "client", scouting: { multicast: { enabled: false } },
             connect: { retry: { period_init_ms: 100, period_max_ms: 500, period_increase_factor: 2 } },
             transport: { link: { tx: { lease: 1500 } } } }"#,
    )
    .expect("config");
    let config_arg = config.to_string_lossy().to_string();
    let client_mode = ["--quiet", "--zenoh-config", config_arg.as_str()];
    let mut primary = server("restart-primary", &["arena"], &router, &client_mode);
    assert!(primary.wait_for_output("listening on", Duration::from_secs(20)), "{}", primary.output());
    let world = WorldId::new("arena").unwrap();
    std::thread::sleep(Duration::from_secs(1));
    let mut standby = server("restart-standby", &["arena"], &router, &["--standby", "--zenoh-config", &config_arg]);
    assert!(
        standby.wait_for_output("following from the checkpoint", Duration::from_secs(20)),
        "the standby never restored a checkpoint:\n{}",
        standby.output()
    );
    r.signal("KILL");
    let _ = r.wait(Duration::from_secs(5));
    std::thread::sleep(Duration::from_secs(1));
    let _r2 = Proc::router("restart-router-2", &router, &[]);
    std::thread::sleep(Duration::from_secs(2));
    // A tap through the new router, from here on.
    let s = through(&router);
    let taps = world_taps(&s, &world);
    let mut seen = Owners::default();
    let from = Instant::now();
    while from.elapsed() < Duration::from_secs(6) {
        seen.take(&taps.iter().collect::<Vec<_>>());
        std::thread::sleep(Duration::from_millis(20));
    }
    let status = standby.stop();
    let s_out = standby.output();
    let p_status = primary.stop();
    let p_out = primary.output();
    let _ = std::fs::remove_file(&config);
    assert!(!s_out.contains("took over"), "the standby took over from a live primary:\n{s_out}");
    // It did see the token go: the case under test was reached.
    let cut = s_out.lines().find(|l| l.contains("cut off from every router"));
    eprintln!("router restart: {}", cut.unwrap_or("the standby never saw itself cut off"));
    assert!(cut.is_some(), "the standby never saw itself cut off:\n{s_out}");
    assert!(status.is_some_and(|x| x.success()), "the standby did not stop cleanly:\n{s_out}");
    assert!(p_status.is_some_and(|x| x.success()), "the primary did not stop cleanly:\n{p_out}");
    assert!(!p_out.contains("another server owns it"), "the primary was fenced:\n{p_out}");
    let heard = seen.epochs_since(from);
    eprintln!("router restart: epochs heard after it: {heard:?}");
    assert_eq!(heard.keys().copied().collect::<Vec<_>>(), vec![Some(Epoch(1))], "owners heard: {heard:?}");
    seen.confirmed_once(&format!("{p_out}\n{s_out}"));
}

/// Access control at the edge, as README deploys it: a zenohd router loaded with what
/// `impact-server --users FILE --print-acl` prints (and the dictionary beside it), a server behind
/// it without `--users` that authenticates as the deployment's `[[server]]`, and players in client
/// mode through the router with their own credentials. Alice plays as usual; mallory cannot put an
/// input on alice's key, read alice's answers (by key or by wildcard), or spawn bob with a token
/// on bob's presence key; a session without the right password gets nowhere.
#[test]
fn the_router_enforces_the_acl_the_server_prints() {
    let dir = std::env::temp_dir().join(format!("impact-router-acl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let users = dir.join("users.toml");
    let dict = dir.join("users.dict");
    std::fs::write(&users, common::USERS).expect("users file");
    std::fs::write(&dict, "alice:alice-secret\nbob:bob-secret\nmallory:mallory-secret\nsrv:srv-secret\n")
        .expect("dict");
    let printed = Command::new(server_binary())
        .arg("--users")
        .arg(&users)
        .arg("--print-acl")
        .arg("--dictionary-path")
        .arg(&dict)
        .output()
        .expect("impact-server --print-acl");
    assert!(printed.status.success(), "--print-acl: {}", String::from_utf8_lossy(&printed.stderr));
    let mut config: serde_json::Value = serde_json::from_slice(&printed.stdout).expect("--print-acl prints JSON");
    let router = endpoint();
    config["mode"] = "router".into();
    config["scouting"] = serde_json::json!({ "multicast": { "enabled": false } });
    config["listen"] = serde_json::json!({ "endpoints": [router] });
    let router_config = dir.join("router.json5");
    std::fs::write(&router_config, config.to_string()).expect("router config");
    let mut cmd = Command::new(common::process::zenohd());
    cmd.arg("--config").arg(&router_config);
    let _router = Proc::spawn("acl-router", cmd);
    std::thread::sleep(Duration::from_millis(800));

    // The server authenticates as the deployment's server; it enforces nothing itself.
    let server_config = dir.join("server.json5");
    let server_json = serde_json::json!({
        "mode": "peer",
        "scouting": { "multicast": { "enabled": false } },
        "listen": { "endpoints": ["tcp/127.0.0.1:0"] },
        "transport": { "auth": { "usrpwd": { "user": "srv", "password": "srv-secret" } } },
    });
    std::fs::write(&server_config, server_json.to_string()).expect("server config");
    let server_config_arg = server_config.to_string_lossy().to_string();
    let mut server = server("acl-server", &["arena"], &router, &["--quiet", "--zenoh-config", &server_config_arg]);
    assert!(server.wait_for_output("listening on", Duration::from_secs(20)), "{}", server.output());
    std::thread::sleep(Duration::from_millis(500));

    let world = WorldId::new("arena").unwrap();
    let player = |name: &str, password: &str| {
        let creds = net::Credentials { user: name.into(), password: password.into() };
        net::open(std::slice::from_ref(&router), None, Some(&creds), Mode::Client)
    };
    let alice = player("alice", "alice-secret").expect("alice connects through the router");
    let mallory = player("mallory", "mallory-secret").expect("mallory connects");
    assert!(player("alice", "wrong").is_err(), "a wrong password opened a session through the router");
    let (alice_id, bob_id) = (ClientId(1), ClientId(2));
    let alice_ack = Tap::new(&alice, &keys::CLIENT_ACK.key(&world, Some(alice_id)));
    let stolen_ack = Tap::new(&mallory, &keys::CLIENT_ACK.key(&world, Some(alice_id)));
    let stolen_all = Tap::new(&mallory, &format!("impact/v1/{world}/client/**"));
    let _alice_token = join(&alice, &world, alice_id);
    let welcome = |tap: &Tap| {
        tap.wait_for(Duration::from_secs(10), |_, m, at| match m {
            ServerMessage::Welcome(w) => Some((w.avatar.expect("arena spawns avatars"), w.tick, at)),
            _ => None,
        })
    };
    let (avatar, tick, at) = welcome(&alice_ack).expect("alice is welcomed through the router");
    let walk = |seq: u32| ClientInput {
        aim_tick: None,
        view_tick: None,
        client: alice_id,
        seq,
        tick: Tick(tick.0 + (at.elapsed().as_secs_f64() * 64.0) as u32 + 3),
        actions: vec![impact_protocol::Action::SetVelocity { entity: avatar, velocity: [2.0, 0.0, 0.0] }],
    };
    let answer = |seq: u32, wait: Duration| {
        alice_ack.wait_for(wait, |_, m, _| match m {
            ServerMessage::Ack(a) if a.seq == seq => Some(true),
            ServerMessage::Reject(r) if r.seq == Some(seq) => Some(false),
            _ => None,
        })
    };
    send(&alice, &world, &walk(1));
    assert_eq!(answer(1, Duration::from_secs(5)), Some(true), "alice's own input is acked");
    // Mallory puts an input on alice's key, with alice's id; alice's next proves the path live.
    // (An answer to the forged one, before or after alice's, is looked for in the same wait.)
    send(&mallory, &world, &walk(2));
    send(&alice, &world, &walk(3));
    let mut forged = None;
    let third = alice_ack.wait_for(Duration::from_secs(5), |_, m, _| match m {
        m if answers(m, 2) => {
            forged = Some(format!("{m:?}"));
            None
        }
        m if answers(m, 3) => Some(matches!(m, ServerMessage::Ack(_))),
        _ => None,
    });
    assert_eq!(third, Some(true), "alice's third input");
    let forged = forged.or_else(|| answer(2, Duration::from_millis(500)).map(|a| format!("answered {a}")));
    assert_eq!(forged, None, "mallory's forged input reached the server");
    // Mallory heard none of alice's answers.
    let nothing = |tap: &Tap| tap.wait_for(Duration::from_millis(500), |k, m, _| Some(format!("{k}: {m:?}")));
    assert_eq!(nothing(&stolen_ack), None, "mallory read alice's ack key through the router");
    assert_eq!(nothing(&stolen_all), None, "mallory read another client's keys by wildcard");
    // Mallory declares bob's presence token: no avatar, no welcome for bob; bob's own works.
    let bob = player("bob", "bob-secret").expect("bob connects");
    let bob_ack = Tap::new(&bob, &keys::CLIENT_ACK.key(&world, Some(bob_id)));
    let spoofed = join(&mallory, &world, bob_id);
    assert!(welcome(&bob_ack).is_none(), "a token on bob's key from mallory spawned bob");
    drop(spoofed);
    let _bob_token = join(&bob, &world, bob_id);
    assert!(welcome(&bob_ack).is_some(), "bob's own token is honoured through the router");

    let status = server.stop();
    let out = server.output();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(status.is_some_and(|x| x.success()), "the server did not stop cleanly:\n{out}");
    assert!(out.contains("inputs accepted 2 "), "only alice's two inputs were accepted:\n{out}");
}

/// Network namespaces of one test, deleted (with their veth links) when dropped.
struct Namespaces(Vec<String>);

impl Namespaces {
    fn ip(args: &[&str]) -> Result<(), String> {
        let out = Command::new("ip").args(args).output().map_err(|e| format!("ip: {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!("ip {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()))
        }
    }

    /// A namespace with its loopback up.
    fn add(&mut self, name: String) -> Result<(), String> {
        Namespaces::ip(&["netns", "add", &name])?;
        self.0.push(name.clone());
        Namespaces::ip(&["-n", &name, "link", "set", "lo", "up"])
    }

    /// A veth pair between `a` (address `ip_a`) and `b` (`ip_b`), both /24.
    fn link(&self, a: &str, ip_a: &str, b: &str, ip_b: &str, tag: &str) -> Result<(), String> {
        let (ea, eb) =
            (format!("{tag}a{}", std::process::id() % 100_000), format!("{tag}b{}", std::process::id() % 100_000));
        Namespaces::ip(&["link", "add", &ea, "netns", a, "type", "veth", "peer", "name", &eb, "netns", b])?;
        Namespaces::ip(&["-n", a, "addr", "add", &format!("{ip_a}/24"), "dev", &ea])?;
        Namespaces::ip(&["-n", b, "addr", "add", &format!("{ip_b}/24"), "dev", &eb])?;
        Namespaces::ip(&["-n", a, "link", "set", &ea, "up"])?;
        Namespaces::ip(&["-n", b, "link", "set", &eb, "up"])
    }
}

impl Drop for Namespaces {
    fn drop(&mut self) {
        for n in &self.0 {
            let _ = Namespaces::ip(&["netns", "del", n]);
        }
    }
}

/// `cmd` run inside namespace `ns`.
fn inside(ns: &str, program: &std::path::Path) -> Command {
    let mut c = Command::new("ip");
    c.args(["netns", "exec", ns]).arg(program);
    c
}

/// Separate hosts, simulated: the router, the server and the clients each in a network
/// namespace of their own, the server's and the clients' joined to the router's by veth pairs
/// (10.77.1.0/24 and 10.77.2.0/24, addresses inside this test's namespaces only). The clients
/// cannot reach the server except through the router, and play a load run through it.
///
/// Needs root and iproute2 (CI has both); elsewhere it says why and does nothing.
#[test]
fn router_server_and_clients_in_separate_network_namespaces() {
    let tag = format!("impact{}", std::process::id());
    let mut ns = Namespaces(Vec::new());
    let (r, s, c) = (format!("{tag}-r"), format!("{tag}-s"), format!("{tag}-c"));
    if let Err(e) = ns.add(r.clone()) {
        eprintln!("SKIPPED: network namespaces are not available here (needs root and iproute2): {e}");
        return;
    }
    ns.add(s.clone()).expect("server namespace");
    ns.add(c.clone()).expect("client namespace");
    ns.link(&r, "10.77.1.1", &s, "10.77.1.2", "vs").expect("router <-> server link");
    ns.link(&r, "10.77.2.1", &c, "10.77.2.2", "vc").expect("router <-> client link");

    let zenohd = common::process::zenohd();
    let mut router = inside(&r, &zenohd);
    router.arg("--config").arg(common::process::router_config()).args(["--listen", "tcp/0.0.0.0:7447"]);
    router.env("RUST_LOG", "warn");
    let _router = Proc::spawn("netns-router", router);
    std::thread::sleep(Duration::from_millis(500));
    let mut cmd = inside(&s, &server_binary());
    cmd.arg("--scene").arg(impact_core::scene::Scene::bundled_path("arena"));
    cmd.args(["--listen", "tcp/10.77.1.2:7450", "--connect", "tcp/10.77.1.1:7447", "--quiet"]);
    let mut server = Proc::spawn("netns-server", cmd);
    assert!(server.wait_for_output("listening on", Duration::from_secs(20)), "{}", server.output());

    // The client namespace has no route to the server: only the router joins them.
    let direct = Command::new("ip")
        .args(["netns", "exec", &c, "timeout", "2", "bash", "-c", "exec 3<>/dev/tcp/10.77.1.2/7450"])
        .output()
        .expect("bash");
    assert!(!direct.status.success(), "the client namespace reached the server directly");

    // Built by `cargo test` for impact-client-sim's own integration tests.
    let sim = common::process::binary("impact-sim");
    let out = inside(&c, &sim)
        .args(["--connect", "tcp/10.77.2.1:7447", "--zenoh-mode", "client", "--world", "arena"])
        .args(["--clients", "40", "--duration", "5s", "--latency-ms", "20", "--jitter-ms", "5"])
        .args(["--assert-views", "--assert-p99-ms", "200"])
        .output()
        .expect("impact-sim");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    eprintln!("{}", text.lines().filter(|l| !l.starts_with("   ")).collect::<Vec<_>>().join("\n"));
    assert!(out.status.success(), "the load run through the router failed:\n{text}");
    assert!(text.contains("(40 welcomed)"), "not every client was welcomed:\n{text}");
    let status = server.stop();
    assert!(status.is_some_and(|x| x.success()), "{}", server.output());
}

/// Pumps `game` until `done` says so or `limit` passes, an input every 50 ms once it plays.
fn play_until(
    conn: &impact_client::transport::Connection,
    game: &mut impact_client::Session,
    limit: Duration,
    mut done: impl FnMut(&impact_client::Session) -> bool,
) -> bool {
    let end = Instant::now() + limit;
    let mut next = Instant::now();
    while Instant::now() < end {
        let now = Instant::now();
        conn.pump(game, now).expect("pump");
        if done(game) {
            return true;
        }
        if let (impact_client::Status::Playing, Some(avatar), true) = (game.status(), game.avatar(), now >= next) {
            next += Duration::from_millis(50);
            let action = impact_protocol::Action::SetVelocity { entity: avatar, velocity: [1.0, 0.0, 0.5] };
            game.input(vec![action], now).expect("input");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

/// The router a client plays through is killed and restarted on the same port mid-game: the
/// client's Zenoh session reconnects by itself, the server welcomes it again (it came back within
/// the grace period), and its inputs are answered again within 2 s of the restart; nothing it sent
/// was applied twice or refused as a replay.
#[test]
fn a_client_resumes_after_its_router_restarts() {
    use impact_client::transport::{ConnectOptions, Connection, Mode};
    let r = endpoint();
    let router = Proc::router("restart-r", &r, &[]);
    std::thread::sleep(Duration::from_millis(300));
    let srv = server("restart-s", &["arena"], &r, &["--quiet"]);
    assert!(srv.wait_for_output("listening on", Duration::from_secs(20)), "{}", srv.output());
    let world = WorldId::new("arena").unwrap();
    let me = ClientId(7);
    let opts = ConnectOptions { mode: Mode::Client, ..ConnectOptions::new(vec![r.clone()], world, me) };
    let conn = Connection::open(&opts).expect("connects through the router");
    let mut game = impact_client::Session::new(impact_client::SessionConfig::new(me));
    assert!(play_until(&conn, &mut game, Duration::from_secs(20), |g| g.stats().inputs_acked >= 20), "played");

    drop(router);
    play_until(&conn, &mut game, Duration::from_secs(1), |_| false);
    let router = Proc::router("restart-r2", &r, &[]);
    let restarted = Instant::now();
    let answered = game.stats().inputs_acked;
    let back = play_until(&conn, &mut game, Duration::from_secs(10), |g| g.stats().inputs_acked > answered);
    let took = restarted.elapsed();
    assert!(back, "never answered again after the restart: {:?}\nserver:\n{}", game.stats(), srv.output());
    assert!(took < Duration::from_secs(2), "the first answer came {took:?} after the restart");
    assert!(play_until(&conn, &mut game, Duration::from_secs(5), |g| g.stats().inputs_acked > answered + 20), "steady");
    let s = game.stats().clone();
    assert!(s.welcomes >= 2, "welcomed again: {s:?}");
    assert_eq!(s.rejects.get(&impact_protocol::RejectReason::Duplicate), None, "{s:?}");
    assert_eq!(s.unmatched_answers, 0, "an input answered twice: {s:?}");
    // The server's own count: never more inputs accepted than the client made.
    let stats = Tap::new(conn.zenoh(), &keys::STATS.key(&WorldId::new("arena").unwrap(), None));
    let accepted = stats
        .wait_for(Duration::from_secs(3), |_, m, _| match m {
            ServerMessage::Stats(st) => Some(st.inputs_accepted),
            _ => None,
        })
        .expect("stats");
    assert!(accepted <= s.inputs_sent && accepted >= s.inputs_acked, "{accepted} accepted, {s:?}");
    eprintln!(
        "router restart: first answer {took:?} after; {} welcomes; {accepted} accepted of {} sent",
        s.welcomes, s.inputs_sent
    );
    drop(router);
}
