//! The `[world]` settings resolved: each key the scene gives, or its default, with where the
//! value came from. One place decides every default, so `impact-server --scene F --explain` can
//! print exactly what a world runs with, and so the defaults follow what the scene says of
//! itself.
//!
//! A world without gravity keeps the defaults the zero-gravity arena was tuned with (elastic,
//! frictionless, 0.1 mm contact slop). A world with gravity gets the defaults of the engines game
//! developers already know (rapier 0.36: restitution 0, friction 0.5, 5 mm allowed error; Box2D
//! v3: restitution 0, friction 0.6, 5 mm linear slop; Jolt: restitution 0, friction 0.2): bodies
//! that land stay down, rest on slopes up to 26 degrees, and a contact slop of a little over one
//! tick of free fall, so a resting contact that lifts by a tick's fall is still a contact. The
//! slop is capped at a tenth of the thinnest falling body, so small bodies do not float.

use super::format::{ResponseKind, SceneFile, ShapeSpec, WorldDef};
use std::fmt;

/// Where a resolved value came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    /// The scene file gives it.
    Scene,
    /// Left out: the default.
    Default,
    /// A command-line flag of the server overrides it (`why` names the flag).
    Flag,
}

/// One resolved `[world]` key, as `--explain` prints it.
#[derive(Clone, Debug, PartialEq)]
pub struct Setting {
    /// The key, as written in a scene file.
    pub key: &'static str,
    /// The value, as a scene file would write it.
    pub value: String,
    /// Where it came from.
    pub source: Source,
    /// Why the default is what it is (empty for a value the scene gives).
    pub why: String,
}

impl fmt::Display for Setting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.source {
            Source::Scene => write!(f, "{:<26} {:<22} scene", self.key, self.value),
            Source::Default => write!(f, "{:<26} {:<22} default: {}", self.key, self.value, self.why),
            Source::Flag => write!(f, "{:<26} {:<22} command line: {}", self.key, self.value, self.why),
        }
    }
}

/// The `[world]` values a world runs with, every key resolved (see [`resolve`]). Recordings and
/// standby checkpoints carry them, so a build with other defaults replays what was run.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldKeys {
    /// Ticks per second.
    pub tick_hz: u32,
    /// Gravity, m/s^2.
    pub gravity: [f64; 3],
    /// Rollback window, ms.
    pub rollback_ms: u32,
    /// How far ahead of the server an input may be stamped, ticks.
    pub input_lead_ticks: u32,
    /// How far back a hitscan ray is rewound at most, ms.
    pub max_rewind_ms: u32,
    /// Most bodies.
    pub max_bodies: u32,
    /// Response for class pairs with no `[[response]]` entry.
    pub default_response: ResponseKind,
    /// Restitution of the default bounce.
    pub restitution: f64,
    /// Bodies closer than this count as touching, m.
    pub contact_slop_m: f64,
    /// Closing speed at or below which a bounce does not rebound, m/s.
    pub bounce_threshold_mps: f64,
    /// Time-of-impact tolerance, fraction of a tick.
    pub toi_tolerance: f64,
    /// Most contact resolutions in one tick.
    pub max_resolutions_per_tick: u32,
    /// Coulomb friction of resting contacts.
    pub friction: f64,
    /// A body slower than this counts as still, m/s.
    pub sleep_speed_mps: f64,
    /// An island still for this long falls asleep, s (0: never).
    pub sleep_after_s: f64,
    /// Under gravity, islands also sleep in parts, from the bottom up. Absent from recordings
    /// made before the key existed: `false`, how those ran.
    #[serde(default)]
    pub partial_sleep: bool,
}

impl WorldKeys {
    /// Writes every value into `w`, as if the scene gave them all: a world built from it runs
    /// with exactly these (a recording's, replayed by a build whose defaults differ).
    pub fn write_into(&self, w: &mut WorldDef) {
        w.tick_hz = Some(self.tick_hz);
        w.gravity = Some(self.gravity);
        w.rollback_ms = Some(self.rollback_ms);
        w.input_lead_ticks = Some(self.input_lead_ticks);
        w.max_rewind_ms = Some(self.max_rewind_ms);
        w.max_bodies = Some(self.max_bodies);
        w.default_response = Some(self.default_response);
        w.restitution = Some(self.restitution);
        w.contact_slop_m = Some(self.contact_slop_m);
        w.bounce_threshold_mps = Some(self.bounce_threshold_mps);
        w.toi_tolerance = Some(self.toi_tolerance);
        w.max_resolutions_per_tick = Some(self.max_resolutions_per_tick);
        w.friction = Some(self.friction);
        w.sleep_speed_mps = Some(self.sleep_speed_mps);
        w.sleep_after_s = Some(self.sleep_after_s);
        w.partial_sleep = Some(self.partial_sleep);
    }

