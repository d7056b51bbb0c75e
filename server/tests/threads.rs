//! The thread count never changes a result: every bundled scene, a 20,000-sphere world and a
//! rollback stress run give identical state hashes and identical events, tick by tick, on one
//! thread and on pools of two and four (in the spirit of rapier's thread-count determinism
//! test). The small scenes run on pools that cut every loop as finely as the threads allow, so
//! each parallel stage joins pieces even where a real pool would run it inline; the large world
//! runs on an ordinary pool, whose thresholds it crosses. `.ci/run` also compares
//! `impact-server --offline --threads 1` against `--threads 2` on every bundled scene.

use impact_core::scene::Scene;
use impact_core::sim::{Plan, Pool, Stepper, TickOutput};
use impact_protocol::{ClientId, CollisionEvent};
use impact_server::offline::{self, InputScript};
use impact_server::rollback::{RollbackConfig, Session};

const SCENES: [&str; 11] =
    ["arena", "breakout", "bullets", "corridor", "hillside", "pile", "ramp", "stack", "standing", "terrain", "yard"];

/// The pools compared: one thread (no pool), two and four threads cut finely.
fn pools() -> Vec<(String, Pool)> {
    vec![
        ("1 thread".into(), Pool::sequential()),
        ("2 threads".into(), Pool::new(2).unwrap().cut_finely()),
        ("4 threads".into(), Pool::new(4).unwrap().cut_finely()),
    ]
}

/// `(state hash after each tick, every event)` of `ticks` ticks of a bundled scene with its
/// inputs script, if it has one.
fn run_scene(name: &str, pool: &Pool, ticks: u32) -> (Vec<u64>, Vec<CollisionEvent>) {
    let scene = Scene::load(&Scene::bundled_path(name)).unwrap();
    let script = Scene::bundled_path(name).with_extension("inputs.jsonl");
    let inputs = if script.exists() { offline::read_inputs(&script).unwrap() } else { InputScript::new() };
    let mut hashes = Vec::new();
    let mut events = Vec::new();
    // offline::run reports each event as it comes and calls back after every tick; the hash
    // per tick comes from stepping the same world alongside would double the work, so the
    // offline runner's final hash is checked here and the per-tick hashes below, without inputs.
    let report = offline::run(
        &scene,
        Plan::for_world(&scene.world),
        pool,
        ticks,
        &inputs,
        |e| {
            events.push(e.clone());
            Ok(())
        },
        |_| {},
    )
    .unwrap();
    hashes.push(report.state_hash);
    // Tick by tick, without inputs: the first tick that differs is named.
    let mut w = scene.world.clone();
    let mut st = Stepper::new(Plan::for_world(&w), false);
    st.set_pool(pool.clone());
    let mut out = TickOutput::default();
    for _ in 0..ticks {
        st.step(&mut w, &[], &mut out);
        hashes.push(w.state_hash());
    }
    (hashes, events)
}

#[test]
fn every_bundled_scene_is_identical_at_one_two_and_four_threads() {
    let pools = pools();
    for name in SCENES {
        let ticks = 240;
        let base = run_scene(name, &pools[0].1, ticks);
        assert!(!base.1.is_empty() || name == "standing", "{name}: no events, nothing compared");
        for (label, pool) in &pools[1..] {
            let other = run_scene(name, pool, ticks);
            assert_eq!(other.0[0], base.0[0], "{name}: the run with its inputs ends in another state on {label}");
            if let Some(t) = (1..base.0.len()).find(|&t| base.0[t] != other.0[t]) {
                panic!("{name}: on {label} the state first differs after tick {}", t - 1);
            }
            assert_eq!(other.1, base.1, "{name}: events differ on {label}");
        }
    }
}

/// 20,000 moving spheres (`impact-bench scale`'s scene at a fifth of its largest size): loops
/// long enough for an ordinary pool to cut them, as in production.
#[test]
fn a_large_world_is_identical_on_an_ordinary_pool() {
    let side = (8.0f64 * 20_000.0).cbrt();
    let text = format!(
        "[world]\nname = \"many\"\ntick_hz = 64\nmax_bodies = 100000\ndefault_response = \"bounce\"\nrestitution = 0.9\n\
         [[class]]\nname = \"ball\"\ngravity = false\nmax_speed_mps = 5.0\n\
         [[scatter]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = 0.5 }}\ncount = 20000\n\
         min = [0.0, 0.0, 0.0]\nmax = [{side}, {side}, {side}]\nspeed_mps = [0.0, 5.0]\nseed = 7\n"
    );
    let scene = Scene::parse(&text, "<many>").unwrap();
    let run = |pool: &Pool| {
        let mut w = scene.world.clone();
        let mut st = Stepper::new(Plan::for_world(&w), false);
        st.set_pool(pool.clone());
        let mut out = TickOutput::default();
        let mut trace = Vec::new();
        for _ in 0..40 {
            st.step(&mut w, &[], &mut out);
            trace.push((w.state_hash(), out.events.clone()));
        }
        trace
    };
    let one = run(&Pool::sequential());
    assert!(one.iter().map(|t| t.1.len()).sum::<usize>() > 1000, "a crowded world has many events");
    for threads in [2, 4] {
        let other = run(&Pool::new(threads).unwrap());
        for (t, (a, b)) in one.iter().zip(&other).enumerate() {
            assert_eq!(a.0, b.0, "{threads} threads: the state differs after tick {t}");
            assert_eq!(a.1, b.1, "{threads} threads: the events of tick {t} differ");
        }
    }
}

/// Depth-16 rollbacks every tick (the stability suite's rollback stress, each input arriving
/// 16 ticks late): re-simulation runs on the pool too, and every tick's provisional and
/// confirmed events, corrections and hash are the same at every thread count.
#[test]
fn rollback_stress_is_identical_at_one_two_and_four_threads() {
    let text = std::fs::read_to_string(Scene::bundled_path("arena")).unwrap().replace("count = 2000", "count = 300")
        + "\n[[body]]\nclass = \"player\"\nshape = { type = \"sphere\", radius_m = 0.5 }\nposition = [0.0, 10.0, 0.0]\nowner = 1\n";
    let scene = Scene::parse(&text, "<rollback>").unwrap();
    let b = &scene.world.bodies;
    let player = b.id[b.owner.iter().position(|o| *o == Some(ClientId(1))).unwrap()];
    let input = |t: u32| impact_server::stability::stress_input(player, t);
    let run = |pool: &Pool| {
        let mut cfg = RollbackConfig::for_world(&scene.world);
        cfg.window_ticks = 17;
        let mut s = Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg);
        s.set_pool(pool.clone());
        let mut trace = Vec::new();
        for t in 0..200 {
            if t >= 16 {
                s.submit(input(t - 16)).unwrap();
            }
            let adv = s.advance();
            trace.push(format!(
                "{} {} {:?} {:?} {:?}",
                s.world().state_hash(),
                adv.rollback_depth,
                adv.events,
                adv.corrections,
                adv.confirmed
            ));
        }
        assert!(s.stats.rollbacks > 150, "rollbacks happened: {}", s.stats.rollbacks);
        trace
    };
    let pools = pools();
    let base = run(&pools[0].1);
    for (label, pool) in &pools[1..] {
        let other = run(pool);
        if let Some(t) = (0..base.len()).find(|&t| base[t] != other[t]) {
            panic!("rollback stress: tick {t} differs on {label}:\n{}\n{}", base[t], other[t]);
        }
    }
}
