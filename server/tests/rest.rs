//! Bodies at rest: what resting contact, islands and sleeping guarantee.
//!
//! A body standing on a support produces one `begin` and nothing else, however long it stands
//! (before resting contacts were solved, a standing body fell into its floor every tick and was
//! bisected back out: 1,000 impacts a tick for 1,000 standing bodies). Sleeping is invisible in
//! the results: an island that sleeps and is woken by a hit publishes exactly the events of a
//! run with sleeping disabled; a rollback across a sleep or a wake reproduces the on-time run
//! bit for bit; selective re-simulation equals the full one with sleepers in the world.

use impact_core::scene::Scene;
use impact_core::sim::{Plan, Stepper, TickOutput, World};
use impact_protocol::{Action, ClientId, ClientInput, CollisionEvent, EntityId, Phase, Tick};
use impact_server::rollback::{RollbackConfig, Session};

/// A floor, a stack of three boxes, a sphere and a capsule standing on it, a row of three
/// boxes side by side, and a ball (no gravity) that reaches the row at about tick 130. With
/// `player`, the ball is owned by client 1.
fn yard(sleep_after_s: f64, player: bool) -> Scene {
    let owner = if player { "owner = 1\n" } else { "" };
    let text = format!(
        r#"
[world]
name = "rest"
gravity = [0.0, -9.81, 0.0]
default_response = "bounce"
restitution = 0.0
friction = 0.5
sleep_after_s = {sleep_after_s}
[[class]]
name = "crate"
[[class]]
name = "ball"
gravity = false
max_speed_mps = 20.0
[[class]]
name = "floor"
static = true
[[response]]
between = ["ball", "crate"]
kind = "bounce"
restitution = 1.0
[[body]]
class = "floor"
shape = {{ type = "cuboid", half_extents_m = [20.0, 0.5, 20.0] }}
position = [0.0, -0.5, 0.0]
[[body]]
class = "crate"
shape = {{ type = "cuboid", half_extents_m = [0.5, 0.5, 0.5] }}
position = [5.0, 0.5, 5.0]
[[body]]
class = "crate"
shape = {{ type = "cuboid", half_extents_m = [0.5, 0.5, 0.5] }}
position = [5.0, 1.5, 5.0]
[[body]]
class = "crate"
shape = {{ type = "cuboid", half_extents_m = [0.5, 0.5, 0.5] }}
position = [5.0, 2.5, 5.0]
[[body]]
class = "crate"
shape = {{ type = "sphere", radius_m = 0.5 }}
position = [-5.0, 0.5, 5.0]
[[body]]
class = "crate"
shape = {{ type = "capsule", half_height_m = 0.5, radius_m = 0.3 }}
position = [-5.0, 0.8, -5.0]
[[array]]
class = "crate"
shape = {{ type = "cuboid", half_extents_m = [0.5, 0.5, 0.5] }}
origin = [0.0, 0.5, 0.0]
count = [3, 1, 1]
spacing_m = [1.0, 1.0, 1.0]
[[body]]
class = "ball"
shape = {{ type = "sphere", radius_m = 0.3 }}
position = [-8.0, 0.6, 0.0]
velocity = [4.0, 0.0, 0.0]
{owner}"#
    );
    Scene::parse(&text, "<rest>").unwrap()
}

/// Entity ids follow the file: bodies (floor 0, stack 1-3, sphere 4, capsule 5, ball 6), then
/// the row (7-9).
const BALL: EntityId = EntityId(6);

fn run(mut w: World, ticks: u32, mut each: impl FnMut(u32, &World, &[CollisionEvent])) -> World {
    let mut st = Stepper::new(Plan::for_world(&w), false);
    let mut out = TickOutput::default();
    for k in 0..ticks {
        st.step(&mut w, &[], &mut out);
        each(k, &w, &out.events);
    }
    w
}

#[test]
fn a_standing_body_begins_once_and_says_nothing_more_for_1000_ticks() {
    let mut w = yard(0.5, false).world;
    // Without the ball: only bodies standing still.
    let ball = w.bodies.slot(BALL).unwrap();
    let flags: Vec<bool> = (0..w.bodies.len()).map(|i| i == ball).collect();
    w.bodies.remove_flagged(&flags);
    let start = w.bodies.pos.clone();
    let mut events = Vec::new();
    let mut asleep_at = None;
    let w = run(w, 1000, |k, w, ev| {
        events.extend_from_slice(ev);
        if asleep_at.is_none() && w.bodies.asleep.iter().all(|a| *a) {
            asleep_at = Some(k);
        }
    });
    // One begin per resting contact: stack (floor-1, 1-2, 2-3), sphere, capsule, the row on the
    // floor (3) and its two side contacts; nothing else.
    assert!(events.iter().all(|e| e.phase == Phase::Begin), "only begins: {events:?}");
    let mut keys: Vec<_> = events.iter().map(|e| (e.a, e.b)).collect();
    keys.sort();
    let n = keys.len();
    keys.dedup();
    assert_eq!(keys.len(), n, "a contact began twice");
    assert_eq!(n, 10, "{events:?}");
    assert_eq!(w.touching.len(), 10);
    // Every island sleeps after half a second (32 ticks) of rest.
    let t = asleep_at.expect("everything fell asleep");
    assert!(t <= 40, "asleep only at tick {t}");
    // Nothing slid, or moved up or down by as much as the contact slop (3 mm under gravity at
    // 64 Hz: a resting contact is left to rest within it).
    let slop = w.config.contact_slop_m;
    for (p0, p1) in start.iter().zip(&w.bodies.pos) {
        let d = *p1 - *p0;
        assert!(d.x.abs() < 1e-6 && d.z.abs() < 1e-6 && d.y.abs() < slop, "{p0} moved to {p1}");
    }
}

