//! The server: Zenoh declarations, the tick thread, and shutdown.

use super::egress::{self, Out};
use super::error::RuntimeError;
use super::gate::TickGate;
use super::metrics::{Metrics, Totals};
use super::owner::{epoch_of, Owner};
use super::state::{Capture, StateCounters, StateOptions, Watcher};
use super::timing::LeadEstimator;
use crate::rollback::RollbackConfig;
use impact_core::scene::Scene;
use impact_protocol::{
    keys, ClientId, ClientInput, Encoding, EntityId, InputReject, RejectReason, ServerMessage, Tick, TimePing, WorldId,
};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use zenoh::Wait;

mod answer;
mod capture;
mod host;
mod ingress;
mod recent;
mod standby;
mod stats;
mod summary;
mod tick;

pub use host::{Host, HostOptions, SceneLoader, WorldOptions};
use ingress::declare_primary;
pub use summary::{Summary, TickThread};
use tick::TickLoop;

/// How to run the server.
#[derive(Clone, Debug)]
pub struct ServerOptions {
    /// Endpoints to listen on (default `tcp/127.0.0.1:7447`).
    pub listen: Vec<String>,
    /// Endpoints (routers or peers) to connect to.
    pub connect: Vec<String>,
    /// A Zenoh configuration file, for anything the flags do not cover.
    pub zenoh_config: Option<PathBuf>,
    /// Encoding of broadcast messages (replies follow the request's encoding).
    pub encoding: Encoding,
    /// Rollback settings (window, lead, stale policy, self-check, selective).
    pub rollback: Option<RollbackConfig>,
    /// Inputs the ingress queue holds between ticks.
    pub ingress_capacity: usize,
    /// Messages the egress queue holds.
    pub egress_capacity: usize,
    /// Inputs per second one client may send (token bucket, burst of one second's worth).
    pub inputs_per_client_per_s: u32,
    /// Ticks an avatar outlives its client's presence token.
    pub grace_ticks: u32,
    /// Most clients with avatars at once.
    pub max_clients: usize,
    /// Stop after this many ticks (tests, benchmarks); `None` runs until stopped.
    pub max_ticks: Option<u64>,
    /// Print a line per second to stderr.
    pub verbose: bool,
    /// Authenticated users and access control (`--users`); `None` lets anyone in.
    pub users: Option<super::auth::Users>,
    /// Clients with the game-logic role beside the users file's `role = "logic"` users
    /// (`--logic-client`): their inputs act on any body and may teleport, spawn and change
    /// classes.
    pub logic_clients: Vec<impact_protocol::ClientId>,
    /// Write the input log to this file (`--record`): a header line, then one JSON
    /// [`LogTick`](impact_protocol::LogTick) per confirmed tick.
    pub record: Option<PathBuf>,
    /// Follow the world's primary (its checkpoint and log) and take over when its liveliness
    /// token goes (`--standby`).
    pub standby: bool,
    /// The state streams (`--state-hz`, `--aoi-m`, `--state-budget`).
    pub state: StateOptions,
    /// Prometheus metrics to keep (`--metrics`); the registry may be shared by several worlds.
    pub metrics: Option<Metrics>,
    /// Threads for the core's parallel stages (`--threads`), shared by the process's worlds.
    pub pool: impact_core::par::Pool,
    /// The tick thread's nice value (`--tick-nice`; default -10): ahead of the process's other
    /// threads and of other processes when a core is contended, so a tick does not wait behind
    /// state streams or a neighbour. Below 0 needs `CAP_SYS_NICE` (or root); without it the
    /// thread keeps its priority and the server says so once. 0 leaves it alone. Linux only.
    pub tick_nice: i32,
}

impl Default for ServerOptions {
    fn default() -> Self {
        ServerOptions {
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: Vec::new(),
            zenoh_config: None,
            encoding: Encoding::MsgPack,
            rollback: None,
            ingress_capacity: 16_384,
            egress_capacity: 65_536,
            inputs_per_client_per_s: 120,
            grace_ticks: 128,
            max_clients: 10_000,
            max_ticks: None,
            verbose: false,
            users: None,
            logic_clients: Vec::new(),
            record: None,
            standby: false,
            state: StateOptions::default(),
            metrics: None,
            pool: impact_core::par::Pool::sequential(),
            tick_nice: DEFAULT_TICK_NICE,
        }
    }
}

