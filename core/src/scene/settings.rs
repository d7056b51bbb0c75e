//! The `[world]` settings resolved: each key the scene gives, or its default, with where the
//! value came from. One place decides every default, so `impact-server --scene F --explain` can
//! print exactly what a world runs with, and so the defaults can follow what the scene says of
//! itself.

use super::format::{ResponseKind, WorldDef};
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
    pub why: &'static str,
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

/// The `[world]` values a world runs with, every key resolved (see [`resolve`]).
#[derive(Clone, Debug, PartialEq)]
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
}

/// Collects the resolved values and where each came from.
struct Resolver {
    settings: Vec<Setting>,
}

impl Resolver {
    /// `given`, or `default` (with why), recorded under `key`.
    fn key<T: Copy + fmt::Debug>(&mut self, key: &'static str, given: Option<T>, default: T, why: &'static str) -> T {
        let (value, source) = match given {
            Some(v) => (v, Source::Scene),
            None => (default, Source::Default),
        };
        let why = if source == Source::Default { why } else { "" };
        self.settings.push(Setting { key, value: format!("{value:?}").to_lowercase(), source, why });
        value
    }
}

/// Every `[world]` key of `w` resolved, and the list saying where each came from, in the order
/// SCENES.md documents them. Values are not checked here: the loader checks the resolved ones
/// and names the key.
pub fn resolve(w: &WorldDef) -> (WorldKeys, Vec<Setting>) {
    let mut r = Resolver { settings: Vec::new() };
    let tick_hz = r.key("tick_hz", w.tick_hz, 64, "a power of two makes the tick exact in binary");
    let gravity = r.key("gravity", w.gravity, [0.0; 3], "none");
    let rollback_ms = r.key("rollback_ms", w.rollback_ms, 250, "covers a 200 ms round trip and its jitter");
    let input_lead_ticks = r.key("input_lead_ticks", w.input_lead_ticks, 8, "an eighth of a second at 64 Hz");
    let max_rewind_ms = r.key("max_rewind_ms", w.max_rewind_ms, rollback_ms, "the rollback window");
    let max_bodies = r.key("max_bodies", w.max_bodies, 100_000, "a bound, not a budget");
    let default_response = r.key("default_response", w.default_response, ResponseKind::Bounce, "bodies bounce");
    let restitution = r.key("restitution", w.restitution, 1.0, "elastic, as the zero-gravity arena wants");
    let contact_slop_m = r.key("contact_slop_m", w.contact_slop_m, 1.0e-4, "0.1 mm");
    let bounce_threshold_mps =
        r.key("bounce_threshold_mps", w.bounce_threshold_mps, 0.5, "slower contacts rest instead of rebounding");
    let toi_tolerance = r.key("toi_tolerance", w.toi_tolerance, 1.0 / 32_768.0, "2^-15 of a tick");
    let max_resolutions_per_tick =
        r.key("max_resolutions_per_tick", w.max_resolutions_per_tick, 100_000, "a bound on one tick's work");
    let friction = r.key("friction", w.friction, 0.0, "frictionless");
    let sleep_speed_mps = r.key("sleep_speed_mps", w.sleep_speed_mps, 0.05, "5 cm/s");
    let sleep_after_s = r.key("sleep_after_s", w.sleep_after_s, 0.5, "Box2D's half second");
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
        let (keys, settings) = resolve(&world("friction = 0.5\ngravity = [0.0, -9.81, 0.0]"));
        assert_eq!(
            (keys.friction, keys.gravity, keys.restitution, keys.contact_slop_m),
            (0.5, [0.0, -9.81, 0.0], 1.0, 1e-4)
        );
        let get = |k: &str| settings.iter().find(|s| s.key == k).unwrap().clone();
        assert_eq!((get("friction").source, get("friction").value.as_str()), (Source::Scene, "0.5"));
        assert_eq!(get("restitution").source, Source::Default);
        assert!(!get("restitution").why.is_empty() && get("friction").why.is_empty());
        assert_eq!(get("default_response").value, "bounce");
        let mut names: Vec<&str> = settings.iter().map(|s| s.key).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), settings.len());
        assert_eq!(settings.len(), 15, "every [world] key but the name");
    }

    /// The rewind bound follows the rollback window unless the scene sets it.
    #[test]
    fn the_rewind_bound_follows_the_window() {
        assert_eq!(resolve(&world("rollback_ms = 400")).0.max_rewind_ms, 400);
        assert_eq!(resolve(&world("rollback_ms = 400\nmax_rewind_ms = 100")).0.max_rewind_ms, 100);
    }
}
