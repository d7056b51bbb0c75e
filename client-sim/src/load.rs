//! The load generator: many simulated clients over a few Zenoh sessions, each one a player
//! behind a network path with latency, jitter and loss.
//!
//! Every client declares its presence, waits for its welcome (its avatar and the server's tick),
//! then acts at `input_hz`: it stamps each input with the tick it believes the server is at (its
//! own clock since the welcome, which it saw one downlink latency late), and sends it through the
//! uplink delay line, so inputs reach the server late and exercise rollback. Everything the server
//! sends back passes the downlink delay line before the client sees it. Each client keeps its
//! view of its event stream (events, then corrections) and checks it against every confirmed
//! tick.
//!
//! Clients share `sessions` Zenoh sessions (default one per 100 clients): a session per client
//! would cost a TCP connection and its buffers each, for nothing the test measures, and a single
//! session would serialise every client's traffic through one link.

use crate::report::Report;
use crate::timing::{Margins, Timing};
use hdrhistogram::Histogram;
use impact_client::clock::Clock;
use impact_client::events::EventView;
use impact_client::inputs::{Outbox, Sent};
use impact_client::netsim::{DelayLine, Link, Rng};
use impact_protocol::{
    keys, Action, ClientId, ClientInput, ClientMessage, Encoding, EntityId, RejectReason, ServerMessage, WorldId,
};
use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::atomic::AtomicU64;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use zenoh::Wait;

/// What the simulated players do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Behaviour {
    /// Random walks: a new random velocity at each input.
    Wander,
    /// Head for a moving point in the middle of the world.
    Chase,
    /// Fire hitscan rays in random directions, and move now and then.
    Shooter,
    /// A third of each.
    Mixed,
}

/// Load test settings.
#[derive(Clone, Debug)]
pub struct LoadConfig {
    /// Endpoints of the server (or a router).
    pub connect: Vec<String>,
    /// A Zenoh configuration file instead.
    pub zenoh_config: Option<PathBuf>,
    /// Peer or client sessions (client: through a router only).
    pub mode: crate::net::Mode,
    /// World name.
    pub world: WorldId,
    /// Number of clients.
    pub clients: u32,
    /// Id of the first client.
    pub first_client: u32,
    /// Zenoh sessions the clients share (ignored with `users`: one session per client).
    pub sessions: u32,
    /// Credentials by client id (a server's `--users` file): each client then has a session of
    /// its own, authenticated as the user that is that client, as a real deployment would.
    pub users: Option<impact_server::runtime::auth::Users>,
    /// Length of the load.
    pub duration: Duration,
    /// Client -> server path.
    pub uplink: Link,
    /// Server -> client path.
    pub downlink: Link,
    /// What players do.
    pub behaviour: Behaviour,
    /// How clients stamp their inputs.
    pub timing: Timing,
    /// Inputs per second per client.
    pub input_hz: f64,
    /// Encoding of inputs.
    pub encoding: Encoding,
    /// Seed for the random behaviour and the network model.
    pub seed: u64,
    /// Time after the load to wait for acks and confirmations.
    pub settle: Duration,
    /// Live progress.
    pub progress: bool,
    /// Faults to inject (none by default).
    pub faults: Faults,
    /// Subscribe each client to its state stream (`client/{id}/state`) and count its bytes.
    pub state: bool,
}

/// Faults injected into a load run: the fault simulation of `tests/tests/faults.rs` (in the
/// spirit of TigerBeetle's VOPR). [`Faults::from_seed`] draws them from one seed, so a failing
/// run is reproduced by its seed.
#[derive(Clone, Debug, Default)]
pub struct Faults {
    /// Probability that a delivered input is delivered a second time (a retransmission).
    pub duplicate: f64,
    /// Network partitions between the clients and the server: (start after the load began,
    /// length). Nothing crosses in either direction during one; what was sent meanwhile is
    /// delivered after it, in order, as Zenoh over TCP does after a stalled link recovers.
    pub partitions: Vec<(Duration, Duration)>,
    /// The server's process id, to stall it with SIGSTOP and resume it with SIGCONT.
    pub stall_pid: Option<u32>,
    /// Server stalls: (start after the load began, length).
    pub stalls: Vec<(Duration, Duration)>,
}