/// The tick thread's nice value unless told otherwise (see [`ServerOptions::tick_nice`]).
pub const DEFAULT_TICK_NICE: i32 = -10;

/// A running server.
#[derive(Debug)]
pub struct ServerHandle {
    stop: Arc<AtomicBool>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<Summary>>,
    /// The world's name.
    pub world: WorldId,
}

impl ServerHandle {
    /// Asks the server to stop after the current tick and waits for its summary.
    pub fn stop(mut self) -> Summary {
        self.stop.store(true, Ordering::SeqCst);
        self.join()
    }

    /// Closes the world for good (game logic ended the match): every client in it is told
    /// ([`ServerMessage::Closed`](impact_protocol::ServerMessage::Closed), with `next` and
    /// `reason`) after its last confirmed events; then it stops. Returns its summary.
    pub fn close(self, next: Option<WorldId>, reason: String) -> Summary {
        if let Ok(mut c) = self.shared.closing.lock() {
            *c = Some((next, reason));
        }
        self.shared.closed.store(true, Ordering::SeqCst);
        self.stop()
    }

    /// Whether its tick thread has ended (`max_ticks`, or stopped).
    pub fn finished(&self) -> bool {
        self.thread.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// Waits for the server to stop by itself (`max_ticks`) or by the stop flag.
    pub fn join(&mut self) -> Summary {
        self.thread.take().map(|t| t.join().unwrap_or_default()).unwrap_or_default()
    }

    /// The flag that stops the server (for a Ctrl-C handler).
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }
}

impl Drop for ServerHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

enum Control {
    Join(ClientId),
    Leave(ClientId),
}

/// What the input subscriber hands the tick thread: inputs, and time-sync probes (answered
/// there, so the round trip a probe measures includes the queue an input waits in).
enum Ingress {
    /// `copy`: an input a batch carried before its newest, sent again against loss; its delay
    /// is not the path's, so it does not move the lead recommended to the client.
    Input {
        input: ClientInput,
        encoding: Encoding,
        copy: bool,
    },
    Ping {
        ping: TimePing,
        encoding: Encoding,
    },
    FullFrame(ClientId),
}

struct ClientState {
    avatar: Option<EntityId>,
    present: bool,
    leave_at: Option<u32>,
    tokens: f64,
    encoding: Encoding,
    /// Its recent delays, for the lead recommended in its acks.
    timing: LeadEstimator,
    /// Its `client/{id}/ack` and `client/{id}/events` keys, formatted once (a key is formatted
    /// for every ack and event batch otherwise: 5 % of the tick at 1,000 clients), shared with
    /// the egress queue's messages rather than copied into each.
    ack_key: Arc<str>,
    events_key: Arc<str>,
    /// It asked for a full state frame (after a gap); cleared once a capture carries the ask.
    want_full: bool,
}

/// Counters shared with the callbacks.
#[derive(Debug, Default)]
struct Shared {
    /// Who owns the world: the epoch every message carries, and the fence.
    owner: Arc<Owner>,
    rejected_in_callbacks: [AtomicU64; RejectReason::ALL.len()],
    egress_dropped: AtomicU64,
    /// Of them, messages for a key (not query replies): the egress numbers each key's messages
    /// past them ([`Out::Put`]'s `dropped_before`).
    keyed_dropped: AtomicU64,
    /// Set by [`ServerHandle::close`]: the clients are told, with where to go next and why.
    closing: std::sync::Mutex<Option<(Option<WorldId>, String)>>,
    /// Closed for good ([`ServerHandle::close`]): inputs are no longer answered.
    closed: AtomicBool,
}

impl Shared {
    /// The egress queue was full for a message on a key.
    fn dropped_for_key(&self) {
        self.egress_dropped.fetch_add(1, Ordering::Relaxed);
        self.keyed_dropped.fetch_add(1, Ordering::Relaxed);
    }
}

fn reason_index(r: RejectReason) -> usize {
    RejectReason::ALL.iter().position(|x| *x == r).unwrap_or(0)
}

/// Sends a message through the bounded egress queue (the egress thread encodes it); a full queue
/// drops it and counts.
fn send(tx: &SyncSender<Out>, shared: &Shared, key: Arc<str>, msg: ServerMessage, encoding: Encoding) {
    let dropped_before = shared.keyed_dropped.load(Ordering::Relaxed);
    if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) =
        tx.try_send(Out::Put { key, msg: Box::new(msg), encoding, dropped_before })
    {
        shared.dropped_for_key();
    }
}

