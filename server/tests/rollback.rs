//! Rollback's promises: an input that arrives late gives exactly the outcome it would have had
//! on time (state hash and confirmed events, bit for bit); the window's edges refuse or clamp
//! with the right reason; a client that applies events then corrections ends with exactly the
//! confirmed stream; hitscan is judged at the shooter's tick; memory stays fixed over a long run;
//! and the self-check catches a planted non-determinism.

use impact_core::scene::Scene;
use impact_core::sim::{Plan, Pool, TickInput};
use impact_protocol::{
    Action, ClientId, ClientInput, CollisionEvent, EntityId, EventBatch, EventKey, Phase, RejectReason, Tick,
};
use impact_server::rollback::{RollbackConfig, Session, StalePolicy};
use std::collections::BTreeMap;

mod common;
use common::{bat_input, range};

fn session(name: &str, cfg: impl FnOnce(&mut RollbackConfig)) -> Session {
    let scene = Scene::load(&Scene::bundled_path(name)).unwrap();
    let mut c = RollbackConfig::for_world(&scene.world);
    cfg(&mut c);
    Session::new(scene.world.clone(), Plan::for_world(&scene.world), c)
}

/// Runs `s` to `until`, submitting each input when the session reaches its `arrive` tick, and
/// returns the confirmed batches and the final state hash.
fn run(mut s: Session, inputs: &[(u32, ClientInput)], until: u32) -> (Vec<EventBatch>, u64) {
    let mut confirmed = Vec::new();
    while s.now().0 < until {
        for (arrive, input) in inputs {
            if *arrive == s.now().0 {
                s.submit(input.clone()).unwrap();
            }
        }
        if let Some(c) = s.advance().confirmed {
            confirmed.push(c);
        }
    }
    (confirmed, s.world().state_hash())
}

#[test]
fn a_late_input_ends_exactly_as_if_it_had_been_on_time() {
    let inputs_on_time = [(40, bat_input(1, 40, -5.0)), (90, bat_input(2, 90, 3.0))];
    // The same inputs stamped with the same ticks, arriving 6 ticks late.
    let inputs_late = [(46, bat_input(1, 40, -5.0)), (96, bat_input(2, 90, 3.0))];
    let (c1, h1) = run(session("breakout", |_| {}), &inputs_on_time, 400);
    let (c2, h2) = run(session("breakout", |_| {}), &inputs_late, 400);
    assert_eq!(h1, h2, "final state differs");
    assert_eq!(c1.len(), c2.len());
    for (a, b) in c1.iter().zip(&c2) {
        assert_eq!(a.tick, b.tick);
        let strip = |v: &[CollisionEvent]| {
            v.iter().map(|e| (e.key(), e.toi, e.point, e.normal, e.response)).collect::<Vec<_>>()
        };
        assert_eq!(strip(&a.events), strip(&b.events), "confirmed events of tick {} differ", a.tick);
    }
    // And the inputs mattered: without them the outcome is different.
    let (_, h0) = run(session("breakout", |_| {}), &[], 400);
    assert_ne!(h0, h1);
}

