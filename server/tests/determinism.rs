//! The core is a function of (world, inputs): the same scene and inputs give the same state hash
//! and the same events, bit for bit, whatever the broadphase, the order inputs arrived in, or
//! how many times it runs. A hash recorded here catches any change to results: if a change is
//! meant to alter results, run `cargo test -p impact-server --test determinism -- --nocapture`,
//! check the new behaviour, and update the hashes with the reason in the commit.

use impact_core::broadphase::BroadphaseKind;
use impact_core::scene::Scene;
use impact_core::sim::{Plan, Stepper, TickInput, TickOutput, World};
use impact_protocol::{Action, ClientId, CollisionEvent, EntityId};

fn run(
    scene: &Scene,
    plan: Plan,
    ticks: u32,
    inputs: &dyn Fn(u32) -> Vec<TickInput>,
) -> (u64, Vec<CollisionEvent>, World) {
    let mut w = scene.world.clone();
    let mut st = Stepper::new(plan, false);
    let mut out = TickOutput::default();
    let mut events = Vec::new();
    for _ in 0..ticks {
        let tick_inputs = inputs(w.tick.0);
        st.step(&mut w, &tick_inputs, &mut out);
        events.extend(out.events.iter().cloned());
    }
    (w.state_hash(), events, w)
}

fn none(_: u32) -> Vec<TickInput> {
    Vec::new()
}

#[test]
fn every_broadphase_gives_identical_results() {
    for name in ["arena", "breakout", "terrain", "bullets", "corridor"] {
        let scene = Scene::load(&Scene::bundled_path(name)).unwrap();
        let plan = Plan::for_world(&scene.world);
        let mut results = Vec::new();
        for kind in [BroadphaseKind::BruteForce, BroadphaseKind::SweepAndPrune, BroadphaseKind::Grid] {
            let (hash, events, _) = run(&scene, Plan { broadphase: kind, ..plan.clone() }, 200, &none);
            results.push((kind, hash, events));
        }
        for r in &results[1..] {
            assert_eq!(r.1, results[0].1, "{name}: {:?} and {:?} differ", r.0, results[0].0);
            assert_eq!(r.2, results[0].2, "{name}: events differ");
        }
    }
}

/// A pile is where order could leak in: its settle pass is Gauss-Seidel over the tick's pairs,
/// so it depends on their order, and sweep and prune's order depends on its history. The pairs
/// must reach it in one canonical order whatever the method.
#[test]
fn a_settling_pile_is_identical_under_every_broadphase() {
    let (scene, _) = impact_server::stability::pile_scene(150);
    let plan = Plan::for_world(&scene.world);
    let mut results = Vec::new();
    for kind in [BroadphaseKind::BruteForce, BroadphaseKind::SweepAndPrune, BroadphaseKind::Grid, BroadphaseKind::Bvh] {
        let (hash, events, _) = run(&scene, Plan { broadphase: kind, ..plan.clone() }, 400, &none);
        results.push((kind, hash, events));
    }
    for r in &results[1..] {
        assert_eq!(r.1, results[0].1, "pile: {:?} and {:?} differ", r.0, results[0].0);
        assert_eq!(r.2, results[0].2, "pile: events differ");
    }
}

#[test]
fn the_same_run_twice_is_bit_identical_and_matches_the_recorded_hash() {
    let scene = Scene::load(&Scene::bundled_path("breakout")).unwrap();
    let plan = Plan::for_world(&scene.world);
    let (h1, e1, _) = run(&scene, plan.clone(), 640, &none);
    let (h2, e2, _) = run(&scene, plan, 640, &none);
    assert_eq!(h1, h2);
    assert_eq!(e1, e2);
    assert!(!e1.is_empty());
    println!("breakout 640 ticks: hash {h1:016x}, {} events", e1.len());
    assert_eq!(h1, RECORDED_BREAKOUT_640, "results changed: see this file's header");
}

/// The state hash of `scenes/breakout.toml` after 640 ticks.
const RECORDED_BREAKOUT_640: u64 = 0x801a_2d5f_7e8f_987a;

#[test]
fn input_arrival_order_does_not_matter() {
    let scene = Scene::load(&Scene::bundled_path("corridor")).unwrap();
    let plan = Plan::for_world(&scene.world);
    let make = |reverse: bool| {
        move |tick: u32| {
            if tick % 16 != 3 {
                return Vec::new();
            }
            let mut v: Vec<TickInput> = (1..=3u32)
                .map(|c| {
                    TickInput::new(
                        ClientId(c),
                        tick,
                        vec![Action::SetVelocity {
                            entity: EntityId(6 + c),
                            velocity: [f64::from(c) - 2.0, 0.0, f64::from(tick % 5) - 2.0],
                        }],
                    )
                })
                .collect();
            if reverse {
                v.reverse();
            }
            v
        }
    };
    let (h1, e1, _) = run(&scene, plan.clone(), 300, &make(false));
    let (h2, e2, _) = run(&scene, plan, 300, &make(true));
    assert_eq!(h1, h2);
    assert_eq!(e1, e2);
}

#[test]
fn a_changed_input_changes_the_hash() {
    // The negative control: the hash is not blind to what happened.
    let scene = Scene::load(&Scene::bundled_path("breakout")).unwrap();
    let plan = Plan::for_world(&scene.world);
    let nudge = |tick: u32| {
        if tick == 10 {
            vec![TickInput::new(
                ClientId(1),
                1,
                vec![Action::SetVelocity { entity: EntityId(6), velocity: [-4.0, 0.0, 0.0] }],
            )]
        } else {
            Vec::new()
        }
    };
    let (h1, _, _) = run(&scene, plan.clone(), 100, &none);
    let (h2, _, _) = run(&scene, plan, 100, &nudge);
    assert_ne!(h1, h2);
}
