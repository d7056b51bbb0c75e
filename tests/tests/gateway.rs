//! The WebSocket gateway end to end: a server under `--users`, `impact-gateway` in front of it
//! with the users file's `[[gateway]]` credential, and WebSocket clients speaking the binding as
//! a browser does (PROTOCOL.md, "WebSocket binding"). A player plays (welcome, ack, state,
//! scene); every way the gateway refuses or ends a connection reaches the client as its close
//! code and reason; a player's messages go out on its own keys only, whatever it writes in them;
//! rounds of abuse against the gateway as a process (half-open connections among them) end in
//! closes with reasons and leave its memory flat. Every wait is bounded.

mod common;

use common::*;
use impact_client::transport::{open_session, Credentials, Mode};
use impact_core::scene::Scene;
use impact_gateway::auth::Authenticator;
use impact_gateway::gateway::{start, Running, HEADER_TIMEOUT};
use impact_gateway::token::{unix_now, Grant, Secret};
use impact_gateway::{Config, Gateway};
use impact_protocol::users::Users;
use impact_protocol::{keys, Action, ClientId, ClientInput, ClientMessage, Encoding, ServerMessage, Tick, WorldId};
use serde_json::json;
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

const GATEWAY: &str = "\n[[gateway]]\nname = \"gw\"\npassword = \"gw-secret\"\n";
const SECRET: &[u8] = b"a shared secret of at least 32 bytes";

/// A server enforcing the users file (and its gateway entry), and a gateway in front of it.
fn deployment(tweak: impl FnOnce(&mut Config)) -> (impact_server::runtime::ServerHandle, String, Running) {
    let users = Users::parse(&format!("{USERS}{GATEWAY}")).unwrap();
    let scene = Scene::load(&Scene::bundled_path("arena")).unwrap();
    let (server, ep) = server(scene, |o| o.users = Some(users.clone()));
    let creds = Credentials { user: "gw".into(), password: "gw-secret".into() };
    let session = open_session(std::slice::from_ref(&ep), None, Some(&creds), Mode::Peer)
        .expect("the gateway's credential is accepted");
    let mut config = Config {
        auth: Authenticator { users: Some(users), secret: Some(Secret::new(SECRET).unwrap()) },
        ..Config::default()
    };
    tweak(&mut config);
    let gw = start(Gateway::new(config, session), "127.0.0.1:0", 2).expect("the gateway starts");
    (server, ep, gw)
}

/// What a WebSocket client read next.
#[derive(Debug)]
enum Got {
    Msg(Vec<u8>),
    Closed(u16, String),
    Nothing,
}

struct Ws(WebSocket<MaybeTlsStream<TcpStream>>);

impl Ws {
    fn connect(gw: &Running) -> Ws {
        Ws::connect_to(gw.addr)
    }

    fn connect_to(addr: SocketAddr) -> Ws {
        Ws::connect_from(addr, None).expect("the upgrade succeeds")
    }

    /// Connects as a page of `origin` would.
    fn connect_from(addr: SocketAddr, origin: Option<&str>) -> Result<Ws, tungstenite::Error> {
        use tungstenite::client::IntoClientRequest;
        let mut req = format!("ws://{addr}/ws").into_client_request().unwrap();
        if let Some(o) = origin {
            req.headers_mut().insert("origin", o.parse().unwrap());
        }
        let stream = TcpStream::connect(addr).unwrap();
        let (ws, _) = tungstenite::client(req, MaybeTlsStream::Plain(stream)).map_err(|e| match e {
            tungstenite::HandshakeError::Failure(e) => e,
            tungstenite::HandshakeError::Interrupted(_) => tungstenite::Error::ConnectionClosed,
        })?;
        Ok(Ws(ws))
    }

    fn send(&mut self, v: &serde_json::Value) {
        self.send_bytes(rmp_serde::to_vec_named(v).unwrap());
    }

    fn send_bytes(&mut self, b: Vec<u8>) {
        let _ = self.0.send(Message::Binary(b.into()));
    }

    fn send_msg(&mut self, m: &ClientMessage) {
        self.send_bytes(impact_protocol::encode(m, Encoding::MsgPack).unwrap());
    }

