//! Helpers for end-to-end tests: a server on an ephemeral loopback port, client sessions, and
//! a bounded wait for messages.
#![allow(dead_code)]

pub mod browser;
pub mod process;
pub mod seeded;

use impact_core::scene::Scene;
use impact_protocol::{encode, keys, ClientId, ClientInput, ClientMessage, Encoding, ServerMessage, WorldId};
use impact_server::runtime::{self, ServerHandle, ServerOptions};
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::{Duration, Instant};
use zenoh::Wait;

/// The users file of the access-control tests: three players (alice, bob, mallory: clients 1, 2,
/// 3) and the deployment's server (`srv`, for a server behind a router that enforces).
pub const USERS: &str = r#"
[[user]]
name = "alice"
password = "alice-secret"
client = 1

[[user]]
name = "bob"
password = "bob-secret"
client = 2

[[user]]
name = "mallory"
password = "mallory-secret"
client = 3

[[server]]
name = "srv"
password = "srv-secret"
"#;

/// A free TCP port on loopback (bound and released; the race is harmless in tests).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).map(|a| a.port()).expect("a free port")
}

/// Starts a server on `scene` listening on a fresh port; returns it and the endpoint.
pub fn server(scene: Scene, tweak: impl FnOnce(&mut ServerOptions)) -> (ServerHandle, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut opts = ServerOptions { listen: vec![endpoint.clone()], ..ServerOptions::default() };
    tweak(&mut opts);
    let h = runtime::start(scene, opts).expect("server starts");
    (h, endpoint)
}

/// A client session connected to `endpoint`.
pub fn client(endpoint: &str) -> zenoh::Session {
    client_as(endpoint, None).expect("client session")
}

/// A client session connected to `endpoint`, authenticated as `(user, password)` if given.
pub fn client_as(endpoint: &str, creds: Option<(&str, &str)>) -> anyhow::Result<zenoh::Session> {
    let creds = creds.map(|(u, p)| impact_client_sim::net::Credentials { user: u.into(), password: p.into() });
    let s = impact_client_sim::net::open(&[endpoint.to_string()], None, creds.as_ref(), Default::default())?;
    // Give the link a moment to come up before declaring interest.
    std::thread::sleep(Duration::from_millis(300));
    Ok(s)
}

/// Decoded messages published on `key`.
pub struct Inbox {
    rx: Receiver<ServerMessage>,
    _sub: zenoh::pubsub::Subscriber<()>,
}

impl Inbox {
    /// Subscribes to `key`.
    pub fn new(s: &zenoh::Session, key: String) -> Inbox {
        let (tx, rx) = sync_channel(100_000);
        let sub = s
            .declare_subscriber(key)
            .callback(move |sample| {
                if let Ok(m) = impact_client_sim::net::decode_server(&sample) {
                    let _ = tx.try_send(m);
                }
            })
            .wait()
            .expect("subscriber");
        Inbox { rx, _sub: sub }
    }

    /// The first message within `timeout` for which `f` returns something.
    pub fn wait_for<T>(&self, timeout: Duration, mut f: impl FnMut(&ServerMessage) -> Option<T>) -> Option<T> {
        let end = Instant::now() + timeout;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.rx.recv_timeout(left) {
                Ok(m) => {
                    if let Some(t) = f(&m) {
                        return Some(t);
                    }
                }
                Err(_) => return None,
            }
        }
        None
    }
}

/// Publishes an input on the client's key.
pub fn send(s: &zenoh::Session, world: &WorldId, input: &ClientInput, encoding: Encoding) {
    let bytes = encode(&ClientMessage::Input(input.clone()), encoding).expect("encodes");
    send_raw(s, world, input.client, bytes, encoding);
}

/// Publishes raw bytes on a client's input key.
pub fn send_raw(s: &zenoh::Session, world: &WorldId, client: ClientId, bytes: Vec<u8>, encoding: Encoding) {
    s.put(keys::INPUT.key(world, Some(client)), bytes).encoding(encoding.zenoh_tag()).wait().expect("put");
}

/// Declares presence for a client and returns the token (drop it to leave).
pub fn join(s: &zenoh::Session, world: &WorldId, client: ClientId) -> zenoh::liveliness::LivelinessToken {
    s.liveliness().declare_token(keys::PRESENCE.key(world, Some(client))).wait().expect("token")
}

/// Queries a server key with parameters.
pub fn query(s: &zenoh::Session, key: String, params: &str) -> Option<ServerMessage> {
    let replies = s.get(format!("{key}?{params}")).timeout(Duration::from_secs(5)).wait().ok()?;
    let reply = replies.recv().ok()?;
    impact_client_sim::net::decode_server(reply.result().ok()?).ok()
}

