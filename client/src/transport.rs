//! The Zenoh transport: a [`Session`] driven over Zenoh, as a peer or through a router, with a
//! user and password where the server asks for them. The one module here that does I/O (behind
//! the default `zenoh` feature); a WebSocket transport or another language's port drives the same
//! [`Session`] the same way: feed [`Session::receive`], send [`Session::poll_transmit`].
//!
//! [`Connection::open`] opens a Zenoh session, finds the world's server and checks that it
//! speaks this protocol version (a clear error if not), subscribes to the client's keys, and
//! declares the client's presence, which makes the server spawn its avatar and send its welcome.
//! It asks the server for its rules and static world (`query/scene`): the session predicts the
//! own avatar with them once they come. Each frame, [`Connection::pump`] hands the session what
//! arrived and sends what it gives.
//!
//! Received messages are decoded in Zenoh's callback and queued for the next pump, at most
//! [`INBOX_CAPACITY`] (past it they are dropped and counted in [`Connection::dropped`]); a
//! message that does not decode is counted by the session ([`Session::malformed`]) and skipped.
//! A dropped link is Zenoh's to restore: the session retries its endpoints with back-off (100 ms
//! doubling to 500 ms) and re-declares the presence and subscriptions; the server welcomes the
//! client again within its grace period and the session resumes its seqs.
//!
//! A welcome that does not come (lost on its way, or a presence the server never heard) is asked
//! for again: while the session is joining, the presence is withdrawn and declared again after
//! [`WELCOME_WAIT`], doubling up to [`WELCOME_WAIT_MAX`] ([`Connection::presence_repeats`]).

use crate::session::{Session, Status};
use ::zenoh::Wait;
use impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES;
use impact_protocol::{
    encode, keys, ClientId, ClientMessage, Encoding, Epoch, EventBatch, SceneDescription, ServerMessage, Stamp, Tick,
    WorldAnswer, WorldCommand, WorldId,
};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Messages queued between Zenoh's callbacks and the next [`Connection::pump`], at most: a
/// second of a busy client's messages at a 60 Hz frame rate many times over.
pub const INBOX_CAPACITY: usize = 16_384;

/// How long a joining client waits for its welcome before it declares its presence again.
pub const WELCOME_WAIT: Duration = Duration::from_secs(1);

/// The longest wait between two declarations of a joining client's presence.
pub const WELCOME_WAIT_MAX: Duration = Duration::from_secs(8);

/// A Zenoh user name and password (for a server started with `--users`).
#[derive(Clone, Debug)]
pub struct Credentials {
    /// User name.
    pub user: String,
    /// Password.
    pub password: String,
}

/// How the client's Zenoh session joins the network.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// A peer: connects to the endpoints given and, through gossip, directly to the peers they
    /// know (the servers): the default for a server without a router.
    #[default]
    Peer,
    /// A client: talks only to the router (or peer) it connects to, as game clients behind a
    /// zenohd router do.
    Client,
}

/// Why a connection could not be made or went wrong.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TransportError {
    /// Zenoh refused the configuration or could not open the session (no endpoint reachable,
    /// credentials refused).
    Open(String),
    /// No server owns the world: nothing answered for its liveliness token in time.
    NoServer {
        /// The world.
        world: String,
        /// How long the client looked.
        waited: Duration,
    },
    /// A server owns the world but speaks another protocol version.
    VersionMismatch {
        /// The world.
        world: String,
        /// The versions its servers speak.
        server: Vec<String>,
        /// The version this client speaks.
        client: &'static str,
    },
    /// Declaring a subscription, the presence token, or a put failed.
    Zenoh(String),
}

impl std::fmt::Display for TransportError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TransportError::Open(e) => write!(f, "{e}"),
            TransportError::NoServer { world, waited } => write!(
                f,
                "no impact server owns world {world:?}: nothing answered for impact/*/{world}/server within {:.1} s \
                 (is impact-server running with --world {world}, and reachable from the endpoints given?)",
                waited.as_secs_f64()
            ),
            TransportError::VersionMismatch { world, server, client } => write!(
                f,
                "the server of world {world:?} speaks protocol {}, this client speaks {client}: upgrade the one \
                 that is older",
                server.join(", ")
            ),
            TransportError::Zenoh(e) => write!(f, "zenoh: {e}"),
        }
    }
}

impl std::error::Error for TransportError {}

