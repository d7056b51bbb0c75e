//! The load generator: many simulated clients over a few Zenoh sessions, each one a player
//! behind a network path with latency, jitter and loss.
//!
//! Every client is an [`impact_client::Session`], the library a game uses: it declares its
//! presence, waits for its welcome, syncs its clock with the server's, then acts at `input_hz`
//! (inputs stamped ahead by the lead the acks recommend, or behind, each carrying the
//! unanswered ones before it). What it sends passes the uplink delay line, what the server sends
//! back the downlink one. `predict` of them are game clients: they read their state stream,
//! predict their avatar, draw at 60 frames a second, and twice a second draw their remote world
//! at one tick the server is asked about (`query/state?tick=T`): the prediction and
//! interpolation errors. Beside each session the load test keeps what the server owes it: an
//! answer per delivered input not yet accepted, never two acks for one seq.
//!
//! Clients share `sessions` Zenoh sessions (default one per 100 clients): a session per client
//! would cost a TCP connection and its buffers each, for nothing the test measures, and a single
//! session would serialise every client's traffic through one link.

use crate::ledger::Ledger;
use crate::report::{quantile, Report, UNEXPECTED_KEPT};
use crate::timing::{Margins, Timing};
use hdrhistogram::Histogram;
use impact_client::netsim::{DelayLine, Link, Rng};
use impact_client::predict::{PredictConfig, Predictor};
use impact_client::report::{DrawCheck, CHECK_EVERY};
use impact_client::{Outcome, Session, SessionConfig, Status};
use impact_protocol::{
    keys, Action, ClientId, ClientMessage, Encoding, EntityId, RejectReason, ServerMessage, Tick, WorldId,
};
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
    /// Play a deathmatch: head for the nearest other player drawn from the state stream (with
    /// `--state` or `--predict`), fire at it when within 40 m, jump now and then; wander while
    /// nobody is in sight.
    Fighter,
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
    /// Game clients among them (spread evenly over the ids): they read their state streams,
    /// predict their avatars and draw (see the module docs). 0: none.
    pub predict: u32,
    /// The rules the game clients predict with (`None`: the server's, asked with `query/scene`).
    pub scene: Option<impact_core::scene::SceneRules>,
}

/// Faults injected into a load run: the fault simulation of `tests/tests/faults.rs` (in the
/// spirit of TigerBeetle's VOPR). [`Faults::from_seed`] and [`Faults::deployment`] draw them from
/// one seed, so a failing run is reproduced by its seed (as far as real processes over real
/// Zenoh replay: the schedule is the seed's, the threads' timing is not).
#[derive(Clone, Debug, Default)]
pub struct Faults {
    /// Probability that a delivered input is delivered a second time (a retransmission).
    pub duplicate: f64,
    /// Network partitions between clients and the server, of every session or one. Nothing
    /// crosses in either direction during one; what was sent meanwhile is delivered after it, in
    /// order, as Zenoh over TCP does after a stalled link recovers within its lease.
    pub partitions: Vec<Window>,
    /// The server's process id, to stall it with SIGSTOP and resume it with SIGCONT.
    pub stall_pid: Option<u32>,
    /// Server stalls.
    pub stalls: Vec<Window>,
    /// A session of the load generator closed and opened again (a phone's network handover, a
    /// player's connection dropping): its clients' presence goes, what they send meanwhile is
    /// lost, and they come back on a new Zenoh session, to the avatar they had if within the
    /// server's grace period. Never the first session (it carries the world's stats).
    pub drops: Vec<Window>,
}

/// When a fault holds: from `start` after the load began, for `len`, on one of the load
/// generator's Zenoh sessions (the clients on it) or on all of them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    /// After the load began.
    pub start: Duration,
    /// How long.
    pub len: Duration,
    /// The session (`None`: every one).
    pub session: Option<usize>,
}

impl Window {
    /// Holds at `since` (after the load began) on `session`.
    fn holds(&self, session: usize, since: Duration) -> bool {
        self.session.is_none_or(|s| s == session) && since >= self.start && since < self.start + self.len
    }
}

/// The server's grace period for a client whose presence went (PROTOCOL.md, "Presence"): 128
/// ticks at 64 Hz. A client back well within it keeps its avatar.
pub const GRACE: Duration = Duration::from_secs(2);

impl Faults {
    /// Faults for a run of `duration` drawn from `seed`: up to 10 % duplicated inputs, one or
    /// two partitions of 0.1 to 1.5 s, and (with `stall_pid`) one or two stalls of 0.1 to 1 s.
    pub fn from_seed(seed: u64, duration: Duration, stall_pid: Option<u32>) -> Faults {
        let mut rng = Rng::new(seed ^ 0x5eed_fa17);
        let partitions = windows(&mut rng, 1 + (seed % 2) as usize, 0.1, 1.5, duration, None);
        let stalls = match stall_pid {
            Some(_) => windows(&mut rng, 1 + (seed / 2 % 2) as usize, 0.1, 1.0, duration, None),
            None => Vec::new(),
        };
        let duplicate = Rng::new(seed).unit() * 0.1;
        Faults { duplicate, partitions, stall_pid, stalls, drops: Vec::new() }
    }

    /// Faults for a deployment's run of `duration` over `sessions` sessions (at least 3), drawn
    /// from `seed`: up to 5 % duplicated inputs; one partition of every session (0.1 to 1 s) and
    /// one or two of a single session's clients (0.2 to 4 s: shorter and longer than the grace
    /// period, shorter than a lease); two sessions dropped, one for 0.3 to 1.5 s (back within
    /// the 2 s grace period) and another for 2.6 to 4 s (back past it); and (with `stall_pid`)
    /// a stall of 0.1 to 1 s, shorter than the server's 1.5 s lease. Everything ends a second
    /// before the load does, so what it left is answered while the load still runs.
    pub fn deployment(seed: u64, duration: Duration, sessions: usize, stall_pid: Option<u32>) -> Faults {
        let mut rng = Rng::new(seed ^ 0x0de9_10e5);
        let within = duration.saturating_sub(Duration::from_secs(1));
        let others = sessions.max(2) - 1;
        let one = |rng: &mut Rng| Some(1 + ((rng.unit() * others as f64) as usize).min(others - 1));
        let mut partitions = windows(&mut rng, 1, 0.1, 1.0, within, None);
        for _ in 0..1 + seed % 2 {
            let s = one(&mut rng);
            partitions.extend(windows(&mut rng, 1, 0.2, 4.0, within, s));
        }
        let short = one(&mut rng);
        let long = short.map(|s| 1 + s % others);
        let mut drops = windows(&mut rng, 1, 0.3, 1.5, within, short);
        drops.extend(windows(&mut rng, 1, 2.6, 4.0, within, long));
        let stalls = match stall_pid {
            Some(_) => windows(&mut rng, 1, 0.1, 1.0, within, None),
            None => Vec::new(),
        };
        Faults { duplicate: rng.unit() * 0.05, partitions, stall_pid, stalls, drops }
    }

    /// A long run's drops: every `every`, one session's clients dropped for `len` (sessions 1,
    /// 2, ... in turn; never the first, which carries the world's stats), the last ending at
    /// least a second before the load does. None with fewer than 2 sessions.
    pub fn periodic_drops(duration: Duration, sessions: usize, every: Duration, len: Duration) -> Vec<Window> {
        if sessions < 2 || every.is_zero() {
            return Vec::new();
        }
        let last = duration.saturating_sub(len + Duration::from_secs(1));
        (1u32..)
            .map(|k| every * k)
            .take_while(|start| *start <= last)
            .enumerate()
            .map(|(k, start)| Window { start, len, session: Some(1 + k % (sessions - 1)) })
            .collect()
    }

    /// When the partition holding at `since_start` on `session` ends, if one does.
    fn partition_end(&self, session: usize, since_start: Duration) -> Option<Duration> {
        self.partitions.iter().filter(|w| w.holds(session, since_start)).map(|w| w.start + w.len).max()
    }

    /// Whether `session` is dropped at `since_start`.
    fn dropped(&self, session: usize, since_start: Duration) -> bool {
        self.drops.iter().any(|w| w.holds(session, since_start))
    }
}

/// `n` windows of `min_s` to `max_s` seconds each, inside `within`, on `session`.
fn windows(rng: &mut Rng, n: usize, min_s: f64, max_s: f64, within: Duration, session: Option<usize>) -> Vec<Window> {
    let d = within.as_secs_f64();
    (0..n)
        .map(|_| {
            let len = min_s + rng.unit() * (max_s - min_s);
            let start = rng.unit() * (d - len).max(0.0);
            Window { start: Duration::from_secs_f64(start), len: Duration::from_secs_f64(len), session }
        })
        .collect()
}

/// The server's stalls as the load generator applies them: a window stops the server while it
/// holds, and one the load generator's loop lagged past whole stops it late, for its length, so
/// every scheduled stall happens (the long run's seed 581 missed a 100 ms window on a busy
/// machine, its loop 171 ms late, and tested no stall).
#[derive(Debug, Default)]
struct Stalls {
    /// Per window: whether the server was stopped for it.
    begun: Vec<bool>,
    /// When the late stall under way ends (after the load began).
    late_until: Option<Duration>,
}

