//! The input log's promises: a session that follows the log of another reaches the same state
//! hash after every tick, late inputs and lag-compensated shots included; a checkpoint restores
//! the complete state (and a different scene is refused); a recording replays to every hash,
//! and a tampered one is caught at the tick that changed.

use impact_core::scene::Scene;
use impact_core::sim::{Plan, Pool};
use impact_protocol::{Action, ClientId, ClientInput, EntityId, GameState, LogTick, ShapeSpec, Tick};
use impact_server::recording::{self, Recorder};
use impact_server::rollback::log::ConfirmedTick;
use impact_server::rollback::{RollbackConfig, Session};

mod common;
use common::{bat_input as bat, range};

fn new_session(scene: &Scene) -> Session {
    Session::new(scene.world.clone(), Plan::for_world(&scene.world), RollbackConfig::for_world(&scene.world))
}

/// The game-logic client of these tests.
const LOGIC: ClientId = ClientId(900);

/// Runs `scene` to `until` with inputs arriving at their `arrive` tick (late ones roll back),
/// and returns every tick's log entry, in order (the window's last ticks from `finish`).
fn run_logged(scene: &Scene, inputs: &[(u32, ClientInput)], until: u32) -> Vec<ConfirmedTick> {
    let mut s = new_session(scene);
    s.set_logic_clients([LOGIC]);
    let mut log = Vec::new();
    while s.now().0 < until {
        for (arrive, input) in inputs {
            if *arrive == s.now().0 {
                s.submit(input.clone()).unwrap();
            }
        }
        log.extend(s.advance().log);
    }
    log.extend(s.finish().into_iter().map(|(_, l)| l));
    log
}

/// Follows `log` from `s`'s present tick; returns the ticks whose hash differed.
fn follow(s: &mut Session, log: &[ConfirmedTick], scene: &Scene) -> Vec<u32> {
    let avatar = scene.avatar.as_ref().map(|a| (a.class, &a.shape));
    let mut differ = Vec::new();
    let from = s.now();
    for entry in log.iter().filter(|e| e.tick >= from) {
        // Through the wire form, as a standby receives it.
        let wire: LogTick = serde_json::from_str(&serde_json::to_string(&entry.clone().into_wire()).unwrap()).unwrap();
        let t = ConfirmedTick::from_wire(wire, avatar).unwrap();
        s.follow(t.tick, t.system, t.inputs).unwrap();
        s.advance();
        if s.world().state_hash() != t.state_hash {
            differ.push(t.tick.0);
        }
    }
    differ
}

/// Breakout with bat inputs arriving on time, early and up to 12 ticks late.
fn breakout_inputs() -> Vec<(u32, ClientInput)> {
    (0..60u32).map(|k| (10 + k * 5 + k % 13, bat(k, 10 + k * 5, (k % 7) as f64 - 3.0))).collect()
}

#[test]
fn a_follower_reaches_every_hash_of_a_run_with_late_inputs() {
    let scene = Scene::load(&Scene::bundled_path("breakout")).unwrap();
    let log = run_logged(&scene, &breakout_inputs(), 400);
    assert_eq!(log.len(), 400);
    assert!(log.iter().map(|l| l.inputs.len()).sum::<usize>() == 60);
    let mut f = new_session(&scene);
    assert_eq!(follow(&mut f, &log, &scene), Vec::<u32>::new());
    assert_eq!(f.now(), Tick(400));
}

#[test]
fn a_late_rewound_shot_is_followed_as_the_primary_cast_it() {
    // A shot for tick 106 looking at tick 100 (the target in the line of fire) arrives at tick
    // 121: by then the oldest world held is 105, so the server clamps the view there and misses.
    // Stepped on time, tick 106 could still look at tick 100 and would hit: only the logged
    // outcome keeps the follower equal.
    let scene = range();
    let shot = ClientInput {
        aim_tick: None,
        client: ClientId(1),
        seq: 1,
        tick: Tick(106),
        view_tick: Some(Tick(100)),
        actions: vec![Action::FireRay {
            shooter: EntityId(0),
            origin: [0.0, 0.0, 0.0],
            direction: [1.0, 0.0, 0.0],
            max_distance_m: 50.0,
        }],
    };
    let log = run_logged(&scene, &[(121, shot)], 200);
    let logged = &log[106].inputs[0];
    assert!(logged.rewound[0].clamped && logged.rewound[0].view_tick == Tick(105), "{:?}", logged.rewound);
    let mut f = new_session(&scene);
    assert_eq!(follow(&mut f, &log, &scene), Vec::<u32>::new());
    assert!(f.world().bodies.slot(EntityId(1)).is_some(), "the target survives, as on the primary");
}

