//! What each kind of scene must do, checked every tick: bullets never pass a wall whatever their
//! speed, balls never leave the arena or sink into the terrain, players slide along walls without
//! entering them, bricks are destroyed exactly when an event says so, and begin/end events pair
//! up. Each check fails if the feature it names breaks (tunnelling, a missed terrain contact, a
//! slide that stops or penetrates, a silent destroy).

use glam::DVec3;
use impact_core::scene::Scene;
use impact_core::sim::{Plan, Stepper, TickOutput, World};
use impact_protocol::{CollisionEvent, Phase, Response};
use std::collections::BTreeSet;

fn stepper(w: &World) -> Stepper {
    Stepper::new(Plan::for_world(w), false)
}

fn scene(name: &str) -> Scene {
    Scene::load(&Scene::bundled_path(name)).unwrap()
}

/// Runs `ticks`, calling `check` after each with the world and that tick's events.
fn run(mut w: World, ticks: u32, mut check: impl FnMut(&World, &[CollisionEvent])) -> World {
    let mut st = stepper(&w);
    let mut out = TickOutput::default();
    for _ in 0..ticks {
        st.step(&mut w, &[], &mut out);
        for e in &out.events {
            assert!(e.toi.is_finite() && e.point.iter().chain(&e.normal).all(|x| x.is_finite()), "{e:?}");
        }
        check(&w, &out.events);
    }
    w
}

fn bullet_wall_scene(speed: f64) -> Scene {
    let text = format!(
        r#"
[world]
name = "wall"
[[class]]
name = "bullet"
max_speed_mps = 20000.0
gravity = false
[[class]]
name = "wall"
static = true
[[response]]
between = ["bullet", "wall"]
kind = "stop"
[[body]]
class = "wall"
shape = {{ type = "cuboid", half_extents_m = [0.005, 5.0, 5.0] }}
position = [0.0, 0.0, 0.0]
[[array]]
class = "bullet"
shape = {{ type = "sphere", radius_m = 0.05 }}
origin = [-3.0, -2.0, -2.0]
count = [1, 5, 5]
spacing_m = [0.0, 1.0, 1.0]
velocity = [{speed}, 0.0, 0.0]
"#
    );
    Scene::parse(&text, "<bullets>").unwrap()
}

#[test]
fn bullets_never_tunnel_through_a_1cm_wall() {
    for speed in [1.0, 10.0, 100.0, 1000.0, 10_000.0] {
        let s = bullet_wall_scene(speed);
        let ticks = (64.0 * 6.0 / speed).ceil() as u32 + 2;
        let w = run(s.world.clone(), ticks, |w, _| {
            for p in &w.bodies.pos {
                assert!(p.x <= -0.005 - 0.05 + 1e-6, "a bullet at {speed} m/s passed the wall: x = {}", p.x);
            }
        });
        // Every bullet reached the wall and stopped against it.
        for (p, v) in w.bodies.pos.iter().zip(&w.bodies.vel) {
            assert!((p.x + 0.055).abs() < 1e-3, "speed {speed}: stopped at x = {}", p.x);
            assert_eq!(*v, DVec3::ZERO);
        }
    }
}

#[test]
fn bullets_scene_destroys_each_bullet_at_the_first_plate() {
    let s = scene("bullets");
    let mut destroyed = BTreeSet::new();
    run(s.world.clone(), 200, |w, events| {
        for e in events.iter().filter(|e| e.response == Response::Destroy && e.phase == Phase::Begin) {
            destroyed.insert(e.b.max(e.a));
        }
        for (id, p) in w.bodies.id.iter().zip(&w.bodies.pos) {
            // Plates at x = +-20 and z = 25 span |y|, |z| < 10 (resp. |x|, |y| < 10): a live
            // bullet is never beyond a plate within that span.
            let within_x_plates = p.y.abs() < 9.9 && p.z.abs() < 9.9;
            assert!(!(within_x_plates && p.x.abs() > 20.0), "bullet {id} passed an x plate at {p:?}");
            assert!(!(p.x.abs() < 9.9 && p.y.abs() < 9.9 && p.z > 25.0), "bullet {id} passed the z plate at {p:?}");
        }
    });
    assert!(destroyed.len() > 50, "only {} bullets hit a plate", destroyed.len());
}