/// Opens a Zenoh session connected to `connect` (or configured by the file `config`),
/// authenticated as `creds` if given. Without a configuration file the session has multicast
/// scouting off, listens nowhere, fails if it cannot reach every endpoint within 10 s (no server
/// there, or credentials refused), and later retries a lost endpoint with back-off.
pub fn open_session(
    connect: &[String],
    config: Option<&std::path::Path>,
    creds: Option<&Credentials>,
    mode: Mode,
) -> Result<::zenoh::Session, TransportError> {
    let bad = |e: ::zenoh::Error| TransportError::Open(format!("zenoh configuration: {e}"));
    let mut c = match config {
        Some(p) => ::zenoh::Config::from_file(p).map_err(|e| TransportError::Open(format!("{}: {e}", p.display())))?,
        None => {
            let mut c = ::zenoh::Config::default();
            let mode = if mode == Mode::Client { "\"client\"" } else { "\"peer\"" };
            c.insert_json5("mode", mode).map_err(bad)?;
            c.insert_json5("scouting/multicast/enabled", "false").map_err(bad)?;
            c.insert_json5("listen/endpoints", "[]").map_err(bad)?;
            c.insert_json5("connect/timeout_ms", "10000").map_err(bad)?;
            c.insert_json5("connect/exit_on_failure", "true").map_err(bad)?;
            c.insert_json5(
                "connect/retry",
                r#"{"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}"#,
            )
            .map_err(bad)?;
            // What was held back comes out at once (a link that stalled and recovered; a load
            // generator's many clients on one session after a partition), and Zenoh drops what its
            // queue of two 64 KB batches cannot take within a millisecond: inputs lost before they
            // left the machine. Sixteen batches, allocated only when a burst needs them, as the
            // server has.
            c.insert_json5("transport/link/tx/queue/size/data", "16").map_err(bad)?;
            // A receive window that stays open after a pause, as the server's (see the constant).
            let rcvbuf = impact_protocol::limits::TCP_RECEIVE_BUFFER_BYTES.to_string();
            c.insert_json5("transport/link/tcp/so_rcvbuf", &rcvbuf).map_err(bad)?;
            c
        }
    };
    if !connect.is_empty() {
        let list = format!("[{}]", connect.iter().map(|e| format!("{e:?}")).collect::<Vec<_>>().join(", "));
        c.insert_json5("connect/endpoints", &list).map_err(bad)?;
    }
    if let Some(k) = creds {
        c.insert_json5("transport/auth/usrpwd/user", &format!("{:?}", k.user)).map_err(bad)?;
        c.insert_json5("transport/auth/usrpwd/password", &format!("{:?}", k.password)).map_err(bad)?;
    }
    let who = creds.map_or(String::new(), |k| format!(" as user {:?}", k.user));
    ::zenoh::open(c)
        .wait()
        .map_err(|e| TransportError::Open(format!("opening a zenoh session to {}{who}: {e}", connect.join(", "))))
}

/// Decodes a sample's payload by its encoding tag (MessagePack when untagged).
pub fn decode_server(sample: &::zenoh::sample::Sample) -> Result<ServerMessage, impact_protocol::ProtocolError> {
    let tag = sample.encoding().to_string();
    let enc = Encoding::from_zenoh_tag(&tag).unwrap_or_default();
    impact_protocol::decode(&sample.payload().to_bytes(), enc, MAX_SERVER_MESSAGE_BYTES)
}

/// The owner epoch a sample carries as its attachment (PROTOCOL.md, "Failover"), if any.
pub fn epoch_of(sample: &::zenoh::sample::Sample) -> Option<Epoch> {
    stamp_of(sample).map(|s| s.epoch)
}

/// The owner epoch and the message's number on its key a sample carries as its attachment
/// ([`Stamp`]), if any.
pub fn stamp_of(sample: &::zenoh::sample::Sample) -> Option<Stamp> {
    sample.attachment().and_then(|a| Stamp::from_attachment(&a.to_bytes()))
}

