//! The gateway: its settings, the players it relays, and the HTTP side that turns a request
//! into a WebSocket connection (`GET /ws`) after the origin check and the connection limit,
//! serves its counters (`GET /stats`) and the play page ([`crate::page`]).

use crate::auth::{Authenticator, Player};
use crate::outbox::Mailbox;
use crate::page::{self, GuestPolicy};
use crate::relay::{Link, Relay};
use crate::stats::Counters;
use crate::wire::{encode_notice, Close, Notice};
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use impact_protocol::{ClientId, WorldId};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU32, Ordering::Relaxed};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

/// The gateway's settings, each with a default that serves a game on one machine.
#[derive(Clone, Debug)]
pub struct Config {
    /// Who may play.
    pub auth: Authenticator,
    /// Origins (`https://game.example`) whose pages may connect, besides the gateway's own
    /// (an `Origin` equal to the request's `Host`); `*` allows any. A request without an
    /// `Origin` (not a browser) is not checked.
    pub allow_origins: Vec<String>,
    /// WebSocket connections open at once; beyond, `503` before the upgrade.
    pub max_connections: usize,
    /// Time a connection has to send its hello.
    pub hello_timeout: Duration,
    /// Largest message read from a browser, in bytes (the protocol's client message bound).
    pub max_message_bytes: usize,
    /// Messages a second one connection may send (a burst of as many); beyond, closed `flood`.
    pub max_messages_per_s: u32,
    /// One connection's queue toward its browser: messages and bytes.
    pub outbox_messages: usize,
    /// See `outbox_messages`.
    pub outbox_bytes: usize,
    /// Time the browser has to take one batch of messages before it is closed `too_slow`.
    pub write_timeout: Duration,
    /// Guests: pages without credentials get a token at `POST /guest` (needs `auth.secret`).
    pub guests: Option<GuestPolicy>,
}

impl Default for Config {
    fn default() -> Config {
        Config {
            auth: Authenticator::default(),
            allow_origins: Vec::new(),
            max_connections: 2048,
            hello_timeout: Duration::from_secs(5),
            max_message_bytes: impact_protocol::limits::MAX_CLIENT_MESSAGE_BYTES,
            // Four times the server's default input rate (120 a second): pings, full-frame
            // requests and a burst after a stall fit; a flood does not.
            max_messages_per_s: 480,
            outbox_messages: 256,
            outbox_bytes: 1 << 20,
            write_timeout: Duration::from_secs(5),
            guests: None,
        }
    }
}

/// A player relayed now: its connection's mailbox and its declarations, held here only (the
/// connection has a weak reference), so that removing the entry undeclares them at once.
#[derive(Debug)]
struct Relayed {
    mailbox: Arc<Mailbox>,
    #[allow(dead_code, reason = "held for its drop: the declarations live as long as the entry")]
    link: Arc<Link>,
}

/// The gateway: settings, the Zenoh relay, the players and the counters.
#[derive(Debug)]
pub struct Gateway {
    /// Its settings.
    pub config: Config,
    /// The Zenoh side.
    pub relay: Relay,
    /// Its counters.
    pub counters: Arc<Counters>,
    players: Mutex<BTreeMap<(WorldId, ClientId), Relayed>>,
    /// Guest tokens issued (the next guest's offset from the first guest id).
    pub(crate) guests_issued: AtomicU32,
}

impl Gateway {
    /// A gateway relaying over `session`.
    pub fn new(config: Config, session: zenoh::Session) -> Arc<Gateway> {
        Arc::new(Gateway {
            config,
            relay: Relay::new(session),
            counters: Arc::new(Counters::default()),
            players: Mutex::new(BTreeMap::new()),
            guests_issued: AtomicU32::new(0),
        })
    }

    fn players(&self) -> std::sync::MutexGuard<'_, BTreeMap<(WorldId, ClientId), Relayed>> {
        self.players.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Starts relaying `player` into `mailbox`. A connection already relaying the same player
    /// is closed `replaced` first, and its declarations dropped, so the server sees the player
    /// leave and come back (welcomed again within the grace period).
    pub async fn join(
        &self,
        player: &Player,
        state: bool,
        mailbox: &Arc<Mailbox>,
    ) -> Result<Weak<Link>, crate::relay::RelayError> {
        let key = (player.world.clone(), player.client);
        if let Some(old) = self.players().remove(&key) {
            old.mailbox.close(Close::Replaced, "the same player connected again");
        }
        self.relay.find_server(&player.world).await?;
        let link = Arc::new(self.relay.join(player, state, mailbox.clone()).await?);
        let weak = Arc::downgrade(&link);
        let replaced = self.players().insert(key, Relayed { mailbox: mailbox.clone(), link });
        if let Some(old) = replaced {
            // Two connections for one player joined at once: the later one plays.
            old.mailbox.close(Close::Replaced, "the same player connected again");
        }
        self.counters.joined.fetch_add(1, Relaxed);
        Ok(weak)
    }

