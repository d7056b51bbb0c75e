//! The server: Zenoh declarations, the tick thread, and shutdown.

use super::egress::{self, Out};
use super::error::RuntimeError;
use super::metrics::{Metrics, Totals, WorldMetrics};
use super::state::{Capture, StateCounters, StateOptions, Viewer};
use super::timing::LeadEstimator;
use crate::rollback::{RollbackConfig, Session};
use crate::scene::{avatar_position, AvatarRule, Scene};
use crate::sim::{Plan, SystemAction};
use impact_protocol::{
    encode, keys, Admitted, ClientId, ClientInput, CollisionEvent, Encoding, EntityId, EventBatch, InputAck,
    InputReject, LoggedInput, RejectReason, ServerMessage, Tick, Welcome, WorldId,
};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use zenoh::Wait;

mod answer;
mod ingress;
mod standby;
mod stats;
mod summary;

use ingress::declare_primary;
pub use summary::Summary;

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
            record: None,
            standby: false,
            state: StateOptions::default(),
            metrics: None,
        }
    }
}

/// A running server.
#[derive(Debug)]
pub struct ServerHandle {
    stop: Arc<AtomicBool>,
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

struct Ingress {
    input: ClientInput,
    encoding: Encoding,
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
    /// for every ack and event batch otherwise: 5 % of the tick at 1,000 clients).
    ack_key: String,
    events_key: String,
}

/// Counters shared with the callbacks.
#[derive(Default)]
struct Shared {
    rejected_in_callbacks: [AtomicU64; RejectReason::ALL.len()],
    egress_dropped: AtomicU64,
    egress_failed: AtomicU64,
}

fn reason_index(r: RejectReason) -> usize {
    RejectReason::ALL.iter().position(|x| *x == r).unwrap_or(0)
}

/// Sends a message through the bounded egress queue; a full queue drops it and counts.
fn send(tx: &SyncSender<Out>, shared: &Shared, key: String, msg: &ServerMessage, encoding: Encoding) {
    let Ok(bytes) = encode(msg, encoding) else {
        shared.egress_failed.fetch_add(1, Ordering::Relaxed);
        return;
    };
    if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(Out::Put { key, bytes, encoding }) {
        shared.egress_dropped.fetch_add(1, Ordering::Relaxed);
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
    let dictionary = opts.users.as_ref().map(|u| u.apply(&mut config)).transpose()?;
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
    let mut names = std::collections::BTreeSet::new();
    for (scene, _) in &worlds {
        if !names.insert(scene.name.clone()) {
            return Err(RuntimeError::Config(format!("world {} is given twice", scene.name)));
        }
    }
    let Some((_, first)) = worlds.first() else { return Ok(Vec::new()) };
    let zs = open_session(first)?;
    worlds.into_iter().map(|(scene, opts)| start_world(&zs, scene, opts)).collect()
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
    let shared = Arc::new(Shared::default());
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
    let follower = if opts.standby { Some(standby::Follower::start(&zs.0, &world_id)?) } else { None };
    let primary = if opts.standby { None } else { Some(declare_primary(&zs.0, &world_id, &wiring)?) };

    let egress_session = zs.0.clone();
    let egress_failures = Arc::new(AtomicU64::new(0));
    let ef = egress_failures.clone();
    let egress_thread = std::thread::Builder::new()
        .name(format!("impact-egress-{world_id}"))
        .spawn(move || egress::run(egress_session, egress_rx, ef))
        .map_err(|e| RuntimeError::Thread(e.to_string()))?;

    let state_counters = Arc::new(StateCounters::default());
    let (state_tx, state_thread) = if opts.state.hz > 0 {
        let (tx, rx) = sync_channel::<Capture>(2);
        let (session, world, so, enc, c) =
            (zs.0.clone(), world_id.clone(), opts.state.clone(), opts.encoding, state_counters.clone());
        let t = std::thread::Builder::new()
            .name(format!("impact-state-{world_id}"))
            .spawn(move || super::state::run(session, world, so, enc, rx, c))
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
            drop(wiring);
            drop(t);
            let _ = egress_thread.join();
            // The session closes with the process's last world.
            drop(zs);
            summary
        })
        .map_err(|e| RuntimeError::Thread(e.to_string()))?;
    Ok(ServerHandle { stop, thread: Some(thread), world: world_id })
}

struct TickLoop {
    session: Session,
    opts: ServerOptions,
    world: WorldId,
    avatar: Option<AvatarRule>,
    egress: SyncSender<Out>,
    shared: Arc<Shared>,
    clients: BTreeMap<ClientId, ClientState>,
    summary: Summary,
    /// This second's tick durations, ms (the stats message carries them).
    tick_times: Vec<f64>,
    /// Every tick's duration, microseconds, for the run's percentiles.
    all_tick_times: hdrhistogram::Histogram<u64>,
    /// Core stage times and steps at the last stats message, for the period's means.
    last_stages: (u64, Vec<Duration>),
    /// Where state captures go (`None`: no state streams).
    state_tx: Option<SyncSender<Capture>>,
    state_counters: Arc<StateCounters>,
    /// The state frame the last capture was for.
    state_frame: Option<u64>,
    metrics: Option<WorldMetrics>,
    period_events: u64,
    period_rollbacks: u32,
    period_depth: u32,
    period_queue_max: u32,
    /// Rollbacks by depth (index: ticks re-simulated; bounded by the window).
    depths: Vec<u64>,
    /// The declarations of the world's server (`None` while a standby follows).
    primary: Option<Primary>,
    /// The `--record` file.
    record: Option<crate::recording::Recorder>,
    /// Inputs acked and server actions queued in this tick: the `log/admitted` message.
    admitted: Admitted,
    /// This tick's acks, held until `admitted` is out.
    acks: Vec<(String, ServerMessage, Encoding)>,
    /// The last tick an earlier primary confirmed: a standby that took over never publishes a
    /// tick up to it as confirmed again.
    confirmed_upto: Option<Tick>,
}

impl TickLoop {
    fn new(
        scene: Scene,
        opts: ServerOptions,
        world: WorldId,
        egress: SyncSender<Out>,
        shared: Arc<Shared>,
    ) -> TickLoop {
        let w = scene.world;
        let mut rb = opts.rollback.clone().unwrap_or_else(|| RollbackConfig::for_world(&w));
        rb.window_ticks = rb.window_ticks.max(1);
        let plan = Plan::for_world(&w);
        let session = Session::new(w, plan, rb);
        let metrics = opts.metrics.as_ref().map(|m| m.world(world.as_str()));
        TickLoop {
            session,
            opts,
            world,
            avatar: scene.avatar,
            egress,
            shared,
            clients: BTreeMap::new(),
            summary: Summary::default(),
            tick_times: Vec::with_capacity(128),
            // 1 us to 1 h at three significant figures: the bounds cannot be out of range.
            all_tick_times: hdrhistogram::Histogram::new_with_bounds(1, 3_600_000_000, 3).expect("valid bounds"),
            last_stages: (0, Vec::new()),
            state_tx: None,
            state_counters: Arc::new(StateCounters::default()),
            state_frame: None,
            metrics,
            period_events: 0,
            period_rollbacks: 0,
            period_depth: 0,
            depths: Vec::new(),
            period_queue_max: 0,
            primary: None,
            record: None,
            admitted: Admitted { tick: Tick(0), system: Vec::new(), inputs: Vec::new() },
            acks: Vec::new(),
            confirmed_upto: None,
        }
    }