    /// The keys whose values differ from `other`'s, as `key: this vs other` (empty: the same).
    pub fn differences(&self, other: &WorldKeys) -> Vec<String> {
        let (a, b) = (resolved_list(self), resolved_list(other));
        a.iter()
            .zip(&b)
            .filter(|(x, y)| x.value != y.value)
            .map(|(x, y)| format!("{}: {} vs {}", x.key, x.value, y.value))
            .collect()
    }
}

/// Every key of `keys` as a setting (the values as a scene would write them).
fn resolved_list(keys: &WorldKeys) -> Vec<Setting> {
    let mut w = WorldDef::named("");
    keys.write_into(&mut w);
    resolve(&w, SceneFacts::default()).1
}

/// The defaults of every build before they followed the scene (recordings of format 1 ran with
/// them): elastic, frictionless, 0.1 mm slop, islands asleep only whole, whatever the gravity.
/// Fills the keys `w` leaves out.
pub fn fixed_defaults(w: &mut WorldDef) {
    w.restitution.get_or_insert(1.0);
    w.contact_slop_m.get_or_insert(1.0e-4);
    w.friction.get_or_insert(0.0);
    w.sleep_speed_mps.get_or_insert(0.05);
    w.bounce_threshold_mps.get_or_insert(0.5);
    w.partial_sleep.get_or_insert(false);
}

/// Collects the resolved values and where each came from.
struct Resolver {
    settings: Vec<Setting>,
}

impl Resolver {
    /// `given`, or `default` (with why), recorded under `key`.
    fn key<T: Copy + fmt::Debug>(
        &mut self,
        key: &'static str,
        given: Option<T>,
        default: T,
        why: impl Into<String>,
    ) -> T {
        let (value, source) = match given {
            Some(v) => (v, Source::Scene),
            None => (default, Source::Default),
        };
        let why = if source == Source::Default { why.into() } else { String::new() };
        self.settings.push(Setting { key, value: format!("{value:?}").to_lowercase(), source, why });
        value
    }
}

/// What the scene says of itself beyond `[world]`, which the defaults follow.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SceneFacts {
    /// Half the thinnest dimension of the thinnest body that falls (a sphere's or capsule's
    /// radius, a box's smallest half extent), m; `None` when no body falls.
    pub thinnest_falling_m: Option<f64>,
}

impl SceneFacts {
    /// The facts of a scene file as written (before it is built).
    pub fn of(def: &SceneFile) -> SceneFacts {
        let falls = |class: &str| {
            def.classes.iter().find(|c| c.name == class).is_some_and(|c| !c.is_static && !c.immovable && c.gravity)
        };
        let shapes = def
            .bodies
            .iter()
            .map(|b| (&b.class, &b.shape))
            .chain(def.arrays.iter().map(|a| (&a.class, &a.shape)))
            .chain(def.scatters.iter().map(|s| (&s.class, &s.shape)));
        let thinnest_falling_m =
            shapes.filter(|(class, _)| falls(class)).filter_map(|(_, shape)| half_thickness(shape)).reduce(f64::min);
        SceneFacts { thinnest_falling_m }
    }
}

/// Half the thinnest dimension of a shape, m (`None` for a mesh, which never falls).
fn half_thickness(shape: &ShapeSpec) -> Option<f64> {
    let min3 = |v: [f64; 3]| v[0].min(v[1]).min(v[2]);
    match shape {
        ShapeSpec::Sphere { radius_m } | ShapeSpec::Capsule { radius_m, .. } => Some(*radius_m),
        ShapeSpec::Cuboid { half_extents_m } => Some(min3(*half_extents_m)),
        ShapeSpec::Ellipsoid { radii_m } => Some(min3(*radii_m)),
        ShapeSpec::Convex { points } => {
            let extent = |k: usize| {
                let (lo, hi) =
                    points.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p[k]), hi.max(p[k])));
                (hi - lo) / 2.0
            };
            (!points.is_empty()).then(|| extent(0).min(extent(1)).min(extent(2)))
        }
        ShapeSpec::Mesh { .. } => None,
    }
}

/// `value` rounded to two significant figures, so a derived default reads as a person would
/// write it.
fn two_figures(value: f64) -> f64 {
    if value <= 0.0 || !value.is_finite() {
        return value;
    }
    let step = 10f64.powf(value.log10().floor() - 1.0);
    (value / step).round() * step
}

