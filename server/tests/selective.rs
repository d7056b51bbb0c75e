//! Selective re-simulation must be invisible: on random scenes with random late inputs, a
//! session that re-simulates only what a late input can reach publishes exactly what a session
//! that re-simulates everything publishes (events, corrections, confirmations, state hashes),
//! tick after tick. The run must also take the selective path often, or it proves nothing.

use impact_core::scene::Scene;
use impact_core::sim::Plan;
use impact_protocol::{Action, ClientId, ClientInput, EntityId, Tick};
use impact_server::rollback::{RollbackConfig, Session};
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

fn scene(seed: u64, balls: u32, owned: u32, gravity: bool) -> Scene {
    let mut text = format!(
        r#"
[world]
name = "sel"
gravity = [0.0, {g}, 0.0]
restitution = 0.9
[[class]]
name = "ball"
max_speed_mps = 30.0
[[class]]
name = "wall"
static = true
[[body]]
class = "wall"
shape = {{ type = "cuboid", half_extents_m = [21.0, 0.5, 21.0] }}
position = [0.0, -0.5, 0.0]
[[body]]
class = "wall"
shape = {{ type = "cuboid", half_extents_m = [0.5, 10.0, 21.0] }}
position = [-20.5, 10.0, 0.0]
[[body]]
class = "wall"
shape = {{ type = "cuboid", half_extents_m = [0.5, 10.0, 21.0] }}
position = [20.5, 10.0, 0.0]
"#,
        g = if gravity { -9.81 } else { 0.0 }
    );
    for k in 0..owned {
        text += &format!(
            "[[body]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = 0.5 }}\nposition = [{}, 2.0, {}]\nowner = 1\n",
            -15.0 + 6.0 * f64::from(k),
            -15.0
        );
    }
    text += &format!(
        "[[scatter]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = 0.5 }}\ncount = {balls}\nmin = [-19.0, 4.0, -19.0]\nmax = [19.0, 15.0, 19.0]\nspeed_mps = [0.0, 4.0]\nseed = {seed}\n"
    );
    Scene::parse(&text, "<sel>").unwrap()
}

fn pair(scene: &Scene) -> (Session, Session) {
    let mut cfg = RollbackConfig::for_world(&scene.world);
    cfg.window_ticks = 20;
    cfg.selective = false;
    let full = Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg.clone());
    cfg.selective = true;
    let sel = Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg);
    (full, sel)
}

/// A shot from owned ball `who` across the scene.
fn shot(who: u32, vx: f64, vz: f64) -> Action {
    Action::FireRay {
        shooter: EntityId(3 + who),
        origin: [-15.0 + 6.0 * f64::from(who), 2.0, -15.0],
        direction: [vx, 0.5, vz + 9.0],
        max_distance_m: 30.0,
    }
}

/// Submits `input` to both sessions: the same answer.
fn submit_both(full: &mut Session, sel: &mut Session, input: ClientInput) -> Result<(), TestCaseError> {
    let a = full.submit(input.clone());
    prop_assert_eq!(a, sel.submit(input));
    Ok(())
}

/// Advances both sessions: the same world, events, corrections, confirmations, ray answers and
/// confirmed log (which carries each shot's hit as cast).
fn advance_both(full: &mut Session, sel: &mut Session) -> Result<(), TestCaseError> {
    let now = full.now().0;
    let (a, b) = (full.advance(), sel.advance());
    prop_assert_eq!(full.world().state_hash(), sel.world().state_hash(), "tick {}", now);
    prop_assert_eq!(&a.events, &b.events);
    prop_assert_eq!(&a.corrections, &b.corrections, "corrections at tick {}", now);
    prop_assert_eq!(&a.confirmed, &b.confirmed);
    prop_assert_eq!(&a.rays, &b.rays);
    let logged = |l: &Option<impact_server::rollback::log::ConfirmedTick>| {
        l.as_ref().map(|l| (l.tick, l.state_hash, l.inputs.clone()))
    };
    prop_assert_eq!(logged(&a.log), logged(&b.log));
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    #[test]
    fn selective_equals_full(seed in 0u64..1000, balls in 20u32..120, gravity in any::<bool>(),
                             late in proptest::collection::vec((0u32..4, 1u32..19, -8.0..8.0f64, -8.0..8.0f64, any::<bool>()), 20..40)) {
        let sc = scene(seed, balls, 4, gravity);
        let (mut full, mut sel) = pair(&sc);
        let mut seq = 0;
        let mut late = late.into_iter();
        for step in 0..160u32 {
            let now = full.now().0;
            if now > 25 && step % 4 == 0 {
                if let Some((who, depth, vx, vz, shoot)) = late.next() {
                    seq += 1;
                    let action = if shoot {
                        shot(who, vx, vz)
                    } else {
                        Action::SetVelocity { entity: EntityId(3 + who), velocity: [vx, 0.0, vz] }
                    };
                    let input = ClientInput { aim_tick: None, view_tick: None, client: ClientId(1), seq, tick: Tick(now - depth), actions: vec![action] };
                    submit_both(&mut full, &mut sel, input)?;
                }
            }
            advance_both(&mut full, &mut sel)?;
        }
        prop_assert!(sel.stats.rollbacks > 0);
        prop_assert!(sel.stats.selective_rollbacks * 2 >= sel.stats.rollbacks, "selective ran {} of {} rollbacks", sel.stats.selective_rollbacks, sel.stats.rollbacks);
    }
}

