//! The server over real Zenoh sessions on loopback: an input becomes an acknowledged change and
//! events; a late input becomes a correction; malformed, oversized and foreign inputs get the
//! right rejection while other clients are still served; a client that leaves loses its avatar;
//! a subscriber that stops reading does not slow the tick; state and history queries answer.
//! Every wait is bounded, so a broken feature fails the test instead of hanging it.

mod common;

use common::*;
use impact_core::scene::Scene;
use impact_protocol::{
    Action, ClientId, ClientInput, Encoding, EntityId, Phase, RejectReason, ServerMessage, Tick, WorldId,
};
use std::time::{Duration, Instant};
use zenoh::Wait;

fn arena() -> Scene {
    Scene::load(&Scene::bundled_path("arena")).unwrap()
}

fn welcome(inbox: &Inbox) -> (EntityId, Tick) {
    inbox
        .wait_for(Duration::from_secs(10), |m| match m {
            ServerMessage::Welcome(w) => Some((w.avatar.expect("arena spawns avatars"), w.tick)),
            _ => None,
        })
        .expect("welcome with an avatar")
}

#[test]
fn an_input_is_acknowledged_and_moves_the_avatar() {
    let (server, ep) = server(arena(), |_| {});
    let s = client(&ep);
    let world = WorldId::new("arena").unwrap();
    let me = ClientId(7);
    let ack = Inbox::new(&s, impact_protocol::keys::CLIENT_ACK.key(&world, Some(me)));
    let _token = join(&s, &world, me);
    let (avatar, tick) = welcome(&ack);
    let input = ClientInput {
        aim_tick: None,
        view_tick: None,
        client: me,
        seq: 1,
        tick: Tick(tick.0 + 1),
        actions: vec![Action::SetVelocity { entity: avatar, velocity: [3.0, 0.0, 0.0] }],
    };
    send(&s, &world, &input, Encoding::Json);
    let applied = ack
        .wait_for(Duration::from_secs(5), |m| match m {
            ServerMessage::Ack(a) if a.seq == 1 => Some(a.applied_tick),
            ServerMessage::Reject(r) if r.seq == Some(1) => panic!("rejected: {r:?}"),
            _ => None,
        })
        .expect("ack");
    assert_eq!(applied, Tick(tick.0 + 1));
    // The world at the start of the next tick has the avatar moving at the velocity set, unless
    // it collided during that very tick (then the history shows an event for it).
    std::thread::sleep(Duration::from_millis(200));
    let state = impact_protocol::keys::QUERY_STATE.key(&world, None);
    let snap = match query(&s, state, &format!("tick={}", applied.0 + 1)) {
        Some(ServerMessage::Snapshot(s)) => s,
        other => panic!("state query: {other:?}"),
    };
    let body = snap.bodies.iter().find(|b| b.entity == avatar).expect("avatar in the snapshot");
    assert_eq!(body.owner, Some(me));
    let collided =
        match query(&s, impact_protocol::keys::QUERY_HISTORY.key(&world, None), &format!("from={0};to={0}", applied.0))
        {
            Some(ServerMessage::History(h)) => h.events.iter().any(|e| e.a == avatar || e.b == avatar),
            other => panic!("history query: {other:?}"),
        };
    assert!(collided || body.velocity == [3.0, 0.0, 0.0], "{body:?}");
    drop(server);
}