    fn next(&mut self, wait: Duration) -> Got {
        if let MaybeTlsStream::Plain(s) = self.0.get_ref() {
            s.set_read_timeout(Some(wait.max(Duration::from_millis(1)))).unwrap();
        }
        loop {
            match self.0.read() {
                Ok(Message::Binary(b)) => return Got::Msg(b.to_vec()),
                Ok(Message::Close(Some(f))) => return Got::Closed(f.code.into(), f.reason.to_string()),
                Ok(Message::Close(None)) => return Got::Closed(1005, String::new()),
                Ok(_) => continue,
                Err(_) => return Got::Nothing,
            }
        }
    }

    /// The first server message within `wait` for which `f` says something (gateway notices
    /// and other messages skipped).
    fn until<T>(&mut self, wait: Duration, mut f: impl FnMut(&ServerMessage) -> Option<T>) -> Option<T> {
        let end = Instant::now() + wait;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.next(left) {
                Got::Msg(b) => {
                    let m = impact_protocol::decode::<ServerMessage>(&b, Encoding::MsgPack, usize::MAX);
                    if let Some(t) = m.ok().as_ref().and_then(&mut f) {
                        return Some(t);
                    }
                }
                Got::Closed(..) | Got::Nothing => return None,
            }
        }
        None
    }

    /// The close code and reason within `wait`, reading past any message.
    fn closed(&mut self, wait: Duration) -> Option<(u16, String)> {
        let end = Instant::now() + wait;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            match self.next(left) {
                Got::Msg(_) => continue,
                Got::Closed(code, reason) => return Some((code, reason)),
                Got::Nothing => return None,
            }
        }
        None
    }

    /// The gateway's `ready` notice, as JSON.
    fn ready(&mut self, wait: Duration) -> Option<serde_json::Value> {
        match self.next(wait) {
            Got::Msg(b) => rmp_serde::from_slice::<serde_json::Value>(&b).ok().filter(|v| v["type"] == "ready"),
            _ => None,
        }
    }
}

fn hello(user: &str, password: &str, client: u32) -> serde_json::Value {
    json!({"type": "hello", "world": "arena", "client": client, "user": user, "password": password})
}

fn walk(client: u32, seq: u32, tick: Tick, avatar: impact_protocol::EntityId) -> ClientMessage {
    ClientMessage::Input(ClientInput {
        aim_tick: None,
        view_tick: None,
        client: ClientId(client),
        seq,
        tick,
        actions: vec![Action::SetVelocity { entity: avatar, velocity: [2.0, 0.0, 0.0] }],
    })
}

const WAIT: Duration = Duration::from_secs(10);

/// Join, welcome, an input acked, the state stream and the scene: a browser player's whole
/// path, through the gateway and the server's access control.
#[test]
fn a_browser_player_plays_through_the_gateway() {
    let (_server, _ep, gw) = deployment(|_| {});
    let mut alice = Ws::connect(&gw);
    alice.send(&hello("alice", "alice-secret", 1));
    let ready = alice.ready(WAIT).expect("ready");
    assert_eq!((ready["client"].as_u64(), ready["world"].as_str()), (Some(1), Some("arena")));
    let (avatar, tick) = alice
        .until(WAIT, |m| match m {
            ServerMessage::Welcome(w) => Some((w.avatar.expect("arena spawns avatars"), w.tick)),
            _ => None,
        })
        .expect("welcomed through the gateway");
    alice.send_msg(&walk(1, 1, tick, avatar));
    let acked = alice.until(WAIT, |m| match m {
        ServerMessage::Ack(a) if a.seq == 1 => Some(true),
        ServerMessage::Reject(r) if r.seq == Some(1) => Some(false),
        _ => None,
    });
    assert_eq!(acked, Some(true), "the input is acked");
    assert!(alice.until(WAIT, |m| matches!(m, ServerMessage::State(_)).then_some(())).is_some(), "state frames come");
    alice.send(&json!({"type": "scene"}));
    assert!(alice.until(WAIT, |m| matches!(m, ServerMessage::Scene(_)).then_some(())).is_some(), "the scene comes");
    // A confirmed batch asked for again: the tick before alice's avatar was, so empty, which her
    // own stream never carries (it only has batches with her events).
    let before = tick.0 - 1;
    // Confirmed once it left the window (a quarter second).
    std::thread::sleep(Duration::from_millis(500));
    alice.send(&json!({"type": "confirmed", "tick": before}));
    let again = alice.until(WAIT, |m| match m {
        ServerMessage::Confirmed(b) if b.tick.0 == before => Some(b.events.len()),
        _ => None,
    });
    assert_eq!(again, Some(0), "the kept batch of tick {before}, for alice");
    // A token does as well as a password.
    let token = Secret::new(SECRET).unwrap().issue(&Grant {
        client: ClientId(2),
        world: WorldId::new("arena").unwrap(),
        expires: unix_now() + 60,
    });
    let mut bob = Ws::connect(&gw);
    bob.send(&json!({"type": "hello", "token": token}));
    assert_eq!(bob.ready(WAIT).expect("ready")["client"], 2);
    assert!(bob.until(WAIT, |m| matches!(m, ServerMessage::Welcome(_)).then_some(())).is_some());
    let stats = gw.gateway.counters.snapshot();
    assert!(stats.joined >= 2 && stats.messages_in >= 2 && stats.messages_out > 0, "{stats:?}");
    // The welcomes, the ack and the scene went through the gateway's timing of what it never drops.
    assert!(stats.relayed_kept >= 4 && stats.relay_us_p99 >= stats.relay_us_p50, "{stats:?}");
    assert!(stats.relay_us_max < 10_000_000, "a message stayed {} us in the gateway", stats.relay_us_max);
    // A gateway that stops tells its players so (and they come back to another, or to it).
    gw.stop().expect("the gateway stops");
    assert_eq!(alice.closed(WAIT).map(|c| c.0), Some(1001), "going_away");
}