impl Stalls {
    /// Whether the server is to be stopped at `since` (after the load began).
    fn want(&mut self, windows: &[Window], since: Duration) -> bool {
        self.begun.resize(windows.len(), false);
        let mut want = false;
        for (w, begun) in windows.iter().zip(&mut self.begun) {
            if w.holds(0, since) {
                want = true;
                *begun = true;
            } else if !*begun && since >= w.start + w.len {
                *begun = true;
                self.late_until = Some(self.late_until.map_or(since + w.len, |u| u.max(since + w.len)));
            }
        }
        want || self.late_until.is_some_and(|u| since < u)
    }
}

/// Stops or resumes a process (SIGSTOP / SIGCONT) with `kill`, so nothing unsafe is needed here.
fn signal(pid: u32, stop: bool) {
    let sig = if stop { "-STOP" } else { "-CONT" };
    let _ = std::process::Command::new("kill").arg(sig).arg(pid.to_string()).status();
}

enum Inbound {
    Msg(usize, ServerMessage, Option<impact_protocol::Stamp>),
    Malformed(usize),
    Stats(impact_protocol::ServerStats),
    /// A `query/confirmed` reply for client `k`, and the end of its answer.
    Recovered(usize, impact_protocol::EventBatch),
    RecoveryEnded(usize, impact_protocol::Tick),
}

/// One simulated player: an [`impact_client::Session`], the library a game uses, with what the
/// load test checks about its answers beside it.
struct Client {
    id: ClientId,
    behaviour: Behaviour,
    session: Session,
    /// A game client: decodes its state stream, predicts its avatar, draws at 60 frames a
    /// second (`--predict`).
    game: bool,
    welcomed: bool,
    /// When it started playing, and when it acts and draws next.
    playing_since: Option<Instant>,
    next_action: Instant,
    next_frame: Instant,
    /// The answers the server owes it, and those it gave.
    ledger: Ledger,
    margins: Margins,
    /// Accepted inputs sent in the first two seconds of play, and how many of them were late;
    /// the same after.
    early: (u64, u64),
    steady: (u64, u64),
    /// Each confirmed batch it received, by tick (a digest of its events): a second batch of a
    /// tick must say the same. The last [`CONFIRMED_KEPT`] ticks.
    confirmed: Confirmed,
    /// Its session was dropped: when.
    left: Option<Instant>,
    /// Its latest return after a dropped session, still being filled in: an earlier one is
    /// final and told into the report when the next comes (a list of them grew all a soak long).
    returned: Option<Return>,
    /// The last `future` reject: the tick the input carried, the newest the server took then,
    /// and the client's view tick and lead when it came (told when a return never resumed).
    last_future: Option<String>,
}

/// Messages each session's delay line holds at most, up and down.
const UP_LINE: usize = 1 << 20;
const DOWN_LINE: usize = 1 << 21;

/// Confirmed batches a client keeps the digest of, to see one change.
const CONFIRMED_KEPT: u32 = 2048;

/// A client back after its session was dropped: what the invariants ask of it.
#[derive(Clone, Copy, Debug)]
struct Return {
    /// When its new session opened.
    at: Instant,
    /// How long it was gone.
    away: Duration,
    /// The avatar it had when it left.
    avatar: Option<EntityId>,
    /// Welcomed again, and whether to the avatar it had.
    welcomed: Option<bool>,
    /// A full state frame came after it returned.
    full_frame: bool,
    /// An input it sent after it returned was accepted.
    resumed: bool,
    /// Of the inputs it sent after it returned: how many were refused (the last reason) and
    /// known lost, told when it never resumed.
    refused: (u32, Option<RejectReason>),
    lost: u32,
}

impl Return {
    /// Counts the return of client `c` into the report, and tells it one by one if its client
    /// drew and no full frame came after it, or if it never resumed.
    fn tell(&self, r: &mut Report, load_start: Instant, c: &Client) {
        // A client that left before its first welcome reached it knew no avatar to keep.
        let in_grace = self.away + Duration::from_millis(250) < GRACE && self.avatar.is_some();
        r.returns += 1;
        r.returns_welcomed += u64::from(self.welcomed.is_some());
        r.returns_in_grace += u64::from(in_grace);
        r.returns_kept_avatar += u64::from(in_grace && self.welcomed == Some(true));
        r.returns_drawing += u64::from(c.game);
        r.returns_full_frame += u64::from(c.game && self.full_frame);
        r.returns_resumed += u64::from(self.resumed);
        // Who, when, how long away and how welcomed: the start of each line told.
        let who = || {
            format!(
                "client {} back at {:.3} s after {:.3} s away, welcomed {:?}",
                c.id.0,
                self.at.saturating_duration_since(load_start).as_secs_f64(),
                self.away.as_secs_f64(),
                self.welcomed
            )
        };
        if c.game && !self.full_frame && r.unframed.len() < UNEXPECTED_KEPT {
            let s = c.session.stats();
            r.unframed.push(format!(
                "{}, epoch {}; its session: {} state frames, {} full frames asked",
                who(),
                c.session.epoch().0,
                s.state_frames,
                s.full_frames_asked
            ));
        }
        if !self.resumed && r.unresumed.len() < UNEXPECTED_KEPT {
            r.unresumed.push(format!(
                "{}, inputs after: {} refused (last {:?}), {} lost, {} awaiting; the last future reject: {}",
                who(),
                self.refused.0,
                self.refused.1.map(RejectReason::name),
                self.lost,
                c.session.pending_inputs(),
                c.last_future.as_deref().unwrap_or("none"),
            ));
        }
    }
}

/// Inputs sent this long after play began are "early": the clock has only the sync's estimate.
const EARLY: Duration = Duration::from_secs(2);

/// A game client draws this often.
const FRAME: Duration = Duration::from_nanos(16_666_667);

/// A confirmed batch's events, digested (FNV-1a over their JSON, folded to 31 bits, the lowest
/// set) to see a second batch of a tick differ. Written into the hash as it is made: every client digests
/// every batch, 64 a second.
fn digest(events: &[impact_protocol::CollisionEvent]) -> u32 {
    struct Fnv(u64);
    impl std::io::Write for Fnv {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0 = buf.iter().fold(self.0, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3));
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    let _ = serde_json::to_writer(&mut h, events);
    (h.0 ^ h.0 >> 32) as u32 | 1
}

/// The digests of the confirmed batches a client received over the last [`CONFIRMED_KEPT`]
/// ticks: a fixed ring of (tick, digest), the digest 0 when empty ([`digest`]s are odd), 8 bytes
/// a tick (a map of them made and freed a node a tick for every client).
struct Confirmed(Box<[(u32, u32)]>);

impl Confirmed {
    fn new() -> Confirmed {
        Confirmed(vec![(0, 0); CONFIRMED_KEPT as usize].into_boxed_slice())
    }

    /// Notes the digest of `tick`'s batch and gives the one noted for that tick before, if any
    /// (a tick older than those kept is not noted).
    fn note(&mut self, tick: u32, digest: u32) -> Option<u32> {
        let slot = &mut self.0[(tick % CONFIRMED_KEPT) as usize];
        if slot.1 != 0 && slot.0 == tick {
            return Some(slot.1);
        }
        if slot.1 == 0 || impact_protocol::serial::precedes(slot.0, tick) {
            *slot = (tick, digest);
        }
        None
    }
}

/// The seqs a message carries.
fn seqs(msg: &ClientMessage) -> Vec<u32> {
    match msg {
        ClientMessage::Input(i) => vec![i.seq],
        ClientMessage::Inputs(b) => b.inputs.iter().map(|i| i.seq).collect(),
        ClientMessage::Ping(_) | ClientMessage::FullFrame(_) | ClientMessage::World(_) => Vec::new(),
    }
}

/// What a player does next (`t`: seconds since the load began).
fn action(behaviour: Behaviour, entity: EntityId, rng: &mut Rng, t: f64) -> Action {
    let dir = |rng: &mut Rng| {
        let a = std::f64::consts::TAU * rng.unit();
        [a.cos(), 0.3 * (rng.unit() - 0.5), a.sin()]
    };
    match behaviour {
        Behaviour::Wander => {
            let d = dir(rng);
            let s = 2.0 + 6.0 * rng.unit();
            Action::SetVelocity { entity, velocity: [d[0] * s, d[1] * s, d[2] * s] }
        }
        Behaviour::Chase => {
            // The goal circles the middle of the world; players head roughly for it.
            let goal = [10.0 * t.cos(), 10.0, 10.0 * t.sin()];
            let jitter = dir(rng);
            Action::SetVelocity {
                entity,
                velocity: [goal[0] * 0.3 + jitter[0], (goal[1] - 10.0) * 0.3, goal[2] * 0.3 + jitter[2]],
            }
        }
        Behaviour::Shooter | Behaviour::Mixed | Behaviour::Fighter => {
            if rng.unit() < 0.7 {
                let d = dir(rng);
                let o = [40.0 * (rng.unit() - 0.5), 2.0 + 15.0 * rng.unit(), 40.0 * (rng.unit() - 0.5)];
                Action::FireRay { shooter: entity, origin: o, direction: d, max_distance_m: 60.0 }
            } else {
                let d = dir(rng);
                Action::SetVelocity { entity, velocity: [d[0] * 5.0, d[1] * 5.0, d[2] * 5.0] }
            }
        }
    }
}