#[test]
fn a_checkpoint_restores_the_complete_state() {
    let scene = Scene::load(&Scene::bundled_path("breakout")).unwrap();
    let inputs = breakout_inputs();
    // The primary, stopped at tick 150: its checkpoint is the state after its last confirmed tick.
    let mut p = new_session(&scene);
    let mut log = Vec::new();
    while p.now().0 < 150 {
        for (arrive, input) in &inputs {
            if *arrive == p.now().0 {
                p.submit(input.clone()).unwrap();
            }
        }
        log.extend(p.advance().log);
    }
    let c = p.checkpoint().unwrap();
    assert_eq!(c.tick.0, 150 - p.config().window_ticks);
    assert_eq!(c.clients.len(), 1, "client 1's replay window travels with it");
    let c: impact_protocol::Checkpoint = rmp_serde::from_slice(&rmp_serde::to_vec_named(&c).unwrap()).unwrap();
    let mut f = Session::restore(&scene.world, &c, Plan::for_world(&scene.world), p.config().clone()).unwrap();
    assert_eq!(f.now(), c.tick);
    assert_eq!(f.next_seq(ClientId(1)), p.next_seq(ClientId(1)));
    // The rest of the run, as the primary logs it, is followed bit for bit.
    let full = run_logged(&scene, &inputs, 400);
    assert_eq!(follow(&mut f, &full, &scene), Vec::<u32>::new());
    // Another scene's statics with this state: refused by the hash, not silently diverging.
    let other = Scene::load(&Scene::bundled_path("bullets")).unwrap();
    let e = Session::restore(&other.world, &c, Plan::for_world(&other.world), p.config().clone()).unwrap_err();
    assert!(e.contains("other settings") || e.contains("class") || e.contains("hash"), "{e}");
}

/// Game logic's commands (the ball teleported back into play, a second ball spawned, the bat
/// pushed and its score kept as game state), some arriving late: they roll back like inputs, the log marks them, and a follower
/// and a replay of the recording reach every hash without knowing who has the role.
#[test]
fn game_logic_commands_roll_back_log_and_replay_bit_for_bit() {
    let scene = Scene::load(&Scene::bundled_path("breakout")).unwrap();
    let ball = scene.world.bodies.id[scene.world.bodies.class.iter().position(|c| c.0 == 0).unwrap()];
    let command = |seq: u32, tick: u32, actions: Vec<Action>| ClientInput {
        aim_tick: None,
        view_tick: None,
        client: LOGIC,
        seq,
        tick: Tick(tick),
        actions,
    };
    let mut inputs = breakout_inputs();
    let back = Action::Teleport { entity: ball, position: [0.0, 2.0, 0.0], velocity: Some([3.0, 6.0, 0.0]) };
    let another = Action::Spawn {
        class: "ball".into(),
        shape: ShapeSpec::Sphere { radius_m: 0.25 },
        position: [1.0, 3.0, 0.0],
        velocity: [-4.0, 5.0, 0.0],
        owner: None,
    };
    let push = Action::ApplyImpulse { entity: EntityId(6), impulse: [0.0, 50.0, 0.0] };
    inputs.push((90, command(1, 80, vec![back.clone()]))); // 10 ticks late
    inputs.push((120, command(2, 120, vec![another])));
    let score = Action::SetState { entity: EntityId(6), values: GameState::from([("score", 1.0)]) };
    inputs.push((165, command(3, 160, vec![push, back, score]))); // 5 ticks late
    let log = run_logged(&scene, &inputs, 300);
    let marked: Vec<_> = log.iter().flat_map(|l| &l.inputs).filter(|i| i.logic).map(|i| i.seq).collect();
    // The score is in the world the log ends with (its hash covers it).
    let mut end = new_session(&scene);
    follow(&mut end, &log, &scene);
    let bat = end.world().bodies.slot(EntityId(6)).expect("the bat");
    assert_eq!(end.world().bodies.game[bat].get("score"), Some(1.0));
    assert_eq!(marked, vec![1, 2, 3], "every command logged, marked as game logic's");
    assert!(log.iter().flat_map(|l| &l.inputs).filter(|i| i.client != LOGIC).all(|i| !i.logic));
    // A follower that knows no logic client applies them as logged.
    let mut s = new_session(&scene);
    assert_eq!(follow(&mut s, &log, &scene), Vec::<u32>::new());

    let path = std::env::temp_dir().join(format!("impact-logic-recording-{}.jsonl", std::process::id()));
    let mut r = Recorder::create(&path, &scene).unwrap();
    for l in &log {
        r.write(&l.clone().into_wire());
    }
    r.flush().unwrap();
    let report = recording::replay(&scene, &path, &Pool::sequential(), |_| {}).unwrap();
    assert_eq!((report.ticks, report.matched, report.first_mismatch), (300, 300, None), "{report}");
    let _ = std::fs::remove_file(&path);
}

