//! Keys that contradict each other or the scene: a world that loads but cannot come to rest, or
//! whose bodies are placed inside each other. Each is a named warning with the value that would
//! work; impossible values stay load errors.

use super::format::ResponseKind;
use super::settings::WorldKeys;
use crate::geometry::Shape;
use crate::narrow;
use crate::sim::overlaps::{self, Other};
use crate::sim::World;
use glam::DVec3;
use impact_protocol::EntityId;
use std::fmt;

/// A warning about a loaded scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneWarning {
    /// Its name, stable for scripts and searches: `slop_below_free_fall`,
    /// `elastic_under_gravity`, `sleep_above_free_fall_speed`, `friction_below_slope`,
    /// `bodies_overlap`.
    pub name: &'static str,
    /// The key it is about, as written in a scene file (`world.contact_slop_m`).
    pub key: &'static str,
    /// What is wrong and the value that would work.
    pub detail: String,
}

impl fmt::Display for SceneWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "warning[{}]: {}: {}", self.name, self.key, self.detail)
    }
}

/// The steepest slope, in degrees, a static box may have and still count as ground something
/// rests on (steeper is a wall).
const MAX_GROUND_SLOPE_DEG: f64 = 60.0;

/// `value` rounded up to two significant figures, for a suggestion a person would type.
fn round_up(value: f64) -> f64 {
    if value <= 0.0 {
        return value;
    }
    let step = 10f64.powf(value.log10().floor() - 1.0);
    (value / step).ceil() * step
}

/// What `keys` contradict in `world`, and bodies placed inside each other (empty for a scene
/// that can rest).
pub fn check(keys: &WorldKeys, world: &World) -> Vec<SceneWarning> {
    let mut out = Vec::new();
    if let Some(w) = overlapping(world) {
        out.push(w);
    }
    let cfg = &world.config;
    let g = cfg.gravity.length();
    let falls = cfg.classes.props.iter().any(|p| p.gravity && !p.is_static);
    if g == 0.0 || !falls {
        return out;
    }
    let fall_m = g * cfg.dt * cfg.dt;
    if keys.contact_slop_m < fall_m {
        out.push(SceneWarning {
            name: "slop_below_free_fall",
            key: "world.contact_slop_m",
            detail: format!(
                "{} m is below one tick of free fall ({fall_m:.4} m at {} Hz): a resting contact that lifts \
                 a hair is dropped and comes back as an impact, so stacks and piles may never settle; {} \
                 would work",
                keys.contact_slop_m,
                cfg.tick_hz,
                round_up(1.25 * fall_m)
            ),
        });
    }
    if keys.default_response == ResponseKind::Bounce && keys.restitution >= 0.9 && cfg.sleep_after_ticks > 0 {
        out.push(SceneWarning {
            name: "elastic_under_gravity",
            key: "world.restitution",
            detail: format!(
                "{} under gravity: a body that lands bounces back nearly as high, so bodies never come \
                 to rest or sleep; 0 would work (rapier, Box2D and Jolt default to it)",
                keys.restitution
            ),
        });
    }
    let fall_mps = g * cfg.dt;
    if keys.sleep_speed_mps > fall_mps {
        out.push(SceneWarning {
            name: "sleep_above_free_fall_speed",
            key: "world.sleep_speed_mps",
            detail: format!(
                "{} m/s is above the speed gravity gives in one tick ({fall_mps:.3} m/s at {} Hz): a body \
                 at the top of its fall counts as still and may fall asleep in the air; {} would work",
                keys.sleep_speed_mps,
                cfg.tick_hz,
                round_up(fall_mps / 3.0)
            ),
        });
    }
    if let Some(deg) = steepest_ground(world, cfg.gravity / g) {
        let needed = deg.to_radians().tan();
        if keys.friction < needed {
            out.push(SceneWarning {
                name: "friction_below_slope",
                key: "world.friction",
                detail: format!(
                    "{} cannot hold a body on the steepest static slope a body is placed on ({deg:.1} degrees, which \
                     needs {needed:.2}): the bodies on it slide off rather than rest; {} would work",
                    keys.friction,
                    round_up(needed * 1.1)
                ),
            });
        }
    }
    out
}