/// A reject without window bounds; `header` is the input's `(seq, tick)` when it could be read.
fn reject(client: ClientId, header: Option<(u32, Tick)>, reason: RejectReason, detail: String) -> ServerMessage {
    let (seq, tick) = (header.map(|h| h.0), header.map(|h| h.1));
    ServerMessage::Reject(InputReject { client, seq, tick, reason, detail, oldest_tick: None, newest_tick: None })
}

/// Opens the process's Zenoh session (with `--users`' access control when given).
fn open_session(opts: &ServerOptions) -> Result<Arc<Closer>, RuntimeError> {
    let mut config = super::zenoh_config(opts.zenoh_config.as_deref(), &opts.listen, &opts.connect)?;
    let dictionary = opts.users.as_ref().map(|u| super::auth::apply(u, &mut config)).transpose()?;
    let zs = zenoh::open(config).wait().map_err(|e| RuntimeError::Zenoh(format!("opening the session: {e}")))?;
    // Zenoh read the password dictionary while opening: the file need not outlive this line.
    drop(dictionary);
    Ok(Arc::new(Closer(zs)))
}

/// The process's Zenoh session, shared by its worlds and closed when the last one ends.
pub(super) struct Closer(pub(super) zenoh::Session);

impl Drop for Closer {
    fn drop(&mut self) {
        let _ = self.0.close().wait();
    }
}

/// Starts the server on `scene` and returns at once; the tick thread runs until stopped.
pub fn start(scene: Scene, opts: ServerOptions) -> Result<ServerHandle, RuntimeError> {
    let zs = open_session(&opts)?;
    start_world(&zs, scene, opts)
}

/// Starts several worlds in one process: one Zenoh session, one tick thread and one egress
/// thread per world. Each world has its own options (record file, standby); the session's
/// (listen, connect, users) are the first world's.
pub fn start_worlds(worlds: Vec<(Scene, ServerOptions)>) -> Result<Vec<ServerHandle>, RuntimeError> {
    let Some((_, first)) = worlds.first() else { return Ok(Vec::new()) };
    let zs = open_session(first)?;
    start_on(&zs, worlds)
}

/// Starts `worlds` on the session `zs`, once their names are known to differ.
fn start_on(zs: &Arc<Closer>, worlds: Vec<(Scene, ServerOptions)>) -> Result<Vec<ServerHandle>, RuntimeError> {
    let mut names = std::collections::BTreeSet::new();
    for (scene, _) in &worlds {
        if !names.insert(scene.name.clone()) {
            return Err(RuntimeError::Config(format!("world {} is given twice", scene.name)));
        }
    }
    worlds.into_iter().map(|(scene, opts)| start_world(zs, scene, opts)).collect()
}

/// What a world's callbacks send into its tick thread, kept to declare the primary's
/// subscriber and queryables (at start, or when a standby takes over).
struct Wiring {
    ingress: SyncSender<Ingress>,
    queries: SyncSender<zenoh::query::Query>,
    egress: SyncSender<Out>,
    shared: Arc<Shared>,
    encoding: Encoding,
}

/// The declarations that make a process the world's server: inputs, queries and the
/// liveliness token a standby watches. Undeclared when dropped.
struct Primary {
    _inputs: zenoh::pubsub::Subscriber<()>,
    _queryables: Vec<zenoh::query::Queryable<()>>,
    _token: zenoh::liveliness::LivelinessToken,
}