/// Where and how to connect.
#[derive(Clone, Debug)]
pub struct ConnectOptions {
    /// Zenoh endpoints (`tcp/127.0.0.1:7447`): the server's, or a router's.
    pub connect: Vec<String>,
    /// Peer or client mode.
    pub mode: Mode,
    /// A Zenoh configuration file instead of the settings above.
    pub config: Option<PathBuf>,
    /// User and password, for a server started with `--users`.
    pub credentials: Option<Credentials>,
    /// The world to join.
    pub world: WorldId,
    /// The client id.
    pub client: ClientId,
    /// Subscribe to the client's own state stream (`client/{id}/state`; the server must run with
    /// `--state-hz`).
    pub state: bool,
    /// How inputs are encoded (MessagePack by default).
    pub encoding: Encoding,
    /// How long to look for the world's server before giving up (default 10 s).
    pub find_server: Duration,
    /// Ask the server for its rules and static world (`query/scene`), so the session predicts
    /// the own avatar with them ([`crate::SessionConfig::predict`]; default on).
    pub scene: bool,
}

impl ConnectOptions {
    /// Client `client` of world `world` through `connect`, with the defaults: a peer, its state
    /// stream on, MessagePack, 10 s to find the server.
    pub fn new(connect: Vec<String>, world: WorldId, client: ClientId) -> ConnectOptions {
        ConnectOptions {
            connect,
            mode: Mode::Peer,
            config: None,
            credentials: None,
            world,
            client,
            state: true,
            encoding: Encoding::MsgPack,
            find_server: Duration::from_secs(10),
            scene: true,
        }
    }
}

/// What the callbacks queue: a message, one that did not decode, or why the scene query got no
/// scene.
#[derive(Debug)]
// Nearly every item is a message: boxing it would cost an allocation each for the rare others.
#[allow(clippy::large_enum_variant)]
enum Inbound {
    Msg(ServerMessage, Option<Stamp>, Instant),
    Malformed,
    NoScene(String),
    /// A `query/confirmed` reply: a batch the client missed.
    Recovered(EventBatch),
    /// The `query/confirmed` answer for this tick ended.
    RecoveryEnded(Tick),
}

/// How long a `query/confirmed` waits for its replies.
pub const RECOVERY_QUERY_TIMEOUT: Duration = Duration::from_secs(1);

/// Asks the server for the confirmed batch of `tick` it kept for `client`
/// (`query/confirmed?from=T;to=T;client=C`, see [`crate::Session::poll_recovery`]): `batch`
/// hears the batch if the server still keeps it, `ended` hears that the answer ended (Zenoh drops
/// the callback then, after its last reply or at [`RECOVERY_QUERY_TIMEOUT`]).
pub fn ask_confirmed(
    session: &::zenoh::Session,
    world: &WorldId,
    client: ClientId,
    tick: Tick,
    batch: impl Fn(EventBatch) + Send + Sync + 'static,
    ended: impl FnOnce() + Send + Sync + 'static,
) -> Result<(), TransportError> {
    /// Calls `ended` when the query's callback is dropped.
    struct Ended<F: FnOnce()>(Option<F>);
    impl<F: FnOnce()> Drop for Ended<F> {
        fn drop(&mut self) {
            if let Some(f) = self.0.take() {
                f();
            }
        }
    }
    let guard = Ended(Some(ended));
    let selector =
        format!("{}?from={};to={};client={}", keys::QUERY_CONFIRMED.key(world, None), tick.0, tick.0, client.0);
    session
        .get(selector)
        // One reply per tick, all on the query's key: Zenoh would keep only the latest.
        .consolidation(::zenoh::query::ConsolidationMode::None)
        .timeout(RECOVERY_QUERY_TIMEOUT)
        .callback(move |reply| {
            let _ = &guard;
            if let Ok(ServerMessage::Confirmed(b)) =
                reply.result().map_err(|_| ()).and_then(|s| decode_server(s).map_err(|_| ()))
            {
                if b.tick == tick {
                    batch(b);
                }
            }
        })
        .wait()
        .map_err(|e| TransportError::Zenoh(format!("asking for a confirmed batch: {e}")))
}

/// A reply to `query/scene`: the scene, why there is none, or a payload that is not one.
fn scene_reply(reply: &::zenoh::query::Reply) -> Inbound {
    match reply.result() {
        Ok(sample) => match decode_server(sample) {
            Ok(m @ ServerMessage::Scene(_)) => Inbound::Msg(m, stamp_of(sample), Instant::now()),
            Ok(ServerMessage::QueryError(e)) => Inbound::NoScene(e.detail),
            Ok(_) | Err(_) => Inbound::Malformed,
        },
        Err(e) => Inbound::NoScene(format!("query/scene: {}", e.payload().try_to_string().unwrap_or_default())),
    }
}