impl Faults {
    /// Faults for a run of `duration` drawn from `seed`: up to 10 % duplicated inputs, one or
    /// two partitions of 0.1 to 1.5 s, and (with `stall_pid`) one or two stalls of 0.1 to 1 s.
    pub fn from_seed(seed: u64, duration: Duration, stall_pid: Option<u32>) -> Faults {
        let mut rng = Rng::new(seed ^ 0x5eed_fa17);
        let d = duration.as_secs_f64();
        let mut windows = |n: usize, max_len: f64| -> Vec<(Duration, Duration)> {
            (0..n)
                .map(|_| {
                    let len = 0.1 + rng.unit() * (max_len - 0.1);
                    let start = rng.unit() * (d - len).max(0.0);
                    (Duration::from_secs_f64(start), Duration::from_secs_f64(len))
                })
                .collect()
        };
        let partitions = windows(1 + (seed % 2) as usize, 1.5);
        let stalls = if stall_pid.is_some() { windows(1 + (seed / 2 % 2) as usize, 1.0) } else { Vec::new() };
        let duplicate = Rng::new(seed).unit() * 0.1;
        Faults { duplicate, partitions, stall_pid, stalls }
    }

    fn partitioned(&self, since_start: Duration) -> bool {
        self.partitions.iter().any(|&(a, len)| since_start >= a && since_start < a + len)
    }

    fn stalled(&self, since_start: Duration) -> bool {
        self.stalls.iter().any(|&(a, len)| since_start >= a && since_start < a + len)
    }
}

/// Stops or resumes a process (SIGSTOP / SIGCONT) with `kill`, so nothing unsafe is needed here.
fn signal(pid: u32, stop: bool) {
    let sig = if stop { "-STOP" } else { "-CONT" };
    let _ = std::process::Command::new("kill").arg(sig).arg(pid.to_string()).status();
}

enum Inbound {
    Msg(usize, ServerMessage),
    Stats(impact_protocol::ServerStats),
}

struct Client {
    id: ClientId,
    behaviour: Behaviour,
    avatar: Option<EntityId>,
    clock: Clock,
    /// Sequence numbers, and the inputs sent awaiting an answer (bounded).
    outbox: Outbox,
    next_action: Instant,
    /// Answers owed by the server, per seq: one per delivery (two for a duplicated input).
    owed: BTreeMap<u32, u32>,
    /// Seqs acked, kept only while duplicates are injected: a second ack is a replay accepted, and
    /// a copy delivered after its ack is owed no answer.
    acked: std::collections::BTreeSet<u32>,
    view: EventView,
    margins: Margins,
    corrections: u64,
}

impl Client {
    fn new(id: ClientId, behaviour: Behaviour, next_action: Instant) -> Client {
        Client {
            id,
            behaviour,
            avatar: None,
            clock: Clock::new(),
            outbox: Outbox::default(),
            next_action,
            owed: BTreeMap::new(),
            acked: Default::default(),
            view: EventView::default(),
            margins: Margins::default(),
            corrections: 0,
        }
    }

    /// An ack of `seq`: nothing more is owed for it, however many copies were delivered (a copy
    /// of an accepted input is skipped without an answer); false when none was owed.
    fn accepted(&mut self, seq: u32) -> bool {
        self.owed.remove(&seq).is_some()
    }

    /// Counts a reject of `seq` (a rejected input does not use up its seq, so each copy of it is
    /// answered); false when none was owed (answered twice, or never sent).
    fn answered(&mut self, seq: u32) -> bool {
        match self.owed.get_mut(&seq) {
            Some(n) if *n > 1 => {
                *n -= 1;
                true
            }
            Some(_) => {
                self.owed.remove(&seq);
                true
            }
            None => false,
        }
    }
}

