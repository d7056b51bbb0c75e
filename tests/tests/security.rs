//! `impact-server --users` over real Zenoh sessions on loopback: a user cannot act, listen or
//! appear as another, a session without the right password gets nowhere, and a legitimate client
//! works as it always did. Every wait is bounded; "nothing arrives" is checked after the same
//! traffic has provably reached its rightful receiver.

mod common;

use common::*;
use impact_core::scene::Scene;
use impact_protocol::{keys, Action, ClientId, ClientInput, Encoding, EntityId, ServerMessage, Tick, WorldId};
use impact_server::runtime::auth::Users;
use std::time::Duration;

fn secured() -> (impact_server::runtime::ServerHandle, String) {
    let scene = Scene::load(&Scene::bundled_path("arena")).unwrap();
    server(scene, |o| o.users = Some(Users::parse(USERS).unwrap()))
}

fn welcome(inbox: &Inbox) -> Option<(EntityId, Tick)> {
    inbox.wait_for(Duration::from_secs(10), |m| match m {
        ServerMessage::Welcome(w) => Some((w.avatar.expect("arena spawns avatars"), w.tick)),
        _ => None,
    })
}

fn walk(client: ClientId, seq: u32, tick: Tick, avatar: EntityId) -> ClientInput {
    ClientInput {
        aim_tick: None,
        view_tick: None,
        client,
        seq,
        tick,
        actions: vec![Action::SetVelocity { entity: avatar, velocity: [2.0, 0.0, 0.0] }],
    }
}

/// The answer to `seq` on an ack inbox: `Some(true)` ack, `Some(false)` reject, `None` nothing.
fn answer(inbox: &Inbox, seq: u32, wait: Duration) -> Option<bool> {
    inbox.wait_for(wait, |m| match m {
        ServerMessage::Ack(a) if a.seq == seq => Some(true),
        ServerMessage::Reject(r) if r.seq == Some(seq) => Some(false),
        _ => None,
    })
}