    fn put(&self, key: String, msg: &ServerMessage, encoding: Encoding) {
        send(&self.egress, &self.shared, key, msg, encoding);
    }

    /// Publishes on the log streams: in order with everything else, but never dropped by
    /// congestion (a standby that misses an entry must start again from a checkpoint).
    fn put_log(&self, key: String, msg: &ServerMessage) {
        let enc = self.opts.encoding;
        match encode(msg, enc) {
            Ok(bytes) => {
                if self.egress.try_send(Out::Log { key, bytes, encoding: enc }).is_err() {
                    self.shared.egress_dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
            Err(_) => {
                self.shared.egress_failed.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// A client's `client/{id}/ack` key (formatted once, when the client was first seen).
    fn ack_key(&self, client: ClientId) -> String {
        self.clients.get(&client).map_or_else(|| keys::CLIENT_ACK.key(&self.world, Some(client)), |c| c.ack_key.clone())
    }

    /// A client's `client/{id}/events` key, likewise.
    fn events_key(&self, client: ClientId) -> String {
        self.clients
            .get(&client)
            .map_or_else(|| keys::CLIENT_EVENTS.key(&self.world, Some(client)), |c| c.events_key.clone())
    }

    /// The state of a client first seen now.
    fn new_client(&self, client: ClientId, present: bool, leave_at: Option<u32>, encoding: Encoding) -> ClientState {
        ClientState {
            avatar: None,
            present,
            leave_at,
            tokens: f64::from(self.opts.inputs_per_client_per_s),
            encoding,
            timing: LeadEstimator::default(),
            ack_key: keys::CLIENT_ACK.key(&self.world, Some(client)),
            events_key: keys::CLIENT_EVENTS.key(&self.world, Some(client)),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        stop: &AtomicBool,
        zs: &zenoh::Session,
        wiring: &Wiring,
        follower: Option<standby::Follower>,
        ingress: Receiver<Ingress>,
        control: Receiver<Control>,
        queries: Receiver<zenoh::query::Query>,
    ) -> Summary {
        if let Some(f) = follower {
            if !self.follow(f, stop, zs, &control) {
                return self.finish();
            }
            match declare_primary(zs, &self.world, wiring) {
                Ok(p) => self.primary = Some(p),
                Err(e) => {
                    eprintln!("impact-server: world {}: taking over failed: {e}", self.world);
                    return self.finish();
                }
            }
            self.reanchor();
        }
        let hz = self.session.world().config.tick_hz;
        let dt = Duration::from_secs_f64(1.0 / f64::from(hz));
        let started = Instant::now();
        let mut next = started;
        let mut last_stats = Instant::now();
        loop {
            if stop.load(Ordering::SeqCst) || self.opts.max_ticks.is_some_and(|m| self.summary.ticks >= m) {
                break;
            }
            // Deadline schedule. Behind by more than 4 ticks: drop the backlog and start a new
            // schedule from now (catching up by running ticks back to back would only make the
            // world run fast for a while); each dropped deadline counts as an overrun.
            let now = Instant::now();
            if now < next {
                std::thread::sleep(next - now);
            } else if now - next > dt * 4 {
                let missed = ((now - next).as_secs_f64() / dt.as_secs_f64()) as u64;
                self.summary.overruns += missed;
                next = now;
            }
            next += dt;
            let t0 = Instant::now();
            self.tick(&ingress, &control, &queries);
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            if t0.elapsed() > dt {
                self.summary.overruns += 1;
            }
            self.tick_times.push(ms);
            let _ = self.all_tick_times.record((ms * 1e3).round().max(1.0) as u64);
            if let Some(m) = &self.metrics {
                m.tick(ms / 1e3);
            }
            self.summary.tick_ms_max = self.summary.tick_ms_max.max(ms);
            if last_stats.elapsed() >= Duration::from_secs(1) {
                last_stats = Instant::now();
                self.publish_stats();
            }
        }
        self.summary.run_s = started.elapsed().as_secs_f64();
        // Shutdown: everything still in the window is final now.
        for (batch, log) in self.session.finish() {
            if self.confirmed_upto.is_some_and(|c| batch.tick <= c) {
                continue;
            }
            self.put(keys::CONFIRMED.key(&self.world, None), &ServerMessage::Confirmed(batch), self.opts.encoding);
            let entry = log.to_wire();
            if let Some(r) = self.record.as_mut() {
                r.write(&entry);
            }
            self.put_log(keys::LOG.key(&self.world, None), &ServerMessage::Log(entry));
        }
        self.finish()
    }

    /// The run's summary (after the last tick).
    fn finish(&mut self) -> Summary {
        if let Some(r) = self.record.as_mut() {
            if let Err(e) = r.flush() {
                eprintln!("impact-server: world {}: {e}", self.world);
            }
        }
        let h = &self.all_tick_times;
        self.summary.tick_ms_p50 = h.value_at_quantile(0.5) as f64 / 1e3;
        self.summary.tick_ms_p99 = h.value_at_quantile(0.99) as f64 / 1e3;
        self.summary.tick_ms_mean = h.mean() / 1e3;
        self.summary.egress_dropped = self.shared.egress_dropped.load(Ordering::Relaxed);
        for (k, r) in RejectReason::ALL.iter().enumerate() {
            let n = self.shared.rejected_in_callbacks[k].load(Ordering::Relaxed);
            if n > 0 {
                *self.summary.inputs_rejected.entry(r.name().to_string()).or_insert(0) += n;
            }
        }
        self.summary.rollbacks = self.session.stats.rollbacks;
        self.summary.rollback_depth_max = self.session.stats.depth_max;
        let core = &self.session.stepper().stats;
        self.summary.core_steps = core.ticks;
        let steps = core.ticks.max(1) as f64;
        self.summary.core_stage_ms = core.stages().iter().map(|(n, d)| (*n, d.as_secs_f64() * 1e3 / steps)).collect();
        // Depth percentiles over the ticks that rolled back.
        let total: u64 = self.depths.iter().sum();
        let at = |q: f64| {
            let rank = ((q * total as f64).ceil() as u64).max(1);
            let mut seen = 0;
            self.depths.iter().position(|c| {
                seen += c;
                seen >= rank
            })
        };
        if total > 0 {
            self.summary.rollback_depth_p50 = at(0.5).unwrap_or(0) as u32;
            self.summary.rollback_depth_p99 = at(0.99).unwrap_or(0) as u32;
        }
        self.summary.clone()
    }

    fn count_reject(&mut self, reason: RejectReason) {
        *self.summary.inputs_rejected.entry(reason.name().to_string()).or_insert(0) += 1;
    }

    fn tick(
        &mut self,
        ingress: &Receiver<Ingress>,
        control: &Receiver<Control>,
        queries: &Receiver<zenoh::query::Query>,
    ) {
        self.presence(control);
        self.ingest(ingress);
        self.publish_admitted();
        self.step();
        self.capture_state();
        // Queries, answered from the history.
        while let Ok(q) = queries.try_recv() {
            self.answer(q);
        }
    }

    /// Joins and leaves; avatars whose client's grace ended are removed. A standby only keeps
    /// track (its primary's log carries the spawns and removals).
    fn presence(&mut self, control: &Receiver<Control>) {
        let now = self.session.now();
        while let Ok(c) = control.try_recv() {
            match c {
                Control::Join(client) => self.join(client),
                Control::Leave(client) => {
                    if let Some(s) = self.clients.get_mut(&client) {
                        s.present = false;
                        s.leave_at = Some(now.0 + self.opts.grace_ticks);
                    }
                }
            }
        }
        let leaving: Vec<ClientId> = self
            .clients
            .iter()
            .filter(|(_, s)| !s.present && s.leave_at.is_some_and(|t| t <= now.0))
            .map(|(c, _)| *c)
            .collect();
        if self.primary.is_none() {
            return;
        }
        for c in leaving {
            self.session.forget_client(c);
            if let Some(s) = self.clients.remove(&c) {
                if let Some(entity) = s.avatar {
                    self.submit_system(SystemAction::Remove { entity });
                }
            }
        }
    }

    /// Queues a server action for the present tick, and for the admitted log.
    fn submit_system(&mut self, a: SystemAction) {
        self.admitted.system.push(crate::rollback::log::logged_system(&a));
        self.session.submit_system(a);
    }

    /// Inputs: every one queued now (the queue is bounded, so this is too).
    fn ingest(&mut self, ingress: &Receiver<Ingress>) {
        let now = self.session.now();
        let per_tick = f64::from(self.opts.inputs_per_client_per_s) / f64::from(self.session.world().config.tick_hz);
        for c in self.clients.values_mut() {
            c.tokens = (c.tokens + per_tick).min(f64::from(self.opts.inputs_per_client_per_s));
        }
        let mut queued = 0u32;
        while let Ok(Ingress { input, encoding }) = ingress.try_recv() {
            queued += 1;
            let (client, seq, tick) = (input.client, input.seq, input.tick);
            if !self.clients.contains_key(&client) {
                if self.clients.len() >= self.opts.max_clients {
                    // Every client costs a little state until its grace ends: an input from yet
                    // another id (never present) must not grow it without bound.
                    self.count_reject(RejectReason::QueueFull);
                    let detail = format!("the server already serves its maximum of {} clients", self.opts.max_clients);
                    let msg = reject(client, Some((seq, tick)), RejectReason::QueueFull, detail);
                    self.put(self.ack_key(client), &msg, encoding);
                    continue;
                }
                let state = self.new_client(client, false, Some(now.0 + self.opts.grace_ticks), encoding);
                self.clients.insert(client, state);
            }
            let state = self.clients.get_mut(&client).expect("inserted above");
            let ack_key = state.ack_key.clone();
            state.encoding = encoding;
            if state.tokens < 1.0 {
                self.count_reject(RejectReason::RateLimited);
                let msg = reject(
                    client,
                    Some((seq, tick)),
                    RejectReason::RateLimited,
                    format!("more than {} inputs per second", self.opts.inputs_per_client_per_s),
                );
                self.put(ack_key, &msg, encoding);
                continue;
            }
            state.tokens -= 1.0;
            let view = input.view_tick.unwrap_or(tick);
            let logged = LoggedInput {
                client,
                seq,
                tick,
                view_tick: input.view_tick,
                actions: input.actions.clone(),
                rewound: Vec::new(),
            };
            match self.session.submit(input) {
                Ok(applied) => {
                    self.summary.inputs_accepted += 1;
                    self.admitted.inputs.push(LoggedInput { tick: applied, ..logged });
                    // The most a client can lead by and still be accepted: its round trip (the
                    // smallest lead that is on time) plus the ticks the server accepts ahead.
                    let max_lead = now.0.saturating_sub(view.0).saturating_add(self.session.config().lead_ticks);
                    let lead_ticks = state.timing.observe(now, view, max_lead);
                    let margin_ticks = (i64::from(applied.0) - i64::from(now.0)).clamp(-1 << 30, 1 << 30) as i32;
                    let ack = ServerMessage::Ack(InputAck {
                        client,
                        seq,
                        tick,
                        applied_tick: applied,
                        server_tick: now,
                        margin_ticks,
                        lead_ticks,
                    });
                    // Sent after the admitted log (see `publish_admitted`).
                    self.acks.push((ack_key, ack, encoding));
                }
                Err(r) => {
                    self.count_reject(r.reason);
                    let msg = ServerMessage::Reject(InputReject {
                        client,
                        seq: Some(seq),
                        tick: Some(tick),
                        reason: r.reason,
                        detail: r.detail,
                        oldest_tick: r.oldest_tick,
                        newest_tick: r.newest_tick,
                    });
                    self.put(ack_key, &msg, encoding);
                }
            }
        }
        self.period_queue_max = self.period_queue_max.max(queued);
    }

    /// Publishes what this tick admitted (a standby re-applies it if this process dies before
    /// the tick is confirmed), then the acks: a client never holds an ack for an input a standby
    /// could not know of. Nothing admitted: nothing sent.
    fn publish_admitted(&mut self) {
        let now = self.session.now();
        if !self.admitted.inputs.is_empty() || !self.admitted.system.is_empty() {
            self.admitted.tick = now;
            let msg = ServerMessage::Admitted(std::mem::replace(
                &mut self.admitted,
                Admitted { tick: now, system: Vec::new(), inputs: Vec::new() },
            ));
            self.put_log(keys::LOG_ADMITTED.key(&self.world, None), &msg);
        }
        for (key, ack, encoding) in std::mem::take(&mut self.acks) {
            self.put(key, &ack, encoding);
        }
    }

    /// Steps the present tick and publishes what it produced: events, corrections, the tick
    /// that left the window (confirmed events and its log entry), ray results, skips, welcomes.
    fn step(&mut self) {
        let adv = self.session.advance();
        self.publish(adv);
    }

    /// Publishes what one advance produced.
    fn publish(&mut self, mut adv: crate::rollback::Advance) {
        self.summary.ticks += 1;
        if adv.rollback_depth > 0 {
            if let Some(m) = &self.metrics {
                m.rollback(adv.rollback_depth);
            }
            self.period_rollbacks += 1;
            self.period_depth = self.period_depth.max(adv.rollback_depth);
            let d = adv.rollback_depth as usize;
            if self.depths.len() <= d {
                self.depths.resize(d + 1, 0);
            }
            self.depths[d] += 1;
        }
        let enc = self.opts.encoding;
        if !adv.events.is_empty() {
            self.summary.events += adv.events.len() as u64;
            self.period_events += adv.events.len() as u64;
            let batch = EventBatch { tick: adv.tick, revision: 0, events: adv.events.clone() };
            self.per_client(&batch.events, adv.tick, |events| {
                ServerMessage::Events(EventBatch { tick: batch.tick, revision: 0, events })
            });
            self.put(keys::EVENTS.key(&self.world, None), &ServerMessage::Events(batch), enc);
        }
        for c in &adv.corrections {
            self.summary.corrections += 1;
            let all: Vec<CollisionEvent> = c.retracted.iter().chain(&c.amended).chain(&c.added).cloned().collect();
            let cc = c.clone();
            self.per_client(&all, c.tick, move |events| {
                let keep = |v: &[CollisionEvent]| {
                    v.iter().filter(|e| events.iter().any(|x| x.key() == e.key())).cloned().collect()
                };
                ServerMessage::Corrections(impact_protocol::CorrectionBatch {
                    tick: cc.tick,
                    revision: cc.revision,
                    retracted: keep(&cc.retracted),
                    amended: keep(&cc.amended),
                    added: keep(&cc.added),
                })
            });
            self.put(keys::CORRECTIONS.key(&self.world, None), &ServerMessage::Corrections(c.clone()), enc);
        }
        // A standby that took over re-simulates ticks its primary already confirmed: they were
        // published then, and are not again.
        let fresh = |t: Tick| self.confirmed_upto.is_none_or(|c| t > c);
        if let Some(log) = adv.log.take().filter(|l| fresh(l.tick)) {
            let entry = log.to_wire();
            if let Some(r) = self.record.as_mut() {
                r.write(&entry);
            }
            self.put_log(keys::LOG.key(&self.world, None), &ServerMessage::Log(entry));
        }
        if let Some(c) = adv.confirmed.as_ref().filter(|c| fresh(c.tick)) {
            self.summary.confirmed_events += c.events.len() as u64;
            if !c.events.is_empty() {
                let cc = c.clone();
                self.per_client(&c.events, c.tick, move |events| {
                    ServerMessage::Confirmed(EventBatch { tick: cc.tick, revision: cc.revision, events })
                });
            }
            self.put(keys::CONFIRMED.key(&self.world, None), &ServerMessage::Confirmed(c.clone()), enc);
        }
        for r in &adv.rays {
            let e = self.clients.get(&r.client).map_or(enc, |c| c.encoding);
            self.put(self.ack_key(r.client), &ServerMessage::RayResult(r.clone()), e);
        }
        for s in &adv.skipped {
            self.count_reject(s.reason);
            let e = self.clients.get(&s.client).map_or(enc, |c| c.encoding);
            self.put(self.ack_key(s.client), &reject(s.client, Some((s.seq, s.tick)), s.reason, s.detail.clone()), e);
        }
        for (client, entity) in &adv.spawned {
            if let Some(c) = self.clients.get_mut(client) {
                c.avatar = Some(*entity);
            }
            if self.primary.is_some() {
                self.welcome(*client, Some(*entity));
            }
        }
    }

    fn welcome(&self, client: ClientId, avatar: Option<EntityId>) {
        let cfg = &self.session.world().config;
        let msg = ServerMessage::Welcome(Welcome {
            client,
            avatar,
            tick: self.session.now(),
            tick_hz: cfg.tick_hz,
            window_ticks: cfg.window_ticks,
            input_lead_ticks: self.session.config().lead_ticks,
            max_rewind_ticks: cfg.max_rewind_ticks.min(self.session.config().window_ticks),
            next_seq: self.session.next_seq(client),
        });
        let e = self.clients.get(&client).map_or(self.opts.encoding, |c| c.encoding);
        self.put(self.ack_key(client), &msg, e);
    }

    fn join(&mut self, client: ClientId) {
        let now = self.session.now();
        if self.primary.is_none() {
            // A standby: remember the client is there; its primary spawns the avatar.
            let state = self.new_client(client, true, None, self.opts.encoding);
            let s = self.clients.entry(client).or_insert(state);
            s.present = true;
            s.leave_at = None;
            return;
        }
        if let Some(s) = self.clients.get_mut(&client) {
            s.present = true;
            s.leave_at = None;
            if s.avatar.is_some() {
                let a = s.avatar;
                self.welcome(client, a);
                return;
            }
        }
        if self.clients.len() >= self.opts.max_clients && !self.clients.contains_key(&client) {
            return;
        }
        self.summary.clients += 1;
        let state = self.new_client(client, true, None, self.opts.encoding);
        let had = self.clients.insert(client, state).is_some();
        match (&self.avatar, had) {
            (Some(rule), _) => {
                let pos = avatar_position(rule, client.0, now.0);
                let (class, shape) = (rule.class, rule.shape.clone());
                self.submit_system(SystemAction::SpawnAvatar { client, class, shape, pos });
            }
            (None, _) => self.welcome(client, None),
        }
    }

    /// Publishes, for each client owning an entity in `events`, the batch `make` builds from the
    /// events that concern it.
    fn per_client(&self, events: &[CollisionEvent], tick: Tick, make: impl Fn(Vec<CollisionEvent>) -> ServerMessage) {
        let w = self.session.world();
        let past = self.session.frame(tick).map(|f| &f.state);
        let owner = |id: EntityId| {
            w.bodies
                .slot(id)
                .and_then(|s| w.bodies.owner[s])
                .or_else(|| past.and_then(|p| p.bodies.slot(id).and_then(|s| p.bodies.owner[s])))
        };
        let mut by_client: BTreeMap<ClientId, Vec<CollisionEvent>> = BTreeMap::new();
        for e in events {
            let (oa, ob) = (owner(e.a), owner(e.b));
            for c in [oa, ob].into_iter().flatten() {
                let v = by_client.entry(c).or_default();
                if v.last().is_none_or(|l| l.key() != e.key()) {
                    v.push(e.clone());
                }
            }
        }
        for (client, evs) in by_client {
            let e = self.clients.get(&client).map_or(self.opts.encoding, |c| c.encoding);
            self.put(self.events_key(client), &make(evs), e);
        }
    }
}