/// Every `[world]` key of `w` resolved, and the list saying where each came from, in the order
/// SCENES.md documents them. Where gravity is set, the keys that decide resting behaviour follow
/// gravity, the tick rate and the thinnest falling body (see the module docs). Values are not
/// checked here: the loader checks the resolved ones and names the key.
pub fn resolve(w: &WorldDef, facts: SceneFacts) -> (WorldKeys, Vec<Setting>) {
    let mut r = Resolver { settings: Vec::new() };
    let tick_hz = r.key("tick_hz", w.tick_hz, 64, "a power of two makes the tick exact in binary");
    let gravity = r.key("gravity", w.gravity, [0.0; 3], "none");
    let rollback_ms = r.key("rollback_ms", w.rollback_ms, 250, "covers a 200 ms round trip and its jitter");
    let input_lead_ticks = r.key("input_lead_ticks", w.input_lead_ticks, 8, "an eighth of a second at 64 Hz");
    let max_rewind_ms = r.key("max_rewind_ms", w.max_rewind_ms, rollback_ms, "the rollback window");
    let max_bodies = r.key("max_bodies", w.max_bodies, 100_000, "a bound, not a budget");
    let default_response = r.key("default_response", w.default_response, ResponseKind::Bounce, "bodies bounce");
    let g = gravity.iter().map(|x| x * x).sum::<f64>().sqrt();
    let falls = g > 0.0 && g.is_finite() && tick_hz > 0;
    let dt = 1.0 / f64::from(tick_hz.max(1));
    let restitution = if falls {
        r.key(
            "restitution",
            w.restitution,
            0.0,
            "under gravity a body that lands stays down (rapier, Box2D and Jolt default to 0)",
        )
    } else {
        r.key("restitution", w.restitution, 1.0, "no gravity: elastic, so moving bodies keep their energy")
    };
    let contact_slop_m = if falls {
        let fall = g * dt * dt;
        let wanted = 1.25 * fall;
        match facts.thinnest_falling_m {
            Some(thin) if wanted > thin / 10.0 => r.key(
                "contact_slop_m",
                w.contact_slop_m,
                two_figures(thin / 10.0).max(1.0e-4),
                format!(
                    "a tenth of the thinnest falling body ({thin} m), below 1.25 ticks of free fall ({wanted:.4} m at {tick_hz} Hz): a faster tick rate would let it rest"
                ),
            ),
            _ => r.key(
                "contact_slop_m",
                w.contact_slop_m,
                two_figures(wanted).max(1.0e-4),
                format!("1.25 ticks of free fall (one is {fall:.4} m at {tick_hz} Hz): a resting contact that lifts by a tick's fall stays one"),
            ),
        }
    } else {
        r.key("contact_slop_m", w.contact_slop_m, 1.0e-4, "no gravity: 0.1 mm, contacts are impacts")
    };
    let bounce_threshold_mps =
        r.key("bounce_threshold_mps", w.bounce_threshold_mps, 0.5, "slower contacts rest instead of rebounding");
    let toi_tolerance = r.key("toi_tolerance", w.toi_tolerance, 1.0 / 32_768.0, "2^-15 of a tick");
    let max_resolutions_per_tick =
        r.key("max_resolutions_per_tick", w.max_resolutions_per_tick, 100_000, "a bound on one tick's work");
    let friction = if falls {
        r.key("friction", w.friction, 0.5, "under gravity, rapier's: holds a body on a slope up to 26 degrees")
    } else {
        r.key("friction", w.friction, 0.0, "no gravity: frictionless, nothing rests")
    };
    let sleep_speed_mps = if falls && g * dt / 3.0 < 0.05 {
        r.key(
            "sleep_speed_mps",
            w.sleep_speed_mps,
            two_figures(g * dt / 3.0),
            format!("a third of the speed gravity gives in one tick at {tick_hz} Hz, so a body at the top of a bounce is not still"),
        )
    } else {
        r.key("sleep_speed_mps", w.sleep_speed_mps, 0.05, "5 cm/s")
    };
    let sleep_after_s = r.key("sleep_after_s", w.sleep_after_s, 0.5, "Box2D's half second");
    let partial_sleep = r.key(
        "partial_sleep",
        w.partial_sleep,
        false,
        "islands sleep whole: in parts, the untuned pile ends past its height bound (BENCHMARKS.md)",
    );
    let keys = WorldKeys {
        tick_hz,
        gravity,
        rollback_ms,
        input_lead_ticks,
        max_rewind_ms,
        max_bodies,
        default_response,
        restitution,
        contact_slop_m,
        bounce_threshold_mps,
        toi_tolerance,
        max_resolutions_per_tick,
        friction,
        sleep_speed_mps,
        sleep_after_s,
        partial_sleep,
    };
    (keys, r.settings)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world(toml_body: &str) -> WorldDef {
        toml::from_str(&format!("name = \"w\"\n{toml_body}")).unwrap()
    }

    /// A key the scene gives is used and said to come from the scene; one it leaves out takes
    /// its default and says why; every key is listed once.
    #[test]
    fn given_keys_win_and_the_rest_say_why() {
        let (keys, settings) = resolve(&world("friction = 0.7\nrestitution = 1.0"), SceneFacts::default());
        assert_eq!((keys.friction, keys.gravity, keys.restitution, keys.contact_slop_m), (0.7, [0.0; 3], 1.0, 1e-4));
        let get = |k: &str| settings.iter().find(|s| s.key == k).unwrap().clone();
        assert_eq!((get("friction").source, get("friction").value.as_str()), (Source::Scene, "0.7"));
        assert_eq!(get("contact_slop_m").source, Source::Default);
        assert!(!get("contact_slop_m").why.is_empty() && get("friction").why.is_empty());
        assert_eq!(get("default_response").value, "bounce");
        let mut names: Vec<&str> = settings.iter().map(|s| s.key).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), settings.len());
        assert_eq!(settings.len(), 16, "every [world] key but the name");
    }

    /// The rewind bound follows the rollback window unless the scene sets it.
    #[test]
    fn the_rewind_bound_follows_the_window() {
        let none = SceneFacts::default();
        assert_eq!(resolve(&world("rollback_ms = 400"), none).0.max_rewind_ms, 400);
        assert_eq!(resolve(&world("rollback_ms = 400\nmax_rewind_ms = 100"), none).0.max_rewind_ms, 100);
    }

    /// Without gravity the defaults are the arena's; with it they are what lets a body land and
    /// rest: no rebound, rapier's friction, a slop of 1.25 ticks of free fall, a sleep speed below
    /// one tick of it. Explicit keys still win.
    #[test]
    fn the_defaults_follow_gravity_the_tick_and_the_bodies() {
        let facts = SceneFacts { thinnest_falling_m: Some(0.4) };
        let flat = resolve(&world(""), facts).0;
        assert_eq!(
            (flat.restitution, flat.friction, flat.contact_slop_m, flat.sleep_speed_mps),
            (1.0, 0.0, 1e-4, 0.05)
        );
        let g = resolve(&world("gravity = [0.0, -9.81, 0.0]"), facts).0;
        // 1.25 * 9.81 / 64^2 = 2.99 mm.
        assert_eq!((g.restitution, g.friction, g.contact_slop_m, g.sleep_speed_mps), (0.0, 0.5, 0.003, 0.05));
        // At 240 Hz a tick's fall is 0.17 mm and its speed 4.1 cm/s.
        let fast = resolve(&world("gravity = [0.0, -9.81, 0.0]\ntick_hz = 240"), facts).0;
        assert_eq!((fast.contact_slop_m, fast.sleep_speed_mps), (0.00021, 0.014));
        // At 10 Hz a tick's fall is 9.8 cm: a 4 cm marble caps the slop at a tenth of it.
        let slow = SceneFacts { thinnest_falling_m: Some(0.02) };
        let (keys, settings) = resolve(&world("gravity = [0.0, -9.81, 0.0]\ntick_hz = 10"), slow);
        assert_eq!(keys.contact_slop_m, 0.002);
        assert!(settings.iter().any(|s| s.key == "contact_slop_m" && s.why.contains("thinnest")));
        let given = resolve(&world("gravity = [0.0, -9.81, 0.0]\ncontact_slop_m = 0.01\nrestitution = 0.3"), facts).0;
        assert_eq!((given.contact_slop_m, given.restitution), (0.01, 0.3));
    }

    /// The thinnest falling body: statics, immovable bodies and classes without gravity do not
    /// count.
    #[test]
    fn the_thinnest_falling_body_is_found() {
        let def: SceneFile = toml::from_str(
            "[world]\nname = \"w\"\n[[class]]\nname = \"wall\"\nstatic = true\n[[class]]\nname = \"float\"\ngravity = false\n\
             [[class]]\nname = \"crate\"\n\
             [[body]]\nclass = \"wall\"\nshape = { type = \"cuboid\", half_extents_m = [5.0, 0.01, 5.0] }\nposition = [0.0, 0.0, 0.0]\n\
             [[body]]\nclass = \"float\"\nshape = { type = \"sphere\", radius_m = 0.05 }\nposition = [0.0, 1.0, 0.0]\n\
             [[body]]\nclass = \"crate\"\nshape = { type = \"cuboid\", half_extents_m = [0.5, 0.25, 0.3] }\nposition = [0.0, 2.0, 0.0]\n",
        )
        .unwrap();
        assert_eq!(SceneFacts::of(&def).thinnest_falling_m, Some(0.25));
    }
}
