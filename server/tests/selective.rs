//! Selective re-simulation must be invisible: on random scenes with random late inputs, a
//! session that re-simulates only what a late input can reach publishes exactly what a session
//! that re-simulates everything publishes (events, corrections, confirmations, state hashes),
//! tick after tick. The run must also take the selective path often, or it proves nothing.

use impact_core::scene::Scene;
use impact_core::sim::Plan;
use impact_protocol::{Action, ClientId, ClientInput, EntityId, Tick};
use impact_server::rollback::{RollbackConfig, Session};
use proptest::prelude::*;

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
    let full = Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg.clone());
    cfg.selective = true;
    let sel = Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg);
    (full, sel)
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
                    let entity = EntityId(3 + who);
                    let action = if shoot {
                        Action::FireRay { shooter: entity, origin: [-15.0 + 6.0 * f64::from(who), 2.0, -15.0], direction: [vx, 0.5, vz + 9.0], max_distance_m: 30.0 }
                    } else {
                        Action::SetVelocity { entity, velocity: [vx, 0.0, vz] }
                    };
                    let input = ClientInput { aim_tick: None, view_tick: None, client: ClientId(1), seq, tick: Tick(now - depth), actions: vec![action] };
                    let a = full.submit(input.clone());
                    let b = sel.submit(input);
                    prop_assert_eq!(a, b);
                }
            }
            let a = full.advance();
            let b = sel.advance();
            prop_assert_eq!(full.world().state_hash(), sel.world().state_hash(), "tick {}", now);
            prop_assert_eq!(&a.events, &b.events);
            prop_assert_eq!(&a.corrections, &b.corrections, "corrections at tick {}", now);
            prop_assert_eq!(&a.confirmed, &b.confirmed);
            prop_assert_eq!(&a.rays, &b.rays);
        }
        prop_assert!(sel.stats.rollbacks > 0);
        prop_assert!(sel.stats.selective_rollbacks * 2 >= sel.stats.rollbacks, "selective ran {} of {} rollbacks", sel.stats.selective_rollbacks, sel.stats.rollbacks);
    }
}

/// Where every late input reaches most of the world (a long ray across it), selective
/// re-simulation cannot succeed; failed attempts must back off instead of costing every
/// rollback, and the results must still be the full re-simulation's.
#[test]
fn failed_attempts_back_off_and_change_nothing() {
    let sc = scene(7, 100, 4, true);
    let (mut full, mut sel) = pair(&sc);
    let mut seq = 0;
    for _ in 0..160u32 {
        let now = full.now().0;
        if now > 25 {
            seq += 1;
            let ray = Action::FireRay {
                shooter: EntityId(3),
                origin: [-19.0, 2.0, -19.0],
                direction: [1.0, 0.3, 1.0],
                max_distance_m: 60.0,
            };
            let input = ClientInput {
                aim_tick: None,
                view_tick: None,
                client: ClientId(1),
                seq,
                tick: Tick(now - 8),
                actions: vec![ray],
            };
            assert_eq!(full.submit(input.clone()), sel.submit(input));
        }
        let (a, b) = (full.advance(), sel.advance());
        assert_eq!(full.world().state_hash(), sel.world().state_hash(), "tick {now}");
        assert_eq!(a.corrections, b.corrections);
        assert_eq!(a.rays, b.rays);
    }
    let st = &sel.stats;
    assert!(st.rollbacks > 100, "{} rollbacks", st.rollbacks);
    assert_eq!(st.selective_rollbacks, 0, "a ray across the world reaches everything");
    assert!(
        st.selective_attempts * 8 < st.rollbacks,
        "{} attempts in {} rollbacks",
        st.selective_attempts,
        st.rollbacks
    );
}