fn act(c: &mut Client, rng: &mut Rng, timing: Timing, now: Instant) -> Option<ClientInput> {
    let entity = c.avatar?;
    let (tick, view) = c.clock.stamp(timing == Timing::Ahead, now)?;
    let seq = c.outbox.next_seq();
    let dir = |rng: &mut Rng| {
        let a = std::f64::consts::TAU * rng.unit();
        [a.cos(), 0.3 * (rng.unit() - 0.5), a.sin()]
    };
    let action = match c.behaviour {
        Behaviour::Wander => {
            let d = dir(rng);
            let s = 2.0 + 6.0 * rng.unit();
            Action::SetVelocity { entity, velocity: [d[0] * s, d[1] * s, d[2] * s] }
        }
        Behaviour::Chase => {
            // The goal circles the middle of the world; players head roughly for it.
            let t = now.elapsed().as_secs_f64() + f64::from(seq) * 0.1;
            let goal = [10.0 * t.cos(), 10.0, 10.0 * t.sin()];
            let jitter = dir(rng);
            Action::SetVelocity {
                entity,
                velocity: [goal[0] * 0.3 + jitter[0], (goal[1] - 10.0) * 0.3, goal[2] * 0.3 + jitter[2]],
            }
        }
        Behaviour::Shooter | Behaviour::Mixed => {
            if rng.unit() < 0.7 {
                let d = dir(rng);
                let o = [40.0 * (rng.unit() - 0.5), 2.0 + 15.0 * rng.unit(), 40.0 * (rng.unit() - 0.5)];
                Action::FireRay { shooter: entity, origin: o, direction: d, max_distance_m: 60.0 }
            } else {
                let d = dir(rng);
                Action::SetVelocity { entity, velocity: [d[0] * 5.0, d[1] * 5.0, d[2] * 5.0] }
            }
        }
    };
    // Behind mode stamps the view tick itself; saying so again would change nothing.
    let view_tick = (timing == Timing::Ahead).then_some(view);
    Some(ClientInput { client: c.id, seq, tick, view_tick, actions: vec![action] })
}

/// The sessions the clients share, or with `users` one per client, authenticated as its user.
fn open_sessions(cfg: &LoadConfig) -> anyhow::Result<Vec<zenoh::Session>> {
    let file = cfg.zenoh_config.as_deref();
    let Some(users) = &cfg.users else {
        return (0..cfg.sessions.max(1)).map(|_| crate::net::open(&cfg.connect, file, None, cfg.mode)).collect();
    };
    let mut sessions = Vec::with_capacity(cfg.clients as usize);
    for k in 0..cfg.clients {
        let id = cfg.first_client + k;
        let u = users.for_client(id).ok_or_else(|| anyhow::anyhow!("the users file has no user for client {id}"))?;
        let creds = crate::net::Credentials { user: u.name.clone(), password: u.password.clone() };
        sessions.push(crate::net::open(&cfg.connect, file, Some(&creds), cfg.mode)?);
        if cfg.progress && (k + 1) % 100 == 0 {
            eprintln!("  {} of {} sessions authenticated", k + 1, cfg.clients);
        }
    }
    Ok(sessions)
}

/// Messages the callbacks queue for the run loop: at most this many (past it they are dropped and
/// counted), about a second of 1,000 busy clients.
const INBOX_MAX: usize = 1 << 20;

/// What the callbacks hand the run loop, with when each arrived.
type Inbox = Arc<Mutex<Vec<(Instant, Inbound)>>>;

/// A run's Zenoh side: the sessions, and the subscriptions and presence tokens that live as long
/// as the run, with what their callbacks fill.
struct Wiring {
    sessions: Vec<zenoh::Session>,
    inbox: Inbox,
    /// Messages the inbox had no room for.
    inbox_dropped: Arc<AtomicU64>,
    /// State stream bytes and frames received by every client, counted without decoding.
    state_bytes: Arc<AtomicU64>,
    state_frames: Arc<AtomicU64>,
    subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    tokens: Vec<zenoh::liveliness::LivelinessToken>,
}