/// Bodies placed inside each other (deeper than the contact slop) whose classes stop each other:
/// the first tick pushes them apart, which looks like an explosion. Dynamic pairs and dynamic
/// bodies against static geometry, through the broadphase and the exact kernels.
fn overlapping(world: &World) -> Option<SceneWarning> {
    let b = &world.bodies;
    let slop = world.config.contact_slop_m;
    let classes = &world.config.classes;
    let mut found: Vec<(EntityId, EntityId, f64)> = Vec::new();
    overlaps::each(world, |i, other, c| {
        let (class, id) = match other {
            Other::Body(j) => (b.class[j], b.id[j]),
            Other::Static(k) => (world.statics.class[k], world.statics.id[k]),
            // The terrain is solid below its surface: a body placed through it is lifted out.
            Other::Terrain => return,
        };
        if c.depth > slop && classes.rule(b.class[i], class).stops() {
            found.push((b.id[i], id, c.depth));
        }
    });
    let (a, other, depth) = *found.iter().max_by(|x, y| x.2.total_cmp(&y.2))?;
    Some(SceneWarning {
        name: "bodies_overlap",
        key: "bodies",
        detail: format!(
            "{} pairs of bodies are placed inside each other, deeper than the contact slop (the deepest: \
             entities {a} and {other}, by {depth:.3} m): the first tick pushes them apart, which looks like \
             an explosion; space them further (an [[array]]'s spacing_m at least the bodies' size)",
            found.len()
        ),
    })
}

/// How near a body must be placed to a slope to count as lying on it, m (beside the slop).
const LIES_ON_M: f64 = 0.02;

/// The steepest top face of a static box that is ground (tilted, but less than
/// [`MAX_GROUND_SLOPE_DEG`]) with a falling body placed on it (within [`LIES_ON_M`] and the
/// slop of it at load), in degrees from level; `down` is gravity's direction. A ramp bodies
/// arrive on and slide down is not warned about: only a body set down to rest there.
fn steepest_ground(world: &World, down: DVec3) -> Option<f64> {
    let s = &world.statics;
    let b = &world.bodies;
    let margin = LIES_ON_M + world.config.contact_slop_m;
    let up = -down;
    let mut steepest: Option<f64> = None;
    for k in 0..s.shape.len() {
        let (shape, rot) = (&s.shape[k], s.rot[k]);
        if !matches!(shape, Shape::Cuboid { .. }) {
            continue;
        }
        // The face whose normal is nearest to up is the one a body rests on.
        let cos = [DVec3::X, DVec3::Y, DVec3::Z].iter().map(|a| (rot * *a).dot(up).abs()).fold(0.0, f64::max);
        let deg = cos.clamp(-1.0, 1.0).acos().to_degrees();
        if deg <= 0.5 || deg >= MAX_GROUND_SLOPE_DEG || steepest.is_some_and(|d| d >= deg) {
            continue;
        }
        let falls = |i: usize| b.inv_mass[i] > 0.0 && world.config.classes.props[b.class[i].0 as usize].gravity;
        let lies_on = (0..b.len()).any(|i| {
            falls(i) && narrow::contact(&b.shape[i], b.rot[i], shape, rot, s.pos[k] - b.pos[i], margin).is_some()
        });
        if lies_on {
            steepest = Some(deg);
        }
    }
    steepest
}

#[cfg(test)]
mod tests {
    use crate::scene::Scene;