#[test]
fn window_edges_stale_clamp_future_duplicate() {
    let mut s = session("breakout", |c| c.window_ticks = 16);
    for _ in 0..40 {
        s.advance();
    }
    assert_eq!(s.now(), Tick(40));
    assert_eq!(s.oldest_accepted(), Tick(24));
    let stale = s.submit(bat_input(1, 23, 1.0)).unwrap_err();
    assert_eq!(stale.reason, RejectReason::Stale);
    assert_eq!(stale.oldest_tick, Some(Tick(24)));
    assert_eq!(s.submit(bat_input(2, 24, 1.0)), Ok(Tick(24)), "the oldest tick in the window is accepted");
    let future = s.submit(bat_input(3, 40 + 9, 1.0)).unwrap_err();
    assert_eq!(future.reason, RejectReason::Future);
    assert_eq!(future.newest_tick, Some(Tick(48)));
    assert_eq!(s.submit(bat_input(4, 48, 1.0)), Ok(Tick(48)));
    assert_eq!(s.submit(bat_input(2, 30, 1.0)).unwrap_err().reason, RejectReason::Duplicate);
    let not_owner = ClientInput { aim_tick: None, view_tick: None, client: ClientId(9), ..bat_input(5, 35, 1.0) };
    assert_eq!(s.submit(not_owner).unwrap_err().reason, RejectReason::NotOwner);
    let too_fast = bat_input(6, 35, 1000.0);
    assert_eq!(s.submit(too_fast).unwrap_err().reason, RejectReason::OutOfRange);
    // A seq is a nonce for the client's whole life, not just the rollback window: replayed with a
    // fresh tick long after its own tick was confirmed, it is still a duplicate.
    for _ in 0..100 {
        s.advance();
    }
    let replayed = s.submit(bat_input(2, s.now().0, 1.0)).unwrap_err();
    assert_eq!(replayed.reason, RejectReason::Duplicate, "{}", replayed.detail);
    assert_eq!(s.next_seq(ClientId(1)), 5);
    s.forget_client(ClientId(1));
    assert_eq!(s.next_seq(ClientId(1)), 0);
    assert_eq!(s.submit(bat_input(2, s.now().0, 1.0)), Ok(s.now()), "a forgotten client starts afresh");

    let mut clamping = session("breakout", |c| {
        c.window_ticks = 16;
        c.stale = StalePolicy::Clamp;
    });
    for _ in 0..40 {
        clamping.advance();
    }
    assert_eq!(clamping.submit(bat_input(1, 3, 1.0)), Ok(Tick(24)), "clamped to the oldest tick");
    assert_eq!(clamping.advance().rollback_depth, 16);
}

/// A client whose seqs pass `u32::MAX` goes on at 1: its inputs of one tick apply in the order
/// it numbered them (the last velocity set wins, as it would with small seqs), a copy from
/// before the wrap is a duplicate, and the acks and the resume point count across the wrap.
#[test]
fn seqs_go_on_across_the_wrap() {
    let on_tick = |inputs: &[ClientInput]| {
        let mut s = session("breakout", |_| {});
        for _ in 0..40 {
            s.advance();
        }
        for i in inputs {
            assert_eq!(s.submit(i.clone()), Ok(Tick(41)), "seq {}", i.seq);
        }
        for _ in 0..20 {
            s.advance();
        }
        s
    };
    let last = |seq: u32| bat_input(seq, 41, -3.0);
    let wrapped = on_tick(&[bat_input(u32::MAX - 1, 41, 1.0), bat_input(u32::MAX, 41, 2.0), last(1)]);
    let small = on_tick(&[bat_input(7, 41, 1.0), bat_input(8, 41, 2.0), last(9)]);
    let alone = on_tick(&[last(1)]);
    assert_eq!(wrapped.world().state_hash(), small.world().state_hash(), "applied in the order numbered");
    assert_eq!(wrapped.world().state_hash(), alone.world().state_hash(), "the last velocity set wins");
    let mut s = wrapped;
    let copy = s.submit(bat_input(u32::MAX, s.now().0, 2.0)).unwrap_err();
    assert_eq!(copy.reason, RejectReason::Duplicate, "{}", copy.detail);
    assert_eq!(s.next_seq(ClientId(1)), 2, "seq 0 is skipped");
    // An ack of 2: 1 accepted, 0 never used, MAX and MAX - 1 accepted.
    assert_eq!(s.accepted_before(ClientId(1), 2), 0b1101);
}

/// A client's view: events as published, then corrections applied by identity.
#[derive(Default)]
struct ClientView {
    ticks: BTreeMap<Tick, BTreeMap<EventKey, CollisionEvent>>,
}

impl ClientView {
    fn events(&mut self, tick: Tick, events: &[CollisionEvent]) {
        let t = self.ticks.entry(tick).or_default();
        for e in events {
            t.insert(e.key(), e.clone());
        }
    }
    fn correct(&mut self, c: &impact_protocol::CorrectionBatch) {
        let t = self.ticks.entry(c.tick).or_default();
        for e in &c.retracted {
            assert!(t.remove(&e.key()).is_some(), "retracted an event the client never had: {e:?}");
        }
        for e in &c.amended {
            assert!(t.insert(e.key(), e.clone()).is_some(), "amended an event the client never had: {e:?}");
        }
        for e in &c.added {
            assert!(t.insert(e.key(), e.clone()).is_none(), "added an event the client already had: {e:?}");
        }
    }
}