/// A fighter's next action, if another player is in sight: fire at the nearest (within 40 m,
/// half the time) or head for it. Players are the bodies of the own avatar's class that a
/// client owns, as the state stream drew them.
fn fight(s: &Session, me: EntityId, now: Instant, rng: &mut Rng) -> Option<Action> {
    let remote = s.remote()?;
    let mine = remote.info(me)?;
    let mut drawn = Vec::new();
    s.draw_remote(now, &mut drawn);
    let at = drawn.iter().find(|b| b.entity == me)?.position;
    let (target, d2) = drawn
        .iter()
        .filter(|b| b.entity != me)
        .filter(|b| remote.info(b.entity).is_some_and(|i| i.owner.is_some() && i.class == mine.class))
        .map(|b| (b, (0..3).map(|k| (b.position[k] - at[k]).powi(2)).sum::<f64>()))
        .filter(|(_, d2)| *d2 > 1e-6)
        .min_by(|x, y| x.1.total_cmp(&y.1))?;
    let d = d2.sqrt();
    let toward = [0, 1, 2].map(|k| (target.position[k] - at[k]) / d);
    if d < 40.0 && rng.unit() < 0.5 {
        return Some(Action::FireRay { shooter: me, origin: at, direction: toward, max_distance_m: 60.0 });
    }
    Some(Action::SetVelocity { entity: me, velocity: toward.map(|x| x * 5.0) })
}

/// The sessions the clients share, or with `users` one per client, authenticated as its user.
fn open_sessions(cfg: &LoadConfig) -> anyhow::Result<Vec<zenoh::Session>> {
    let n = if cfg.users.is_some() { cfg.clients } else { cfg.sessions.max(1) };
    let mut sessions = Vec::with_capacity(n as usize);
    for k in 0..n as usize {
        sessions.push(open_session(cfg, k)?);
        if cfg.users.is_some() && cfg.progress && (k + 1) % 100 == 0 {
            eprintln!("  {} of {} sessions authenticated", k + 1, cfg.clients);
        }
    }
    Ok(sessions)
}

/// Session `k` of [`open_sessions`]: with `users`, client `k`'s, authenticated as its user.
fn open_session(cfg: &LoadConfig, k: usize) -> anyhow::Result<zenoh::Session> {
    let file = cfg.zenoh_config.as_deref();
    let Some(users) = &cfg.users else {
        return crate::net::open(&cfg.connect, file, None, cfg.mode);
    };
    let id = cfg.first_client + k as u32;
    let u = users.for_client(id).ok_or_else(|| anyhow::anyhow!("the users file has no user for client {id}"))?;
    let creds = crate::net::Credentials { user: u.name.clone(), password: u.password.clone() };
    crate::net::open(&cfg.connect, file, Some(&creds), cfg.mode)
}

/// Messages the callbacks queue for the run loop: at most this many (past it they are dropped and
/// counted), about a second of 1,000 busy clients.
const INBOX_MAX: usize = 1 << 20;