#[test]
fn arena_balls_stay_in_the_box_and_keep_their_energy() {
    let s = scene("arena");
    let energy = |w: &World| {
        w.bodies.vel.iter().zip(&w.bodies.inv_mass).map(|(v, im)| 0.5 * v.length_squared() / im).sum::<f64>()
    };
    let e0 = energy(&s.world);
    let w = run(s.world.clone(), 640, |w, _| {
        for p in &w.bodies.pos {
            assert!(p.x.abs() <= 30.0 - 0.5 + 1e-3 && p.z.abs() <= 30.0 - 0.5 + 1e-3, "left the box: {p:?}");
            assert!(p.y >= 0.5 - 1e-3 && p.y <= 20.0 - 0.5 + 1e-3, "left the box: {p:?}");
        }
    });
    let drift = (energy(&w) - e0).abs() / e0;
    assert!(drift < 1e-3, "kinetic energy drifted by {:.3e}", drift);
}

#[test]
fn terrain_balls_never_sink_below_the_surface() {
    let s = scene("terrain");
    let field = &s.world.statics.terrain.as_ref().unwrap().field;
    let mut landed = 0;
    run(s.world.clone(), 640, |w, events| {
        landed += events.iter().filter(|e| e.phase == Phase::Begin && e.a.0 == 0).count();
        for (p, r) in w.bodies.pos.iter().zip(&w.bodies.radius) {
            if let Some(h) = field.height_at(p.x, p.z) {
                // The centre stays above the surface (a sphere on a slope touches it with its
                // side, so the centre may be less than r above the point below it).
                assert!(p.y > h, "ball centre {p:?} below the terrain height {h}");
            }
            let _ = r;
        }
    });
    assert!(landed > 100, "only {landed} terrain contacts began");
}

#[test]
fn corridor_players_slide_along_walls_without_entering_them() {
    let s = scene("corridor");
    let walls = s.world.statics.clone();
    let mut slides = 0;
    let mut w0 = s.world.clone();
    let speed0: Vec<f64> = w0.bodies.vel.iter().map(|v| v.length()).collect();
    w0 = run(w0, 320, |w, events| {
        slides += events.iter().filter(|e| e.response == Response::Slide && e.phase == Phase::Begin).count();
        for i in 0..w.bodies.len() {
            for k in 0..walls.id.len() {
                let d = walls.pos[k] - w.bodies.pos[i];
                if let Some(c) = impact_core::narrow::contact(
                    &w.bodies.shape[i],
                    w.bodies.rot[i],
                    &walls.shape[k],
                    walls.rot[k],
                    d,
                    0.0,
                ) {
                    assert!(
                        c.depth <= 1e-3,
                        "player {} is {:.4} m inside wall {}",
                        w.bodies.id[i],
                        c.depth,
                        walls.id[k]
                    );
                }
            }
        }
    });
    assert!(slides >= 3, "only {slides} slides");
    // Players still move after sliding (sliding keeps the tangential motion).
    let moving = w0.bodies.vel.iter().filter(|v| v.length() > 0.5).count();
    assert!(moving >= 1, "every player stopped: {:?} (started at {speed0:?})", w0.bodies.vel);
}

#[test]
fn breakout_bricks_go_exactly_when_a_destroy_event_says_so() {
    let s = scene("breakout");
    let mut announced = BTreeSet::new();
    let mut w = s.world.clone();
    let mut st = stepper(&w);
    let mut out = TickOutput::default();
    for _ in 0..1280 {
        let before: BTreeSet<_> = w.bodies.id.iter().copied().collect();
        st.step(&mut w, &[], &mut out);
        let after: BTreeSet<_> = w.bodies.id.iter().copied().collect();
        let gone: BTreeSet<_> = before.difference(&after).copied().collect();
        let said: BTreeSet<_> = out
            .events
            .iter()
            .filter(|e| e.response == Response::Destroy && e.phase == Phase::Begin)
            .flat_map(|e| [e.a, e.b])
            .filter(|id| gone.contains(id))
            .collect();
        assert_eq!(gone, said, "tick {}: removed without an event, or announced but kept", w.tick);
        announced.extend(said);
    }
    assert!(announced.len() >= 5, "only {} bodies destroyed", announced.len());
}