#[test]
fn a_client_applying_events_then_corrections_ends_with_the_confirmed_stream() {
    // Randomised late inputs (a fixed-seed generator, so a failure reproduces).
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let mut s = session("breakout", |c| c.window_ticks = 24);
    let mut view = ClientView::default();
    let mut confirmed_count = 0;
    let mut corrections = 0;
    let mut seq = 0;
    for _ in 0..600 {
        let now = s.now().0;
        if now > 30 && next() % 3 == 0 {
            let late = 1 + (next() % 20) as u32;
            seq += 1;
            let vx = (next() % 11) as f64 - 5.0;
            s.submit(bat_input(seq, now - late, vx)).unwrap();
        }
        let adv = s.advance();
        view.events(adv.tick, &adv.events);
        for c in &adv.corrections {
            view.correct(c);
            corrections += 1;
        }
        if let Some(c) = adv.confirmed {
            let mine = view.ticks.remove(&c.tick).unwrap_or_default();
            let theirs: BTreeMap<_, _> = c.events.iter().map(|e| (e.key(), e)).collect();
            assert_eq!(
                mine.len(),
                theirs.len(),
                "tick {}: client has {} events, confirmed {}",
                c.tick,
                mine.len(),
                theirs.len()
            );
            for (k, e) in &mine {
                let f = theirs.get(k).unwrap_or_else(|| panic!("tick {}: client has {k:?}, not confirmed", c.tick));
                assert!(!impact_server::rollback::reconcile::differs(e, f), "tick {}: {e:?} != {f:?}", c.tick);
            }
            confirmed_count += 1;
        }
    }
    assert!(confirmed_count > 500);
    assert!(corrections > 10, "the run must exercise corrections (got {corrections})");
}

/// A session of the range, advanced to tick `now`.
fn range_at(now: u32) -> (Scene, Session) {
    let scene = range();
    let mut s =
        Session::new(scene.world.clone(), Plan::for_world(&scene.world), RollbackConfig::for_world(&scene.world));
    for _ in 0..now {
        s.advance();
    }
    (scene, s)
}

/// The shooter's ray along +x, for `tick`, looking at `view` (None: behind mode).
fn shot(tick: u32, view: Option<u32>) -> ClientInput {
    ClientInput {
        aim_tick: None,
        client: ClientId(1),
        seq: tick,
        tick: Tick(tick),
        view_tick: view.map(Tick),
        actions: vec![Action::FireRay {
            shooter: EntityId(0),
            origin: [0.0, 0.0, 0.0],
            direction: [1.0, 0.0, 0.0],
            max_distance_m: 50.0,
        }],
    }
}

#[test]
fn hitscan_is_judged_at_the_shooters_tick() {
    // A target crossing the line of fire: at tick 100 it is in front of the shooter, by tick 106
    // it has moved on. A shot stamped 100 arriving at 106 must hit; the same shot stamped 106
    // must miss.
    let (_, mut s) = range_at(106);
    // The target's centre crosses z = 0 at t = 12.5 / 8 s = tick 100: at tick 106 it is 0.75 m past.
    s.submit(shot(100, None)).unwrap();
    let adv = s.advance();
    assert_eq!(adv.rollback_depth, 6);
    let ray = adv.rays.iter().find(|r| r.seq == 100).expect("the late shot is answered");
    assert_eq!(ray.tick, Tick(100));
    assert_eq!(ray.hit.as_ref().map(|h| h.entity), Some(EntityId(1)), "a shot at the shooter's tick hits");
    let added: Vec<_> = adv.corrections.iter().flat_map(|c| c.added.iter()).filter(|e| e.phase == Phase::Hit).collect();
    assert_eq!(added.len(), 1, "the hit is published as a correction of tick 100");
    assert_eq!(added[0].tick, Tick(100));
    // The target was destroyed in the past, so it is gone now.
    assert!(s.world().bodies.slot(EntityId(1)).is_none());

    let (_, mut s2) = range_at(106);
    s2.submit(shot(106, None)).unwrap();
    let adv = s2.advance();
    assert!(adv.rays[0].hit.is_none(), "the same shot at the present misses: {:?}", adv.rays[0]);
}