/// What the callbacks hand the run loop, with when each arrived and the wiring's generation
/// (the world it came from: one that closed is counted no more).
type Inbox = Arc<Mutex<Vec<(Instant, u32, Inbound)>>>;

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
    /// Bytes of every message the clients received on their own keys (answers, events, state).
    down_bytes: Arc<AtomicU64>,
    /// Each client's subscriptions (answers, events, state), replaced with its session's.
    subscribers: Vec<Vec<zenoh::pubsub::Subscriber<()>>>,
    /// The run's subscription to the world's stats, on session 0.
    stats: Option<zenoh::pubsub::Subscriber<()>>,
    /// Each client's input publisher (none while its session is closed). Declared, as a game's
    /// transport declares it: the key is then resolved once, not on every message at the server.
    inputs: Vec<Option<zenoh::pubsub::Publisher<'static>>>,
    tokens: Vec<Option<zenoh::liveliness::LivelinessToken>>,
    /// When each client's presence was last declared, and how long it waits for its welcome
    /// before declaring it again.
    announced: Vec<(Instant, Duration)>,
    /// One more for each world the clients moved to.
    generation: u32,
    /// Sessions closed by the fault `drops`.
    closed: Vec<bool>,
    /// Sessions being opened again, each on a thread of its own (opening waits for a router
    /// that is down, and the clients on the other sessions play on meanwhile).
    opening: Vec<Option<std::thread::JoinHandle<anyhow::Result<zenoh::Session>>>>,
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
            down_bytes: Arc::new(AtomicU64::new(0)),
            subscribers: Vec::new(),
            stats: None,
            inputs: Vec::new(),
            tokens: Vec::new(),
            announced: Vec::new(),
            generation: 0,
            closed: Vec::new(),
            opening: Vec::new(),
        };
        w.closed = vec![false; w.sessions.len()];
        w.opening = (0..w.sessions.len()).map(|_| None).collect();
        w.subscribe(cfg, &cfg.world, clients)?;
        Ok(w)
    }

    /// Subscribes each client to its answers, events and state stream in `world`, and the run
    /// to its stats.
    fn subscribe(&mut self, cfg: &LoadConfig, world: &WorldId, clients: &[Client]) -> anyhow::Result<()> {
        self.subscribers = clients
            .iter()
            .enumerate()
            .map(|(k, c)| self.subscribe_client(cfg, world, k, c))
            .collect::<anyhow::Result<_>>()?;
        self.inputs = clients
            .iter()
            .enumerate()
            .map(|(k, c)| self.input_publisher(cfg, world, k, c).map(Some))
            .collect::<anyhow::Result<_>>()?;
        self.subscribe_stats(world)
    }

    /// Subscribes the run to `world`'s stats, on session 0 (again when that session reopens).
    fn subscribe_stats(&mut self, world: &WorldId) -> anyhow::Result<()> {
        let (inbox, generation) = (self.inbox.clone(), self.generation);
        let stats = self.sessions[0]
            .declare_subscriber(keys::STATS.key(world, None))
            .callback(move |sample| {
                if let Ok(ServerMessage::Stats(s)) = crate::net::decode_server(&sample) {
                    inbox.lock().unwrap_or_else(|e| e.into_inner()).push((
                        Instant::now(),
                        generation,
                        Inbound::Stats(s),
                    ));
                }
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("subscribing: {e}"))?;
        self.stats = Some(stats);
        Ok(())
    }

    /// Moves every client to `world` (the one before closed): its subscriptions and presence
    /// there, on the same sessions.
    fn rewire(&mut self, cfg: &LoadConfig, world: &WorldId, clients: &[Client]) -> anyhow::Result<()> {
        self.tokens.clear();
        self.subscribers.clear();
        self.stats = None;
        self.generation += 1;
        self.subscribe(cfg, world, clients)?;
        self.declare_presence(world, clients)
    }

    /// The session client `k` shares.
    fn session(&self, k: usize) -> &zenoh::Session {
        &self.sessions[self.session_of(k)]
    }

    /// Which session client `k` shares.
    fn session_of(&self, k: usize) -> usize {
        k % self.sessions.len()
    }

    fn input_publisher(
        &self,
        cfg: &LoadConfig,
        world: &WorldId,
        k: usize,
        c: &Client,
    ) -> anyhow::Result<zenoh::pubsub::Publisher<'static>> {
        self.session(k)
            .declare_publisher(keys::INPUT.key(world, Some(c.id)))
            .encoding(cfg.encoding.zenoh_tag())
            .wait()
            .map_err(|e| anyhow::anyhow!("declaring an input publisher: {e}"))
    }

    /// The fault `drops`: session `s` closes, and its clients' presence, subscriptions and
    /// publishers with it. They are undeclared first: Zenoh 1.10 keeps what was declared on a
    /// session when it is undeclared after the close, and keeps a closed session's state (its
    /// runtime, its tables) alive, so undeclared after, 100 clients' declarations stayed with
    /// every drop (heaptrack: 26 KB a drop, 15 KB of it the publishers' entries and keys).
    fn close_session(&mut self, s: usize) {
        let n = self.sessions.len();
        for k in (0..self.inputs.len()).filter(|k| k % n == s) {
            self.tokens[k] = None;
            self.subscribers[k].clear();
            self.inputs[k] = None;
        }
        if s == 0 {
            self.stats = None;
        }
        let _ = self.sessions[s].close().wait();
        self.closed[s] = true;
    }

    /// Session `s` opens again, a new Zenoh session (as a game's transport after a handover),
    /// and each of its clients subscribes and declares its presence on it in `world`. Opening
    /// runs on a thread: true once the session is open and wired, false while it is not yet (or
    /// opening failed, to be tried again).
    fn reopen_session(
        &mut self,
        cfg: &LoadConfig,
        world: &WorldId,
        s: usize,
        clients: &[Client],
    ) -> anyhow::Result<bool> {
        let Some(opening) = self.opening[s].take() else {
            let cfg = cfg.clone();
            self.opening[s] = Some(std::thread::spawn(move || open_session(&cfg, s)));
            return Ok(false);
        };
        if !opening.is_finished() {
            self.opening[s] = Some(opening);
            return Ok(false);
        }
        match opening.join() {
            Ok(Ok(session)) => self.sessions[s] = session,
            // Tried again on the next call.
            Ok(Err(_)) | Err(_) => return Ok(false),
        }
        let n = self.sessions.len();
        for (k, c) in clients.iter().enumerate().filter(|(k, _)| k % n == s) {
            self.subscribers[k] = self.subscribe_client(cfg, world, k, c)?;
            self.inputs[k] = Some(self.input_publisher(cfg, world, k, c)?);
            self.tokens[k] = Some(self.presence(world, k, c.id)?);
        }
        if s == 0 {
            self.subscribe_stats(world)?;
        }
        self.closed[s] = false;
        Ok(true)
    }

    /// Client `k`'s subscriptions in `world`, on its session.
    fn subscribe_client(
        &self,
        cfg: &LoadConfig,
        world: &WorldId,
        k: usize,
        c: &Client,
    ) -> anyhow::Result<Vec<zenoh::pubsub::Subscriber<()>>> {
        let mut subs = Vec::new();
        let mut decoded = vec![(keys::CLIENT_ACK, false), (keys::CLIENT_EVENTS, false)];
        // A game client reads its state stream; the others (with `state`) only count its bytes.
        if c.game {
            decoded.push((keys::CLIENT_STATE, true));
        }
        for (pattern, state) in decoded {
            let (inbox, generation) = (self.inbox.clone(), self.generation);
            let dropped = self.inbox_dropped.clone();
            let counts = state.then(|| (self.state_bytes.clone(), self.state_frames.clone()));
            let down = self.down_bytes.clone();
            let sub = self
                .session(k)
                .declare_subscriber(pattern.key(world, Some(c.id)))
                .callback(move |sample| {
                    down.fetch_add(sample.payload().len() as u64, Relaxed);
                    if let Some((bytes, frames)) = &counts {
                        bytes.fetch_add(sample.payload().len() as u64, Relaxed);
                        frames.fetch_add(1, Relaxed);
                    }
                    let item = match crate::net::decode_server(&sample) {
                        Ok(msg) => Inbound::Msg(k, msg, impact_client::transport::stamp_of(&sample)),
                        Err(_) => Inbound::Malformed(k),
                    };
                    let mut q = inbox.lock().unwrap_or_else(|e| e.into_inner());
                    if q.len() < INBOX_MAX {
                        q.push((Instant::now(), generation, item));
                    } else {
                        dropped.fetch_add(1, Relaxed);
                    }
                })
                .wait()
                .map_err(|e| anyhow::anyhow!("subscribing: {e}"))?;
            subs.push(sub);
        }
        if cfg.state && !c.game {
            let (bytes, frames) = (self.state_bytes.clone(), self.state_frames.clone());
            let down = self.down_bytes.clone();
            let sub = self
                .session(k)
                .declare_subscriber(keys::CLIENT_STATE.key(world, Some(c.id)))
                .callback(move |sample| {
                    down.fetch_add(sample.payload().len() as u64, Relaxed);
                    bytes.fetch_add(sample.payload().len() as u64, Relaxed);
                    frames.fetch_add(1, Relaxed);
                })
                .wait()
                .map_err(|e| anyhow::anyhow!("subscribing: {e}"))?;
            subs.push(sub);
        }
        Ok(subs)
    }

    /// Declares every client's presence: last, so every subscription is in place when the
    /// welcome comes.
    fn declare_presence(&mut self, world: &WorldId, clients: &[Client]) -> anyhow::Result<()> {
        self.tokens.clear();
        self.announced.clear();
        for (k, c) in clients.iter().enumerate() {
            let t = self.presence(world, k, c.id)?;
            self.tokens.push(Some(t));
        }
        Ok(())
    }

    /// Client `k`'s presence token in `world`, declared now.
    fn presence(
        &mut self,
        world: &WorldId,
        k: usize,
        id: ClientId,
    ) -> anyhow::Result<zenoh::liveliness::LivelinessToken> {
        let now = (Instant::now(), impact_client::transport::WELCOME_WAIT);
        match self.announced.get_mut(k) {
            Some(a) => *a = now,
            None => self.announced.push(now),
        }
        self.session(k)
            .liveliness()
            .declare_token(keys::PRESENCE.key(world, Some(id)))
            .wait()
            .map_err(|e| anyhow::anyhow!("presence token: {e}"))
    }

    /// As a game's transport does: each client still joining whose welcome has not come within
    /// its wait withdraws its presence and declares it again (the wait doubles, up to
    /// `WELCOME_WAIT_MAX`). How many did.
    fn repeat_presence(&mut self, world: &WorldId, clients: &[Client], now: Instant) -> u64 {
        let mut repeated = 0;
        for (k, c) in clients.iter().enumerate() {
            let open = !self.closed[self.session_of(k)];
            let Some(&(at, wait)) = self.announced.get(k) else { continue };
            if !open || c.session.status() != Status::Joining || now.saturating_duration_since(at) < wait {
                continue;
            }
            // The old token goes first: a second one on the same key would be no news.
            drop(self.tokens[k].take());
            self.tokens[k] = self.presence(world, k, c.id).ok();
            self.announced[k].1 = (wait * 2).min(impact_client::transport::WELCOME_WAIT_MAX);
            repeated += 1;
        }
        repeated
    }

    /// What the clients received so far: state stream bytes and frames, and bytes in all.
    fn counts(&self) -> Received {
        Received {
            state_bytes: self.state_bytes.load(Relaxed),
            state_frames: self.state_frames.load(Relaxed),
            bytes: self.down_bytes.load(Relaxed),
            inbox_dropped: self.inbox_dropped.load(Relaxed),
        }
    }

    /// Counts from the start of the load on (what joining cost is not in them).
    fn reset_counts(&self) {
        for c in [&self.state_bytes, &self.state_frames, &self.down_bytes] {
            c.store(0, Relaxed);
        }
    }

    /// Drops the tokens and subscriptions, then closes the sessions.
    fn close(self) {
        drop(self.tokens);
        drop(self.subscribers);
        drop(self.stats);
        drop(self.inputs);
        for s in self.sessions {
            let _ = s.close().wait();
        }
    }
}

/// What the clients received, counted by the callbacks (without decoding what no client reads).
#[derive(Clone, Copy, Debug)]
struct Received {
    state_bytes: u64,
    state_frames: u64,
    bytes: u64,
    inbox_dropped: u64,
}

/// A message on its way to the server: the client's index, the seqs it carries, its bytes.
type Outgoing = (usize, Vec<u32>, Vec<u8>);

/// The run loop's state: the clients, both delay lines, and the figures gathered.
struct Run<'a> {
    cfg: &'a LoadConfig,
    /// The avatars' walk speed when they are characters: velocities become `move` intents.
    walk_mps: Option<f64>,
    clients: Vec<Client>,
    rng: Rng,
    /// A delay line each way per Zenoh session (a partition may cut one session's clients).
    up: Vec<DelayLine<Outgoing>>,
    down: Vec<DelayLine<Inbound>>,
    /// Input round trips, microseconds.
    latency: Histogram<u64>,
    /// How many ticks back each correction reached.
    depth: Histogram<u64>,
    /// Every tick's duration the server reported during the load, microseconds (1 us to 1 h).
    server_ticks: Histogram<u64>,
    /// How late each client's input was made after its turn came, microseconds: whether the
    /// load generator kept up.
    lag: Histogram<u64>,
    /// Bytes put on the input keys.
    up_bytes: u64,
    r: Report,
    /// Time between one client's inputs.
    period: Duration,
    load_start: Instant,
    load_end: Instant,
    server_stopped: bool,
    stalls: Stalls,
    checks: Vec<DrawCheck>,
    next_check: Instant,
    /// Remote bodies as drawn minus as the server had them, m, and whether each was steady.
    interpolation: Vec<(f64, bool)>,
    /// The world played now: `cfg.world`, or the one a closed world named next.
    world: WorldId,
    /// The sessions of worlds that closed (and whether each was a game client's): their
    /// figures count in the report.
    retired: Vec<(bool, Session)>,
}

/// Which clients are game clients: `predict` of them, spread evenly over the ids (so over the
/// behaviours too).
fn is_game(k: usize, clients: u32, predict: u32) -> bool {
    (k as u64 * u64::from(predict)) % u64::from(clients.max(1)) < u64::from(predict)
}