/// Asks the server of `world` for its rules and static world (`query/scene`) and waits for the
/// answer, at most `timeout`: for a tool or a load generator that drives sessions itself
/// ([`Connection`] asks on its own).
pub fn query_scene(
    session: &::zenoh::Session,
    world: &WorldId,
    timeout: Duration,
) -> Result<SceneDescription, TransportError> {
    let key = keys::QUERY_SCENE.key(world, None);
    let replies = session
        .get(&key)
        .timeout(timeout)
        .wait()
        .map_err(|e| TransportError::Zenoh(format!("asking for the scene: {e}")))?;
    let why = match replies.recv() {
        Err(_) => format!("no server answered {key} within {:.1} s", timeout.as_secs_f64()),
        Ok(reply) => match scene_reply(&reply) {
            Inbound::Msg(ServerMessage::Scene(d), _, _) => return Ok(*d),
            Inbound::NoScene(why) => why,
            _ => format!("{key} answered something that is not a scene"),
        },
    };
    Err(TransportError::Zenoh(why))
}

/// Game logic's command for `world` (open it from a scene, or close it), as client `client`
/// (which must have the game-logic role), waiting for the answer at most `timeout`. A refusal
/// is an answer ([`WorldOutcome::Refused`](impact_protocol::WorldOutcome::Refused) with its
/// reason); no answer at all is an error (no server in reach opens worlds, or none runs it).
pub fn world_command(
    session: &::zenoh::Session,
    world: &WorldId,
    client: ClientId,
    command: WorldCommand,
    timeout: Duration,
) -> Result<WorldAnswer, TransportError> {
    let key = keys::WORLD_COMMAND.key(world, Some(client));
    let bytes = encode(&ClientMessage::World(command), Encoding::MsgPack)
        .map_err(|e| TransportError::Zenoh(format!("encoding the world command: {e}")))?;
    let replies = session
        .get(&key)
        .payload(bytes)
        .encoding(Encoding::MsgPack.zenoh_tag())
        .timeout(timeout)
        .wait()
        .map_err(|e| TransportError::Zenoh(format!("sending the world command: {e}")))?;
    let why = match replies.recv() {
        Err(_) => format!(
            "no server answered {key} within {:.1} s: is a server with --open-worlds (to open) or running the \
             world (to close) in reach, and is client {client} game logic?",
            timeout.as_secs_f64()
        ),
        Ok(reply) => match reply.result() {
            Ok(sample) => match decode_server(sample) {
                Ok(ServerMessage::World(a)) => return Ok(a),
                Ok(_) => format!("{key} answered something that is not a world answer"),
                Err(e) => format!("{key}: {e}"),
            },
            Err(e) => format!("{key}: {}", e.payload().try_to_string().unwrap_or_default()),
        },
    };
    Err(TransportError::Zenoh(why))
}

/// Asks the server for its scene; the answer (or why there is none) is queued for the next pump.
fn ask_scene(session: &::zenoh::Session, world: &WorldId, tx: SyncSender<Inbound>) -> Result<(), TransportError> {
    /// Says why when the query ends without a scene (Zenoh drops the callback then).
    struct Asked {
        tx: SyncSender<Inbound>,
        answered: AtomicBool,
    }
    impl Drop for Asked {
        fn drop(&mut self) {
            if !self.answered.load(Relaxed) {
                let _ = self.tx.try_send(Inbound::NoScene("no server answered query/scene within 10 s".into()));
            }
        }
    }
    let asked = Asked { tx, answered: AtomicBool::new(false) };
    session
        .get(keys::QUERY_SCENE.key(world, None))
        .timeout(Duration::from_secs(10))
        .callback(move |reply| {
            let item = scene_reply(&reply);
            if !asked.answered.swap(true, Relaxed) {
                let _ = asked.tx.try_send(item);
            }
        })
        .wait()
        .map_err(|e| TransportError::Zenoh(format!("asking for the scene: {e}")))
}

/// A client's Zenoh side (see the module docs). Dropping it withdraws the presence.
#[derive(Debug)]
pub struct Connection {
    world: WorldId,
    /// The client's input key, declared once: the server resolves it once rather than match the
    /// key of every message against its subscriptions.
    input: ::zenoh::pubsub::Publisher<'static>,
    encoding: Encoding,
    inbox: Receiver<Inbound>,
    /// The inbox's sending side, for the answers to `query/confirmed`.
    tx: SyncSender<Inbound>,
    dropped: Arc<AtomicU64>,
    /// Whether the session had a link to a router or peer at the last pump.
    linked: AtomicBool,
    _subscribers: Vec<::zenoh::pubsub::Subscriber<()>>,
    presence: std::sync::Mutex<Presence>,
    /// Last, so that dropped, everything declared on it is undeclared before it closes (fields
    /// drop in order; Zenoh 1.10 keeps what is undeclared after the close).
    session: ::zenoh::Session,
}