#[test]
fn a_user_acts_listens_and_appears_only_as_itself() {
    let (server, ep) = secured();
    let world = WorldId::new("arena").unwrap();
    let (alice_id, bob_id) = (ClientId(1), ClientId(2));
    let alice = client_as(&ep, Some(("alice", "alice-secret"))).expect("alice connects");
    let mallory = client_as(&ep, Some(("mallory", "mallory-secret"))).expect("mallory connects");

    // A legitimate client works unchanged: welcome, ack.
    let alice_ack = Inbox::new(&alice, keys::CLIENT_ACK.key(&world, Some(alice_id)));
    // Mallory listens on alice's keys, exactly and by wildcard.
    let stolen_ack = Inbox::new(&mallory, keys::CLIENT_ACK.key(&world, Some(alice_id)));
    let stolen_all = Inbox::new(&mallory, format!("impact/v1/{}/client/**", world.as_str()));
    let _alice_token = join(&alice, &world, alice_id);
    let (avatar, tick) = welcome(&alice_ack).expect("alice is welcomed");
    send(&alice, &world, &walk(alice_id, 1, Tick(tick.0 + 4), avatar), Encoding::MsgPack);
    assert_eq!(answer(&alice_ack, 1, Duration::from_secs(5)), Some(true), "alice's own input is acked");

    // Impersonating put: mallory publishes an input for alice, on alice's key, with alice's id.
    let now = |s: &zenoh::Session| match query(s, keys::QUERY_STATE.key(&world, None), "") {
        Some(ServerMessage::Snapshot(snap)) => snap.tick,
        other => panic!("state query: {other:?}"),
    };
    let t = now(&alice);
    send(&mallory, &world, &walk(alice_id, 2, Tick(t.0 + 2), avatar), Encoding::MsgPack);
    // Alice's next input proves the path is live; the forged one was never answered (looked for
    // in the same wait: its answer could come before alice's).
    send(&alice, &world, &walk(alice_id, 3, Tick(t.0 + 2), avatar), Encoding::MsgPack);
    let mut forged = None;
    let third = alice_ack.wait_for(Duration::from_secs(5), |m| match m {
        m if answers(m, 2) => {
            forged = Some(format!("{m:?}"));
            None
        }
        m if answers(m, 3) => Some(matches!(m, ServerMessage::Ack(_))),
        _ => None,
    });
    assert_eq!(third, Some(true));
    let forged = forged.or_else(|| answer(&alice_ack, 2, Duration::from_millis(500)).map(|a| format!("answered {a}")));
    assert_eq!(forged, None, "the forged input reached the server");

    // Replay: seq 1, accepted seconds ago (its tick long confirmed), sent again with a fresh tick
    // by alice herself is a repeat: not applied again, and no reject either (a client resending
    // after a reconnect, or carrying it as a redundant copy, did nothing wrong); the server counts
    // it. The window outlives the rollback window.
    let stats = Inbox::new(&alice, keys::STATS.key(&world, None));
    let t = now(&alice);
    send(&alice, &world, &walk(alice_id, 1, Tick(t.0 + 2), avatar), Encoding::MsgPack);
    send(&alice, &world, &walk(alice_id, 4, Tick(t.0 + 2), avatar), Encoding::MsgPack);
    assert_eq!(answer(&alice_ack, 4, Duration::from_secs(5)), Some(true), "the input after the replay");
    let replayed = alice_ack.wait_for(Duration::from_millis(500), |m| match m {
        ServerMessage::Reject(r) if r.seq == Some(1) => Some(format!("rejected: {r:?}")),
        ServerMessage::Ack(a) if a.seq == 1 => Some(format!("a replayed seq was accepted: {a:?}")),
        _ => None,
    });
    assert_eq!(replayed, None);
    let repeated = stats.wait_for(Duration::from_secs(3), |m| match m {
        ServerMessage::Stats(s) if s.inputs_repeated > 0 => Some(s.inputs_repeated),
        _ => None,
    });
    assert_eq!(repeated, Some(1), "the server counted the repeat");

    // Eavesdropping: alice received her welcome and acks; mallory received none of them.
    let anything = |inbox: &Inbox| inbox.wait_for(Duration::from_millis(500), |m| Some(format!("{m:?}")));
    assert_eq!(anything(&stolen_ack), None, "mallory read alice's ack key");
    assert_eq!(anything(&stolen_all), None, "mallory read another client's keys by wildcard");

    // Spoofed presence: mallory declares bob's token. No avatar, no welcome for bob.
    let bob = client_as(&ep, Some(("bob", "bob-secret"))).expect("bob connects");
    let bob_ack = Inbox::new(&bob, keys::CLIENT_ACK.key(&world, Some(bob_id)));
    let spoofed = join(&mallory, &world, bob_id);
    assert!(welcome(&bob_ack).is_none() || panic!("a spoofed token spawned bob"));
    drop(spoofed);
    let _bob_token = join(&bob, &world, bob_id);
    assert!(welcome(&bob_ack).is_some(), "bob's own token is honoured");

    // Public streams and queries still reach every user.
    let events = Inbox::new(&mallory, keys::STATS.key(&world, None));
    assert!(events.wait_for(Duration::from_secs(3), |m| matches!(m, ServerMessage::Stats(_)).then_some(())).is_some());
    assert!(matches!(query(&mallory, keys::QUERY_STATE.key(&world, None), ""), Some(ServerMessage::Snapshot(_))));
    // ...the scene a client predicts with too.
    assert!(matches!(query(&mallory, keys::QUERY_SCENE.key(&world, None), ""), Some(ServerMessage::Scene(_))));

    let summary = server.stop();
    assert_eq!(summary.inputs_accepted, 3, "only alice's three inputs were accepted: {summary}");
    assert_eq!(summary.inputs_repeated, 1, "{summary}");
}

#[test]
fn wrong_password_and_no_credentials_get_no_session() {
    let (server, ep) = secured();
    for (who, creds) in [
        ("a wrong password", Some(("alice", "guess"))),
        ("an unknown user", Some(("eve", "alice-secret"))),
        ("no credentials", None),
    ] {
        let t0 = std::time::Instant::now();
        match client_as(&ep, creds) {
            Err(e) => assert!(t0.elapsed() < Duration::from_secs(30), "{who}: refused, but slowly: {e}"),
            Ok(s) => panic!("{who}: a session was opened (zid {})", s.zid()),
        }
    }
    drop(server);
}

/// The client library's transport connects under access control: it finds the world's server
/// by a liveliness query on the servers' tokens, which the rules allow every user (before they
/// did, a client with a password was told no server ran the world), and is welcomed.
#[test]
fn the_client_library_connects_under_access_control() {
    use impact_client::transport::{ConnectOptions, Connection, Credentials};
    use impact_client::{Session, SessionConfig, Status};
    let (_server, ep) = secured();
    let mut opts = ConnectOptions::new(vec![ep], WorldId::new("arena").unwrap(), ClientId(1));
    opts.credentials = Some(Credentials { user: "alice".into(), password: "alice-secret".into() });
    opts.find_server = Duration::from_secs(3);
    let conn = Connection::open(&opts).expect("finds the server under access control");
    let mut game = Session::new(SessionConfig::new(ClientId(1)));
    let end = std::time::Instant::now() + Duration::from_secs(10);
    while game.status() != Status::Playing && std::time::Instant::now() < end {
        conn.pump(&mut game, std::time::Instant::now()).expect("pumps");
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(game.status(), Status::Playing, "welcomed and synced");
    conn.close();
}