    /// Stops relaying `player` for the connection of `mailbox` (not for a newer connection
    /// that replaced it).
    pub fn leave(&self, player: &Player, mailbox: &Arc<Mailbox>) {
        let key = (player.world.clone(), player.client);
        let mut players = self.players();
        if players.get(&key).is_some_and(|r| Arc::ptr_eq(&r.mailbox, mailbox)) {
            players.remove(&key);
        }
    }

    /// Players relayed now.
    pub fn relayed(&self) -> usize {
        self.players().len()
    }

    /// Tells every player that the gateway's link to the servers came back.
    pub fn link_restored(&self) {
        let notice = encode_notice(&Notice::LinkRestored);
        for r in self.players().values() {
            r.mailbox.deliver(crate::outbox::Kind::Kept, notice.clone());
        }
    }

    /// Closes every connection `going_away`.
    pub fn shut_down(&self) {
        for (_, r) in std::mem::take(&mut *self.players()) {
            r.mailbox.close(Close::GoingAway, "the gateway is shutting down");
        }
    }
}

/// Whether a request from `origin` (its `Origin` header) to `host` (its `Host`) may connect,
/// given the origins allowed besides the gateway's own.
pub fn origin_allowed(allow: &[String], origin: Option<&str>, host: Option<&str>) -> bool {
    let Some(origin) = origin else { return true };
    let own = host.is_some_and(|h| origin.split_once("://").is_some_and(|(_, rest)| rest == h));
    own || allow.iter().any(|o| o == "*" || o == origin)
}

/// The HTTP routes: `/ws` (the WebSocket binding), `/stats`, and the play page (`/`, `/play.js`,
/// `POST /guest`; [`crate::page`]).
pub fn router(gw: Arc<Gateway>) -> axum::Router {
    axum::Router::new()
        .route("/ws", get(upgrade))
        .route("/stats", get(stats))
        .route("/", get(page::index))
        .route("/play.js", get(page::script))
        .route("/guest", post(page::guest))
        .with_state(gw)
}

async fn stats(State(gw): State<Arc<Gateway>>) -> Response {
    let json = serde_json::to_string(&gw.counters.snapshot()).unwrap_or_default();
    ([(axum::http::header::CONTENT_TYPE, "application/json")], json).into_response()
}

async fn upgrade(State(gw): State<Arc<Gateway>>, headers: HeaderMap, ws: WebSocketUpgrade) -> Response {
    let header = |name: &str| headers.get(name).and_then(|v| v.to_str().ok());
    if !origin_allowed(&gw.config.allow_origins, header("origin"), header("host")) {
        gw.counters.refused.fetch_add(1, Relaxed);
        return (StatusCode::FORBIDDEN, "this page's origin may not connect (impact-gateway --allow-origin)\n")
            .into_response();
    }
    // Counted open from here, so a burst of upgrades cannot pass the limit together.
    let open = gw.counters.open.fetch_add(1, Relaxed);
    if open >= gw.config.max_connections as u64 {
        gw.counters.open.fetch_sub(1, Relaxed);
        gw.counters.refused.fetch_add(1, Relaxed);
        return (StatusCode::SERVICE_UNAVAILABLE, "the gateway is at its connection limit\n").into_response();
    }
    gw.counters.accepted.fetch_add(1, Relaxed);
    let limit = gw.config.max_message_bytes;
    let gw2 = gw.clone();
    ws.max_message_size(limit)
        .max_frame_size(limit)
        // A browser's messages are small (at most `limit`): tungstenite zero-fills its whole read
        // buffer on every read it tries, 128 KiB by default, which was a third of the gateway's
        // CPU at 500 players. Backpressure is the outbox's: the socket's own buffer stays small.
        .read_buffer_size(READ_BUFFER_BYTES)
        .write_buffer_size(0)
        .max_write_buffer_size(4 * 1024 * 1024)
        .on_failed_upgrade(move |_| {
            gw2.counters.open.fetch_sub(1, Relaxed);
        })
        .on_upgrade(move |socket| async move {
            crate::conn::serve(socket, gw.clone()).await;
            gw.counters.open.fetch_sub(1, Relaxed);
        })
}

/// A gateway serving on a runtime of its own: what the binary runs, and what tests and a game
/// embedding the gateway start.
#[derive(Debug)]
pub struct Running {
    /// The address it accepts browsers on.
    pub addr: std::net::SocketAddr,
    /// The gateway.
    pub gateway: Arc<Gateway>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<std::io::Result<()>>>,
}

impl Running {
    /// Closes every connection `going_away` and stops serving.
    pub fn stop(mut self) -> std::io::Result<()> {
        self.stop_and_join()
    }