#[test]
fn a_hit_wakes_the_island_and_events_match_a_run_that_never_slept() {
    let ticks = 400;
    let mut slept = Vec::new();
    let mut with_sleep = Vec::new();
    let mut woke = None;
    let row = |w: &World| (0..3).map(|k| w.bodies.slot(EntityId(7 + k)).unwrap()).collect::<Vec<_>>();
    run(yard(0.5, false).world, ticks, |k, w, ev| {
        with_sleep.push(ev.to_vec());
        let asleep = row(w).iter().all(|&s| w.bodies.asleep[s]);
        slept.push(asleep);
        if k > 0 && slept[k as usize - 1] && !asleep && woke.is_none() {
            woke = Some(k);
        }
    });
    let mut never = Vec::new();
    run(yard(0.0, false).world, ticks, |_, w, ev| {
        assert!(w.bodies.asleep.iter().all(|a| !a), "sleep_after_s = 0 must disable sleeping");
        never.push(ev.to_vec());
    });
    let woke = woke.expect("the row slept and then woke");
    assert!(slept[60], "the row was asleep before the hit");
    // The hit that woke it is in the events, with the ball.
    assert!(
        with_sleep[woke as usize].iter().chain(&with_sleep[woke as usize + 1]).any(|e| e.a == BALL || e.b == BALL),
        "woken at tick {woke} without the ball touching the row"
    );
    for k in 0..ticks as usize {
        assert_eq!(with_sleep[k], never[k], "tick {k} (row woke at {woke})");
    }
}

/// The ball driven by client 1: toward the row, back, and to a stop, so the row and the ball
/// sleep, wake and sleep again inside the run.
fn input(t: u32, ball: EntityId) -> Option<ClientInput> {
    let v = match t {
        40 => [0.0, 0.0, 0.0],
        120 => [6.0, 0.0, 0.0],
        200 => [-3.0, 0.0, 0.5],
        260 => [0.0, 0.0, 0.0],
        _ => return None,
    };
    Some(ClientInput {
        aim_tick: None,
        view_tick: None,
        client: ClientId(1),
        seq: t,
        tick: Tick(t),
        actions: vec![Action::SetVelocity { entity: ball, velocity: v }],
    })
}

/// A session on `scene` with a 24-tick window, re-simulating selectively or in full.
fn session(scene: &Scene, selective: bool) -> Session {
    let mut cfg = RollbackConfig::for_world(&scene.world);
    cfg.window_ticks = 24;
    cfg.selective = selective;
    Session::new(scene.world.clone(), Plan::for_world(&scene.world), cfg)
}

#[test]
fn rollback_across_sleep_and_wake_equals_the_on_time_run() {
    let scene = yard(0.5, true);
    let ball = BALL;
    let mut on_time = session(&scene, false);
    let mut late = session(&scene, false);
    let (mut transitions, mut was_asleep, mut compared) = (0, 0usize, 0);
    for t in 0..400u32 {
        if let Some(i) = input(t, ball) {
            on_time.submit(i).unwrap();
        }
        if t >= 12 {
            if let Some(i) = input(t - 12, ball) {
                late.submit(i).unwrap();
            }
        }
        let a = on_time.advance();
        let b = late.advance();
        let asleep = on_time.world().awake_asleep().1;
        transitions += usize::from(asleep != was_asleep);
        was_asleep = asleep;
        if let (Some(x), Some(y)) = (&a.confirmed, &b.confirmed) {
            assert_eq!(x, y, "confirmed tick {}", x.tick.0);
            compared += 1;
        }
    }
    assert_eq!(on_time.world().state_hash(), late.world().state_hash());
    assert!(late.stats.rollbacks >= 4, "the late session rolled back {} times", late.stats.rollbacks);
    assert!(transitions >= 4, "only {transitions} sleep/wake transitions: the test proves nothing");
    assert!(compared > 300);
}

#[test]
fn selective_equals_full_with_sleeping_bodies() {
    let scene = yard(0.5, true);
    let ball = BALL;
    let mut full = session(&scene, false);
    let mut sel = session(&scene, true);
    let mut max_asleep = 0;
    for t in 0..400u32 {
        if t >= 6 {
            if let Some(i) = input(t - 6, ball) {
                assert_eq!(full.submit(i.clone()), sel.submit(i));
            }
        }
        let a = full.advance();
        let b = sel.advance();
        assert_eq!(full.world().state_hash(), sel.world().state_hash(), "tick {t}");
        assert_eq!(a.events, b.events);
        assert_eq!(a.corrections, b.corrections);
        assert_eq!(a.confirmed, b.confirmed);
        max_asleep = max_asleep.max(sel.world().awake_asleep().1);
    }
    assert!(max_asleep >= 9, "sleepers in the world: {max_asleep}");
    assert!(sel.stats.selective_rollbacks > 0, "selective never ran");
}