/// Queries a server key with parameters and takes every reply (a query answered with one reply
/// per item, on the query's key: Zenoh's consolidation would keep only the latest).
pub fn query_all(s: &zenoh::Session, key: String, params: &str) -> Vec<ServerMessage> {
    let Ok(replies) = s
        .get(format!("{key}?{params}"))
        .consolidation(zenoh::query::ConsolidationMode::None)
        .timeout(Duration::from_secs(5))
        .wait()
    else {
        return Vec::new();
    };
    let mut out = Vec::new();
    while let Ok(reply) = replies.recv() {
        if let Some(m) = reply.result().ok().and_then(|r| impact_client_sim::net::decode_server(r).ok()) {
            out.push(m);
        }
    }
    out
}

/// Whether `m` answers input `seq` (its ack or its reject).
pub fn answers(m: &ServerMessage, seq: u32) -> bool {
    match m {
        ServerMessage::Ack(a) => a.seq == seq,
        ServerMessage::Reject(r) => r.seq == Some(seq),
        _ => false,
    }
}

/// A "server" of the arena world that answers none of the declarations until told: a bare Zenoh
/// peer listening on a free port, holding the server's liveliness token and counting the
/// presences clients declare. For what a client does while its welcome does not come.
pub struct SilentServer {
    /// Where it listens.
    pub endpoint: String,
    world: WorldId,
    host: zenoh::Session,
    _token: zenoh::liveliness::LivelinessToken,
    _presence: zenoh::pubsub::Subscriber<()>,
    presences: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl SilentServer {
    pub fn start() -> Self {
        use std::sync::atomic::Ordering::Relaxed;
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        let mut c = zenoh::Config::default();
        c.insert_json5("scouting/multicast/enabled", "false").unwrap();
        c.insert_json5("listen/endpoints", &format!("[\"{endpoint}\"]")).unwrap();
        let host = zenoh::open(c).wait().expect("the silent server's session");
        let world = WorldId::new("arena").unwrap();
        let _token = host.liveliness().declare_token(keys::SERVER.key(&world, None)).wait().unwrap();
        let presences = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        let p = presences.clone();
        let _presence = host
            .liveliness()
            .declare_subscriber(keys::PRESENCE.any_client(&world))
            .callback(move |s| {
                if s.kind() == zenoh::sample::SampleKind::Put {
                    p.fetch_add(1, Relaxed);
                }
            })
            .wait()
            .unwrap();
        SilentServer { endpoint, world, host, _token, _presence, presences }
    }

    /// How many times a client's presence was declared.
    pub fn presences(&self) -> u64 {
        self.presences.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Welcomes `client` at last (no avatar, tick 100).
    pub fn welcome(&self, client: ClientId) {
        self.welcome_as(client, None);
    }

    /// Welcomes `client` as the world's owner at `epoch` (the sample's attachment).
    pub fn welcome_as(&self, client: ClientId, epoch: Option<impact_protocol::Epoch>) {
        let welcome = ServerMessage::Welcome(impact_protocol::Welcome {
            client,
            avatar: None,
            tick: impact_protocol::Tick(100),
            tick_hz: 64,
            window_ticks: 16,
            input_lead_ticks: 2,
            max_rewind_ticks: 16,
            next_seq: 0,
            scene_hash: 0,
        });
        self.publish(&keys::CLIENT_ACK.key(&self.world, Some(client)), &welcome, epoch.map(Into::into));
    }

    /// Sends `client` an empty `events` batch of `tick` on its events key, stamped `stamp`.
    pub fn events(&self, client: ClientId, tick: u32, stamp: impact_protocol::Stamp) {
        let batch = impact_protocol::EventBatch { tick: impact_protocol::Tick(tick), revision: 0, events: vec![] };
        self.publish(&keys::CLIENT_EVENTS.key(&self.world, Some(client)), &ServerMessage::Events(batch), Some(stamp));
    }

    /// Publishes `msg` on `key` (MessagePack), with `stamp` as the attachment when given.
    fn publish(&self, key: &str, msg: &ServerMessage, stamp: Option<impact_protocol::Stamp>) {
        let bytes = encode(msg, Encoding::MsgPack).unwrap();
        let put = self.host.put(key, bytes).encoding(Encoding::MsgPack.zenoh_tag());
        match stamp {
            Some(s) => put.attachment(s.attachment()).wait().unwrap(),
            None => put.wait().unwrap(),
        }
    }
}