/// A shot that arrives early (ahead mode: stamped for a tick the server has not reached) is
/// answered when that tick is simulated, once, and a late one when its re-simulation runs; a
/// later re-simulation of the same ticks answers neither again. (Early shots went unanswered:
/// only inputs accepted since the last advance were answered.)
#[test]
fn every_shot_is_answered_once_early_or_late() {
    let (_, mut s) = range_at(106);
    s.submit(shot(108, Some(104))).unwrap();
    s.submit(shot(110, Some(106))).unwrap();
    let mut answered = Vec::new();
    for _ in 0..2 {
        answered.extend(s.advance().rays.iter().map(|r| r.seq));
    }
    assert_eq!(answered, Vec::<u32>::new(), "nothing before its tick");
    answered.extend(s.advance().rays.iter().map(|r| r.seq));
    assert_eq!(answered, [108]);
    s.submit(shot(105, None)).unwrap();
    answered.extend(s.advance().rays.iter().map(|r| r.seq));
    answered.extend(s.advance().rays.iter().map(|r| r.seq));
    assert_eq!(answered, [108, 105, 110], "the late one at its re-simulation, the early one at its tick");
    s.submit(shot(107, None)).unwrap();
    for _ in 0..4 {
        answered.extend(s.advance().rays.iter().map(|r| r.seq));
    }
    assert_eq!(answered, [108, 105, 110, 107], "re-simulating 108 and 110 answers neither again");
}

#[test]
fn a_rewound_shot_hits_where_the_shooter_saw_the_target_without_rolling_back() {
    // Ahead mode: the shot is for the present tick 106 (on time), but the shooter was looking at
    // tick 100, when the target stood in the line of fire. It has moved 0.75 m on since.
    let (scene, mut s) = range_at(106);
    s.submit(shot(106, Some(100))).unwrap();
    let adv = s.advance();
    assert_eq!(adv.rollback_depth, 0, "a rewound shot re-simulates nothing");
    let ray = &adv.rays[0];
    assert_eq!((ray.tick, ray.view_tick, ray.clamped), (Tick(106), Tick(100), false));
    let hit = ray.hit.as_ref().expect("hit where the shooter saw it");
    assert_eq!(hit.entity, EntityId(1));
    assert!(hit.point[2].abs() < 0.5, "the hit point is where the target was at tick 100: {:?}", hit.point);
    // Its consequences happen now: the hit event at tick 106, and the target destroyed then.
    let hits: Vec<_> = adv.events.iter().filter(|e| e.phase == Phase::Hit).collect();
    assert_eq!(hits.len(), 1);
    assert_eq!(hits[0].tick, Tick(106));
    assert!(adv.corrections.is_empty());
    assert!(s.world().bodies.slot(EntityId(1)).is_none(), "destroyed at the input's tick");
    // The offline run of the same input rewinds the same way and ends in the same state.
    let mut script = std::collections::BTreeMap::new();
    script.insert(
        106,
        vec![TickInput { view_tick: Some(Tick(100)), ..TickInput::new(ClientId(1), 106, shot(106, None).actions) }],
    );
    let offline = impact_server::offline::run(
        &scene,
        Plan::for_world(&scene.world),
        &Pool::sequential(),
        107,
        &script,
        |_| Ok(()),
        |_| {},
    )
    .unwrap();
    assert_eq!(offline.state_hash, s.world().state_hash());
}