    fn names(text: &str) -> Vec<&'static str> {
        Scene::parse(text, "<test>").unwrap().warnings.iter().map(|w| w.name).collect()
    }

    const PILE: &str = "[world]\nname = \"p\"\ngravity = [0.0, -9.81, 0.0]\n[[class]]\nname = \"ball\"\n\
        [[class]]\nname = \"floor\"\nstatic = true\n\
        [[body]]\nclass = \"floor\"\nshape = { type = \"cuboid\", half_extents_m = [10.0, 0.5, 10.0] }\nposition = [0.0, -0.5, 0.0]\n\
        [[body]]\nclass = \"ball\"\nshape = { type = \"sphere\", radius_m = 0.5 }\nposition = [0.0, 2.0, 0.0]\n";

    /// A pile written with no tuning keys gets defaults that let it rest, and no warning; keys
    /// that keep it from resting are told so; a world without gravity never is.
    #[test]
    fn a_pile_that_cannot_rest_is_told_so() {
        assert!(names(PILE).is_empty(), "{:?}", names(PILE));
        let untuned = PILE.replace(
            "gravity = [0.0, -9.81, 0.0]",
            "gravity = [0.0, -9.81, 0.0]\nrestitution = 1.0\ncontact_slop_m = 0.0001",
        );
        assert_eq!(names(&untuned), ["slop_below_free_fall", "elastic_under_gravity"]);
        assert!(names(&PILE.replace("gravity = [0.0, -9.81, 0.0]", "")).is_empty());
        let fast = PILE.replace("gravity = [0.0, -9.81, 0.0]", "gravity = [0.0, -9.81, 0.0]\nsleep_speed_mps = 0.5");
        assert!(names(&fast).contains(&"sleep_above_free_fall_speed"));
    }

    /// Two boxes of an array placed 0.4 m apart though 0.6 m wide are told of; spaced 0.7 m
    /// apart they are not; nor are bodies whose classes ignore each other.
    #[test]
    fn bodies_placed_inside_each_other_are_told_so() {
        let array = |spacing: f64| {
            format!("{PILE}[[array]]\nclass = \"ball\"\nshape = {{ type = \"cuboid\", half_extents_m = [0.3, 0.3, 0.3] }}\norigin = [3.0, 1.0, 0.0]\ncount = [3, 1, 1]\nspacing_m = [{spacing}, 1.0, 1.0]\n")
        };
        let warned = Scene::parse(&array(0.4), "<t>").unwrap().warnings;
        assert_eq!(warned.iter().map(|w| w.name).collect::<Vec<_>>(), ["bodies_overlap"], "{warned:?}");
        assert!(warned[0].detail.starts_with("2 pairs") && warned[0].detail.contains("by 0.200 m"), "{}", warned[0]);
        assert!(names(&array(0.7)).is_empty());
        let ghosts = array(0.4) + "[[response]]\nbetween = [\"ball\", \"ball\"]\nkind = \"ignore\"\n";
        assert!(names(&ghosts).is_empty());
    }

    /// A 40 degree ramp a box is set down on needs friction above tan 40 = 0.84 to hold it; a
    /// wall is not a ramp, and a ramp nothing is placed on (bodies arrive and slide down it) is
    /// not warned about.
    #[test]
    fn a_ramp_steeper_than_the_friction_holds_is_told_so() {
        let ramp = |deg: f64, friction: f64, placed: bool| {
            let r = f64::to_radians(deg);
            let lift = 0.2 + 0.25 + 0.005;
            let on = [-r.sin() * lift, 2.0 + r.cos() * lift, 5.0];
            let crate_on = format!(
                "[[body]]\nclass = \"ball\"\nshape = {{ type = \"cuboid\", half_extents_m = [0.25, 0.25, 0.25] }}\nposition = [{}, {}, {}]\nrotation_deg = [0.0, 0.0, {deg}]\n",
                on[0], on[1], on[2]
            );
            PILE.replace("gravity = [0.0, -9.81, 0.0]", &format!("gravity = [0.0, -9.81, 0.0]\nfriction = {friction}"))
                + &format!("[[body]]\nclass = \"floor\"\nshape = {{ type = \"cuboid\", half_extents_m = [4.0, 0.2, 2.0] }}\nposition = [0.0, 2.0, 5.0]\nrotation_deg = [0.0, 0.0, {deg}]\n")
                + if placed { crate_on.as_str() } else { "" }
        };
        let warned = Scene::parse(&ramp(40.0, 0.5, true), "<t>").unwrap().warnings;
        assert_eq!(warned.len(), 1, "{warned:?}");
        assert!(warned[0].detail.contains("40.0 degrees") && warned[0].detail.contains("0.84"), "{}", warned[0]);
        assert!(names(&ramp(40.0, 0.9, true)).is_empty());
        assert!(names(&ramp(40.0, 0.5, false)).is_empty(), "nothing is set down on it");
        assert!(names(&ramp(90.0, 0.5, true)).is_empty(), "a wall");
    }
}