/// The client's presence token, and when to declare it again while no welcome comes.
#[derive(Debug)]
struct Presence {
    token: Option<::zenoh::liveliness::LivelinessToken>,
    declared: Instant,
    wait: Duration,
    repeats: u64,
}

impl Presence {
    fn declare(session: &::zenoh::Session, world: &WorldId, client: ClientId) -> Result<Presence, TransportError> {
        let token = Presence::token(session, world, client)?;
        Ok(Presence { token: Some(token), declared: Instant::now(), wait: WELCOME_WAIT, repeats: 0 })
    }

    fn token(
        session: &::zenoh::Session,
        world: &WorldId,
        client: ClientId,
    ) -> Result<::zenoh::liveliness::LivelinessToken, TransportError> {
        session
            .liveliness()
            .declare_token(keys::PRESENCE.key(world, Some(client)))
            .wait()
            .map_err(|e| TransportError::Zenoh(format!("declaring the presence: {e}")))
    }

    /// Withdraws the presence and declares it again (the server sees the client leave and join:
    /// it welcomes it, with the avatar it has if it heard it before), once `wait` has passed.
    fn repeat_if_due(&mut self, session: &::zenoh::Session, world: &WorldId, client: ClientId, now: Instant) {
        if now.saturating_duration_since(self.declared) < self.wait {
            return;
        }
        drop(self.token.take());
        self.token = Presence::token(session, world, client).ok();
        self.declared = now;
        self.wait = (self.wait * 2).min(WELCOME_WAIT_MAX);
        self.repeats += 1;
    }
}

/// Whether a Zenoh session has a live link to a router or a peer.
pub fn reachable(session: &::zenoh::Session) -> bool {
    let info = session.info();
    info.routers_zid().wait().next().is_some() || info.peers_zid().wait().next().is_some()
}

