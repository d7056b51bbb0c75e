//! The plan: which stages and kernels a scene needs, chosen once from the scene so a tick never
//! pays for what the scene does not have. Printed at start; the benchmark compares plans.

use crate::broadphase::BroadphaseKind;
use crate::geometry::ShapeKind;
use crate::narrow::Kernel;
use crate::sim::world::World;
use std::collections::BTreeSet;
use std::fmt;

/// Stages and kernels for a world.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Broadphase for dynamic bodies.
    pub broadphase: BroadphaseKind,
    /// Pair kernels the scene's shapes need (dynamic-dynamic and dynamic-static).
    pub kernels: BTreeSet<Kernel>,
    /// Sphere pairs take the exact swept-sphere time of impact instead of bisection.
    pub analytic_spheres: bool,
    /// Force every convex pair through parry's GJK (benchmarks only: the general path).
    pub force_general: bool,
    /// Dynamic-static pass (the scene has static bodies).
    pub statics: bool,
    /// Terrain pass (the scene has a height field).
    pub terrain: bool,
    /// Fine sampling for fast pairs (a pair that moves farther than its shapes' extents in one
    /// tick is sampled so it cannot tunnel). Off, every pair is tested at the end of the step
    /// only: benchmarks compare the two.
    pub ccd_sampling: bool,
    /// Gravity is non-zero.
    pub gravity: bool,
    /// Rollback stage (window > 0 ticks).
    pub rollback: bool,
    /// Islands fall asleep after this many still ticks (0: never).
    pub sleep_after_ticks: u32,
    /// Islands also sleep in parts, from the bottom up (gravity and `partial_sleep`).
    pub partial_sleep: bool,
    /// Some class is a character: the controller runs before gravity.
    pub characters: bool,
}

/// Up to this many bodies at start a world is planned as one that fills up later.
const SMALL_WORLD: usize = 48;

impl Plan {
    /// The plan the scene needs.
    pub fn for_world(w: &World) -> Plan {
        let cfg = &w.config;
        let b = &w.bodies;
        let dyn_kinds: BTreeSet<ShapeKind> = b.shape.iter().map(|s| s.kind()).collect();
        let static_kinds: BTreeSet<ShapeKind> = w.statics.shape.iter().map(|s| s.kind()).collect();
        let mut kernels = BTreeSet::new();
        for a in &dyn_kinds {
            for k in dyn_kinds.iter().chain(&static_kinds) {
                kernels.insert(Kernel::for_pair(*a, *k));
            }
        }
        // Sampling fast pairs costs nothing for a pair that moves less than its own extents in a
        // tick (it is tested once, at the end, either way), so it is on wherever anything can
        // move: a speed limit bounds inputs, not what gravity, bounces and spawns give a body,
        // and the plan is made once, before the avatars, spawns and projectiles that join
        // later. Off, a pair faster than its extents could pass through between two ticks.
        let ccd_sampling = cfg.classes.props.iter().any(|p| !p.is_static);
        // Grid for bodies of similar size; sweep and prune when sizes vary a lot (the grid's cell
        // is the largest box, which would put many small bodies in one cell), and for a world
        // that starts with few: the plan is made once, and players' avatars and spawns join
        // later (a world of characters starts empty and holds hundreds). Sweep and prune costs
        // what brute force does on a few bodies, and keeps up as they come.
        let (rmin, rmax) = b.radius.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &r| (lo.min(r), hi.max(r)));
        let broadphase = if b.len() <= SMALL_WORLD || rmax > 8.0 * rmin {
            BroadphaseKind::SweepAndPrune
        } else {
            BroadphaseKind::Grid
        };
        Plan {
            broadphase,
            kernels,
            analytic_spheres: true,
            force_general: false,
            statics: !w.statics.id.is_empty(),
            terrain: w.statics.terrain.is_some(),
            ccd_sampling,
            gravity: cfg.gravity != glam::DVec3::ZERO,
            rollback: cfg.window_ticks > 0,
            sleep_after_ticks: cfg.sleep_after_ticks,
            partial_sleep: cfg.sleeps_in_parts().is_some(),
            characters: cfg.classes.props.iter().any(|p| p.character.is_some()),
        }
    }

    /// The general path on the same world: no analytic sphere kernels, GJK for every pair,
    /// sampling always on. What a plan-less engine would run; benchmarks compare against it.
    pub fn general(w: &World) -> Plan {
        Plan { analytic_spheres: false, force_general: true, ccd_sampling: true, ..Plan::for_world(w) }
    }
}

