//! Scenes shared by the core's tests.

use impact_core::scene::Scene;
use impact_protocol::{Action, ClientId, ClientInput, EntityId, Tick};

/// A shooter (entity 0, client 1) at the origin and a target (entity 1) crossing its line of
/// fire (+x) at 8 m/s along z: its centre crosses z = 0 at tick 100, and it is destroyed when hit.
pub fn range() -> Scene {
    let text = r#"
[world]
name = "range"
rollback_ms = 250
default_response = "trigger"
[[class]]
name = "shooter"
gravity = false
[[class]]
name = "target"
gravity = false
[[response]]
between = ["shooter", "target"]
kind = "destroy"
destroy = "second"
[[body]]
class = "shooter"
shape = { type = "sphere", radius_m = 0.3 }
position = [0.0, 0.0, 0.0]
owner = 1
[[body]]
class = "target"
shape = { type = "sphere", radius_m = 0.5 }
position = [20.0, 0.0, -12.5]
velocity = [0.0, 0.0, 8.0]
"#;
    Scene::parse(text, "<range>").unwrap()
}

/// In breakout, entity 6 is the bat, owned by client 1: input `seq` for `tick` sets its velocity.
pub fn bat_input(seq: u32, tick: u32, vx: f64) -> ClientInput {
    ClientInput {
        aim_tick: None,
        view_tick: None,
        client: ClientId(1),
        seq,
        tick: Tick(tick),
        actions: vec![Action::SetVelocity { entity: EntityId(6), velocity: [vx, 2.0, 0.0] }],
    }
}
