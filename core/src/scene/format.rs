//! The scene file format (TOML), as documented in SCENES.md. Every table refuses unknown keys,
//! so a typo is an error naming the key rather than a silently ignored setting.

pub use impact_protocol::ShapeSpec;
use serde::{Deserialize, Serialize};

/// A whole scene file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// World settings.
    pub world: WorldDef,
    /// Classes.
    #[serde(default, rename = "class")]
    pub classes: Vec<ClassDef>,
    /// Responses between classes.
    #[serde(default, rename = "response")]
    pub responses: Vec<ResponseDef>,
    /// Individual bodies.
    #[serde(default, rename = "body")]
    pub bodies: Vec<BodyDef>,
    /// Random scatters of many bodies.
    #[serde(default, rename = "scatter")]
    pub scatters: Vec<ScatterDef>,
    /// Regular arrays of bodies (bricks, pins).
    #[serde(default, rename = "array")]
    pub arrays: Vec<ArrayDef>,
    /// Height-field terrain.
    #[serde(default)]
    pub terrain: Option<TerrainDef>,
    /// How client avatars and projectiles are made.
    #[serde(default)]
    pub spawn: Option<SpawnDef>,
}

fn default_max_speed() -> f64 {
    100.0
}
fn default_true() -> bool {
    true
}
fn default_density() -> f64 {
    1000.0
}

/// `[world]`, as written: a key left out is `None`, and [`super::settings`] resolves it (and
/// says where each value came from, for `impact-server --explain`).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldDef {
    /// World name (the `{world}` key segment): `[a-z0-9_-]`, 1 to 64 characters.
    pub name: String,
    /// Ticks per second.
    pub tick_hz: Option<u32>,
    /// Gravity, m/s^2.
    pub gravity: Option<[f64; 3]>,
    /// Rollback window, ms.
    pub rollback_ms: Option<u32>,
    /// How far ahead of the server an input may be stamped, ticks.
    pub input_lead_ticks: Option<u32>,
    /// How far back a hitscan ray is rewound at most, ms. Like Source's `sv_maxunlag`: a shooter
    /// with a worse connection than this shoots at a world younger than the one it saw.
    pub max_rewind_ms: Option<u32>,
    /// Most bodies.
    pub max_bodies: Option<u32>,
    /// Response for class pairs with no `[[response]]` entry.
    pub default_response: Option<ResponseKind>,
    /// Restitution for the default bounce.
    pub restitution: Option<f64>,
    /// Bodies closer than this count as touching, m.
    pub contact_slop_m: Option<f64>,
    /// Closing speed at or below which a bounce does not rebound, m/s.
    pub bounce_threshold_mps: Option<f64>,
    /// Time-of-impact tolerance as a fraction of a tick.
    pub toi_tolerance: Option<f64>,
    /// Most contact resolutions in one tick.
    pub max_resolutions_per_tick: Option<u32>,
    /// Coulomb friction of resting contacts.
    pub friction: Option<f64>,
    /// A body slower than this counts as still, m/s.
    pub sleep_speed_mps: Option<f64>,
    /// An island still for this long falls asleep, s (0 disables sleeping).
    pub sleep_after_s: Option<f64>,
    /// Whether islands also sleep in parts under gravity.
    pub partial_sleep: Option<bool>,
}

impl WorldDef {
    /// A `[world]` named `name` that gives no other key.
    pub fn named(name: &str) -> WorldDef {
        WorldDef { name: name.to_string(), ..WorldDef::default() }
    }
}

/// `[[class]]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassDef {
    /// Name.
    pub name: String,
    /// Static geometry (never moves).
    #[serde(default, rename = "static")]
    pub is_static: bool,
    /// Largest speed an input may set, m/s (default 100).
    #[serde(default = "default_max_speed")]
    pub max_speed_mps: f64,
    /// Whether gravity applies (default true).
    #[serde(default = "default_true")]
    pub gravity: bool,
    /// Density for bodies without `mass_kg`, kg/m^3 (default 1000).
    #[serde(default = "default_density")]
    pub density_kg_m3: f64,
    /// Immovable (infinite mass) but not static: bricks that can be destroyed.
    #[serde(default)]
    pub immovable: bool,
    /// Whether bodies of this class may fall asleep (default true).
    #[serde(default = "default_true")]
    pub can_sleep: bool,
    /// Its bodies are characters: moved by the server's controller from `move` intents (a
    /// client's `set_velocity` and `apply_impulse` on them are refused). Any key left out takes
    /// its default.
    pub character: Option<CharacterDef>,
}

/// `character = { ... }` of a `[[class]]`: a walking character's controller.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharacterDef {
    /// Speed on the ground at a full `move`, m/s (default 5: a jog).
    #[serde(default = "default_walk_speed")]
    pub walk_speed_mps: f64,
    /// How high a jump rises, m (default 1.2).
    #[serde(default = "default_jump_height")]
    pub jump_height_m: f64,
    /// The steepest ground it stands and walks on, degrees from level (default 45); steeper is
    /// a wall it slides down.
    #[serde(default = "default_max_slope")]
    pub max_slope_deg: f64,
    /// The highest ledge it walks onto without a jump, m (default 0.3: a stair, a kerb).
    #[serde(default = "default_step_height")]
    pub step_height_m: f64,
    /// In the air, a `move` changes the horizontal velocity by this fraction of the difference
    /// (default 0.1: a little steering, momentum kept; 0 none, 1 full control).
    #[serde(default = "default_air_control")]
    pub air_control: f64,
}