/// A heap of balls under gravity with one owned ball at its bottom: every body touches the next.
fn heap() -> Scene {
    let text = r#"
[world]
name = "heap"
gravity = [0.0, -9.81, 0.0]
restitution = 0.1
[[class]]
name = "ball"
max_speed_mps = 30.0
[[class]]
name = "wall"
static = true
[[body]]
class = "wall"
shape = { type = "cuboid", half_extents_m = [21.0, 0.5, 21.0] }
position = [0.0, -0.5, 0.0]
[[body]]
class = "ball"
shape = { type = "sphere", radius_m = 0.5 }
position = [0.0, 0.5, 0.0]
owner = 1
[[scatter]]
class = "ball"
shape = { type = "sphere", radius_m = 0.5 }
count = 150
min = [-2.5, 1.5, -2.5]
max = [2.5, 14.0, 2.5]
speed_mps = [0.0, 1.0]
seed = 7
"#;
    Scene::parse(text, "<heap>").unwrap()
}

/// Where every late input reaches most of the world (a ball at the bottom of a heap, pushed in
/// the past), selective re-simulation cannot succeed; failed attempts must back off instead of
/// costing every rollback, and the results must still be the full re-simulation's.
#[test]
fn failed_attempts_back_off_and_change_nothing() {
    let sc = heap();
    let (mut full, mut sel) = pair(&sc);
    let mut seq = 0;
    for step in 0..220u32 {
        let now = full.now().0;
        if now > 60 {
            seq += 1;
            let push = Action::SetVelocity { entity: EntityId(1), velocity: [0.5 * f64::from(step % 3), 0.0, 0.5] };
            let input = ClientInput {
                aim_tick: None,
                view_tick: None,
                client: ClientId(1),
                seq,
                tick: Tick(now - 8),
                actions: vec![push],
            };
            submit_both(&mut full, &mut sel, input).unwrap();
        }
        advance_both(&mut full, &mut sel).unwrap();
    }
    let st = &sel.stats;
    assert!(st.rollbacks > 100, "{} rollbacks", st.rollbacks);
    assert_eq!(st.selective_rollbacks, 0, "a push at the bottom of a heap reaches all of it");
    assert!(
        st.selective_attempts * 8 < st.rollbacks,
        "{} attempts in {} rollbacks",
        st.selective_attempts,
        st.rollbacks
    );
}

/// A late input, or one on time, in the mixed runs below.
#[derive(Clone, Debug)]
enum Kind {
    /// Late: a new velocity for a past tick.
    LateVelocity,
    /// Late: a shot rewound to a view tick before its own.
    LateRewound,
    /// On time: a shot rewound to a view tick (further back than the window: clamped).
    Rewound,
    /// On time: a shot at the world of its own tick.
    Live,
}

fn kind() -> impl Strategy<Value = Kind> {
    prop_oneof![Just(Kind::LateVelocity), Just(Kind::LateRewound), Just(Kind::Rewound), Just(Kind::Live)]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    /// As above, with the shots a game sends: on time and late, rewound to what the shooter saw
    /// (some from further back than the window) or cast at their own tick. Rays on time cross
    /// paths the late inputs change, and rewound rays look at ticks a rollback re-simulates.
    #[test]
    fn selective_equals_full_with_shots(seed in 0u64..1000, balls in 20u32..120, gravity in any::<bool>(),
                                        script in proptest::collection::vec((0u32..4, 1u32..19, -8.0..8.0f64, -8.0..8.0f64, kind(), 0u32..24), 60..100)) {
        let sc = scene(seed, balls, 4, gravity);
        let (mut full, mut sel) = pair(&sc);
        let mut seq = 0;
        let mut script = script.into_iter();
        for step in 0..200u32 {
            let now = full.now().0;
            if now > 25 && step % 2 == 0 {
                if let Some((who, depth, vx, vz, kind, back)) = script.next() {
                    seq += 1;
                    let ray = shot(who, vx, vz);
                    let (tick, view, action) = match kind {
                        Kind::LateVelocity => (now - depth, None, Action::SetVelocity { entity: EntityId(3 + who), velocity: [vx, 0.0, vz] }),
                        Kind::LateRewound => (now - depth, Some(Tick(now - depth - back.min(6))), ray),
                        Kind::Rewound => (now, Some(Tick(now - back)), ray),
                        Kind::Live => (now, None, ray),
                    };
                    let input = ClientInput { aim_tick: None, view_tick: view, client: ClientId(1), seq, tick: Tick(tick), actions: vec![action] };
                    submit_both(&mut full, &mut sel, input)?;
                }
            }
            advance_both(&mut full, &mut sel)?;
        }
        prop_assert!(sel.stats.rollbacks > 0);
        prop_assert!(sel.stats.selective_rollbacks * 3 >= sel.stats.rollbacks, "selective ran {} of {} rollbacks", sel.stats.selective_rollbacks, sel.stats.rollbacks);
    }
}
