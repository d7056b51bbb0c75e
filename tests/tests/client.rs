//! The client library (`impact-client`) against a real server over Zenoh on loopback: it joins,
//! predicts its avatar bit for bit where nothing else touched it with the rules and static world
//! the server sent (`query/scene`), has every shot answered once,
//! measures its round trip before its first input, stamps inputs on time, carries unanswered
//! inputs in each message so a lossy uplink loses none (and the server applies each once), and
//! says clearly when no server, or a server of another protocol version, owns the world.

mod common;

use common::*;
use impact_client::transport::{ConnectOptions, Connection, TransportError};
use impact_client::{Session, SessionConfig, Status};
use impact_core::scene::Scene;
use impact_protocol::{Action, ClientId, ClientMessage, GameState, WorldId};
use std::time::{Duration, Instant};
use zenoh::Wait;

fn options(ep: &str, client: u32) -> ConnectOptions {
    ConnectOptions::new(vec![ep.to_string()], WorldId::new("arena").unwrap(), ClientId(client))
}

/// Pumps until the session plays and has the server's scene to predict with (bounded).
fn join(conn: &Connection, game: &mut Session) {
    let by = Instant::now() + Duration::from_secs(10);
    let predicting = game.config().predict.is_some();
    while game.status() != Status::Playing
        || (predicting && game.predictor().is_none() && game.prediction_problem().is_none())
    {
        assert!(Instant::now() < by, "not playing within 10 s: {:?} {:?}", game.status(), game.stats());
        conn.pump(game, Instant::now()).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Plays `seconds`, an input every 50 ms; `copies` says how many times each outgoing message is
/// really sent (0: lost on the way, 2: duplicated). Then waits up to 2 s for the answers owed.
/// Every fourth input fires a ray; returns how many were fired.
fn play(conn: &Connection, game: &mut Session, seconds: f64, mut copies: impl FnMut(&ClientMessage) -> u32) -> u64 {
    let avatar = game.avatar().expect("arena spawns avatars");
    let start = Instant::now();
    let (mut next, mut k, mut fired) = (start, 0u64, 0u64);
    while start.elapsed().as_secs_f64() < seconds
        || (game.pending_inputs() > 0 && start.elapsed().as_secs_f64() < seconds + 2.0)
    {
        let now = Instant::now();
        conn.pump(game, now).unwrap();
        if now >= next && start.elapsed().as_secs_f64() < seconds {
            next += Duration::from_millis(50);
            k += 1;
            let v = [2.0 * (now - start).as_secs_f64().cos(), 0.0, 1.0];
            let action = match game.draw_avatar(now) {
                Some(origin) if k % 4 == 0 => {
                    fired += 1;
                    Action::FireRay { shooter: avatar, origin, direction: [1.0, 0.0, 0.0], max_distance_m: 60.0 }
                }
                _ => Action::SetVelocity { entity: avatar, velocity: v },
            };
            game.input(vec![action], now).unwrap();
        }
        while let Some(m) = game.poll_transmit(now) {
            for _ in 0..copies(&m) {
                conn.send(&m).unwrap();
            }
        }
        game.draw_avatar(now);
        std::thread::sleep(Duration::from_millis(5));
    }
    fired
}

#[test]
fn a_client_syncs_predicts_plays_on_time_and_loses_no_input_to_a_lossy_uplink() {
    let (server, ep) = server(Scene::load(&Scene::bundled_path("arena")).unwrap(), |_| {});
    let conn = Connection::open(&options(&ep, 1)).expect("connects");
    // No scene file: the connection asks the server for its rules and static world
    // (`query/scene`), and the session predicts with them.
    let mut game = Session::new(SessionConfig::new(ClientId(1)));
    join(&conn, &mut game);
    assert_eq!(game.prediction_problem(), None, "the server's scene rebuilt to its hash");
    assert!(game.predictor().is_some());
    let s = game.stats().clone();
    assert!(s.sync_samples >= 3, "the round trip was measured before play: {s:?}");
    assert!(game.clock().lead().is_some_and(|l| l >= 1.0), "a lead before the first ack");

    // Every input arrives on time from the first on: the lead came from the sync.
    let mut fired = play(&conn, &mut game, 2.0, |_| 1);
    let s = game.stats().clone();
    assert!(s.inputs_sent >= 35, "{s:?}");
    assert_eq!((s.inputs_acked, s.late_acks, s.rejects.len()), (s.inputs_sent, 0, 0), "{s:?}");
    // The avatar, predicted with the server's core, equalled every state the server streamed
    // unless another body came near (the arena's balls): mostly untouched, so mostly exact.
    let pr = game.prediction().clone();
    assert!(pr.compared >= 20, "{pr:?}");
    assert!(pr.exact * 10 >= pr.compared * 8, "mostly exact: {} of {}: {:?}", pr.exact, pr.compared, pr.causes);

    // Half the messages lost: each input rides in up to four, so every one still arrives, once.
    // An input whose own message was lost arrives as a copy an input later than the path takes,
    // late (the server rolls back for it); the lead the server recommends follows the path, not
    // the loss, so the inputs that were not lost stay within the ticks it accepts ahead.
    let lead = game.clock().lead().unwrap();
    let mut k = 0u32;
    fired += play(&conn, &mut game, 2.0, |m| {
        k += 1;
        u32::from(matches!(m, ClientMessage::Ping(_)) || k % 2 == 0)
    });
    let t = game.stats().clone();
    let sent = t.inputs_sent - s.inputs_sent;
    assert!(t.copies_sent > s.copies_sent, "{t:?}");
    assert_eq!(t.inputs_acked - s.inputs_acked, sent, "every input acked: {t:?}");
    let after = game.clock().lead().unwrap();
    assert!(after <= lead + 1.0, "the lead rose from {lead} to {after} ticks for copies that came late");

    // Every message twice (a resend after a reconnect looks the same): applied once, acked once,
    // the repeat neither answered nor rejected.
    fired += play(&conn, &mut game, 1.0, |_| 2);
    // A shot is answered when its tick is simulated: after its ack, for an early one.
    let by = Instant::now() + Duration::from_secs(2);
    while game.stats().ray_results < fired && Instant::now() < by {
        conn.pump(&mut game, Instant::now()).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    let u = game.stats().clone();
    assert!(fired >= 15);
    assert_eq!(u.ray_results, fired, "every shot answered once, early as they all were");
    // Over the whole game every misprediction is explained: another body came near, or an
    // input was late (the copies of lost ones).
    let pr = game.prediction();
    assert!(pr.compared >= 50, "{pr:?}");
    assert_eq!(pr.causes.get("unexplained"), None, "{:?}", pr.causes);
    assert!(pr.errors_untouched_m.iter().all(|&e| e == 0.0));
    assert_eq!(u.inputs_acked, u.inputs_sent, "{u:?}");
    assert!(u.rejects.is_empty(), "no repeat counts as a reject: {u:?}");
    assert_eq!(u.unmatched_answers, 0, "no input answered twice: {u:?}");
    conn.close();
    let summary = server.stop();
    assert_eq!(summary.inputs_accepted, u.inputs_sent, "{summary}");
    assert!(summary.inputs_repeated >= u.inputs_sent - t.inputs_sent, "every second copy skipped: {summary}");
}

#[test]
fn no_server_and_another_protocol_version_are_clear_errors() {
    // Nobody owns world "arena" here: a listening peer with no server in it.
    let port = free_port();
    let ep = format!("tcp/127.0.0.1:{port}");
    let mut c = zenoh::Config::default();
    c.insert_json5("scouting/multicast/enabled", "false").unwrap();
    c.insert_json5("listen/endpoints", &format!("[\"{ep}\"]")).unwrap();
    let host = zenoh::open(c).wait().unwrap();
    let quick = ConnectOptions { find_server: Duration::from_millis(500), ..options(&ep, 1) };
    match Connection::open(&quick) {
        Err(e @ TransportError::NoServer { .. }) => assert!(e.to_string().contains("--world arena"), "{e}"),
        other => panic!("expected no server, got {other:?}"),
    }
    // A server of protocol v0 owns it.
    let _old = host.liveliness().declare_token("impact/v0/arena/server").wait().unwrap();
    match Connection::open(&quick) {
        Err(e @ TransportError::VersionMismatch { .. }) => {
            let text = e.to_string();
            assert!(text.contains("v0") && text.contains("v1"), "{text}");
        }
        other => panic!("expected a version mismatch, got {other:?}"),
    }
}

/// A welcome that does not come (lost on its way, or the server never heard the presence) is
/// asked for again: the joining client withdraws and declares its presence after
/// `WELCOME_WAIT`, doubling, and stops once welcomed. The "server" is a bare Zenoh peer
/// (`common::SilentServer`) that answers none of the declarations until told.
#[test]
fn a_welcome_that_does_not_come_is_asked_for_again() {
    use impact_client::transport::WELCOME_WAIT;
    let host = common::SilentServer::start();
    let opts = ConnectOptions { scene: false, state: false, ..options(&host.endpoint, 7) };
    let conn = Connection::open(&opts).expect("connects");
    let mut game = Session::new(SessionConfig::new(ClientId(7)));
    let pump_for = |game: &mut Session, d: Duration| {
        let end = Instant::now() + d;
        while Instant::now() < end {
            conn.pump(game, Instant::now()).unwrap();
            std::thread::sleep(Duration::from_millis(5));
        }
    };
    pump_for(&mut game, WELCOME_WAIT + Duration::from_millis(500));
    assert_eq!(game.status(), Status::Joining);
    assert!(host.presences() >= 2, "the presence was declared {} times", host.presences());
    assert_eq!(conn.presence_repeats(), host.presences() - 1);
    host.welcome(ClientId(7));
    pump_for(&mut game, Duration::from_millis(300));
    assert_eq!(game.status(), Status::Syncing, "welcomed (its clock probes go unanswered here)");
    let declared = host.presences();
    pump_for(&mut game, WELCOME_WAIT * 3);
    assert_eq!(host.presences(), declared, "a welcomed client declared its presence again");
}

/// On a world whose avatars are characters, a client's velocity is refused with a typed reason
/// (it would fly), and `move` intents walk it, predicted to the bit with the server's scene.
#[test]
fn a_character_is_walked_by_intents_and_its_velocity_is_refused() {
    use impact_client::Outcome;
    use impact_protocol::RejectReason;
    let (server, ep) = server(Scene::load(&Scene::bundled_path("field")).unwrap(), |_| {});
    let opts = ConnectOptions::new(vec![ep.clone()], WorldId::new("field").unwrap(), ClientId(1));
    let conn = Connection::open(&opts).expect("connects");
    let mut game = Session::new(SessionConfig::new(ClientId(1)));
    join(&conn, &mut game);
    assert!(game.predictor().is_some_and(|p| p.is_character()), "{:?}", game.prediction_problem());
    let me = game.avatar().unwrap();

    let fly = game.input(vec![Action::SetVelocity { entity: me, velocity: [0.0, 20.0, 0.0] }], Instant::now()).unwrap();
    let by = Instant::now() + Duration::from_secs(3);
    let mut refused = None;
    while refused.is_none() && Instant::now() < by {
        conn.pump(&mut game, Instant::now()).unwrap();
        refused = game.take_answers().find(|a| a.seq == fly).map(|a| a.outcome);
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(refused, Some(Outcome::Rejected(RejectReason::NotAllowed)));

    let start = Instant::now();
    let (mut next, mut k) = (start, 0u32);
    while start.elapsed() < Duration::from_secs(3) {
        let now = Instant::now();
        conn.pump(&mut game, now).unwrap();
        if now >= next {
            next += Duration::from_millis(50);
            k += 1;
            let a = f64::from(k) * 0.1;
            let walk = Action::Move { entity: me, direction: [a.cos(), 0.0, a.sin()], jump: k % 10 == 0 };
            game.input(vec![walk], now).unwrap();
        }
        game.draw_avatar(now);
        std::thread::sleep(Duration::from_millis(5));
    }
    let s = game.stats().clone();
    assert_eq!(s.rejects.get(&RejectReason::NotAllowed), Some(&1), "only the velocity: {s:?}");
    assert_eq!(s.rejects.len(), 1, "{s:?}");
    let pr = game.prediction();
    assert!(pr.compared >= 40, "{pr:?}");
    assert!(pr.errors_untouched_m.iter().all(|&e| e == 0.0), "{pr:?}");
    assert_eq!(pr.causes.get("unexplained"), None, "{:?}", pr.causes);
    conn.close();
    let summary = server.stop();
    assert!(summary.inputs_accepted >= 50, "{summary}");
}

/// A game-logic client (no avatar of its own) teleports a player's avatar: acked with its tick,
/// and the world has the avatar there; the player sending the same is refused `not_allowed`.
#[test]
fn game_logic_teleports_a_player_and_the_player_may_not() {
    use impact_client::Outcome;
    use impact_protocol::{keys, RejectReason, ServerMessage};
    let logic_id = ClientId(900);
    let (server, ep) = server(Scene::load(&Scene::bundled_path("arena")).unwrap(), |o| {
        o.logic_clients = vec![logic_id];
        // No full frame in the test's time: a changed state must come by itself.
        o.state.full_every = 100_000;
    });
    let conn = Connection::open(&options(&ep, 1)).expect("connects");
    let mut player = Session::new(SessionConfig::new(ClientId(1)));
    join(&conn, &mut player);
    let avatar = player.avatar().unwrap();
    let quiet = ConnectOptions { scene: false, state: false, ..options(&ep, logic_id.0) };
    let lconn = Connection::open(&quiet).expect("connects");
    let mut logic = Session::new(SessionConfig { predict: None, ..SessionConfig::new(logic_id) });
    join(&lconn, &mut logic);
    assert_eq!(logic.avatar(), None, "game logic plays no body");

    // Pumps both until `seq` of `s` is answered.
    let answer = |s: &mut Session, c: &Connection, other: (&mut Session, &Connection), seq: u32| {
        let by = Instant::now() + Duration::from_secs(3);
        loop {
            assert!(Instant::now() < by, "no answer to {seq}");
            c.pump(s, Instant::now()).unwrap();
            other.1.pump(other.0, Instant::now()).unwrap();
            if let Some(a) = s.take_answers().find(|a| a.seq == seq) {
                return a;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    };
    let to = [0.0, 5.0, 0.0];
    let jump = Action::Teleport { entity: avatar, position: to, velocity: Some([0.0; 3]) };
    let seq = player.input(vec![jump.clone()], Instant::now()).unwrap();
    let a = answer(&mut player, &conn, (&mut logic, &lconn), seq);
    assert_eq!(a.outcome, Outcome::Rejected(RejectReason::NotAllowed));

    let seq = logic.input(vec![jump], Instant::now()).unwrap();
    let a = answer(&mut logic, &lconn, (&mut player, &conn), seq);
    let Outcome::Accepted { applied_tick, .. } = a.outcome else { panic!("{:?}", a.outcome) };
    // The world at the start of the next tick: the avatar where it was put (nothing moves it
    // in one tick but a collision, unlikely there and then).
    let next = applied_tick.0 + 1;
    let by = Instant::now() + Duration::from_secs(3);
    let state = loop {
        conn.pump(&mut player, Instant::now()).unwrap();
        lconn.pump(&mut logic, Instant::now()).unwrap();
        match query(
            lconn.zenoh(),
            keys::QUERY_STATE.key(&WorldId::new("arena").unwrap(), None),
            &format!("tick={next}"),
        ) {
            Some(ServerMessage::Snapshot(s)) => break s,
            _ => assert!(Instant::now() < by, "no state at tick {next}"),
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let body = state.bodies.iter().find(|b| b.entity == avatar).unwrap();
    let d = (0..3).map(|k| (body.position[k] - to[k]).powi(2)).sum::<f64>().sqrt();
    assert!(d < 0.5, "the avatar is at {:?}, not {to:?}", body.position);

    // Game state and a class change: the player's own stream announces both on the body it
    // already holds; the player may set neither.
    let hurt = Action::SetState { entity: avatar, values: GameState::from([("health", 75.0), ("team", 2.0)]) };
    let seq = player.input(vec![hurt.clone()], Instant::now()).unwrap();
    let a = answer(&mut player, &conn, (&mut logic, &lconn), seq);
    assert_eq!(a.outcome, Outcome::Rejected(RejectReason::NotAllowed));
    let recolour = Action::SetClass { entity: avatar, class: "ball".into() };
    let seq = logic.input(vec![hurt, recolour], Instant::now()).unwrap();
    let a = answer(&mut logic, &lconn, (&mut player, &conn), seq);
    assert!(matches!(a.outcome, Outcome::Accepted { .. }), "{:?}", a.outcome);
    let by = Instant::now() + Duration::from_secs(3);
    loop {
        conn.pump(&mut player, Instant::now()).unwrap();
        lconn.pump(&mut logic, Instant::now()).unwrap();
        let info = player.remote().and_then(|r| r.info(avatar));
        if let Some(i) = info.filter(|i| !i.state.is_empty()) {
            assert_eq!((i.state.get("health"), i.state.get("team")), (Some(75.0), Some(2.0)), "{i:?}");
            assert_eq!(i.class, "ball", "{i:?}");
            break;
        }
        assert!(Instant::now() < by, "the stream never carried the game state: {info:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
    conn.close();
    lconn.close();
    let summary = server.stop();
    assert_eq!(summary.inputs_accepted, 2, "{summary}");
}

/// Game logic opens a world from a scene at run time (a match starting), a player joins and
/// plays in it, and game logic closes it (the match over) naming the next: the player is told,
/// and its session stops taking inputs. A player may do neither; an unknown scene, a world open
/// already and the process's limit are refused with their reasons.
#[test]
fn game_logic_opens_and_closes_a_world_at_run_time() {
    use impact_client::transport::world_command;
    use impact_client::InputError;
    use impact_protocol::{RejectReason, WorldCommand, WorldOutcome};
    use impact_server::runtime::{Host, HostOptions, ServerOptions};
    let logic = ClientId(900);
    let ep = format!("tcp/127.0.0.1:{}", free_port());
    let options = move |_: &Scene| ServerOptions {
        listen: vec![ep.clone()],
        logic_clients: vec![logic],
        ..ServerOptions::default()
    };
    let arena = Scene::load(&Scene::bundled_path("arena")).unwrap();
    let first = options(&arena);
    let endpoint = first.listen[0].clone();
    let host = HostOptions {
        open_worlds: 1,
        scenes: [("arena".to_string(), Scene::bundled_path("arena"))].into(),
        options: std::sync::Arc::new(options),
        ..HostOptions::none()
    };
    let host = Host::start(vec![(arena, first)], host).expect("host starts");
    let zs = client(&endpoint);
    let match2 = WorldId::new("arena-2").unwrap();
    let t = Duration::from_secs(5);
    let open = |scene: &str| WorldCommand::Open { scene: scene.into() };
    let refused = |a: impact_protocol::WorldAnswer| match a.outcome {
        WorldOutcome::Refused { reason, detail } => (reason, detail),
        o => panic!("not refused: {o:?}"),
    };

    let (why, _) = refused(world_command(&zs, &match2, ClientId(1), open("arena"), t).unwrap());
    assert_eq!(why, RejectReason::NotAllowed, "a player opens no world");
    let (why, detail) = refused(world_command(&zs, &match2, logic, open("no-such"), t).unwrap());
    assert!(why == RejectReason::OutOfRange && detail.contains("no scene"), "{detail}");
    let a = world_command(&zs, &match2, logic, open("arena"), t).unwrap();
    let WorldOutcome::Opened { scene_hash, tick_hz } = a.outcome else { panic!("{a:?}") };
    assert_eq!(tick_hz, 64);
    assert_eq!(host.worlds().len(), 2);
    let (why, detail) = refused(world_command(&zs, &match2, logic, open("arena"), t).unwrap());
    assert!(why == RejectReason::OutOfRange && detail.contains("open already"), "{detail}");
    let (why, detail) =
        refused(world_command(&zs, &WorldId::new("arena-3").unwrap(), logic, open("arena"), t).unwrap());
    assert!(why == RejectReason::OutOfRange && detail.contains("at most 1"), "{detail}");

    // A player in the new match.
    let conn =
        Connection::open(&ConnectOptions::new(vec![endpoint.clone()], match2.clone(), ClientId(1))).expect("connects");
    let mut player = Session::new(SessionConfig::new(ClientId(1)));
    join(&conn, &mut player);
    assert_eq!(player.welcome().map(|w| w.scene_hash), Some(scene_hash));
    let avatar = player.avatar().expect("an avatar in the new world");
    player.input(vec![Action::SetVelocity { entity: avatar, velocity: [1.0, 0.0, 0.0] }], Instant::now()).unwrap();

    let close = WorldCommand::Close { next: Some(WorldId::new("arena").unwrap()), reason: "match over".into() };
    let (why, _) = refused(world_command(&zs, &match2, ClientId(1), close.clone(), t).unwrap());
    assert_eq!(why, RejectReason::NotAllowed, "a player closes no world");
    let a = world_command(&zs, &match2, logic, close, t).unwrap();
    let WorldOutcome::Closed { ticks } = a.outcome else { panic!("{a:?}") };
    assert!(ticks > 0);
    let by = Instant::now() + Duration::from_secs(3);
    while player.status() != Status::Closed {
        assert!(Instant::now() < by, "the player was not told: {:?}", player.status());
        conn.pump(&mut player, Instant::now()).unwrap();
        std::thread::sleep(Duration::from_millis(10));
    }
    let notice = player.closed().unwrap();
    assert_eq!((notice.next.as_ref().map(WorldId::as_str), notice.reason.as_str()), (Some("arena"), "match over"));
    assert_eq!(player.input(Vec::new(), Instant::now()), Err(InputError::Closed));
    assert_eq!(host.worlds(), vec![WorldId::new("arena").unwrap()]);
    // Closed, it may open again (the limit counts running worlds).
    let a = world_command(&zs, &match2, logic, open("arena"), t).unwrap();
    assert!(matches!(a.outcome, WorldOutcome::Opened { .. }), "{a:?}");
    conn.close();
    let _ = zs.close().wait();
    let mut host = host;
    assert_eq!(host.stop_all().len(), 2);
}