#[test]
fn a_recording_replays_and_a_tampered_one_is_caught_where_it_changed() {
    let scene = Scene::load(&Scene::bundled_path("breakout")).unwrap();
    let log = run_logged(&scene, &breakout_inputs(), 300);
    let dir = std::env::temp_dir();
    let path = dir.join(format!("impact-recording-test-{}.jsonl", std::process::id()));
    let mut r = Recorder::create(&path, &scene).unwrap();
    for l in &log {
        r.write(&l.clone().into_wire());
    }
    r.flush().unwrap();
    let report = recording::replay(&scene, &path, &Pool::sequential(), |_| {}).unwrap();
    assert_eq!((report.ticks, report.matched, report.first_mismatch), (300, 300, None));
    assert_eq!(report.inputs, log.iter().map(|l| l.inputs.len() as u64).sum::<u64>());

    // One input's velocity changed: the replay differs from that tick on, and says where.
    let text = std::fs::read_to_string(&path).unwrap();
    let tampered_tick = log.iter().find(|l| !l.inputs.is_empty()).unwrap().tick;
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let at = lines.iter().position(|l| l.contains(&format!("\"tick\":{},", tampered_tick.0))).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&lines[at]).unwrap();
    v["inputs"][0]["actions"][0]["velocity"][0] = serde_json::json!(0.25);
    lines[at] = v.to_string();
    std::fs::write(&path, lines.join("\n")).unwrap();
    let report = recording::replay(&scene, &path, &Pool::sequential(), |_| {}).unwrap();
    assert_eq!(report.first_mismatch.map(|m| m.0), Some(tampered_tick), "{report}");

    // A last line cut short (the server killed mid-write) is ignored, and said so.
    let cut = &text[..text.len() - 20];
    std::fs::write(&path, cut).unwrap();
    let report = recording::replay(&scene, &path, &Pool::sequential(), |_| {}).unwrap();
    assert!(report.truncated && report.first_mismatch.is_none() && report.ticks == 299, "{report}");

    // Another scene: refused before the first tick.
    let other = Scene::load(&Scene::bundled_path("bullets")).unwrap();
    let e = recording::replay(&other, &path, &Pool::sequential(), |_| {}).unwrap_err();
    assert!(e.contains("another scene"), "{e}");
    let _ = std::fs::remove_file(&path);
}

/// Recordings made by an earlier build replay bit for bit on this one, or are refused with the
/// reason: the arena (players joining and leaving, moving, pushing, firing rewound rays, spawning
/// every projectile shape, inputs arriving late) replays, 200 ticks, with the fixed defaults of
/// its time; the standing scene (players among 1,000 bodies resting under gravity, friction 0.5)
/// is refused, as friction now acts at impacts too. Both were written by the build of commit
/// d632698 (recording format 1), before the core became a crate of its own and the defaults
/// followed the scene. A change that moves a state hash, a default or the recording format fails
/// here; one that means to must say so to its users (CHANGELOG.md) and keep old recordings
/// replaying or refuse them with a reason.
#[test]
fn recordings_from_an_earlier_build_replay_or_are_refused_with_the_reason() {
    // cargo runs a test in its package's directory (a path built in would name the clone it was built in)
    let dir = std::path::Path::new("tests/recordings");
    let arena = dir.join("arena-d632698.jsonl");
    let scene = recording::scene_for(&Scene::bundled_path("arena"), &arena).unwrap();
    let report = recording::replay(&scene, &arena, &Pool::sequential(), |_| {}).unwrap();
    assert_eq!((report.ticks, report.matched, report.first_mismatch), (200, 200, None), "{report}");
    assert_eq!((report.inputs, report.system), (104, 4), "{report}");
    let e = recording::scene_for(&Scene::bundled_path("standing"), &dir.join("standing-d632698.jsonl")).unwrap_err();
    assert!(e.contains("before friction acted at impacts") && e.contains("friction 0.5"), "{e}");
}

/// A recording carries the `[world]` values it ran with: a build whose defaults differ (here, a
/// scene file that lost a key it had) replays it with the recorded values, and `replay` refuses
/// a scene loaded without them, naming the key.
#[test]
fn a_recording_replays_with_the_values_it_ran_with() {
    let dir = std::env::temp_dir().join(format!("impact-keys-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let tuned = dir.join("tuned.toml");
    let text = std::fs::read_to_string(Scene::bundled_path("pile")).unwrap().replace("count = 1000", "count = 60");
    std::fs::write(&tuned, text.replace("[world]\n", "[world]\ncontact_slop_m = 0.01\n")).unwrap();
    let scene = Scene::load(&tuned).unwrap();
    let log = run_logged(&scene, &[], 120);
    let rec = dir.join("tuned.jsonl");
    let mut r = Recorder::create(&rec, &scene).unwrap();
    for l in &log {
        r.write(&l.clone().into_wire());
    }
    r.flush().unwrap();
    // The same scene without the key: its default slop differs, the recording's is used.
    let plain = dir.join("plain.toml");
    std::fs::write(&plain, std::fs::read_to_string(&tuned).unwrap().replace("contact_slop_m = 0.01\n", "")).unwrap();
    let as_run = recording::scene_for(&plain, &rec).unwrap();
    assert_eq!(as_run.keys.contact_slop_m, 0.01);
    let report = recording::replay(&as_run, &rec, &Pool::sequential(), |_| {}).unwrap();
    assert_eq!((report.ticks, report.matched), (120, 120), "{report}");
    let e = recording::replay(&Scene::load(&plain).unwrap(), &rec, &Pool::sequential(), |_| {}).unwrap_err();
    assert!(e.contains("contact_slop_m: 0.01 vs 0.003"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
