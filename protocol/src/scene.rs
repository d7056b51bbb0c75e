//! The answer to `query/scene`: the rules and the static world exactly as the server's core runs
//! them, so a client steps the same core on the same bits (its own avatar's prediction) without
//! the scene file.
//!
//! Everything is resolved: every `[world]` key after its default, every number the f64 the
//! server holds, every orientation a unit quaternion `[x, y, z, w]` (a scene file's degrees go
//! through a platform's sine and cosine, which may round differently elsewhere). The dynamic
//! bodies are not here: they come and go with the state streams.

use crate::ids::{EntityId, WorldId};
use crate::shape::ShapeSpec;
use serde::{Deserialize, Serialize};

/// A world's rules and static geometry (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneDescription {
    /// The world.
    pub world: WorldId,
    /// The welcome's `scene_hash`: what a client that rebuilds this world must hash to.
    pub scene_hash: u64,
    /// The world-wide settings.
    pub rules: WorldRules,
    /// The classes; a class id is an index into this list.
    pub classes: Vec<ClassRules>,
    /// What happens when a body of class `a` meets one of class `b`, row-major:
    /// `pair_rules[a * classes.len() + b]`.
    pub pair_rules: Vec<PairRule>,
    /// Static bodies, by ascending entity id.
    pub statics: Vec<StaticBody>,
    /// The height field, if the world has terrain.
    pub terrain: Option<TerrainSpec>,
    /// How an avatar is made for a client that joins (`None`: the world spawns none).
    pub avatar: Option<AvatarSpec>,
    /// Choices the server made once from the whole initial world (its dynamic bodies too) that
    /// change how a tick steps.
    pub plan: PlanSpec,
}

/// World-wide settings, resolved.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldRules {
    /// Ticks per second.
    pub tick_hz: u32,
    /// Step length, seconds.
    pub dt: f64,
    /// Gravity, m/s^2.
    pub gravity: [f64; 3],
    /// Two bodies closer than this (m) touch.
    pub contact_slop_m: f64,
    /// Closing speeds at or below this (m/s) get no rebound.
    pub bounce_threshold_mps: f64,
    /// Most contact resolutions per tick.
    pub max_resolutions_per_tick: u32,
    /// Coulomb friction of resting contacts.
    pub friction: f64,
    /// A body slower than this (m/s) counts as still.
    pub sleep_speed_mps: f64,
    /// Still ticks before an island sleeps (0: never).
    pub sleep_after_ticks: u32,
    /// Whether islands also sleep in parts, from the bottom up, under gravity (absent: `false`,
    /// as before it existed).
    #[serde(default)]
    pub partial_sleep: bool,
    /// Most bodies the world holds.
    pub max_bodies: u32,
    /// Rollback window, ticks.
    pub window_ticks: u32,
    /// How far ahead an input's tick may be, ticks.
    pub input_lead_ticks: u32,
    /// How far back a ray may be rewound, ticks.
    pub max_rewind_ticks: u32,
    /// The class of client-spawned projectiles (`None`: spawning is refused).
    pub projectile_class: Option<u16>,
    /// Time-of-impact search.
    pub toi: ToiRules,
}

/// The time-of-impact search's settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ToiRules {
    /// Widest bracket, a fraction of the step.
    pub tolerance: f64,
    /// Farthest a pair moves across the bracket, m.
    pub tolerance_m: f64,
    /// Most halvings.
    pub max_iterations: u32,
    /// Most overlap samples for a fast pair in a step.
    pub max_samples: u32,
}

/// One class.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassRules {
    /// Its name in the scene.
    pub name: String,
    /// Static geometry.
    pub is_static: bool,
    /// Largest speed an input may set, m/s.
    pub max_speed_mps: f64,
    /// Whether gravity applies.
    pub gravity: bool,
    /// Density of bodies spawned without a mass, kg/m^3.
    pub density_kg_m3: f64,
    /// Whether its bodies may sleep.
    pub can_sleep: bool,
    /// Its controller, if its bodies are characters (moved by `move` only).
    #[serde(default)]
    pub character: Option<CharacterRules>,
}

/// A character class's controller, resolved.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CharacterRules {
    /// Speed on the ground at a full `move`, m/s.
    pub walk_speed_mps: f64,
    /// The vertical speed a jump starts with, m/s (`sqrt(2 g h)` for the scene's jump height).
    pub jump_speed_mps: f64,
    /// Ground is walkable where its normal's component along up is at least this (the cosine
    /// of the scene's slope limit).
    pub min_ground_normal_up: f64,
    /// The highest ledge it walks onto without a jump, m.
    pub step_height_m: f64,
    /// In the air a `move` changes the horizontal velocity by this fraction of the difference.
    pub air_control: f64,
}

/// The response for an ordered pair of classes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairRule {
    /// Never tested.
    Ignore,
    /// An event only.
    Trigger,
    /// Velocities reflected with this restitution.
    Bounce {
        /// In [0, 1].
        restitution: f64,
    },
    /// The approaching normal velocity removed.
    Slide,
    /// The moving bodies stop.
    Stop,
    /// Remove the row class's body (`first`) and/or the column class's (`second`).
    Destroy {
        /// The row class's body goes.
        first: bool,
        /// The column class's body goes.
        second: bool,
        /// The survivor bounces off with this restitution, if set.
        restitution: Option<f64>,
    },
}

/// A static body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StaticBody {
    /// Its entity id.
    pub entity: EntityId,
    /// Its class id.
    pub class: u16,
    /// Its shape, local frame.
    pub shape: ShapeSpec,
    /// Position, m.
    pub position: [f64; 3],
    /// Orientation, a unit quaternion `[x, y, z, w]`.
    pub orientation: [f64; 4],
}

/// A height field: `heights[iz * columns + ix]` metres above `origin[1]` at
/// `(origin[0] + ix * cell_x_m, origin[2] + iz * cell_z_m)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TerrainSpec {
    /// Its entity id.
    pub entity: EntityId,
    /// Its class id.
    pub class: u16,
    /// The corner of cell (0, 0), m.
    pub origin: [f64; 3],
    /// Cell size along x, m.
    pub cell_x_m: f64,
    /// Cell size along z, m.
    pub cell_z_m: f64,
    /// Samples along x.
    pub columns: u32,
    /// Samples along z.
    pub rows: u32,
    /// Heights, row-major by z.
    pub heights: Vec<f64>,
}

/// How a joining client's avatar is made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AvatarSpec {
    /// Its class id.
    pub class: u16,
    /// Its shape.
    pub shape: ShapeSpec,
    /// The spawn box's min corner, m.
    pub region_min: [f64; 3],
    /// ...and max corner, m.
    pub region_max: [f64; 3],
}

/// What the server chose from its initial world that a client cannot see from the rest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlanSpec {
    /// Fast pairs are sampled finely through the step (some class may move farther than a
    /// shape's extent in one tick); off, a pair is tested at the end of the step only.
    pub ccd_sampling: bool,
    /// The broadphase's name (`brute`, `grid`, `sap`, `bvh`; informative: pairs are
    /// sorted, so results do not depend on it).
    pub broadphase: String,
}