/// A bare Zenoh peer standing in for the server (`common::SilentServer`), a gateway linked to
/// it, and alice connected and ready as client 1 (nobody has welcomed her).
fn alice_before_a_silent_server() -> (common::SilentServer, Running, Ws) {
    let host = common::SilentServer::start();
    let session =
        open_session(std::slice::from_ref(&host.endpoint), None, None, Mode::Peer).expect("the gateway's session");
    let config =
        Config { auth: Authenticator { users: Some(Users::parse(USERS).unwrap()), secret: None }, ..Config::default() };
    let gw = start(Gateway::new(config, session), "127.0.0.1:0", 2).expect("the gateway starts");
    let mut alice = Ws::connect(&gw);
    alice.send(&hello("alice", "alice-secret", 1));
    assert!(alice.ready(WAIT).is_some(), "ready");
    (host, gw, alice)
}

/// The kind of each message within a short wait: a notice's or a server message's type.
fn kinds(ws: &mut Ws) -> Vec<String> {
    let mut out = Vec::new();
    while let Got::Msg(b) = ws.next(Duration::from_millis(700)) {
        let v = rmp_serde::from_slice::<serde_json::Value>(&b).unwrap_or_default();
        out.push(v["type"].as_str().unwrap_or("?").to_string());
    }
    out
}