/// A client draws other bodies an interpolation delay behind its view: a shot carries the tick
/// it aimed at, and is rewound there, not to the view tick (where the target has moved on).
#[test]
fn a_shot_is_rewound_to_the_tick_it_was_aimed_at() {
    let fire = |aim: Option<u32>| {
        let (_, mut s) = range_at(106);
        s.submit(ClientInput { aim_tick: aim.map(Tick), ..shot(106, Some(106)) }).unwrap();
        s.advance().rays[0].clone()
    };
    let aimed = fire(Some(100));
    assert_eq!(aimed.view_tick, Tick(100));
    assert_eq!(aimed.hit.map(|h| h.entity), Some(EntityId(1)), "hit where it was drawn at tick 100");
    assert!(fire(None).hit.is_none(), "at the view tick the target has moved on");
}

#[test]
fn a_shot_from_beyond_the_rewind_limit_is_clamped_and_says_so() {
    // max_rewind_ms defaults to the window (250 ms: 16 ticks). Looking at tick 80 from tick 106
    // is 26 ticks back: the ray is tested at tick 90 instead, when the target was still 1.25 m
    // short of the line of fire, and misses.
    let scene = range();
    assert_eq!(scene.world.config.max_rewind_ticks, 16);
    let mut s =
        Session::new(scene.world.clone(), Plan::for_world(&scene.world), RollbackConfig::for_world(&scene.world));
    for _ in 0..106 {
        s.advance();
    }
    s.submit(shot(106, Some(80))).unwrap();
    let adv = s.advance();
    let ray = &adv.rays[0];
    assert_eq!((ray.view_tick, ray.clamped), (Tick(90), true));
    assert!(ray.hit.is_none(), "{ray:?}");
    assert!(s.world().bodies.slot(EntityId(1)).is_some());
}

#[test]
fn ahead_inputs_on_time_never_roll_back_and_equal_the_offline_run() {
    // Every input is submitted before its tick (as an ahead client's arrive), 3 ticks early.
    let scene = Scene::load(&Scene::bundled_path("breakout")).unwrap();
    let mut s =
        Session::new(scene.world.clone(), Plan::for_world(&scene.world), RollbackConfig::for_world(&scene.world));
    let mut script: BTreeMap<u32, Vec<TickInput>> = BTreeMap::new();
    for k in 0..300u32 {
        if k % 5 == 0 {
            let input = ClientInput {
                aim_tick: None,
                view_tick: Some(Tick(k.saturating_sub(9))),
                ..bat_input(k + 1, k + 3, f64::from(k % 7) - 3.0)
            };
            script.entry(k + 3).or_default().push(TickInput {
                view_tick: input.view_tick,
                ..TickInput::new(input.client, input.seq, input.actions.clone())
            });
            assert_eq!(s.submit(input).unwrap(), Tick(k + 3));
        }
        s.advance();
    }
    assert_eq!(s.stats.rollbacks, 0, "on-time inputs need no rollback");
    let offline = impact_server::offline::run(
        &scene,
        Plan::for_world(&scene.world),
        &Pool::sequential(),
        300,
        &script,
        |_| Ok(()),
        |_| {},
    )
    .unwrap();
    assert_eq!(offline.state_hash, s.world().state_hash(), "the session ends where the offline run does");
}

#[test]
fn memory_is_fixed_over_a_long_run() {
    let mut s = session("corridor", |c| c.window_ticks = 16);
    let mut seq = 0;
    for k in 0..100_000u32 {
        let now = s.now().0;
        if k % 7 == 0 && now > 20 {
            seq += 1;
            let input = ClientInput {
                aim_tick: None,
                view_tick: None,
                client: ClientId(1),
                seq,
                tick: Tick(now - 5),
                actions: vec![Action::SetVelocity {
                    entity: EntityId(6),
                    velocity: [f64::from(k % 5) - 2.0, 0.0, 1.0],
                }],
            };
            let _ = s.submit(input);
        }
        s.advance();
        assert!(s.history().len() <= 16);
        assert!(s.replay_windows() <= 1, "at most one fixed-size replay window per client");
        assert!(s.future_ticks() <= 9);
    }
    assert!(s.stats.rollbacks > 10_000);
}