#[test]
fn a_late_shot_becomes_a_correction_of_the_past() {
    let text = r#"
[world]
name = "range"
rollback_ms = 1000
default_response = "trigger"
[[class]]
name = "shooter"
gravity = false
[[class]]
name = "target"
gravity = false
[[body]]
class = "shooter"
shape = { type = "sphere", radius_m = 0.3 }
position = [0.0, 0.0, 0.0]
owner = 1
[[body]]
class = "target"
shape = { type = "sphere", radius_m = 2.0 }
position = [20.0, 0.0, -12.5]
velocity = [0.0, 0.0, 8.0]
"#;
    let scene = Scene::parse(text, "<range>").unwrap();
    let (server, ep) = server(scene, |_| {});
    let s = client(&ep);
    let world = WorldId::new("range").unwrap();
    let me = ClientId(1);
    let ack = Inbox::new(&s, impact_protocol::keys::CLIENT_ACK.key(&world, Some(me)));
    let corrections = Inbox::new(&s, impact_protocol::keys::CORRECTIONS.key(&world, None));
    let _token = join(&s, &world, me);
    let (start_tick, at) = ack
        .wait_for(Duration::from_secs(10), |m| match m {
            ServerMessage::Welcome(w) => Some((w.tick, Instant::now())),
            _ => None,
        })
        .expect("welcome");
    // The target is in the line of fire for ticks 84..116; wait until the server is past that
    // (tick ~135), then fire a shot stamped with tick 100.
    let wait_ticks = 135u32.saturating_sub(start_tick.0);
    let target_time = at + Duration::from_secs_f64(f64::from(wait_ticks) / 64.0);
    std::thread::sleep(target_time.saturating_duration_since(Instant::now()));
    let shot = ClientInput {
        aim_tick: None,
        view_tick: None,
        client: me,
        seq: 1,
        tick: Tick(100),
        actions: vec![Action::FireRay {
            shooter: EntityId(0),
            origin: [0.0, 0.0, 0.0],
            direction: [1.0, 0.0, 0.0],
            max_distance_m: 50.0,
        }],
    };
    send(&s, &world, &shot, Encoding::MsgPack);
    let ray = ack
        .wait_for(Duration::from_secs(5), |m| match m {
            ServerMessage::RayResult(r) => Some(r.clone()),
            ServerMessage::Reject(r) => panic!("rejected: {r:?}"),
            _ => None,
        })
        .expect("ray result");
    assert_eq!(ray.tick, Tick(100));
    assert_eq!(ray.hit.map(|h| h.entity), Some(EntityId(1)), "lag-compensated: the target was there at tick 100");
    let added = corrections
        .wait_for(Duration::from_secs(5), |m| match m {
            ServerMessage::Corrections(c) if c.tick == Tick(100) => {
                c.added.iter().find(|e| e.phase == Phase::Hit).cloned()
            }
            _ => None,
        })
        .expect("a correction of tick 100 adding the hit");
    assert_eq!((added.a, added.b), (EntityId(0), EntityId(1)));
    drop(server);
}