/// A client's session (predicting once [`predict`] gives it the rules).
fn new_session(cfg: &LoadConfig, id: ClientId) -> Session {
    Session::new(SessionConfig { ahead: cfg.timing == Timing::Ahead, predict: None, ..SessionConfig::new(id) })
}

/// The clients, each a session (a game client predicts once [`predict`] gave it the rules).
fn clients(cfg: &LoadConfig, start: Instant) -> anyhow::Result<Vec<Client>> {
    let mut out = Vec::with_capacity(cfg.clients as usize);
    for k in 0..cfg.clients as usize {
        let id = ClientId(cfg.first_client + k as u32);
        let behaviour = match cfg.behaviour {
            Behaviour::Mixed => [Behaviour::Wander, Behaviour::Chase, Behaviour::Shooter][k % 3],
            b => b,
        };
        let game = is_game(k, cfg.clients, cfg.predict);
        let session = new_session(cfg, id);
        out.push(Client {
            id,
            behaviour,
            session,
            game,
            welcomed: false,
            playing_since: None,
            next_action: start,
            next_frame: start,
            ledger: Ledger::default(),
            margins: Margins::default(),
            early: (0, 0),
            steady: (0, 0),
            confirmed: Confirmed::new(),
            left: None,
            returned: None,
            last_future: None,
        });
    }
    Ok(out)
}

/// The rules the world runs: `cfg.scene`, or the server's own (asked once, as a game's transport
/// asks for each). Game clients cannot do without; the others only learn from them whether
/// avatars are characters, and without an answer (a server that predates `query/scene`) they
/// are taken not to be.
fn scene_rules(
    cfg: &LoadConfig,
    world: &WorldId,
    zs: &zenoh::Session,
    clients: &[Client],
) -> anyhow::Result<Option<impact_core::scene::SceneRules>> {
    if let Some(r) = &cfg.scene {
        return Ok(Some(r.clone()));
    }
    let asked = impact_client::transport::query_scene(zs, world, Duration::from_secs(10))
        .map_err(anyhow::Error::from)
        .and_then(|d| Ok(impact_core::scene::SceneRules::from_description(&d)?));
    match asked {
        Ok(r) => Ok(Some(r)),
        Err(e) if clients.iter().any(|c| c.game) => Err(e.context("the game clients predict with the server's scene")),
        Err(_) => Ok(None),
    }
}

/// Gives the game clients a predictor on `rules`.
fn predict(rules: Option<&impact_core::scene::SceneRules>, clients: &mut [Client]) -> anyhow::Result<()> {
    for c in clients.iter_mut().filter(|c| c.game) {
        let rules = rules.ok_or_else(|| anyhow::anyhow!("predicting needs the server's scene"))?;
        c.session.predict_with(Predictor::new(rules, c.id, PredictConfig::default())?);
    }
    Ok(())
}

/// The walk speed of the world's avatars, if they are characters (moved by `move` only).
fn walk_speed(rules: Option<&impact_core::scene::SceneRules>) -> Option<f64> {
    let r = rules?;
    let class = r.avatar.as_ref()?.class;
    r.world.config.classes.props[class.0 as usize].character.map(|c| c.walk_speed_mps)
}

/// A velocity a behaviour chose, as a character's intent: its direction and the fraction of the
/// walk speed it asks for, with a jump now and then.
fn intent(a: Action, walk_mps: f64, rng: &mut Rng) -> Action {
    match a {
        Action::SetVelocity { entity, velocity } => {
            Action::Move { entity, direction: velocity.map(|v| v / walk_mps), jump: rng.unit() < 0.15 }
        }
        other => other,
    }
}