#[test]
fn the_self_check_finds_no_desync_and_catches_a_planted_one() {
    let mut s = session("arena", |c| c.self_check_ticks = 8);
    for _ in 0..64 {
        s.advance();
    }
    assert!(s.stats.self_checks > 40);
    assert_eq!(s.stats.desyncs, 0, "re-simulation must be bit-identical");
    s.plant_desync();
    for _ in 0..4 {
        s.advance();
    }
    assert!(s.stats.desyncs > 0, "a one-ulp change must be caught");
}

/// A past tick's ray index is built from its world once; a re-simulation that changes that world
/// (through `state_mut`) drops it, and the next shot looking there sees the world as it is now,
/// not as the index was built (the same bodies, moved: nothing but the index would tell).
#[test]
fn a_past_worlds_ray_index_follows_a_change_to_that_world() {
    use impact_core::sim::ray::Ray;
    use impact_core::sim::ray_index::cast_many_indexed;
    use impact_server::rollback::history::Frame;
    let (_, s) = range_at(106);
    let state = s.frame(Tick(100)).expect("tick 100 is in the history").state.clone();
    let mut frame = Frame::at(Tick(100), state);
    let ray = Ray { origin: glam::DVec3::ZERO, dir: glam::DVec3::X, max_m: 50.0, exclude: Some(EntityId(0)) };
    let cast = |f: &Frame| {
        let mut out = Vec::new();
        cast_many_indexed(&f.state, f.ray_index(), &[ray], &mut out);
        out[0].as_ref().map(|h| h.entity)
    };
    // At tick 100 the target stands in the line of fire. Moved out of it, and the index built
    // there; then back into it, each time as a re-simulation could leave it.
    let target = frame.state.bodies.slot(EntityId(1)).unwrap();
    frame.state_mut().bodies.pos[target].z += 10.0;
    assert_eq!(cast(&frame), None, "moved out of the line");
    frame.state_mut().bodies.pos[target].z -= 10.0;
    assert_eq!(cast(&frame), Some(EntityId(1)), "moved back in: the index files it where it is now");
}

/// A frame's path boxes, filed in a grid for selective re-simulation, are found where a
/// re-simulation last left them, not where the grid was built.
#[test]
fn a_frames_path_grid_follows_a_change_to_its_paths() {
    use impact_core::geometry::Aabb;
    use impact_server::rollback::history::Frame;
    let (_, s) = range_at(106);
    let mut frame: Frame = s.frame(Tick(100)).expect("tick 100 is in the history").clone();
    let unit = |x: f64| Aabb { min: glam::DVec3::new(x, 0.0, 0.0), max: glam::DVec3::new(x + 1.0, 1.0, 1.0) };
    // Three boxes to look at, and far ones so that one moved box is few enough to keep the grid.
    let mut paths = vec![unit(0.0), unit(5.0), unit(10.0)];
    paths.extend((0..40).map(|k| unit(100.0 + 3.0 * f64::from(k))));
    *frame.paths_mut() = paths;
    let near = |f: &Frame, x: f64| {
        let mut out = Vec::new();
        f.paths_overlapping(&unit(x), &mut out);
        out.sort_unstable();
        out
    };
    assert_eq!(near(&frame, 5.5), vec![1]);
    frame.paths_mut()[1] = unit(20.0);
    assert_eq!(near(&frame, 5.5), Vec::<u32>::new(), "moved away: the grid is built again");
    assert_eq!(near(&frame, 19.5), vec![1]);
    // One slot set while the grid stands: found where it is now, not where the grid has it.
    frame.set_path(2, unit(5.2));
    assert_eq!(frame.paths_moved, vec![2], "the grid is kept, the slot marked");
    assert_eq!(near(&frame, 10.5), Vec::<u32>::new(), "moved off: the grid's answer is stale");
    assert_eq!(near(&frame, 5.5), vec![2]);
    assert_eq!(near(&frame, 19.5), vec![1], "the others still answer from the grid");
    // Many moved: the grid is dropped and built again from where they all are.
    for k in 3..8 {
        frame.set_path(k, unit(200.0 + f64::from(k as u32)));
    }
    assert!(frame.paths_moved.is_empty());
    assert_eq!(near(&frame, 203.5), vec![3, 4]);
}