    fn stop_and_join(&mut self) -> std::io::Result<()> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        match self.thread.take().map(std::thread::JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(std::io::Error::other("the gateway's thread panicked")),
            None => Ok(()),
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.stop_and_join();
    }
}

/// Serves `gw` on `listen` (`127.0.0.1:0` for any free port) with `threads` async workers (0:
/// one a core), and watches its link to the servers (every player told `link_restored` when it
/// comes back).
pub fn start(gw: Arc<Gateway>, listen: &str, threads: usize) -> std::io::Result<Running> {
    let mut rt = tokio::runtime::Builder::new_multi_thread();
    if threads > 0 {
        rt.worker_threads(threads);
    }
    let rt = rt.thread_name("impact-gateway").enable_all().build()?;
    let listener = rt.block_on(tokio::net::TcpListener::bind(listen))?;
    let addr = listener.local_addr()?;
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    watch_link(Arc::downgrade(&gw));
    let app = router(gw.clone());
    let gw2 = gw.clone();
    let thread = std::thread::Builder::new().name("impact-gateway-serve".into()).spawn(move || {
        rt.block_on(async move {
            serve(listener, app, &gw2, stop_rx).await;
            gw2.shut_down();
            // Each connection sends its `going_away` close before the runtime (and with it every
            // connection's task) is dropped: a short wait, bounded.
            let until = std::time::Instant::now() + SHUTDOWN_WAIT;
            while gw2.counters.open.load(Relaxed) > 0 && std::time::Instant::now() < until {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            Ok(())
        })
    })?;
    Ok(Running { addr, gateway: gw, stop: Some(stop_tx), thread: Some(thread) })
}

/// The longest a stopping gateway waits for its connections to send their `going_away` closes.
const SHUTDOWN_WAIT: Duration = Duration::from_secs(2);

/// The WebSocket read buffer: two of the largest messages a browser may send.
const READ_BUFFER_BYTES: usize = 2 * impact_protocol::limits::MAX_CLIENT_MESSAGE_BYTES;

/// A request's head must arrive within this, or the connection is closed: a half-open
/// connection (a slowloris) costs a task and a socket for this long, not forever.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(5);

/// Accepts connections until `stop`: each is served HTTP/1.1 (with upgrades, for `/ws`) with
/// [`HEADER_TIMEOUT`] on every request head, and at most `max_connections` of them are in their
/// HTTP stage at once (beyond, closed at once, counted as refused; an upgraded connection
/// leaves that count for the gateway's own, `Counters::open`).
async fn serve(
    listener: tokio::net::TcpListener,
    app: axum::Router,
    gw: &Arc<Gateway>,
    mut stop: tokio::sync::oneshot::Receiver<()>,
) {
    use hyper_util::rt::{TokioIo, TokioTimer};
    let http = Arc::new(tokio::sync::Semaphore::new(gw.config.max_connections));
    loop {
        let (tcp, _) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(_) => {
                    // Out of file descriptors, say: wait for some to close.
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = &mut stop => return,
        };
        let Ok(permit) = http.clone().try_acquire_owned() else {
            gw.counters.refused.fetch_add(1, Relaxed);
            continue;
        };
        let _ = tcp.set_nodelay(true);
        let service = hyper_util::service::TowerToHyperService::new(app.clone());
        tokio::spawn(async move {
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT)
                .serve_connection(TokioIo::new(tcp), service)
                .with_upgrades();
            let _ = conn.await;
            drop(permit);
        });
    }
}

/// Tells every player when the link to the servers comes back (checked four times a second,
/// off the async runtime: the check blocks), until the gateway is gone.
fn watch_link(gw: Weak<Gateway>) {
    std::thread::spawn(move || {
        let mut up = true;
        loop {
            std::thread::sleep(Duration::from_millis(250));
            let Some(gw) = gw.upgrade() else { return };
            let now = gw.relay.reachable();
            if now && !up {
                gw.link_restored();
            }
            up = now;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origins_are_checked_against_the_host_and_the_list() {
        let allowed = |list: &[&str], origin: Option<&str>, host: Option<&str>| {
            let list: Vec<String> = list.iter().map(|s| s.to_string()).collect();
            origin_allowed(&list, origin, host)
        };
        assert!(allowed(&[], None, Some("localhost:8080")), "not a browser");
        assert!(allowed(&[], Some("http://localhost:8080"), Some("localhost:8080")), "its own page");
        assert!(!allowed(&[], Some("http://evil.example"), Some("localhost:8080")));
        assert!(!allowed(&[], Some("http://localhost:8081"), Some("localhost:8080")));
        assert!(allowed(&["https://game.example"], Some("https://game.example"), Some("gw.example")));
        assert!(!allowed(&["https://game.example"], Some("http://game.example"), Some("gw.example")));
        assert!(allowed(&["*"], Some("http://anything"), None));
    }
}