/// Runs the load and returns its report.
pub fn run(cfg: &LoadConfig) -> anyhow::Result<Report> {
    let mut clients = clients(cfg, Instant::now())?;
    let mut wiring = Wiring::connect(cfg, &clients)?;
    let rules = scene_rules(cfg, &cfg.world, &wiring.sessions[0], &clients)?;
    predict(rules.as_ref(), &mut clients)?;
    wiring.declare_presence(&cfg.world, &clients)?;
    let mut run = Run::new(cfg, clients, wiring.sessions.len())?;
    run.walk_mps = walk_speed(rules.as_ref());
    // What the clients receive is counted over the load alone.
    wiring.reset_counts();
    let mut received_at_end = None;
    let tty = std::io::stderr().is_terminal();
    let mut last_progress = Instant::now();
    let stop = run.load_end + cfg.settle;
    // Each Zenoh session's link, looked at every 10 ms: when one comes back (a router
    // restarted), its clients' views lost what the server published meanwhile.
    let mut linked = vec![true; wiring.sessions.len()];
    let mut links_checked = Instant::now();
    loop {
        let now = Instant::now();
        if now >= stop {
            break;
        }
        if now.duration_since(links_checked) >= Duration::from_millis(10) {
            links_checked = now;
            run.drops(&mut wiring, &mut linked, now)?;
            for (k, s) in wiring.sessions.iter().enumerate().filter(|(k, _)| !wiring.closed[*k]) {
                let up = impact_client::transport::reachable(s);
                if up && !linked[k] {
                    run.link_restored(k, wiring.sessions.len(), now);
                }
                linked[k] = up;
            }
        }
        if now >= run.load_end && received_at_end.is_none() {
            received_at_end = Some(wiring.counts());
        }
        run.downlink(&wiring, now);
        run.recover(&wiring);
        if let Some(next) = run.closed_to() {
            run.follow(&mut wiring, next, now)?;
        }
        run.r.presence_repeats += wiring.repeat_presence(&run.world, &run.clients, now);
        run.play(now);
        run.check(&wiring, now);
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
    let r = run.report(received_at_end.unwrap_or_else(|| wiring.counts()));
    wiring.close();
    let _ = std::io::stderr().flush();
    Ok(r)
}

impl Run<'_> {
    /// The fault `drops`: a session whose drop began closes, one whose drop ended opens again
    /// (its clients then count as returned; the link watch tells them their link is back).
    fn drops(&mut self, wiring: &mut Wiring, linked: &mut [bool], now: Instant) -> anyhow::Result<()> {
        let since = now.saturating_duration_since(self.load_start);
        for (s, link) in linked.iter_mut().enumerate() {
            let want = self.cfg.faults.dropped(s, since);
            if want && !wiring.closed[s] {
                wiring.close_session(s);
                // What was on its way either way goes with the connection: a message held by a
                // partition does not come out of a new session later.
                (self.up[s], self.down[s]) = (DelayLine::new(UP_LINE), DelayLine::new(DOWN_LINE));
                *link = false;
                self.r.session_drops += 1;
                for k in (0..self.clients.len()).filter(|k| wiring.session_of(*k) == s) {
                    self.clients[k].left = Some(now);
                }
            } else if !want && wiring.closed[s] {
                if !wiring.reopen_session(self.cfg, &self.world, s, &self.clients)? {
                    continue;
                }
                let at = Instant::now();
                for k in (0..self.clients.len()).filter(|k| wiring.session_of(*k) == s) {
                    let c = &mut self.clients[k];
                    let Some(left) = c.left.take() else { continue };
                    let back = Return {
                        at,
                        away: at - left,
                        avatar: c.session.avatar(),
                        welcomed: None,
                        full_frame: false,
                        resumed: false,
                        refused: (0, None),
                        lost: 0,
                    };
                    if let Some(done) = c.returned.replace(back) {
                        done.tell(&mut self.r, self.load_start, c);
                    }
                }
            }
        }
        Ok(())
    }

    /// Zenoh session `session` (of `sessions`) has its link back: each of its clients is told.
    fn link_restored(&mut self, session: usize, sessions: usize, now: Instant) {
        self.r.links_restored += 1;
        for (k, c) in self.clients.iter_mut().enumerate() {
            if k % sessions == session {
                c.session.link_restored(now);
            }
        }
    }

    fn new(cfg: &LoadConfig, clients: Vec<Client>, sessions: usize) -> anyhow::Result<Run<'_>> {
        let load_start = Instant::now();
        Ok(Run {
            cfg,
            walk_mps: None,
            world: cfg.world.clone(),
            retired: Vec::new(),
            clients,
            rng: Rng::new(cfg.seed),
            up: (0..sessions).map(|_| DelayLine::new(UP_LINE)).collect(),
            down: (0..sessions).map(|_| DelayLine::new(DOWN_LINE)).collect(),
            latency: Histogram::new_with_bounds(1, 60_000_000, 3).map_err(|e| anyhow::anyhow!("{e}"))?,
            depth: Histogram::new_with_bounds(1, 100_000, 3).map_err(|e| anyhow::anyhow!("{e}"))?,
            server_ticks: Histogram::new_with_bounds(1, 3_600_000_000, 3).map_err(|e| anyhow::anyhow!("{e}"))?,
            lag: Histogram::new_with_bounds(1, 3_600_000_000, 3).map_err(|e| anyhow::anyhow!("{e}"))?,
            up_bytes: 0,
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
            stalls: Stalls::default(),
            checks: Vec::new(),
            next_check: load_start + CHECK_EVERY,
            interpolation: Vec::new(),
        })
    }

    /// Received messages enter the downlink delay line; due ones reach their client (none while
    /// a partition holds the line).
    fn downlink(&mut self, wiring: &Wiring, now: Instant) {
        let arrived = std::mem::take(&mut *wiring.inbox.lock().unwrap_or_else(|e| e.into_inner()));
        for (at, generation, m) in arrived {
            if generation == wiring.generation {
                let line = match &m {
                    Inbound::Msg(k, ..)
                    | Inbound::Malformed(k)
                    | Inbound::Recovered(k, _)
                    | Inbound::RecoveryEnded(k, _) => wiring.session_of(*k),
                    Inbound::Stats(_) => 0,
                };
                self.down[line].send(at, &self.cfg.downlink, &mut self.rng, m);
            }
        }
        let since = now.saturating_duration_since(self.load_start);
        for line in 0..self.down.len() {
            if let Some(end) = self.cfg.faults.partition_end(line, since) {
                // Nothing crosses either way until it ends; what was sent meanwhile comes after.
                self.down[line].stall_until(self.load_start + end);
                self.up[line].stall_until(self.load_start + end);
            }
            while let Some(m) = self.down[line].pop_due(now) {
                match m {
                    Inbound::Stats(s) => self.on_stats(s, now),
                    Inbound::Msg(k, msg, stamp) => self.on_message(k, msg, stamp, now),
                    Inbound::Malformed(k) => self.clients[k].session.malformed(),
                    Inbound::Recovered(k, b) => self.clients[k].session.recovered(b),
                    Inbound::RecoveryEnded(k, t) => self.clients[k].session.recovery_ended(t),
                }
            }
        }
    }

    /// As a game's transport does: each client asks the server for the confirmed batches it
    /// missed (`query/confirmed`); the answers come down its line like any message.
    fn recover(&mut self, wiring: &Wiring) {
        for (k, c) in self.clients.iter_mut().enumerate() {
            if wiring.closed[wiring.session_of(k)] {
                continue;
            }
            while let Some(t) = c.session.poll_recovery() {
                // Bounded as the subscriptions' pushes are (a lost end is given up on in time).
                let push = |inbox: Inbox, generation: u32, item: Inbound| {
                    let mut q = inbox.lock().unwrap_or_else(|e| e.into_inner());
                    if q.len() < INBOX_MAX {
                        q.push((Instant::now(), generation, item));
                    }
                };
                let (a, b, g) = (wiring.inbox.clone(), wiring.inbox.clone(), wiring.generation);
                let asked = impact_client::transport::ask_confirmed(
                    wiring.session(k),
                    &self.world,
                    c.id,
                    t,
                    move |batch| push(a.clone(), g, Inbound::Recovered(k, batch)),
                    move || push(b, g, Inbound::RecoveryEnded(k, t)),
                );
                if asked.is_err() {
                    c.session.recovery_ended(t);
                }
            }
        }
    }

    fn on_stats(&mut self, s: impact_protocol::ServerStats, now: Instant) {
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
            c.session.receive(ServerMessage::Stats(s.clone()), now);
        }
    }

    /// What the load test checks about a message, then the session takes it. A message from an
    /// older owner than one heard (a primary that came back after a failover) is the session's
    /// to drop and count, not the test's to check.
    fn on_message(&mut self, k: usize, msg: ServerMessage, stamp: Option<impact_protocol::Stamp>, now: Instant) {
        let (r, c) = (&mut self.r, &mut self.clients[k]);
        if stamp.is_some_and(|s| s.epoch < c.session.epoch()) {
            c.session.receive_from(stamp, msg, now);
            return;
        }
        match &msg {
            ServerMessage::Welcome(w) if w.client == c.id => {
                if let Some(back) = c.returned.as_mut().filter(|b| b.welcomed.is_none()) {
                    back.welcomed = Some(w.avatar.is_some() && w.avatar == back.avatar);
                }
                // Welcomed again (a reconnect, a takeover): the server answered every seq below
                // next_seq it heard (the one just below accepted, the others accepted, refused or
                // never heard; answers lost with the old link); the session learns which from the
                // next ack, and a copy still on its way may be answered once more.
                r.answered_by_welcome += c.ledger.welcomed(w.next_seq);
            }
            ServerMessage::Ack(a) if a.client == c.id => {
                // A second ack of one seq: an input applied twice.
                if !c.ledger.accepted(a.seq) {
                    r.not_owed(
                        now.saturating_duration_since(self.load_start),
                        c.id,
                        a.seq,
                        format!("ack at tick {}, acked before", a.tick.0),
                    );
                }
                // Seqs before it the server says it accepted: owed nothing more (their own acks
                // may have been lost on the way).
                c.ledger.acked_before(impact_client::session::accepted_before(a.seq, a.accepted_before));
            }
            ServerMessage::Reject(j) if j.client == c.id => {
                if j.reason == RejectReason::Future {
                    let clock = c.session.clock();
                    c.last_future = Some(format!(
                        "tick {:?}, newest {:?}, view {:?}, lead {:?}",
                        j.tick.map(|t| t.0),
                        j.newest_tick.map(|t| t.0),
                        clock.server_tick(now).map(|t| t.0),
                        clock.lead()
                    ));
                }
                // Each delivered copy of a refused input is answered; a welcome may leave one
                // answer open (`Ledger::rejected`).
                let due = match j.seq {
                    Some(seq) => c.ledger.rejected(seq, j.reason),
                    None => Err("no seq"),
                };
                if let Err(held) = due {
                    let what = format!(
                        "reject {} (seq {:?}: {}), no copy owed an answer, {held}",
                        j.reason.name(),
                        j.seq,
                        j.detail
                    );
                    r.not_owed(now.saturating_duration_since(self.load_start), c.id, j.seq.unwrap_or(0), what);
                }
                *r.rejects.entry(j.reason.name().to_string()).or_insert(0) += 1;
            }
            ServerMessage::Confirmed(b) => {
                // Nothing a client saw confirmed changes: a second batch of a tick (which the
                // protocol never sends) must at least say the same.
                let digest = digest(&b.events);
                match c.confirmed.note(b.tick.0, digest) {
                    Some(d) if d != digest => r.confirmed_changed += 1,
                    Some(_) => r.confirmed_repeated += 1,
                    None => {}
                }
            }
            ServerMessage::State(f) if f.full => {
                if let Some(back) = c.returned.as_mut() {
                    back.full_frame = true;
                }
            }
            ServerMessage::Corrections(cb) => {
                if let Some(t) = c.session.clock().server_tick(now) {
                    let _ = self.depth.record(u64::from(t.0.saturating_sub(cb.tick.0)).max(1));
                }
            }
            _ => {}
        }
        c.session.receive_from(stamp, msg, now);
        if !c.welcomed && c.session.avatar().is_some() {
            c.welcomed = true;
            r.clients_welcomed += 1;
        }
    }

    /// Every client: act when its turn came (once playing; its inputs spread over one period),
    /// draw when a frame is due (game clients), note its answers, and hand what it sends to the
    /// uplink delay line (some twice, when duplicates are injected).
    fn play(&mut self, now: Instant) {
        let cfg = self.cfg;
        let clients = self.clients.len().max(1) as f64;
        let lines = self.up.len();
        let t = now.saturating_duration_since(self.load_start).as_secs_f64();
        for (k, c) in self.clients.iter_mut().enumerate() {
            let s = &mut c.session;
            if s.status() == Status::Playing && c.playing_since.is_none() {
                c.playing_since = Some(now);
                c.next_action = now + self.period.mul_f64(k as f64 / clients);
            }
            if let (Some(entity), true) = (s.avatar(), c.playing_since.is_some() && now < self.load_end) {
                if c.next_action <= now {
                    let _ = self.lag.record(now.duration_since(c.next_action).as_micros().max(1) as u64);
                    c.next_action += self.period;
                    let aimed =
                        if c.behaviour == Behaviour::Fighter { fight(s, entity, now, &mut self.rng) } else { None };
                    let mut a = aimed.unwrap_or_else(|| {
                        let wander = if c.behaviour == Behaviour::Fighter { Behaviour::Wander } else { c.behaviour };
                        action(wander, entity, &mut self.rng, t)
                    });
                    if let Some(walk) = self.walk_mps {
                        a = intent(a, walk, &mut self.rng);
                    }
                    if s.input(vec![a], now).is_ok() {
                        self.r.inputs_sent += 1;
                    }
                }
            }
            if c.game && c.next_frame <= now {
                c.next_frame = (c.next_frame + FRAME).max(now);
                let _ = s.draw_avatar(now);
            }
            // A game reads its event news every frame. The load checks views by the confirmed
            // batches instead, but takes the news too: held, each session's queue would fill to
            // its bound (4,096 news a client, a soak's slow climb of memory).
            s.take_event_news().for_each(drop);
            for a in s.take_answers() {
                if let Some(back) = c.returned.as_mut().filter(|b| a.sent >= b.at) {
                    match a.outcome {
                        Outcome::Rejected(why) => back.refused = (back.refused.0 + 1, Some(why)),
                        Outcome::Lost => back.lost += 1,
                        _ => {}
                    }
                }
                if a.outcome == Outcome::Lost {
                    // Known to the client as never having reached the server (PROTOCOL.md,
                    // "Presence"): owed nothing, and not silent.
                    c.ledger.lost(a.seq);
                    self.r.inputs_known_lost += 1;
                    continue;
                }
                if a.outcome == Outcome::AckLost {
                    // Told by a later ack: no round trip or margin of its own.
                    self.r.acks += 1;
                    self.r.acks_recovered += 1;
                    continue;
                }
                let _ = self.latency.record(a.round_trip.as_micros().max(1) as u64);
                let Outcome::Accepted { margin_ticks, .. } = a.outcome else { continue };
                self.r.acks += 1;
                if let Some(back) = c.returned.as_mut().filter(|b| a.sent >= b.at) {
                    back.resumed = true;
                }
                c.margins.record(margin_ticks);
                let early = c.playing_since.is_some_and(|p| a.sent.saturating_duration_since(p) < EARLY);
                let share = if early { &mut c.early } else { &mut c.steady };
                share.0 += 1;
                share.1 += u64::from(margin_ticks < 0);
            }
            while let Some(msg) = s.poll_transmit(now) {
                // A closed session sends nothing: what its clients send meanwhile is gone (not
                // held by a partition's stalled line to go out through the next session).
                if c.left.is_some() {
                    continue;
                }
                let Ok(bytes) = impact_protocol::encode(&msg, cfg.encoding) else { continue };
                let seqs = seqs(&msg);
                let twice = !seqs.is_empty() && self.rng.unit() < cfg.faults.duplicate;
                let up = &mut self.up[k % lines];
                if up.send(now, &cfg.uplink, &mut self.rng, (k, seqs.clone(), bytes.clone()))
                    && twice
                    && up.send(now, &Link { loss: 0.0, ..cfg.uplink }, &mut self.rng, (k, seqs, bytes))
                {
                    self.r.inputs_duplicated += 1;
                }
            }
        }
    }

    /// Twice a second every game client draws its remote world at one whole tick and the server
    /// is asked where everything was at that tick; answers that came are compared.
    fn check(&mut self, wiring: &Wiring, now: Instant) {
        let mut interpolation = std::mem::take(&mut self.interpolation);
        self.checks.retain(|c| !c.compare(&mut interpolation));
        self.interpolation = interpolation;
        if now < self.next_check || now >= self.load_end || self.cfg.predict == 0 {
            return;
        }
        self.next_check += CHECK_EVERY;
        let render = self.clients.iter().filter(|c| c.game).find_map(|c| c.session.render_tick(now));
        let Some(tick) = render.map(|r| Tick(r.floor().max(0.0) as u32)) else { return };
        let mut drawn = Vec::new();
        let mut one = Vec::new();
        for remote in self
            .clients
            .iter()
            .filter(|c| c.game && c.session.stats().state_frames > 0)
            .filter_map(|c| c.session.remote())
        {
            remote.draw(f64::from(tick.0), &mut one);
            drawn.append(&mut one);
        }
        if let Ok(c) = DrawCheck::ask(&wiring.sessions[0], &self.world, tick, drawn) {
            self.checks.push(c);
        }
    }

    /// Faults first: a stall stops the server process (a partition stalled both lines in
    /// `downlink`). Then the messages due are put.
    fn uplink(&mut self, wiring: &Wiring, now: Instant) {
        let faults = &self.cfg.faults;
        let since = now.saturating_duration_since(self.load_start);
        if let Some(pid) = faults.stall_pid {
            let want = self.stalls.want(&faults.stalls, since);
            if want != self.server_stopped {
                signal(pid, want);
                self.server_stopped = want;
                self.r.server_stalls += u64::from(want);
            }
        }
        for (line, up) in self.up.iter_mut().enumerate() {
            while let Some((k, seqs, bytes)) = up.pop_due(now) {
                if now < self.load_end {
                    self.up_bytes += bytes.len() as u64;
                }
                // A closed session sends nothing: what its clients sent meanwhile is gone.
                let open = !wiring.closed[line];
                if open && wiring.inputs[k].as_ref().is_some_and(|p| p.put(bytes).wait().is_ok()) {
                    self.r.inputs_delivered += self.clients[k].ledger.delivered(&seqs);
                }
            }
        }
    }

    /// The world the clients' world closed to, once one of them was told (a match that ended
    /// and named the next).
    fn closed_to(&self) -> Option<WorldId> {
        self.clients.iter().find_map(|c| c.session.closed().and_then(|n| n.next.clone())).filter(|n| *n != self.world)
    }

    /// Every client follows its world to `next`, as a game would (a new session there): the
    /// subscriptions and presence move, in-flight messages of the closed world are dropped,
    /// inputs it never answered are void (counted apart), and the game clients predict with the
    /// new world's scene.
    fn follow(&mut self, wiring: &mut Wiring, next: WorldId, now: Instant) -> anyhow::Result<()> {
        let cfg = self.cfg;
        for c in &mut self.clients {
            self.r.inputs_void_at_close += c.ledger.unanswered();
            c.ledger = Ledger::default();
            (c.welcomed, c.playing_since) = (false, None);
            let old = std::mem::replace(&mut c.session, new_session(cfg, c.id));
            self.retired.push((c.game, old));
        }
        self.up = (0..self.up.len()).map(|_| DelayLine::new(UP_LINE)).collect();
        self.down = (0..self.down.len()).map(|_| DelayLine::new(DOWN_LINE)).collect();
        self.checks.clear();
        let rules = scene_rules(cfg, &next, &wiring.sessions[0], &self.clients)?;
        predict(rules.as_ref(), &mut self.clients)?;
        self.walk_mps = walk_speed(rules.as_ref());
        wiring.rewire(cfg, &next, &self.clients)?;
        if cfg.progress {
            eprintln!("\n  world {} closed: the players follow to {next}", self.world);
        }
        self.r.worlds_followed += 1;
        // Welcomed counts the clients welcomed in the world played now.
        self.r.clients_welcomed = 0;
        self.world = next;
        self.next_check = now + CHECK_EVERY;
        Ok(())
    }

    /// Every session the run had: the clients' now and those of worlds that closed.
    fn sessions(&self) -> impl Iterator<Item = &Session> {
        self.clients.iter().map(|c| &c.session).chain(self.retired.iter().map(|r| &r.1))
    }

    fn progress_line(&self) -> String {
        let r = &self.r;
        format!(
            "  {:5.1} s | welcomed {}/{} | inputs {} | acks {} | p99 {:.1} ms | corrections {} | views ok {} bad {}",
            self.load_start.elapsed().as_secs_f64(),
            r.clients_welcomed,
            self.cfg.clients,
            r.inputs_sent,
            r.acks,
            self.latency.value_at_quantile(0.99) as f64 / 1000.0,
            self.sessions().map(|s| s.stats().corrections).sum::<u64>(),
            self.sessions().map(|s| s.events().matched).sum::<u64>(),
            self.sessions().map(|s| s.events().mismatched).sum::<u64>()
        )
    }

    /// The returns after dropped sessions, and what the report tells one by one: the clients
    /// whose view of a confirmed tick differed, and the returns that never resumed.
    fn tell_returns_and_views(&self, r: &mut Report) {
        for c in self.clients.iter().filter(|c| !c.session.events().mismatches.is_empty()) {
            if r.views_differed.len() < UNEXPECTED_KEPT {
                let ticks: Vec<String> = c
                    .session
                    .events()
                    .mismatches
                    .iter()
                    .map(|(t, held, confirmed)| format!("{} ({held} held, {confirmed} confirmed)", t.0))
                    .collect();
                r.views_differed.push(format!(
                    "client {} epoch {}: ticks {}",
                    c.id.0,
                    c.session.epoch().0,
                    ticks.join(", ")
                ));
            }
        }
        for c in &self.clients {
            if let Some(back) = &c.returned {
                back.tell(r, self.load_start, c);
            }
        }
    }

    /// The report: what was counted, with the quantiles, rates and per-client figures drawn from
    /// it. `received` is what the clients had received by the end of the load.
    fn report(mut self, received: Received) -> Report {
        let cfg = self.cfg;
        let mut r = std::mem::take(&mut self.r);
        let (latency, depth, server_ticks, clients) = (&self.latency, &self.depth, &self.server_ticks, &self.clients);
        let secs = cfg.duration.as_secs_f64().max(1e-9);
        r.keepalives = self.sessions().map(|s| s.stats().keepalives).sum();
        r.inputs_sent += r.keepalives;
        r.inputs_lost_in_network = r.inputs_sent.saturating_sub(r.inputs_delivered);
        r.messages_lost_in_network = self.up.iter().map(|l| l.lost).sum();
        r.inputs_unanswered = clients.iter().map(|c| c.ledger.unanswered()).sum();
        // Unanswered counts deliveries (a rejected input owes an answer per copy); this counts
        // inputs: those the clients still await an answer for, after the settle.
        r.inputs_awaited =
            clients.iter().map(|c| c.ledger.owed().filter(|&seq| c.session.awaits(seq)).count() as u64).sum();
        r.latency_ms_p50 = latency.value_at_quantile(0.5) as f64 / 1000.0;
        r.latency_ms_p99 = latency.value_at_quantile(0.99) as f64 / 1000.0;
        r.latency_ms_max = latency.max() as f64 / 1000.0;
        for s in self.sessions().map(Session::stats) {
            r.events_received += s.events;
            r.corrections += s.corrections;
            r.clock_resyncs += s.clock_resyncs;
            r.input_copies_sent += s.copies_sent;
            r.malformed += s.malformed;
            r.stale_owner += s.stale_owner;
            r.messages_lost += s.messages_lost;
            r.unmatched_answers += s.unmatched_answers;
        }
        r.events_per_s = r.events_received as f64 / secs;
        r.corrections_per_s = r.corrections as f64 / secs;
        r.correction_depth_p50 = depth.value_at_quantile(0.5) as f64;
        r.correction_depth_max = depth.max() as f64;
        r.correction_depth_p99 = depth.value_at_quantile(0.99) as f64;
        r.state_frames = received.state_frames;
        let streams = if cfg.state { cfg.clients } else { cfg.predict.min(cfg.clients) };
        r.state_bytes_per_client_s = received.state_bytes as f64 / (f64::from(streams.max(1)) * secs);
        let per_client_s = f64::from(cfg.clients.max(1)) * secs;
        r.bytes_down_per_client_s = received.bytes as f64 / per_client_s;
        r.bytes_up_per_client_s = self.up_bytes as f64 / per_client_s;
        r.load_inbox_dropped = received.inbox_dropped;
        if !self.lag.is_empty() {
            r.load_lag_ms_p99 = self.lag.value_at_quantile(0.99) as f64 / 1e3;
            r.load_lag_ms_max = self.lag.max() as f64 / 1e3;
        }
        r.server_ticks_measured = server_ticks.len();
        if !server_ticks.is_empty() {
            r.server_tick_ms_p50 = server_ticks.value_at_quantile(0.5) as f64 / 1e3;
            r.server_tick_ms_p99 = server_ticks.value_at_quantile(0.99) as f64 / 1e3;
            r.server_tick_ms_max = server_ticks.max() as f64 / 1e3;
        }
        r.server_rollbacks_per_s = r.server_rollbacks as f64 / secs;
        r.timing = Some(cfg.timing);
        let mut all = Margins::default();
        let (mut early, mut steady) = ((0, 0), (0, 0));
        for c in clients {
            all.merge(&c.margins);
            early = (early.0 + c.early.0, early.1 + c.early.1);
            steady = (steady.0 + c.steady.0, steady.1 + c.steady.1);
            r.per_client.push(crate::report::ClientTiming {
                client: c.id.0,
                margin_ticks_p1: c.margins.quantile(0.01),
                margin_ticks_p50: c.margins.quantile(0.5),
                margin_ticks_p99: c.margins.quantile(0.99),
                rollbacks_caused: c.margins.late(),
                corrections: c.session.stats().corrections,
            });
        }
        let share = |(n, late): (u64, u64)| (n > 0).then(|| late as f64 / n as f64);
        r.late_share_first_2s = share(early);
        r.late_share_steady = share(steady);
        r.acked_first_2s = early.0;
        r.margin_ticks_p1 = all.quantile(0.01);
        r.margin_ticks_p50 = all.quantile(0.5);
        r.margin_ticks_p99 = all.quantile(0.99);
        r.rollbacks_caused = all.late();
        r.rollbacks_caused_per_s = r.rollbacks_caused as f64 / secs;
        r.views_matched = self.sessions().map(|s| s.events().matched).sum();
        r.views_mismatched = self.sessions().map(|s| s.events().mismatched).sum();
        r.views_unverified = self.sessions().map(|s| s.events().unverified).sum();
        r.views_recovered = self.sessions().map(|s| s.events().recovered).sum();
        r.views_given_up = self.sessions().map(|s| s.events().given_up).sum();
        self.tell_returns_and_views(&mut r);
        let retired = self.retired.iter().filter(|r| r.0).map(|r| &r.1);
        r.prediction =
            crate::report::Prediction::over(clients.iter().filter(|c| c.game).map(|c| &c.session).chain(retired));
        let p = &mut r.prediction;
        let mut all: Vec<f64> = self.interpolation.iter().map(|x| x.0).collect();
        let errors =
            |steady: bool| -> Vec<f64> { self.interpolation.iter().filter(|x| x.1 == steady).map(|x| x.0).collect() };
        let (mut steady, mut changed) = (errors(true), errors(false));
        p.interpolation_samples = all.len() as u64;
        p.interpolation_error_m_p50 = quantile(&mut all, 0.5);
        p.interpolation_error_m_p99 = quantile(&mut all, 0.99);
        p.interpolation_steady_samples = steady.len() as u64;
        p.interpolation_steady_m_p99 = quantile(&mut steady, 0.99);
        p.interpolation_changed_m_p99 = quantile(&mut changed, 0.99);
        let bucket = 5_000u64;
        let top = latency.max().div_ceil(bucket).min(400);
        r.latency_histogram =
            (1..=top).map(|b| (b as f64 * 5.0, latency.count_between((b - 1) * bucket + 1, b * bucket))).collect();
        r
    }
}