fn start_world(zs: &Arc<Closer>, scene: Scene, opts: ServerOptions) -> Result<ServerHandle, RuntimeError> {
    let world_id = scene.name.clone();
    let owner = Arc::new(if opts.standby { Owner::default() } else { Owner::first() });
    let shared = Arc::new(Shared { owner: owner.clone(), ..Shared::default() });
    let handle_shared = shared.clone();
    let (egress_tx, egress_rx) = sync_channel::<Out>(opts.egress_capacity);
    let (ingress_tx, ingress_rx) = sync_channel::<Ingress>(opts.ingress_capacity);
    let (control_tx, control_rx) = sync_channel::<Control>(opts.max_clients.max(16) * 2);
    let (query_tx, query_rx) = sync_channel::<zenoh::query::Query>(256);
    let record = match &opts.record {
        Some(path) => Some(crate::recording::Recorder::create(path, &scene).map_err(RuntimeError::Config)?),
        None => None,
    };
    let wiring = Wiring {
        ingress: ingress_tx,
        queries: query_tx,
        egress: egress_tx.clone(),
        shared: shared.clone(),
        encoding: opts.encoding,
    };
    // Presence: a standby follows it too, to know who is there when it takes over.
    let presence_sub = {
        let tx = control_tx;
        zs.0.liveliness()
            .declare_subscriber(keys::PRESENCE.any_client(&world_id))
            .history(true)
            .callback(move |sample| {
                if let Ok((_, Some(client))) = keys::PRESENCE.parse(sample.key_expr().as_str()) {
                    let c = match sample.kind() {
                        zenoh::sample::SampleKind::Put => Control::Join(client),
                        zenoh::sample::SampleKind::Delete => Control::Leave(client),
                    };
                    let _ = tx.try_send(c);
                }
            })
            .wait()
            .map_err(|e| RuntimeError::Zenoh(format!("declaring the presence subscriber: {e}")))?
    };
    // Owners announce themselves: one that hears a newer epoch than its own is fenced, a standby
    // learns the epoch it must take over above.
    let owner_sub = {
        let owner = owner.clone();
        zs.0.declare_subscriber(keys::OWNER.key(&world_id, None))
            .callback(move |sample| {
                if let Some(e) = epoch_of(&sample) {
                    owner.heard(e);
                }
            })
            .wait()
            .map_err(|e| RuntimeError::Zenoh(format!("declaring the owner subscriber: {e}")))?
    };
    let follower = if opts.standby { Some(standby::Follower::start(&zs.0, &world_id, &owner)?) } else { None };
    let primary = if opts.standby { None } else { Some(declare_primary(&zs.0, &world_id, &wiring)?) };

    let egress_session = zs.0.clone();
    let egress_failures = Arc::new(AtomicU64::new(0));
    let ef = egress_failures.clone();
    // The tick first on its core: the egress and state threads work between ticks.
    let tick_gate = Arc::new(TickGate::default());
    let egress_gate = tick_gate.clone();
    let egress_thread = std::thread::Builder::new()
        .name(format!("impact-egress-{world_id}"))
        .spawn(move || egress::run(egress_session, egress_rx, ef, owner, egress_gate))
        .map_err(|e| RuntimeError::Thread(e.to_string()))?;

    let state_counters = Arc::new(StateCounters::default());
    let (state_tx, state_thread) = if opts.state.hz > 0 {
        let (tx, rx) = sync_channel::<Capture>(2);
        let (session, world, so, enc, c) =
            (zs.0.clone(), world_id.clone(), opts.state.clone(), opts.encoding, state_counters.clone());
        let (owner, gate) = (shared.owner.clone(), tick_gate.clone());
        let t = std::thread::Builder::new()
            .name(format!("impact-state-{world_id}"))
            .spawn(move || super::state::run(session, world, so, enc, rx, c, owner, gate))
            .map_err(|e| RuntimeError::Thread(e.to_string()))?;
        (Some(tx), Some(t))
    } else {
        (None, None)
    };

    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let world_name = world_id.clone();
    let zs = zs.clone();
    let thread = std::thread::Builder::new()
        .name(format!("impact-tick-{world_id}"))
        .spawn(move || {
            let mut t = TickLoop::new(scene, opts, world_name, egress_tx, shared);
            t.record = record;
            t.primary = primary;
            t.state_tx = state_tx;
            t.state_counters = state_counters;
            t.tick_gate = tick_gate;
            let mut summary = t.run(&stop2, &zs.0, &wiring, follower, ingress_rx, control_rx, query_rx);
            // The state thread ends when its queue closes.
            t.state_tx = None;
            if let Some(s) = state_thread {
                let _ = s.join();
            }
            t.state_summary(&mut summary);
            // Undeclare the callbacks (they hold senders of the egress queue), then drop the
            // tick loop's sender: the queue closes, the egress thread drains it and ends.
            drop(presence_sub);
            drop(owner_sub);
            drop(wiring);
            drop(t);
            let _ = egress_thread.join();
            // The session closes with the process's last world.
            drop(zs);
            summary
        })
        .map_err(|e| RuntimeError::Thread(e.to_string()))?;
    Ok(ServerHandle { stop, shared: handle_shared, thread: Some(thread), world: world_id })
}