fn default_walk_speed() -> f64 {
    5.0
}

fn default_jump_height() -> f64 {
    1.2
}

fn default_max_slope() -> f64 {
    45.0
}

fn default_step_height() -> f64 {
    0.3
}

fn default_air_control() -> f64 {
    0.1
}

/// A response kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResponseKind {
    /// Not tested at all.
    Ignore,
    /// Event only.
    Trigger,
    /// Reflect along the normal.
    #[default]
    Bounce,
    /// Slide along.
    Slide,
    /// Stop.
    Stop,
    /// Destroy (see `destroy`).
    Destroy,
}

/// Which side a destroy response removes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DestroyWhich {
    /// The first class in `between`.
    First,
    /// The second class in `between`.
    Second,
    /// Both.
    Both,
}

/// `[[response]]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResponseDef {
    /// The two classes.
    pub between: [String; 2],
    /// What happens.
    pub kind: ResponseKind,
    /// Restitution for `bounce` (default: the world's). With `destroy`, the survivor bounces
    /// off the destroyed body with this restitution; without it, it passes on.
    #[serde(default)]
    pub restitution: Option<f64>,
    /// Who goes, for `destroy` (required there).
    #[serde(default)]
    pub destroy: Option<DestroyWhich>,
}

/// `[[body]]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyDef {
    /// Class name.
    pub class: String,
    /// Shape.
    pub shape: ShapeSpec,
    /// Centre, m.
    pub position: [f64; 3],
    /// Velocity, m/s.
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Orientation as rotations about x, y, z in degrees, applied in that order.
    #[serde(default)]
    pub rotation_deg: [f64; 3],
    /// Mass, kg (default: density x volume).
    #[serde(default)]
    pub mass_kg: Option<f64>,
    /// Owning client id, so scripted or real inputs may drive it.
    #[serde(default)]
    pub owner: Option<u32>,
}

/// `[[scatter]]`: `count` bodies placed on a jittered lattice inside a box, never overlapping,
/// with random velocities, from a seeded generator (the same seed gives the same scene).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScatterDef {
    /// Class name.
    pub class: String,
    /// Shape of every body.
    pub shape: ShapeSpec,
    /// How many.
    pub count: u32,
    /// Region minimum corner, m.
    pub min: [f64; 3],
    /// Region maximum corner, m.
    pub max: [f64; 3],
    /// Speed range `[lo, hi]`, m/s, in uniformly random directions (default at rest).
    #[serde(default)]
    pub speed_mps: [f64; 2],
    /// Restrict velocities to the x-z plane.
    #[serde(default)]
    pub planar: bool,
    /// Generator seed.
    #[serde(default)]
    pub seed: u64,
}

/// `[[array]]`: a regular grid of bodies.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArrayDef {
    /// Class name.
    pub class: String,
    /// Shape of every body.
    pub shape: ShapeSpec,
    /// Centre of the first body, m.
    pub origin: [f64; 3],
    /// Bodies along x, y, z.
    pub count: [u32; 3],
    /// Spacing along x, y, z, m.
    pub spacing_m: [f64; 3],
    /// Velocity of every body, m/s.
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Orientation of every body, as `[[body]]`'s: rotations about x, y, z in degrees, applied
    /// in that order (boxes laid on a ramp).
    #[serde(default)]
    pub rotation_deg: [f64; 3],
}

/// `[terrain]`: a height field, given as rows or generated.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TerrainDef {
    /// Class name (usually a static class).
    pub class: String,
    /// Corner of sample (0, 0); heights are added to its y, m.
    pub origin: [f64; 3],
    /// Cell size along x and z, m.
    pub cell_m: [f64; 2],
    /// Heights by row (z) then column (x), m.
    #[serde(default)]
    pub heights: Option<Vec<Vec<f64>>>,
    /// Or: rolling hills generated on an `nx` x `nz` grid.
    #[serde(default)]
    pub hills: Option<HillsDef>,
}

/// Generated rolling hills: `amplitude * sin(2 pi x / wavelength) * cos(2 pi z / wavelength)`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HillsDef {
    /// Samples along x.
    pub nx: u32,
    /// Samples along z.
    pub nz: u32,
    /// Height amplitude, m.
    pub amplitude_m: f64,
    /// Wavelength, m.
    pub wavelength_m: f64,
}

/// `[spawn]`: avatars for clients that join, and the projectile class.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpawnDef {
    /// Class of avatars (`None`: clients get no avatar).
    #[serde(default)]
    pub avatar_class: Option<String>,
    /// Shape of avatars.
    #[serde(default)]
    pub avatar_shape: Option<ShapeSpec>,
    /// Avatars appear at random points of this box (min corner), m.
    #[serde(default)]
    pub region_min: [f64; 3],
    /// Max corner, m.
    #[serde(default)]
    pub region_max: [f64; 3],
    /// Class of client-spawned projectiles.
    #[serde(default)]
    pub projectile_class: Option<String>,
}