/// Waits for the player's presence: it comes after its subscriptions, so once it is heard they
/// are in place.
fn subscribed(host: &common::SilentServer) {
    let end = Instant::now() + WAIT;
    while host.presences() == 0 && Instant::now() < end {
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A welcome that does not come (lost on its way, or a presence the server never heard) is asked
/// for again: the gateway withdraws and declares its player's presence, as the Rust client's
/// transport does, and stops once the welcome came. The "server" is a bare Zenoh peer
/// (`common::SilentServer`) that answers none of the declarations until told.
#[test]
fn the_gateway_asks_again_for_a_welcome_that_does_not_come() {
    use impact_client::transport::WELCOME_WAIT;
    let (host, gw, mut alice) = alice_before_a_silent_server();
    std::thread::sleep(WELCOME_WAIT + Duration::from_millis(700));
    let declared = host.presences();
    assert!(declared >= 2, "the presence was declared {declared} times");
    assert_eq!(gw.gateway.counters.snapshot().presence_repeats, declared - 1);
    host.welcome(ClientId(1));
    assert!(alice.until(WAIT, |m| matches!(m, ServerMessage::Welcome(_)).then_some(())).is_some(), "welcomed");
    let declared = host.presences();
    std::thread::sleep(WELCOME_WAIT * 3);
    assert_eq!(host.presences(), declared, "a welcomed player's presence was declared again");
    gw.stop().expect("the gateway stops");
}

/// A takeover seen through the gateway: a player that hears a newer owner than it heard before
/// is told `link_restored` before the new owner's first message (what the old owner published as
/// it died may not have arrived; `@impact/client` then leaves the ticks before it uncompared, as
/// the Rust client does), and a message of the older owner is dropped.
#[test]
fn a_new_owner_reaches_a_player_as_a_restored_link() {
    use impact_protocol::Epoch;
    let (host, gw, mut alice) = alice_before_a_silent_server();
    subscribed(&host);
    host.welcome_as(ClientId(1), Some(Epoch(1)));
    assert_eq!(kinds(&mut alice), ["welcome"], "the first owner heard is no change");
    host.welcome_as(ClientId(1), Some(Epoch(2)));
    assert_eq!(kinds(&mut alice), ["link_restored", "welcome"]);
    host.welcome_as(ClientId(1), Some(Epoch(1)));
    host.welcome_as(ClientId(1), Some(Epoch(2)));
    assert_eq!(kinds(&mut alice), ["welcome"], "the old owner's message is dropped, the owner's taken");
    assert_eq!(gw.gateway.counters.snapshot().stale_owner, 1);
    gw.stop().expect("the gateway stops");
}

/// Events dropped on their way to the gateway (a congested path: no link lost, no new owner): a
/// skip in the numbers of a player's events key tells the player `link_restored` before the
/// message after the skip, and counts the messages lost; a new owner's count, which starts again,
/// is a takeover, not a skip.
#[test]
fn a_skip_in_a_players_event_numbers_reaches_it_as_a_restored_link() {
    use impact_protocol::{Epoch, Stamp};
    let (host, gw, mut alice) = alice_before_a_silent_server();
    subscribed(&host);
    let (alice_id, on) = (ClientId(1), |epoch, n| Stamp { epoch: Epoch(epoch), number: Some(n) });
    host.welcome_as(alice_id, Some(Epoch(1)));
    host.events(alice_id, 101, on(1, 1));
    host.events(alice_id, 102, on(1, 2));
    assert_eq!(kinds(&mut alice), ["welcome", "events", "events"], "numbers in order: nothing lost");
    host.events(alice_id, 105, on(1, 5));
    host.events(alice_id, 106, on(1, 6));
    assert_eq!(kinds(&mut alice), ["link_restored", "events", "events"], "3 and 4 lost");
    assert_eq!(gw.gateway.counters.snapshot().messages_lost, 2);
    host.events(alice_id, 120, on(2, 1));
    assert_eq!(kinds(&mut alice), ["link_restored", "events"], "a takeover, told once");
    assert_eq!(gw.gateway.counters.snapshot().messages_lost, 2, "a new owner counts anew");
    gw.stop().expect("the gateway stops");
}

/// Every refusal is a close with its code and reason.
#[test]
fn refusals_close_with_their_reason() {
    let (_server, _ep, gw) = deployment(|c| {
        c.hello_timeout = Duration::from_millis(500);
        c.max_messages_per_s = 20;
    });
    let closed = |ws: &mut Ws| ws.closed(WAIT).expect("a close frame");
    let code = |ws: &mut Ws| closed(ws).0;

    let mut ws = Ws::connect(&gw);
    ws.send(&hello("alice", "wrong", 1));
    let (c, reason) = closed(&mut ws);
    assert_eq!((c, reason.as_str()), (4001, "unauthorized: user or password wrong"));

    let mut ws = Ws::connect(&gw);
    ws.send(&hello("alice", "alice-secret", 2));
    assert_eq!(code(&mut ws), 4001, "alice's password does not make her client 2");

    let expired = Secret::new(SECRET).unwrap().issue(&Grant {
        client: ClientId(2),
        world: WorldId::new("arena").unwrap(),
        expires: unix_now() - 1,
    });
    let mut ws = Ws::connect(&gw);
    ws.send(&json!({"type": "hello", "token": expired}));
    let (c, reason) = closed(&mut ws);
    assert!(c == 4001 && reason.contains("expired"), "{c} {reason}");

    let mut ws = Ws::connect(&gw);
    assert_eq!(closed(&mut ws).0, 4002, "no hello in time");

    let mut ws = Ws::connect(&gw);
    ws.send_bytes(vec![0xc1, 0xff, 0x00]);
    assert_eq!(code(&mut ws), 4000, "garbage for a hello");

    let mut ws = Ws::connect(&gw);
    ws.send(&json!({"type": "hello", "world": "nowhere", "client": 1, "user": "alice", "password": "alice-secret"}));
    let (c, reason) = closed(&mut ws);
    assert!(c == 4004 && reason.contains("nowhere"), "{c} {reason}");

    // Playing, then: garbage, a text frame, a world command, too big, a flood.
    let playing = |then: &dyn Fn(&mut Ws)| {
        let mut ws = Ws::connect(&gw);
        ws.send(&hello("alice", "alice-secret", 1));
        ws.ready(WAIT).expect("ready");
        then(&mut ws);
        code(&mut ws)
    };
    assert_eq!(playing(&|ws| ws.send_bytes(vec![0x93, 1, 2, 3])), 4011);
    assert_eq!(playing(&|ws| drop(ws.0.send(Message::Text("{}".into())))), 4011);
    let world = json!({"type": "world", "command": "close"});
    assert_eq!(playing(&|ws| ws.send(&world)), 4012);
    assert_eq!(playing(&|ws| ws.send_bytes(vec![0; 8 * 1024])), 1009);
    let ping = ClientMessage::Ping(impact_protocol::TimePing { client: ClientId(1), id: 1 });
    assert_eq!(
        playing(&|ws| {
            for _ in 0..100 {
                ws.send_msg(&ping);
            }
        }),
        4029
    );

    // A second connection of a player replaces the first.
    let mut first = Ws::connect(&gw);
    first.send(&hello("bob", "bob-secret", 2));
    first.ready(WAIT).expect("ready");
    let mut second = Ws::connect(&gw);
    second.send(&hello("bob", "bob-secret", 2));
    assert_eq!(code(&mut first), 4030);
    assert!(second.until(WAIT, |m| matches!(m, ServerMessage::Welcome(_)).then_some(())).is_some(), "the newer plays");

    let closed_by = gw.gateway.counters.snapshot().closed;
    for reason in [
        "unauthorized",
        "hello_timeout",
        "bad_hello",
        "no_server",
        "malformed",
        "not_allowed",
        "too_big",
        "flood",
        "replaced",
    ] {
        assert!(closed_by.get(reason).is_some_and(|n| *n > 0), "{reason} counted: {closed_by:?}");
    }
}

/// Another site's page is refused before the upgrade, and so is a connection past the limit.
#[test]
fn origins_and_the_connection_limit_are_enforced() {
    let (_server, _ep, gw) = deployment(|c| {
        c.max_connections = 2;
        c.allow_origins = vec!["https://game.example".into()];
    });
    let status = |r: Result<Ws, tungstenite::Error>| match r {
        Err(tungstenite::Error::Http(resp)) => Some(resp.status().as_u16()),
        _ => None,
    };
    assert_eq!(status(Ws::connect_from(gw.addr, Some("https://evil.example"))), Some(403));
    let own = format!("http://{}", gw.addr);
    let _a = Ws::connect_from(gw.addr, Some(&own)).expect("its own page");
    let _b = Ws::connect_from(gw.addr, Some("https://game.example")).expect("an allowed origin");
    assert_eq!(status(Ws::connect_from(gw.addr, None)), Some(503), "past the limit");
}

/// The gateway publishes a player's inputs on that player's key only: mallory, logged in as
/// herself, names alice in her input; the server hears it on mallory's key (it refuses it to
/// mallory, `not_owner`: the body names another client), and answers nothing on alice's keys,
/// as it would had the gateway published it on alice's key.
#[test]
fn a_player_publishes_only_as_itself() {
    let (_server, ep, gw) = deployment(|_| {});
    let world = WorldId::new("arena").unwrap();
    let observer = client_as(&ep, Some(("srv", "srv-secret"))).expect("a peer of the deployment");
    let alice_acks = Inbox::new(&observer, keys::CLIENT_ACK.key(&world, Some(ClientId(1))));
    let mut mallory = Ws::connect(&gw);
    mallory.send(&hello("mallory", "mallory-secret", 3));
    let (avatar, tick) = mallory
        .until(WAIT, |m| match m {
            ServerMessage::Welcome(w) => Some((w.avatar.unwrap(), w.tick)),
            _ => None,
        })
        .expect("welcomed");
    mallory.send_msg(&walk(1, 77, tick, avatar));
    let refused = mallory.until(WAIT, |m| match m {
        ServerMessage::Reject(r) if r.seq == Some(77) => Some(r.reason),
        _ => None,
    });
    assert_eq!(refused, Some(impact_protocol::RejectReason::NotOwner), "heard on mallory's key");
    assert!(alice_acks.wait_for(Duration::from_secs(1), |m| answers(m, 77).then_some(())).is_none());
}

/// Abuse, round after round, against the gateway as a process, as the internet sends it: garbage
/// for a hello, a message too big, a flood, another player's password, another player's token,
/// and half-open connections (a request head that never ends, a slowloris). Each ends in a close
/// with its code (the half-open ones closed by the gateway within its header timeout); after six
/// rounds the gateway's memory is within 10 % of what it was after the first, and a player still
/// plays.
#[test]
fn abuse_is_closed_with_reasons_and_the_gateway_stays_flat() {
    let dir = std::env::temp_dir().join(format!("impact-gateway-abuse-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (users, secret) = (dir.join("users.toml"), dir.join("secret"));
    std::fs::write(&users, USERS).unwrap();
    std::fs::write(&secret, SECRET).unwrap();
    let (_server, ep) = server(Scene::load(&Scene::bundled_path("arena")).unwrap(), |_| {});
    let mut cmd = std::process::Command::new(process::binary("impact-gateway"));
    cmd.args(["--listen", "127.0.0.1:0", "--connect", &ep, "--max-messages-per-s", "20", "--report-s", "0"])
        .arg("--users")
        .arg(&users)
        .arg("--token-secret")
        .arg(&secret);
    let gateway = process::Proc::spawn("impact-gateway (abuse)", cmd);
    assert!(gateway.wait_for_output("listening on http://", WAIT), "{}", gateway.output());
    let out = gateway.output();
    let addr: SocketAddr = out
        .split("listening on http://")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("the address in {out}"));

    let bobs_token = Secret::new(SECRET).unwrap().issue(&Grant {
        client: ClientId(2),
        world: WorldId::new("arena").unwrap(),
        expires: unix_now() + 600,
    });
    let code = |ws: &mut Ws| ws.closed(WAIT).map(|c| c.0);
    let playing = |then: &dyn Fn(&mut Ws)| {
        let mut ws = Ws::connect_to(addr);
        ws.send(&hello("alice", "alice-secret", 1));
        ws.ready(WAIT).expect("ready");
        then(&mut ws);
        code(&mut ws)
    };
    let ping = ClientMessage::Ping(impact_protocol::TimePing { client: ClientId(1), id: 1 });
    let mut after_first = None;
    for round in 0..6 {
        // Half-open: a request head that never ends.
        let half_open: Vec<TcpStream> = (0..20)
            .map(|_| {
                let mut c = TcpStream::connect(addr).unwrap();
                std::io::Write::write_all(&mut c, b"GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n").unwrap();
                c
            })
            .collect();
        let opened = Instant::now();
        for _ in 0..10 {
            let mut ws = Ws::connect_to(addr);
            ws.send_bytes(vec![0xc1, 0xff, 0x00]);
            assert_eq!(code(&mut ws), Some(4000), "garbage for a hello");
            let mut ws = Ws::connect_to(addr);
            ws.send(&hello("alice", "alice-secret", 2));
            assert_eq!(code(&mut ws), Some(4001), "alice's password for bob's client");
            let mut ws = Ws::connect_to(addr);
            ws.send(&json!({"type": "hello", "token": bobs_token, "client": 1}));
            assert_eq!(code(&mut ws), Some(4001), "bob's token for alice's client");
        }
        assert_eq!(playing(&|ws| ws.send_bytes(vec![0; 64 * 1024])), Some(1009), "too big");
        let flood = |ws: &mut Ws| {
            for _ in 0..100 {
                ws.send_msg(&ping);
            }
        };
        assert_eq!(playing(&flood), Some(4029), "a flood");
        for mut c in half_open {
            c.set_read_timeout(Some(HEADER_TIMEOUT + Duration::from_secs(5))).unwrap();
            let mut buf = [0u8; 256];
            // Closed (end of stream, or reset), possibly after an answer; a read that times out
            // is a connection still open.
            let ended = match std::io::Read::read(&mut c, &mut buf) {
                Ok(_) => true,
                Err(e) => !matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut),
            };
            assert!(ended, "a half-open connection was still open {:?} after it opened", opened.elapsed());
        }
        let mib = process::rss_mib(gateway.pid());
        eprintln!("round {round}: gateway {mib:.1} MiB");
        after_first.get_or_insert(mib);
    }
    let (first, last) = (after_first.unwrap(), process::rss_mib(gateway.pid()));
    assert!(last <= first * 1.10, "the gateway grew from {first:.1} to {last:.1} MiB");
    let mut ws = Ws::connect_to(addr);
    ws.send(&hello("alice", "alice-secret", 1));
    assert!(ws.until(WAIT, |m| matches!(m, ServerMessage::Welcome(_)).then_some(())).is_some(), "a player plays");
    let _ = std::fs::remove_dir_all(&dir);
}