#[cfg(test)]
mod tests {
    /// A stall window is applied while it holds; one the loop lagged past whole is applied late,
    /// for its length, once; a window seen on time is not applied again.
    #[test]
    fn a_stall_window_lagged_past_is_applied_late() {
        let s = |ms: u64| std::time::Duration::from_millis(ms);
        let windows = [
            super::Window { start: s(1000), len: s(100), session: None },
            super::Window { start: s(3000), len: s(500), session: None },
        ];
        let mut st = super::Stalls::default();
        let seen: Vec<bool> = [500, 1300, 1350, 1399, 1400, 2000, 3100, 3499, 3500, 4000]
            .into_iter()
            .map(|ms| st.want(&windows, s(ms)))
            .collect();
        assert_eq!(seen, [false, true, true, true, false, false, true, true, false, false]);
    }

    use super::*;

    /// The ring of confirmed digests tells a second batch of a tick it keeps, across the wrap of
    /// the ticks, and forgets a tick once the ring went round past it.
    #[test]
    fn the_confirmed_ring_tells_a_second_batch_of_a_kept_tick() {
        let mut c = Confirmed::new();
        let start = u32::MAX - 100;
        let d = |k: u32| 2 * k + 1;
        for k in 0..3000u32 {
            assert_eq!(c.note(start.wrapping_add(k), d(k)), None, "tick {k}: the first batch");
        }
        let newest = start.wrapping_add(2999);
        assert_eq!(c.note(newest, 7), Some(d(2999)));
        assert_eq!(c.note(newest.wrapping_sub(CONFIRMED_KEPT - 1), 7), Some(d(3000 - CONFIRMED_KEPT)));
        // Older than the ring keeps: not told, and the newer tick in its slot is kept.
        let old = newest.wrapping_sub(CONFIRMED_KEPT);
        assert_eq!(c.note(old, 7), None);
        assert_eq!(c.note(newest, 7), Some(d(2999)));
    }

    /// The digest is the FNV-1a of the events' JSON, folded: the same as hashing the bytes.
    #[test]
    fn a_digest_is_of_the_events_json() {
        let events: Vec<impact_protocol::CollisionEvent> = Vec::new();
        let bytes = serde_json::to_vec(&events).unwrap();
        let h = bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3));
        assert_eq!(digest(&events), (h ^ h >> 32) as u32 | 1);
    }

    /// Drops every 60 s over a 5-minute run on 3 sessions: sessions 1 and 2 in turn, the first
    /// session never, the last drop over a second before the load ends.
    #[test]
    fn periodic_drops_take_turns_and_end_before_the_load() {
        let s = Duration::from_secs;
        let drops = Faults::periodic_drops(s(300), 3, s(60), s(3));
        let at: Vec<(u64, Option<usize>)> = drops.iter().map(|w| (w.start.as_secs(), w.session)).collect();
        assert_eq!(at, [(60, Some(1)), (120, Some(2)), (180, Some(1)), (240, Some(2))]);
        assert!(drops.iter().all(|w| w.len == s(3) && w.start + w.len + s(1) <= s(300)));
        assert!(Faults::periodic_drops(s(300), 1, s(60), s(3)).is_empty(), "one session: none to drop");
    }
}