#[test]
fn begin_and_end_events_pair_up() {
    for name in ["arena", "terrain", "corridor", "breakout"] {
        let s = scene(name);
        let mut open = BTreeSet::new();
        run(s.world.clone(), 400, |_, events| {
            for e in events {
                let key = (e.a, e.b);
                match e.phase {
                    Phase::Begin => {
                        assert!(open.insert(key), "{name}: {key:?} began twice without an end (tick {})", e.tick)
                    }
                    Phase::End => assert!(open.remove(&key), "{name}: {key:?} ended without a begin (tick {})", e.tick),
                    Phase::Hit => {}
                }
            }
        });
    }
}

#[test]
fn corridor_script_fires_rays_that_hit_and_destroy() {
    let s = scene("corridor");
    let path = Scene::bundled_path("corridor").with_extension("inputs.jsonl");
    let inputs = impact_server::offline::read_inputs(&path).unwrap();
    let mut hits = Vec::new();
    let report = impact_server::offline::run(
        &s,
        Plan::for_world(&s.world),
        &impact_core::sim::Pool::sequential(),
        320,
        &inputs,
        |e| {
            if e.phase == Phase::Hit {
                hits.push(e.clone());
            }
            Ok(())
        },
        |_| {},
    )
    .unwrap();
    assert_eq!(hits.len(), 3, "{hits:?}");
    // Client 3's ray at tick 8 destroys a target (player-target rule: destroy the second).
    assert!(hits.iter().any(|h| h.tick.0 == 8 && h.response == Response::Destroy && h.a.0 == 8));
    // The rays down the corridor hit walls and only trigger.
    assert_eq!(hits.iter().filter(|h| h.response == Response::Trigger).count(), 2);
    assert_eq!(report.skipped, 0);
}

#[test]
fn general_shapes_land_on_a_mesh_floor() {
    // A sphere, a capsule, a box, an ellipsoid and a convex hull dropped onto a static triangle
    // mesh: the mesh kernel (parry's BVH to the triangles, then per-triangle kernels) must stop
    // each of them on the surface, none through it.
    let text = r#"
[world]
name = "mesh"
gravity = [0.0, -9.81, 0.0]
default_response = "stop"
[[class]]
name = "thing"
[[class]]
name = "floor"
static = true
[[body]]
class = "floor"
shape = { type = "mesh", vertices = [[-20, 0, -20], [20, 0, -20], [20, 0, 20], [-20, 0, 20]], triangles = [[0, 2, 1], [0, 3, 2]] }
position = [0.0, 0.0, 0.0]
[[body]]
class = "thing"
shape = { type = "sphere", radius_m = 0.5 }
position = [-8.0, 3.0, 0.0]
[[body]]
class = "thing"
shape = { type = "capsule", half_height_m = 0.5, radius_m = 0.3 }
position = [-4.0, 3.0, 0.0]
[[body]]
class = "thing"
shape = { type = "cuboid", half_extents_m = [0.4, 0.3, 0.4] }
position = [0.0, 3.0, 0.0]
[[body]]
class = "thing"
shape = { type = "ellipsoid", radii_m = [0.6, 0.25, 0.4] }
position = [4.0, 3.0, 0.0]
[[body]]
class = "thing"
shape = { type = "convex", points = [[0, 0.5, 0], [0.5, -0.2, 0.3], [-0.5, -0.2, 0.3], [0, -0.2, -0.5]] }
position = [8.0, 3.0, 0.0]
"#;
    let s = Scene::parse(text, "<mesh>").unwrap();
    let w = run(s.world.clone(), 192, |w, _| {
        for i in 0..w.bodies.len() {
            let low = w.bodies.pos[i].y + w.bodies.aabb_lo[i].y;
            assert!(low > -0.02, "body {} sank to {low}", w.bodies.id[i]);
        }
    });
    // Everything came to rest on the floor: lowest point at the surface (within the
    // resting tolerance of one tick of gravity).
    for i in 0..w.bodies.len() {
        let low = w.bodies.pos[i].y + w.bodies.aabb_lo[i].y;
        assert!(low.abs() < 0.01, "body {} rests at {low}, expected 0", w.bodies.id[i]);
    }
}