#[test]
fn bad_inputs_are_rejected_with_reasons_and_others_are_still_served() {
    let (server, ep) = server(arena(), |_| {});
    let s = client(&ep);
    let world = WorldId::new("arena").unwrap();
    let (bad, good) = (ClientId(21), ClientId(22));
    let bad_ack = Inbox::new(&s, impact_protocol::keys::CLIENT_ACK.key(&world, Some(bad)));
    let good_ack = Inbox::new(&s, impact_protocol::keys::CLIENT_ACK.key(&world, Some(good)));
    let _t1 = join(&s, &world, bad);
    let _t2 = join(&s, &world, good);
    let (bad_avatar, tick) = welcome(&bad_ack);
    let (good_avatar, _) = welcome(&good_ack);
    // Every reject as (reason, seq, tick, detail).
    let next_reject = |inbox: &Inbox| {
        inbox
            .wait_for(Duration::from_secs(5), |m| match m {
                ServerMessage::Reject(r) => Some((r.reason, r.seq, r.tick, r.detail.clone())),
                _ => None,
            })
            .expect("a reject")
    };
    let input = |seq: u32, actions: Vec<Action>| ClientInput {
        aim_tick: None,
        view_tick: None,
        client: bad,
        seq,
        tick,
        actions,
    };
    let msgpack = |i: &ClientInput| rmp_serde::to_vec_named(&impact_protocol::ClientMessage::Input(i.clone())).unwrap();
    // Garbage bytes: nothing to match, so the documented nil placeholder.
    send_raw(&s, &world, bad, vec![0xc1, 0xff, 0x00, 0x13], Encoding::MsgPack);
    let (reason, seq, t, _) = next_reject(&bad_ack);
    assert_eq!((reason, seq, t), (RejectReason::Malformed, None, None));
    // Oversized: refused before a byte is read.
    send_raw(&s, &world, bad, vec![b' '; 5000], Encoding::Json);
    let (reason, seq, t, _) = next_reject(&bad_ack);
    assert_eq!((reason, seq, t), (RejectReason::TooLarge, None, None));
    // Values refused after decoding carry the input's own seq and tick.
    let nan = input(3, vec![Action::SetVelocity { entity: bad_avatar, velocity: [f64::NAN, 0.0, 0.0] }]);
    send_raw(&s, &world, bad, msgpack(&nan), Encoding::MsgPack);
    let (reason, seq, t, detail) = next_reject(&bad_ack);
    assert_eq!((reason, seq, t), (RejectReason::InvalidNumber, Some(3), Some(tick)), "{detail}");
    let ray = Action::FireRay { shooter: bad_avatar, origin: [0.0; 3], direction: [0.0; 3], max_distance_m: 10.0 };
    send_raw(&s, &world, bad, msgpack(&input(4, vec![ray])), Encoding::MsgPack);
    let (reason, seq, t, detail) = next_reject(&bad_ack);
    assert_eq!((reason, seq, t), (RejectReason::OutOfRange, Some(4), Some(tick)), "{detail}");
    assert!(detail.contains("direction"), "{detail}");
    let still = Action::SetVelocity { entity: bad_avatar, velocity: [0.0; 3] };
    send_raw(&s, &world, bad, msgpack(&input(5, vec![still; 17])), Encoding::MsgPack);
    let (reason, seq, t, detail) = next_reject(&bad_ack);
    assert_eq!((reason, seq, t), (RejectReason::TooLarge, Some(5), Some(tick)), "{detail}");
    assert!(detail.contains("17 actions") && detail.contains("16"), "{detail}");
    // `move` drives characters only; the arena's avatars are not: refused by class, typed.
    let walk = Action::Move { entity: bad_avatar, direction: [1.0, 0.0, 0.0], jump: true };
    send_raw(&s, &world, bad, msgpack(&input(9, vec![walk])), Encoding::MsgPack);
    let (reason, seq, t, detail) = next_reject(&bad_ack);
    assert_eq!((reason, seq, t), (RejectReason::NotAllowed, Some(9), Some(tick)), "{detail}");
    // Malformed further in (an action type that does not exist): still matched by its header.
    let unknown_action = serde_json::json!({"type": "input", "client": bad.0, "seq": 6, "tick": tick.0,
        "actions": [{"type": "teleport", "entity": bad_avatar.0}]});
    send_raw(&s, &world, bad, serde_json::to_vec(&unknown_action).unwrap(), Encoding::Json);
    let (reason, seq, t, detail) = next_reject(&bad_ack);
    assert_eq!((reason, seq, t), (RejectReason::Malformed, Some(6), Some(tick)), "{detail}");
    // Someone else's avatar.
    let foreign = ClientInput {
        aim_tick: None,
        view_tick: None,
        client: bad,
        seq: 7,
        tick: Tick(tick.0 + 2),
        actions: vec![Action::SetVelocity { entity: good_avatar, velocity: [1.0, 0.0, 0.0] }],
    };
    send(&s, &world, &foreign, Encoding::MsgPack);
    assert_eq!(next_reject(&bad_ack).0, RejectReason::NotOwner);
    // Claiming to be another client on one's own key.
    let spoof =
        ClientInput { aim_tick: None, view_tick: None, client: good, seq: 8, tick: Tick(tick.0 + 2), actions: vec![] };
    let bytes = impact_protocol::encode(&impact_protocol::ClientMessage::Input(spoof), Encoding::MsgPack).unwrap();
    send_raw(&s, &world, bad, bytes, Encoding::MsgPack);
    let (reason, seq, _, _) = next_reject(&bad_ack);
    assert_eq!((reason, seq), (RejectReason::NotOwner, Some(8)));
    // The other client is served throughout.
    let fine = ClientInput {
        aim_tick: None,
        view_tick: None,
        client: good,
        seq: 1,
        tick: Tick(tick.0 + 3),
        actions: vec![Action::SetVelocity { entity: good_avatar, velocity: [0.0, 1.0, 0.0] }],
    };
    send(&s, &world, &fine, Encoding::MsgPack);
    assert!(good_ack
        .wait_for(Duration::from_secs(5), |m| matches!(m, ServerMessage::Ack(a) if a.seq == 1).then_some(()))
        .is_some());
    let summary = server.stop();
    assert!(summary.inputs_accepted >= 1);
    assert!(summary.inputs_rejected.get("malformed").copied().unwrap_or(0) >= 1, "{summary}");
}