/// Looks for the world's server tokens at every protocol version, until `wait` passes: `Ok`
/// when one speaks [`keys::VERSION`], the versions found otherwise.
fn find_server(zs: &::zenoh::Session, world: &WorldId, wait: Duration) -> Result<(), TransportError> {
    let started = Instant::now();
    let any_version = format!("impact/*/{}/server", world.as_str());
    loop {
        let replies = zs
            .liveliness()
            .get(&any_version)
            .timeout(Duration::from_secs(1))
            .wait()
            .map_err(|e| TransportError::Zenoh(format!("looking for the server: {e}")))?;
        let mut versions = Vec::new();
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result() {
                let v = sample.key_expr().as_str().split('/').nth(1).unwrap_or("").to_string();
                if v == keys::VERSION {
                    return Ok(());
                }
                if !versions.contains(&v) {
                    versions.push(v);
                }
            }
        }
        if !versions.is_empty() {
            return Err(TransportError::VersionMismatch {
                world: world.as_str().to_string(),
                server: versions,
                client: keys::VERSION,
            });
        }
        if started.elapsed() >= wait {
            return Err(TransportError::NoServer { world: world.as_str().to_string(), waited: started.elapsed() });
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

impl Connection {
    /// Opens the Zenoh session, finds the world's server (checking its protocol version),
    /// subscribes to the client's keys and declares its presence: the welcome follows.
    pub fn open(opts: &ConnectOptions) -> Result<Connection, TransportError> {
        let session = open_session(&opts.connect, opts.config.as_deref(), opts.credentials.as_ref(), opts.mode)?;
        Connection::on(session, opts)
    }

    /// The same over a Zenoh session the caller opened.
    pub fn on(session: ::zenoh::Session, opts: &ConnectOptions) -> Result<Connection, TransportError> {
        find_server(&session, &opts.world, opts.find_server)?;
        let (tx, inbox) = sync_channel(INBOX_CAPACITY);
        let dropped = Arc::new(AtomicU64::new(0));
        let (w, c) = (&opts.world, Some(opts.client));
        let mut wanted = vec![keys::CLIENT_ACK.key(w, c), keys::CLIENT_EVENTS.key(w, c)];
        if opts.state {
            wanted.push(keys::CLIENT_STATE.key(w, c));
        }
        let mut subscribers = Vec::new();
        for key in wanted {
            let (tx, dropped): (SyncSender<Inbound>, _) = (tx.clone(), dropped.clone());
            let sub = session
                .declare_subscriber(key)
                .callback(move |sample| {
                    let item = match decode_server(&sample) {
                        Ok(m) => Inbound::Msg(m, stamp_of(&sample), Instant::now()),
                        Err(_) => Inbound::Malformed,
                    };
                    if let Err(TrySendError::Full(_)) = tx.try_send(item) {
                        dropped.fetch_add(1, Relaxed);
                    }
                })
                .wait()
                .map_err(|e| TransportError::Zenoh(format!("subscribing: {e}")))?;
            subscribers.push(sub);
        }
        if opts.scene {
            ask_scene(&session, w, tx.clone())?;
        }
        let input = session
            .declare_publisher(keys::INPUT.key(w, c))
            .encoding(opts.encoding.zenoh_tag())
            .wait()
            .map_err(|e| TransportError::Zenoh(format!("declaring the input publisher: {e}")))?;
        // Last, so every subscription is in place when the welcome comes.
        let presence = Presence::declare(&session, w, opts.client)?;
        Ok(Connection {
            session,
            world: w.clone(),
            input,
            encoding: opts.encoding,
            inbox,
            tx,
            dropped,
            linked: AtomicBool::new(true),
            _subscribers: subscribers,
            presence: std::sync::Mutex::new(presence),
        })
    }

    /// Hands `client` every message that arrived (at the instant it arrived), then sends what
    /// it gives at `now`.
    pub fn pump(&self, client: &mut Session, now: Instant) -> Result<(), TransportError> {
        // A link that came back: what the server published meanwhile is lost to this client.
        let up = reachable(&self.session);
        if up && !self.linked.swap(up, Relaxed) {
            client.link_restored(now);
        } else {
            self.linked.store(up, Relaxed);
        }
        while let Ok(item) = self.inbox.try_recv() {
            match item {
                Inbound::Msg(m, stamp, at) => client.receive_from(stamp, m, at),
                Inbound::Malformed => client.malformed(),
                Inbound::NoScene(why) => client.scene_unavailable(why),
                Inbound::Recovered(b) => client.recovered(b),
                Inbound::RecoveryEnded(t) => client.recovery_ended(t),
            }
        }
        while let Some(t) = client.poll_recovery() {
            let (tx, done) = (self.tx.clone(), self.tx.clone());
            let asked = ask_confirmed(
                &self.session,
                &self.world,
                client.config().client,
                t,
                move |b| {
                    let _ = tx.try_send(Inbound::Recovered(b));
                },
                move || {
                    let _ = done.try_send(Inbound::RecoveryEnded(t));
                },
            );
            if asked.is_err() {
                client.recovery_ended(t);
            }
        }
        if client.status() == Status::Joining {
            let mut p = self.presence.lock().unwrap_or_else(|e| e.into_inner());
            p.repeat_if_due(&self.session, &self.world, client.config().client, now);
        }
        while let Some(msg) = client.poll_transmit(now) {
            self.send(&msg)?;
        }
        Ok(())
    }

    /// How many times the presence was declared again because no welcome came in time.
    pub fn presence_repeats(&self) -> u64 {
        self.presence.lock().map_or(0, |p| p.repeats)
    }

    /// Sends one message on the client's input key.
    pub fn send(&self, msg: &ClientMessage) -> Result<(), TransportError> {
        let bytes = impact_protocol::encode(msg, self.encoding).map_err(|e| TransportError::Zenoh(e.to_string()))?;
        self.input.put(bytes).wait().map_err(|e| TransportError::Zenoh(format!("sending: {e}")))
    }

    /// Messages dropped because the inbox was full (the game stopped pumping).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Relaxed)
    }

    /// The world joined.
    pub fn world(&self) -> &WorldId {
        &self.world
    }

    /// The Zenoh session, for what the game does beside the protocol (queries, say).
    pub fn zenoh(&self) -> &::zenoh::Session {
        &self.session
    }

    /// Withdraws the presence (the server removes the avatar after its grace period) and closes
    /// the session. Everything declared is undeclared before the close: Zenoh 1.10 keeps what is
    /// undeclared after it.
    pub fn close(self) {
        let Connection { session, _subscribers, presence, input, .. } = self;
        drop(presence);
        drop(_subscribers);
        drop(input);
        let _ = session.close().wait();
    }
}