impl fmt::Display for Plan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let on = |b: bool| if b { "on" } else { "skipped" };
        writeln!(f, "plan:")?;
        writeln!(f, "  broadphase      {}", self.broadphase.name())?;
        let kernels: Vec<String> = self.kernels.iter().map(|k| format!("{k:?}")).collect();
        writeln!(f, "  kernels         {}", if kernels.is_empty() { "none".into() } else { kernels.join(", ") })?;
        writeln!(f, "  sphere toi      {}", if self.analytic_spheres { "analytic swept sphere" } else { "bisection" })?;
        writeln!(
            f,
            "  general path    {}",
            if self.force_general { "forced (GJK for every pair)" } else { "only where no analytic kernel" }
        )?;
        writeln!(f, "  static pass     {}", on(self.statics))?;
        writeln!(f, "  terrain pass    {}", on(self.terrain))?;
        writeln!(f, "  ccd sampling    {}", on(self.ccd_sampling))?;
        writeln!(f, "  gravity         {}", on(self.gravity))?;
        writeln!(
            f,
            "  resting contact {}",
            if self.gravity { "solved before the step (warm-started, cached contacts)" } else { "skipped" }
        )?;
        if self.sleep_after_ticks == 0 {
            writeln!(f, "  sleeping        off")?;
        } else {
            writeln!(
                f,
                "  sleeping        islands still for {} ticks{}; sleepers are obstacles only",
                self.sleep_after_ticks,
                if self.partial_sleep { ", and bodies still on sleeping supports" } else { "" }
            )?;
        }
        writeln!(f, "  characters      {}", on(self.characters))?;
        writeln!(f, "  rollback        {}", on(self.rollback))?;
        write!(f, "  always          static-static pairs never tested; resting pairs not re-tested")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Shape;
    use crate::sim::world::{ClassId, NewBody};
    use crate::sim::{Stepper, TickOutput};
    use glam::{DQuat, DVec3};

    /// A fast box spawned after the plan was made hits a thin wall instead of passing through
    /// it between two ticks: in a world that starts with no dynamic body, and in one that starts
    /// with only a large slow one (whose extents would let nothing tunnel).
    #[test]
    fn what_joins_later_fast_is_sampled() {
        let scene = r#"
[world]
name = "later"
[[class]]
name = "bullet"
max_speed_mps = 200.0
[[class]]
name = "wall"
static = true
[[class]]
name = "boulder"
max_speed_mps = 1.0
[[body]]
class = "wall"
shape = { type = "cuboid", half_extents_m = [0.05, 2.0, 2.0] }
position = [0.0, 0.0, 0.0]
"#;
        let boulder = r#"
[[body]]
class = "boulder"
shape = { type = "sphere", radius_m = 5.0 }
position = [0.0, 50.0, 0.0]
"#;
        for text in [scene.to_string(), format!("{scene}{boulder}")] {
            let mut w = crate::scene::Scene::parse(&text, "<later>").unwrap().world;
            let plan = Plan::for_world(&w);
            assert!(plan.ccd_sampling, "{plan}");
            // 150 m/s: 2.3 m a tick, through 0.1 m of wall from one tick's end to the next.
            let shape = Shape::Cuboid { half_extents: DVec3::splat(0.05) };
            let (pos, vel) = (DVec3::new(-1.2, 0.0, 0.0), DVec3::new(150.0, 0.0, 0.0));
            let body = NewBody { class: ClassId(0), shape, pos, vel, rot: DQuat::IDENTITY, inv_mass: 1.0, owner: None };
            let k = w.spawn(body).unwrap();
            let mut stepper = Stepper::new(plan, false);
            let mut out = TickOutput::default();
            for _ in 0..3 {
                stepper.step_with(&mut w, &[], &[], &mut out);
            }
            let x = w.bodies.pos[w.bodies.slot(k).unwrap()].x;
            assert!(x < 0.0, "through the wall: x = {x}");
        }
    }
}