/// Two clients leave a moment apart: each avatar goes once its own grace ends (the server
/// looks for ended graces only from the earliest one due, so the later one must still be found).
#[test]
fn a_client_that_leaves_loses_its_avatar() {
    let (server, ep) = server(arena(), |o| o.grace_ticks = 16);
    let s = client(&ep);
    let world = WorldId::new("arena").unwrap();
    let mut players = Vec::new();
    for me in [ClientId(31), ClientId(32)] {
        let ack = Inbox::new(&s, impact_protocol::keys::CLIENT_ACK.key(&world, Some(me)));
        let token = join(&s, &world, me);
        let (avatar, _) = welcome(&ack);
        players.push((avatar, token));
    }
    let has_avatar =
        |s: &zenoh::Session, avatar: EntityId| match query(s, impact_protocol::keys::QUERY_STATE.key(&world, None), "")
        {
            Some(ServerMessage::Snapshot(snap)) => snap.bodies.iter().any(|b| b.entity == avatar),
            other => panic!("state query: {other:?}"),
        };
    let (second, second_token) = players.pop().unwrap();
    let (first, first_token) = players.pop().unwrap();
    assert!(has_avatar(&s, first) && has_avatar(&s, second));
    drop(first_token);
    // Half the grace (16 ticks, 250 ms) later, the second leaves too.
    std::thread::sleep(Duration::from_millis(125));
    drop(second_token);
    let end = Instant::now() + Duration::from_secs(5);
    for avatar in [first, second] {
        while has_avatar(&s, avatar) {
            assert!(Instant::now() < end, "avatar {avatar} outlived its client");
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    drop(server);
}

#[test]
fn a_stalled_subscriber_does_not_slow_the_tick() {
    let (mut server, ep) = server(arena(), |o| o.max_ticks = Some(192));
    let s = client(&ep);
    let world = WorldId::new("arena").unwrap();
    // A subscriber to everything that never returns from its callback.
    let _stuck = s
        .declare_subscriber(format!("impact/v1/{}/**", world))
        .callback(|_| std::thread::sleep(Duration::from_secs(3600)))
        .wait();
    let summary = server.join();
    assert_eq!(summary.ticks, 192);
    // 192 ticks at 64 Hz is 3 s: the ticks kept their schedule (shutdown, which waits for zenoh
    // to close a link to a peer that stopped reading, is not part of it).
    assert!(summary.run_s < 3.0 + 1.0, "192 ticks took {:.2} s", summary.run_s);
    assert!(summary.tick_ms_p99 < 1000.0 / 64.0, "{summary}");
}

#[test]
fn state_and_history_queries_answer() {
    let (server, ep) = server(arena(), |_| {});
    let s = client(&ep);
    let world = WorldId::new("arena").unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let now = match query(&s, impact_protocol::keys::QUERY_STATE.key(&world, None), "") {
        Some(ServerMessage::Snapshot(snap)) => snap.tick,
        other => panic!("{other:?}"),
    };
    assert!(now.0 > 10);
    let past = Tick(now.0 - 5);
    match query(&s, impact_protocol::keys::QUERY_STATE.key(&world, None), &format!("tick={}", past.0)) {
        Some(ServerMessage::Snapshot(snap)) => {
            assert_eq!(snap.tick, past);
            assert_eq!(snap.bodies.len(), 2000);
        }
        other => panic!("{other:?}"),
    }
    match query(&s, impact_protocol::keys::QUERY_STATE.key(&world, None), "tick=1") {
        Some(ServerMessage::QueryError(e)) => assert!(e.detail.contains("outside the history"), "{e:?}"),
        other => panic!("{other:?}"),
    }
    match query(
        &s,
        impact_protocol::keys::QUERY_HISTORY.key(&world, None),
        &format!("from={};to={}", past.0, now.0 - 1),
    ) {
        Some(ServerMessage::History(h)) => {
            assert_eq!((h.from, h.to), (past, Tick(now.0 - 1)));
            assert!(h.events.iter().all(|e| e.tick >= past && e.tick < now));
            assert!(!h.events.is_empty(), "2000 bouncing balls make events every tick");
        }
        other => panic!("{other:?}"),
    }
    // Ticks that left the window are an error, not an empty history.
    match query(&s, impact_protocol::keys::QUERY_HISTORY.key(&world, None), "from=1;to=2") {
        Some(ServerMessage::QueryError(e)) => assert!(e.detail.contains("not all in the history"), "{e:?}"),
        other => panic!("{other:?}"),
    }
    drop(server);
}

/// Both timing modes end to end (PROTOCOL.md, "Timing"): clients that run ahead by the lead
/// their acks recommend get their inputs in before their tick (arrival margin >= 0, almost no
/// late input), clients that stamp what they see are a round trip late every time and rolled
/// back; in both, every delivered input is answered and every client's view equals the confirmed
/// stream.
#[test]
fn ahead_clients_arrive_on_time_behind_clients_are_rolled_back_and_both_see_the_truth() {
    use impact_client::netsim::Link;
    use impact_client_sim::load::{self, Behaviour, LoadConfig};
    use impact_client_sim::timing::Timing;
    for (timing, first) in [(Timing::Ahead, 100), (Timing::Behind, 200)] {
        let (server, ep) = server(arena(), |_| {});
        let link = Link { latency: Duration::from_millis(40), jitter: Duration::from_millis(5), loss: 0.0 };
        let cfg = LoadConfig {
            mode: Default::default(),
            connect: vec![ep],
            zenoh_config: None,
            world: WorldId::new("arena").unwrap(),
            clients: 20,
            first_client: first,
            sessions: 1,
            users: None,
            duration: Duration::from_secs(4),
            uplink: link,
            downlink: link,
            behaviour: Behaviour::Mixed,
            timing,
            input_hz: 10.0,
            encoding: Encoding::MsgPack,
            seed: 3,
            settle: Duration::from_millis(1500),
            faults: Default::default(),
            state: false,
            predict: 0,
            scene: None,
            progress: false,
        };
        let r = load::run(&cfg).expect("load runs");
        assert_eq!(r.clients_welcomed, 20, "{timing:?}");
        assert!(r.acks > 400, "{timing:?}: {} acks", r.acks);
        assert_eq!(r.inputs_unanswered, 0, "{timing:?}");
        assert!(r.views_matched > 0 && r.views_mismatched == 0, "{timing:?}: {r}");
        match timing {
            Timing::Ahead => {
                assert!(r.margin_ticks_p50 >= 0, "{r}");
                // Only each client's first input or two go out before a lead is known.
                assert!(r.rollbacks_caused * 10 < r.acks, "{r}");
            }
            Timing::Behind => {
                assert!(r.margin_ticks_p99 < 0, "{r}");
                assert_eq!(r.rollbacks_caused, r.acks, "every behind input is late: {r}");
            }
        }
        drop(server);
    }
}