impl Wiring {
    /// Opens the sessions and subscribes each client to its answers, events and (with `state`)
    /// state stream, and the run to the stats.
    fn connect(cfg: &LoadConfig, clients: &[Client]) -> anyhow::Result<Wiring> {
        let mut w = Wiring {
            sessions: open_sessions(cfg)?,
            inbox: Arc::new(Mutex::new(Vec::new())),
            inbox_dropped: Arc::new(AtomicU64::new(0)),
            state_bytes: Arc::new(AtomicU64::new(0)),
            state_frames: Arc::new(AtomicU64::new(0)),
            subscribers: Vec::new(),
            tokens: Vec::new(),
        };
        for (k, c) in clients.iter().enumerate() {
            w.subscribe_client(cfg, k, c.id)?;
        }
        let inbox = w.inbox.clone();
        let stats = w.sessions[0]
            .declare_subscriber(keys::STATS.key(&cfg.world, None))
            .callback(move |sample| {
                if let Ok(ServerMessage::Stats(s)) = crate::net::decode_server(&sample) {
                    inbox.lock().unwrap_or_else(|e| e.into_inner()).push((Instant::now(), Inbound::Stats(s)));
                }
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("subscribing: {e}"))?;
        w.subscribers.push(stats);
        Ok(w)
    }

    /// The session client `k` shares.
    fn session(&self, k: usize) -> &zenoh::Session {
        &self.sessions[k % self.sessions.len()]
    }

    fn subscribe_client(&mut self, cfg: &LoadConfig, k: usize, id: ClientId) -> anyhow::Result<()> {
        for pattern in [keys::CLIENT_ACK, keys::CLIENT_EVENTS] {
            let inbox = self.inbox.clone();
            let dropped = self.inbox_dropped.clone();
            let sub = self
                .session(k)
                .declare_subscriber(pattern.key(&cfg.world, Some(id)))
                .callback(move |sample| {
                    if let Ok(msg) = crate::net::decode_server(&sample) {
                        let mut q = inbox.lock().unwrap_or_else(|e| e.into_inner());
                        if q.len() < INBOX_MAX {
                            q.push((Instant::now(), Inbound::Msg(k, msg)));
                        } else {
                            dropped.fetch_add(1, Relaxed);
                        }
                    }
                })
                .wait()
                .map_err(|e| anyhow::anyhow!("subscribing: {e}"))?;
            self.subscribers.push(sub);
        }
        if cfg.state {
            let (bytes, frames) = (self.state_bytes.clone(), self.state_frames.clone());
            let sub = self
                .session(k)
                .declare_subscriber(keys::CLIENT_STATE.key(&cfg.world, Some(id)))
                .callback(move |sample| {
                    bytes.fetch_add(sample.payload().len() as u64, Relaxed);
                    frames.fetch_add(1, Relaxed);
                })
                .wait()
                .map_err(|e| anyhow::anyhow!("subscribing: {e}"))?;
            self.subscribers.push(sub);
        }
        Ok(())
    }

    /// Declares every client's presence: last, so every subscription is in place when the
    /// welcome comes.
    fn declare_presence(&mut self, cfg: &LoadConfig, clients: &[Client]) -> anyhow::Result<()> {
        for (k, c) in clients.iter().enumerate() {
            let t = self
                .session(k)
                .liveliness()
                .declare_token(keys::PRESENCE.key(&cfg.world, Some(c.id)))
                .wait()
                .map_err(|e| anyhow::anyhow!("presence token: {e}"))?;
            self.tokens.push(t);
        }
        Ok(())
    }

    /// State stream bytes and frames counted so far.
    fn state_counts(&self) -> (u64, u64) {
        (self.state_bytes.load(Relaxed), self.state_frames.load(Relaxed))
    }

    /// Drops the tokens and subscriptions, then closes the sessions.
    fn close(self) {
        drop(self.tokens);
        drop(self.subscribers);
        for s in self.sessions {
            let _ = s.close().wait();
        }
    }
}

/// The run loop's state: the clients, both delay lines, and the figures gathered.
struct Run<'a> {
    cfg: &'a LoadConfig,
    clients: Vec<Client>,
    rng: Rng,
    up: DelayLine<(usize, u32, Vec<u8>)>,
    down: DelayLine<Inbound>,
    /// Input round trips, microseconds.
    latency: Histogram<u64>,
    /// How many ticks back each correction reached.
    depth: Histogram<u64>,
    /// Every tick's duration the server reported during the load, microseconds (1 us to 1 h).
    server_ticks: Histogram<u64>,
    r: Report,
    /// Time between one client's inputs.
    period: Duration,
    load_start: Instant,
    load_end: Instant,
    server_stopped: bool,
    input_keys: Vec<String>,
}

