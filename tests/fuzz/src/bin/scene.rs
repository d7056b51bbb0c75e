//! Fuzz target: the scene loader (`Scene::parse`) on arbitrary text, then the plan for what it
//! built. A crash is a panic: every bad scene must come back as a `SceneError` naming the line.

use impact_core::scene::Scene;
use impact_core::sim::Plan;

fn main() {
    afl::fuzz!(|data: &[u8]| {
        let Ok(text) = std::str::from_utf8(data) else { return };
        if let Ok(scene) = Scene::parse(text, "fuzz.toml") {
            let plan = Plan::for_world(&scene.world);
            let _ = plan.to_string();
        }
    });
}