/// Runs the load and returns its report.
pub fn run(cfg: &LoadConfig) -> anyhow::Result<Report> {
    let start = Instant::now();
    let clients: Vec<Client> = (0..cfg.clients as usize)
        .map(|k| {
            let id = ClientId(cfg.first_client + k as u32);
            let behaviour = match cfg.behaviour {
                Behaviour::Mixed => [Behaviour::Wander, Behaviour::Chase, Behaviour::Shooter][k % 3],
                b => b,
            };
            Client::new(id, behaviour, start)
        })
        .collect();
    let mut wiring = Wiring::connect(cfg, &clients)?;
    wiring.declare_presence(cfg, &clients)?;
    let mut run = Run::new(cfg, clients, wiring.sessions.len())?;
    // State streams are counted over the load alone.
    wiring.state_bytes.store(0, Relaxed);
    wiring.state_frames.store(0, Relaxed);
    let mut state_at_end = None;
    let tty = std::io::stderr().is_terminal();
    let mut last_progress = Instant::now();
    let stop = run.load_end + cfg.settle;
    loop {
        let now = Instant::now();
        if now >= stop {
            break;
        }
        if now >= run.load_end && state_at_end.is_none() {
            state_at_end = Some(wiring.state_counts());
        }
        run.downlink(&wiring.inbox, now);
        if now < run.load_end {
            run.act(now);
        }
        run.uplink(&wiring, now);
        if last_progress.elapsed() >= Duration::from_secs(1) {
            last_progress = Instant::now();
            if cfg.progress {
                let line = run.progress_line();
                if tty {
                    eprint!("\r{line}   ");
                } else {
                    eprintln!("{line}");
                }
            }
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    if cfg.progress && tty {
        eprintln!();
    }
    if run.server_stopped {
        if let Some(pid) = cfg.faults.stall_pid {
            signal(pid, false);
        }
    }
    let r = run.report(state_at_end.unwrap_or_else(|| wiring.state_counts()));
    wiring.close();
    let _ = std::io::stderr().flush();
    Ok(r)
}

impl Run<'_> {
    fn new(cfg: &LoadConfig, clients: Vec<Client>, sessions: usize) -> anyhow::Result<Run<'_>> {
        let load_start = Instant::now();
        Ok(Run {
            cfg,
            input_keys: clients.iter().map(|c| keys::INPUT.key(&cfg.world, Some(c.id))).collect(),
            clients,
            rng: Rng::new(cfg.seed),
            up: DelayLine::new(1 << 20),
            down: DelayLine::new(1 << 21),
            latency: Histogram::new_with_bounds(1, 60_000_000, 3).map_err(|e| anyhow::anyhow!("{e}"))?,
            depth: Histogram::new_with_bounds(1, 100_000, 3).map_err(|e| anyhow::anyhow!("{e}"))?,
            server_ticks: Histogram::new_with_bounds(1, 3_600_000_000, 3).map_err(|e| anyhow::anyhow!("{e}"))?,
            r: Report {
                clients: cfg.clients,
                sessions: sessions as u32,
                duration_s: cfg.duration.as_secs_f64(),
                ..Report::default()
            },
            period: Duration::from_secs_f64(1.0 / cfg.input_hz.max(0.1)),
            load_start,
            load_end: load_start + cfg.duration,
            server_stopped: false,
        })
    }

    /// Received messages enter the downlink delay line; due ones reach their client (none while
    /// a partition holds the line).
    fn downlink(&mut self, inbox: &Inbox, now: Instant) {
        let arrived = std::mem::take(&mut *inbox.lock().unwrap_or_else(|e| e.into_inner()));
        for (at, m) in arrived {
            self.down.send(at, &self.cfg.downlink, &mut self.rng, m);
        }
        let cut = self.cfg.faults.partitioned(now.saturating_duration_since(self.load_start));
        while let Some(m) = if cut { None } else { self.down.pop_due(now) } {
            match m {
                Inbound::Stats(s) => self.on_stats(&s, now),
                Inbound::Msg(k, msg) => self.on_message(k, msg, now),
            }
        }
    }

    fn on_stats(&mut self, s: &impact_protocol::ServerStats, now: Instant) {
        let r = &mut self.r;
        r.server_overruns = s.overruns;
        r.server_queue_depth_max = r.server_queue_depth_max.max(s.queue_depth_max);
        if now < self.load_end {
            // The server's seconds under load: every tick's duration, and the rollbacks they
            // counted.
            for t in &s.tick_ms {
                let _ = self.server_ticks.record((f64::from(*t) * 1e3).round().max(1.0) as u64);
            }
            r.server_rollbacks += u64::from(s.rollbacks);
            r.server_rollback_depth_max = r.server_rollback_depth_max.max(s.rollback_depth_max);
        }
        // Once a second every client hears the server's tick, even one that no event concerns.
        for c in self.clients.iter_mut() {
            r.clock_resyncs += u64::from(c.clock.observe(s.tick, now));
        }
    }

    fn on_message(&mut self, k: usize, msg: ServerMessage, now: Instant) {
        let (r, c) = (&mut self.r, &mut self.clients[k]);
        match msg {
            ServerMessage::Welcome(w) => {
                if c.avatar.is_none() && w.avatar.is_some() {
                    r.clients_welcomed += 1;
                }
                c.avatar = w.avatar;
                c.clock.anchor(w.tick, w.tick_hz, now);
                // Spread the clients' actions over one period.
                c.next_action = now + self.period.mul_f64(k as f64 / self.cfg.clients.max(1) as f64);
            }
            ServerMessage::Ack(a) => {
                r.clock_resyncs += u64::from(c.clock.observe(a.server_tick, now));
                c.margins.record(a.margin_ticks);
                c.clock.recommend(a.lead_ticks);
                r.answers_unexpected += u64::from(!c.accepted(a.seq));
                if self.cfg.faults.duplicate > 0.0 && !c.acked.insert(a.seq) {
                    r.answers_unexpected += 1; // a duplicate delivery was accepted
                }
                if let Some(sent) = c.outbox.answered(a.seq) {
                    r.acks += 1;
                    let _ = self.latency.record((now - sent.at).as_micros().max(1) as u64);
                }
            }
            ServerMessage::Reject(j) => {
                if let Some(seq) = j.seq {
                    let view = c.outbox.answered(seq).and_then(|s| s.view);
                    if let (RejectReason::Future, Some(t), Some(v), Some(n)) = (j.reason, j.tick, view, j.newest_tick) {
                        c.clock.back_off(t, v, n);
                    }
                    // An accepted input whose entity went away before its tick was re-simulated
                    // is told so by a second message (PROTOCOL.md).
                    let after_ack = matches!(j.reason, RejectReason::UnknownEntity | RejectReason::NotOwner);
                    r.answers_unexpected += u64::from(!c.answered(seq) && !after_ack);
                } else {
                    r.answers_unexpected += 1;
                }
                *r.rejects.entry(j.reason.name().to_string()).or_insert(0) += 1;
            }
            ServerMessage::Events(b) => {
                r.clock_resyncs += u64::from(c.clock.observe(b.tick, now));
                r.events_received += b.events.len() as u64;
                c.view.events(&b);
            }
            ServerMessage::Corrections(cb) => {
                r.corrections += 1;
                c.corrections += 1;
                if let Some(t) = c.clock.server_tick(now) {
                    let _ = self.depth.record(u64::from(t.0.saturating_sub(cb.tick.0)).max(1));
                }
                c.view.correct(&cb);
            }
            ServerMessage::Confirmed(b) => {
                c.view.confirm(&b);
            }
            _ => {}
        }
    }

    /// Clients whose turn it is act; their inputs enter the uplink delay line (some twice, when
    /// duplicates are injected).
    fn act(&mut self, now: Instant) {
        let cfg = self.cfg;
        for (k, c) in self.clients.iter_mut().enumerate() {
            if c.next_action > now {
                continue;
            }
            c.next_action += self.period;
            let Some(input) = act(c, &mut self.rng, cfg.timing, now) else { continue };
            let (seq, sent) = (input.seq, Sent { at: now, tick: input.tick, view: input.view_tick });
            let Ok(bytes) = impact_protocol::encode(&ClientMessage::Input(input), cfg.encoding) else { continue };
            self.r.inputs_sent += 1;
            let twice = self.rng.unit() < cfg.faults.duplicate;
            if self.up.send(now, &cfg.uplink, &mut self.rng, (k, seq, bytes.clone())) {
                c.outbox.sent(seq, sent);
                if twice && self.up.send(now, &Link { loss: 0.0, ..cfg.uplink }, &mut self.rng, (k, seq, bytes)) {
                    self.r.inputs_duplicated += 1;
                }
            }
        }
    }

    /// Faults first: a partition holds both lines (they are FIFO, so holding is delaying); a
    /// stall stops the server process. Then the inputs due are put.
    fn uplink(&mut self, wiring: &Wiring, now: Instant) {
        let faults = &self.cfg.faults;
        let since = now.saturating_duration_since(self.load_start);
        let cut = faults.partitioned(since);
        if let Some(pid) = faults.stall_pid {
            let want = faults.stalled(since);
            if want != self.server_stopped {
                signal(pid, want);
                self.server_stopped = want;
                self.r.server_stalls += u64::from(want);
            }
        }
        while let Some((k, seq, bytes)) = if cut { None } else { self.up.pop_due(now) } {
            let put = wiring.session(k).put(&self.input_keys[k], bytes).encoding(self.cfg.encoding.zenoh_tag());
            if put.wait().is_ok() {
                self.r.inputs_delivered += 1;
                // A copy of an input already accepted is owed no answer.
                let c = &mut self.clients[k];
                if !c.acked.contains(&seq) {
                    *c.owed.entry(seq).or_insert(0) += 1;
                }
            }
        }
    }

    fn progress_line(&self) -> String {
        let r = &self.r;
        format!(
            "  {:5.1} s | welcomed {}/{} | inputs {} | acks {} | p99 {:.1} ms | events {} | corrections {} | views ok {} bad {}",
            self.load_start.elapsed().as_secs_f64(),
            r.clients_welcomed,
            self.cfg.clients,
            r.inputs_sent,
            r.acks,
            self.latency.value_at_quantile(0.99) as f64 / 1000.0,
            r.events_received,
            r.corrections,
            self.clients.iter().map(|c| c.view.matched).sum::<u64>(),
            self.clients.iter().map(|c| c.view.mismatched).sum::<u64>()
        )
    }

    /// The report: what was counted, with the quantiles, rates and per-client figures drawn from
    /// it. `state` is the state streams' (bytes, frames) at the end of the load.
    fn report(self, state: (u64, u64)) -> Report {
        let cfg = self.cfg;
        let (latency, depth, server_ticks, clients) = (&self.latency, &self.depth, &self.server_ticks, &self.clients);
        let mut r = self.r;
        r.inputs_lost_in_network = self.up.lost;
        r.inputs_unanswered = clients.iter().map(|c| c.owed.values().map(|&n| u64::from(n)).sum::<u64>()).sum();
        r.latency_ms_p50 = latency.value_at_quantile(0.5) as f64 / 1000.0;
        r.latency_ms_p99 = latency.value_at_quantile(0.99) as f64 / 1000.0;
        r.latency_ms_max = latency.max() as f64 / 1000.0;
        r.events_per_s = r.events_received as f64 / cfg.duration.as_secs_f64().max(1e-9);
        r.corrections_per_s = r.corrections as f64 / cfg.duration.as_secs_f64().max(1e-9);
        r.correction_depth_p50 = depth.value_at_quantile(0.5) as f64;
        r.correction_depth_max = depth.max() as f64;
        r.correction_depth_p99 = depth.value_at_quantile(0.99) as f64;
        let (bytes, frames) = state;
        r.state_frames = frames;
        r.state_bytes_per_client_s =
            bytes as f64 / (f64::from(cfg.clients.max(1)) * cfg.duration.as_secs_f64().max(1e-9));
        r.server_ticks_measured = server_ticks.len();
        if !server_ticks.is_empty() {
            r.server_tick_ms_p50 = server_ticks.value_at_quantile(0.5) as f64 / 1e3;
            r.server_tick_ms_p99 = server_ticks.value_at_quantile(0.99) as f64 / 1e3;
            r.server_tick_ms_max = server_ticks.max() as f64 / 1e3;
        }
        r.server_rollbacks_per_s = r.server_rollbacks as f64 / cfg.duration.as_secs_f64().max(1e-9);
        r.timing = Some(cfg.timing);
        let mut all = Margins::default();
        for c in clients {
            all.merge(&c.margins);
            r.per_client.push(crate::report::ClientTiming {
                client: c.id.0,
                margin_ticks_p1: c.margins.quantile(0.01),
                margin_ticks_p50: c.margins.quantile(0.5),
                margin_ticks_p99: c.margins.quantile(0.99),
                rollbacks_caused: c.margins.late(),
                corrections: c.corrections,
            });
        }
        r.margin_ticks_p1 = all.quantile(0.01);
        r.margin_ticks_p50 = all.quantile(0.5);
        r.margin_ticks_p99 = all.quantile(0.99);
        r.rollbacks_caused = all.late();
        r.rollbacks_caused_per_s = r.rollbacks_caused as f64 / cfg.duration.as_secs_f64().max(1e-9);
        r.views_matched = clients.iter().map(|c| c.view.matched).sum();
        r.views_mismatched = clients.iter().map(|c| c.view.mismatched).sum();
        let bucket = 5_000u64;
        let top = latency.max().div_ceil(bucket).min(400);
        r.latency_histogram =
            (1..=top).map(|b| (b as f64 * 5.0, latency.count_between((b - 1) * bucket + 1, b * bucket))).collect();
        r
    }
}
