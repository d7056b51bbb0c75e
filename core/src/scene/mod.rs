//! Scenes: the TOML format ([`format`](mod@format)), and loading a file into a [`World`] with errors that
//! name the file, the entry and what is wrong. See SCENES.md.

pub mod describe;
pub mod format;
pub mod random;
pub mod settings;
pub mod warnings;

use crate::broadphase::StaticIndex;
use crate::geometry::Shape;
use crate::sim::world::{
    Bodies, CharacterProps, ClassId, ClassProps, Classes, NewBody, Rule, SimConfig, StaticWorld, Terrain, World,
};
use crate::terrain::heightfield::HeightField;
use crate::toi::bisect::BisectConfig;
use format::*;
use glam::{DQuat, DVec3};
use impact_protocol::{ClientId, EntityId, Tick, WorldId};
use random::SplitMix64;
use settings::WorldKeys;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub use describe::SceneRules;

/// A scene that could not be loaded: which file, which entry, what is wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{file}: {entry}: {detail}")]
pub struct SceneError {
    /// The file (or `<inline>`).
    pub file: String,
    /// The entry, e.g. `body[3].shape.radius_m` or `line 12, column 5`.
    pub entry: String,
    /// What is wrong.
    pub detail: String,
}

/// A loaded scene: the initial world and the rules the runtime needs for clients.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The world name.
    pub name: WorldId,
    /// The world at tick 0.
    pub world: World,
    /// Avatar rules, if clients get avatars.
    pub avatar: Option<AvatarRule>,
    /// Every `[world]` key as resolved: what the world runs with (recordings and checkpoints
    /// carry it).
    pub keys: WorldKeys,
    /// What the scene says of itself that the defaults follow (its thinnest falling body).
    pub facts: settings::SceneFacts,
    /// Every `[world]` key as resolved, and where each value came from (`--explain`).
    pub settings: Vec<settings::Setting>,
    /// What the keys contradict: a world that loads but cannot come to rest.
    pub warnings: Vec<warnings::SceneWarning>,
}

/// How an avatar is made for a client that joins.
#[derive(Debug, Clone)]
pub struct AvatarRule {
    /// Class.
    pub class: ClassId,
    /// Shape.
    pub shape: Shape,
    /// Spawn box min corner, m.
    pub region_min: DVec3,
    /// Spawn box max corner, m.
    pub region_max: DVec3,
}

impl Scene {
    /// Loads a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Scene::load_with(path, |_| {})
    }

    /// Loads a scene file with its `[world]` keys adjusted before they are resolved: a command
    /// line's `--tick-hz`, or the values a recording ran with. Defaults that follow a key follow
    /// the adjusted one.
    pub fn load_with(path: &Path, adjust: impl FnOnce(&mut WorldDef)) -> Result<Scene, SceneError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| SceneError {
            file: file.clone(),
            entry: "file".into(),
            detail: e.to_string(),
        })?;
        Scene::parse_with(&text, &file, adjust)
    }

    /// Parses scene text; `file` names it in errors.
    pub fn parse(text: &str, file: &str) -> Result<Scene, SceneError> {
        Scene::parse_with(text, file, |_| {})
    }

    /// Parses scene text with its `[world]` keys adjusted first (see [`Scene::load_with`]).
    pub fn parse_with(text: &str, file: &str, adjust: impl FnOnce(&mut WorldDef)) -> Result<Scene, SceneError> {
        let mut def: SceneFile = toml::from_str(text).map_err(|e| {
            let entry = e
                .span()
                .map(|s| {
                    let line = text[..s.start.min(text.len())].matches('\n').count() + 1;
                    format!("line {line}")
                })
                .unwrap_or_else(|| "document".into());
            SceneError { file: file.into(), entry, detail: e.message().to_string() }
        })?;
        adjust(&mut def.world);
        Builder { file: file.into() }.build(&def)
    }

    /// The bundled scene by name (`arena`, `breakout`, `corridor`, `terrain`, `bullets`), from
    /// the `scenes/` directory of [`checkout`].
    pub fn bundled_path(name: &str) -> PathBuf {
        checkout().join("scenes").join(format!("{name}.toml"))
    }
}

/// The impact repository the working directory is in (its root or any folder below it, as
/// `cargo test` and the README's commands run), else the one this crate was built from. Cargo does
/// not rebuild a crate whose checkout moved, so a build kept across clones (CI's cache) must not
/// send every test and tool to a clone that may be gone, or that holds other scenes.
pub fn checkout() -> PathBuf {
    let is_checkout =
        |root: &Path| root.join("scenes").is_dir() && root.join("core").join("src").join("scene").is_dir();
    let here = std::env::current_dir().ok().and_then(|d| d.ancestors().find(|a| is_checkout(a)).map(Path::to_path_buf));
    here.unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".."))
}

struct Builder {
    file: String,
}

/// A body on its way into the world.
struct Item {
    entry: String,
    class: ClassId,
    shape: Shape,
    pos: DVec3,
    vel: DVec3,
    rot: DQuat,
    mass: Option<f64>,
    owner: Option<ClientId>,
}

impl Item {
    /// A body an `[[array]]` or `[[scatter]]` entry made: placed upright, mass from density, no
    /// owner.
    fn generated(entry: &str, class: ClassId, shape: &Shape, pos: DVec3, vel: DVec3, rot: DQuat) -> Item {
        let (mass, owner) = (None, None);
        Item { entry: entry.to_string(), class, shape: shape.clone(), pos, vel, rot, mass, owner }
    }
}

fn finite3(v: [f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// An orientation written as rotations about x, y, z in degrees, applied in that order.
fn rotation(deg: [f64; 3]) -> DQuat {
    let r = deg.map(f64::to_radians);
    DQuat::from_rotation_z(r[2]) * DQuat::from_rotation_y(r[1]) * DQuat::from_rotation_x(r[0])
}

impl Builder {
    /// Refuses `more` bodies from `entry` when the `so_far` already placed leave no room under
    /// `max_bodies` (checked before they are built, so a count in the billions costs nothing).
    fn room(&self, so_far: usize, more: u64, entry: &str, max_bodies: u32) -> Result<(), SceneError> {
        let total = (so_far as u64).saturating_add(more);
        if total > u64::from(max_bodies) {
            return Err(self.err(
                "world.max_bodies",
                format!("{entry} brings the scene to {total} bodies, over max_bodies = {max_bodies}"),
            ));
        }
        Ok(())
    }

    fn err(&self, entry: impl Into<String>, detail: impl Into<String>) -> SceneError {
        SceneError { file: self.file.clone(), entry: entry.into(), detail: detail.into() }
    }

    fn class(&self, classes: &Classes, name: &str, entry: &str) -> Result<ClassId, SceneError> {
        classes.by_name(name).ok_or_else(|| {
            let known: Vec<&str> = classes.props.iter().map(|p| p.name.as_str()).collect();
            self.err(entry, format!("unknown class {name:?} (classes: {})", known.join(", ")))
        })
    }

    /// An entry's class and shape (`entry` names them in errors as `{entry}.class` and
    /// `{entry}.shape`).
    fn class_and_shape(
        &self,
        classes: &Classes,
        class: &str,
        shape: &ShapeSpec,
        entry: &str,
    ) -> Result<(ClassId, Shape), SceneError> {
        let class = self.class(classes, class, &format!("{entry}.class"))?;
        let shape = self.shape(shape, &format!("{entry}.shape"), classes.props[class.0 as usize].is_static)?;
        Ok((class, shape))
    }

    /// The shape `s` describes (`entry` names it in errors); a mesh only for a static class.
    fn shape(&self, s: &ShapeSpec, entry: &str, is_static: bool) -> Result<Shape, SceneError> {
        if matches!(s, ShapeSpec::Mesh { .. }) && !is_static {
            return Err(self.err(entry, "a mesh can only belong to a static class"));
        }
        Shape::from_spec(s).map_err(|e| {
            let field = if e.field.is_empty() { entry.to_string() } else { format!("{entry}.{}", e.field) };
            self.err(field, e.detail)
        })
    }

    /// The scene `def` describes, checked entry by entry: the world's keys, the classes and their
    /// responses, the terrain, the bodies (placed in file order, ids ascending), the spawn rules.
    fn build(&self, def: &SceneFile) -> Result<Scene, SceneError> {
        let name = WorldId::new(def.world.name.clone()).map_err(|e| self.err("world.name", e.to_string()))?;
        let facts = settings::SceneFacts::of(def);
        let (keys, settings) = settings::resolve(&def.world, facts);
        let w = &keys;
        let bisect = self.world_keys(w)?;
        let (mut classes, immovable) = self.classes(def, w)?;
        self.responses(def, w, &mut classes)?;
        // Bodies, in file order: [[body]], then [[array]], then [[scatter]]. Ids ascend in that
        // order; the terrain, if any, is entity 0.
        let mut next_id: u32 = 0;
        let terrain = self.terrain(def, &classes, &mut next_id)?;
        let mut items: Vec<Item> = Vec::new();
        self.bodies(def, &classes, &mut items)?;
        self.arrays(def, w, &classes, &mut items)?;
        self.scatters(def, w, &classes, &mut items)?;
        let total = items.len() + usize::from(terrain.is_some());
        if total > w.max_bodies as usize {
            return Err(self
                .err("world.max_bodies", format!("the scene has {total} bodies, over max_bodies = {}", w.max_bodies)));
        }

        let (static_world, bodies) = self.place(items, &classes, &immovable, terrain, &mut next_id)?;
        let (avatar, projectile_class) = self.spawn_rules(def, &classes)?;
        let config = sim_config(w, classes, bisect, projectile_class);
        let world = World {
            tick: Tick(0),
            bodies,
            next_entity: next_id,
            touching: Vec::new(),
            statics: Arc::new(static_world),
            config: Arc::new(config),
        };
        let warnings = warnings::check(&keys, &world);
        Ok(Scene { name, world, avatar, keys, facts, settings, warnings })
    }

    /// Checks `[world]`'s keys; the bisection settings they give.
    fn world_keys(&self, w: &WorldKeys) -> Result<BisectConfig, SceneError> {
        if w.max_bodies > MAX_SCENE_BODIES {
            return Err(
                self.err("world.max_bodies", format!("{} is over the limit of {MAX_SCENE_BODIES}", w.max_bodies))
            );
        }
        if !(1..=1000).contains(&w.tick_hz) {
            return Err(self.err("world.tick_hz", format!("{} must be in 1..=1000", w.tick_hz)));
        }
        if !finite3(w.gravity) {
            return Err(self.err("world.gravity", "must be finite"));
        }
        if !(w.contact_slop_m.is_finite() && w.contact_slop_m > 0.0 && w.contact_slop_m < 1.0) {
            return Err(self.err("world.contact_slop_m", format!("{} must be in (0, 1) m", w.contact_slop_m)));
        }
        let tol = w.toi_tolerance;
        if !(tol.is_finite() && tol > 0.0 && tol <= 0.5) {
            return Err(self.err("world.toi_tolerance", format!("{tol} must be in (0, 0.5] (fraction of a tick)")));
        }
        let bisect = BisectConfig { tolerance: tol, ..BisectConfig::default() };
        if !(w.bounce_threshold_mps.is_finite() && w.bounce_threshold_mps >= 0.0) {
            return Err(self.err("world.bounce_threshold_mps", "must be finite and >= 0"));
        }
        if !(w.friction.is_finite() && w.friction >= 0.0 && w.friction <= 10.0) {
            return Err(self.err("world.friction", format!("{} must be in [0, 10]", w.friction)));
        }
        if !(w.sleep_speed_mps.is_finite() && w.sleep_speed_mps >= 0.0) {
            return Err(self.err("world.sleep_speed_mps", format!("{} must be finite and >= 0", w.sleep_speed_mps)));
        }
        if !(w.sleep_after_s.is_finite() && (0.0..=3600.0).contains(&w.sleep_after_s)) {
            return Err(
                self.err("world.sleep_after_s", format!("{} must be in [0, 3600] s (0: never)", w.sleep_after_s))
            );
        }
        if !(0.0..=1.0).contains(&w.restitution) {
            return Err(self.err("world.restitution", format!("{} must be in [0, 1]", w.restitution)));
        }
        Ok(bisect)
    }

    /// A `character` table resolved: the jump height as the speed that reaches it under the
    /// world's gravity, the slope limit as the least walkable normal component along up.
    fn character(&self, c: &CharacterDef, w: &WorldKeys, entry: &str) -> Result<CharacterProps, SceneError> {
        let check = |ok: bool, key: &str, want: &str| {
            if ok {
                Ok(())
            } else {
                Err(self.err(format!("{entry}.character.{key}"), want.to_string()))
            }
        };
        check(c.walk_speed_mps.is_finite() && c.walk_speed_mps > 0.0, "walk_speed_mps", "must be positive and finite")?;
        check(c.jump_height_m.is_finite() && c.jump_height_m >= 0.0, "jump_height_m", "must be 0 or more, finite")?;
        check(c.max_slope_deg > 0.0 && c.max_slope_deg < 90.0, "max_slope_deg", "must be between 0 and 90 degrees")?;
        check((0.0..=1.0).contains(&c.air_control), "air_control", "must be in [0, 1]")?;
        check(c.step_height_m.is_finite() && c.step_height_m >= 0.0, "step_height_m", "must be 0 or more, finite")?;
        let g = DVec3::from_array(w.gravity).length();
        Ok(CharacterProps {
            walk_speed_mps: c.walk_speed_mps,
            jump_speed_mps: (2.0 * g * c.jump_height_m).sqrt(),
            min_ground_normal_up: c.max_slope_deg.to_radians().cos(),
            step_height_m: c.step_height_m,
            air_control: c.air_control,
        })
    }

    /// The classes, with the default response, and which are immovable (static, or marked so).
    fn classes(&self, def: &SceneFile, w: &WorldKeys) -> Result<(Classes, Vec<bool>), SceneError> {
        if def.classes.is_empty() {
            return Err(self.err("class", "a scene needs at least one [[class]]"));
        }
        let mut props = Vec::new();
        let mut immovable = Vec::new();
        for (k, c) in def.classes.iter().enumerate() {
            let entry = format!("class[{k}]");
            if def.classes[..k].iter().any(|o| o.name == c.name) {
                return Err(self.err(format!("{entry}.name"), format!("class {:?} is defined twice", c.name)));
            }
            if !(c.max_speed_mps.is_finite() && c.max_speed_mps > 0.0) {
                return Err(self.err(format!("{entry}.max_speed_mps"), "must be positive and finite"));
            }
            if !(c.density_kg_m3.is_finite() && c.density_kg_m3 > 0.0) {
                return Err(self.err(format!("{entry}.density_kg_m3"), "must be positive and finite"));
            }
            let character = match &c.character {
                Some(_) if c.is_static => {
                    return Err(self.err(format!("{entry}.character"), "a static class cannot be a character"));
                }
                Some(ch) => Some(self.character(ch, w, &entry)?),
                None => None,
            };
            props.push(ClassProps {
                name: c.name.clone(),
                is_static: c.is_static,
                max_speed_mps: c.max_speed_mps,
                gravity: c.gravity,
                density_kg_m3: c.density_kg_m3,
                can_sleep: c.can_sleep,
                character,
            });
            immovable.push(c.immovable || c.is_static);
        }
        let default =
            rule_of(w.default_response, w.restitution, None, None).expect("default response has no destroy side");
        Ok((Classes::new(props, default), immovable))
    }

    /// Sets the rule of each `[[response]]` on `classes`.
    fn responses(&self, def: &SceneFile, w: &WorldKeys, classes: &mut Classes) -> Result<(), SceneError> {
        for (k, r) in def.responses.iter().enumerate() {
            let entry = format!("response[{k}]");
            let a = self.class(classes, &r.between[0], &format!("{entry}.between[0]"))?;
            let b = self.class(classes, &r.between[1], &format!("{entry}.between[1]"))?;
            let restitution = r.restitution.unwrap_or(w.restitution);
            if !(0.0..=1.0).contains(&restitution) {
                return Err(self.err(format!("{entry}.restitution"), format!("{restitution} must be in [0, 1]")));
            }
            let rule = rule_of(r.kind, restitution, r.destroy, r.restitution).ok_or_else(|| {
                self.err(
                    format!("{entry}.destroy"),
                    "kind = \"destroy\" needs destroy = \"first\", \"second\" or \"both\"",
                )
            })?;
            if let Rule::Destroy { first, second, .. } = rule {
                for (goes, class, side) in [(first, a, "first"), (second, b, "second")] {
                    if goes && classes.props[class.0 as usize].is_static {
                        return Err(self.err(
                            format!("{entry}.destroy"),
                            format!(
                                "the {side} class {:?} is static and cannot be destroyed",
                                classes.props[class.0 as usize].name
                            ),
                        ));
                    }
                }
            }
            classes.set_rule(a, b, rule);
        }

        Ok(())
    }

    /// The terrain, if the scene has one (it takes the next id).
    fn terrain(&self, def: &SceneFile, classes: &Classes, next_id: &mut u32) -> Result<Option<Terrain>, SceneError> {
        Ok(match &def.terrain {
            None => None,
            Some(t) => {
                let class = self.class(classes, &t.class, "terrain.class")?;
                let samples = match (&t.heights, &t.hills) {
                    (Some(h), None) => h.iter().map(|r| r.len() as u64).sum::<u64>(),
                    (None, Some(h)) => u64::from(h.nx.max(2)) * u64::from(h.nz.max(2)),
                    _ => 0,
                };
                if samples > MAX_TERRAIN_SAMPLES {
                    return Err(self.err(
                        "terrain",
                        format!("{samples} height samples, at most {MAX_TERRAIN_SAMPLES} (2048 x 2048)"),
                    ));
                }
                let rows = match (&t.heights, &t.hills) {
                    (Some(h), None) => h.clone(),
                    (None, Some(h)) => hills(h),
                    _ => return Err(self.err("terrain", "give exactly one of `heights` or `hills`")),
                };
                if !finite3(t.origin) {
                    return Err(self.err("terrain.origin", "must be finite"));
                }
                let field = HeightField::new(DVec3::from_array(t.origin), t.cell_m[0], t.cell_m[1], &rows)
                    .map_err(|e| self.err("terrain", e.to_string()))?;
                let id = EntityId(*next_id);
                *next_id += 1;
                Some(Terrain { id, class, field })
            }
        })
    }

    /// `[[body]]` entries, one item each.
    fn bodies(&self, def: &SceneFile, classes: &Classes, items: &mut Vec<Item>) -> Result<(), SceneError> {
        for (k, b) in def.bodies.iter().enumerate() {
            let entry = format!("body[{k}]");
            let (class, shape) = self.class_and_shape(classes, &b.class, &b.shape, &entry)?;
            for (field, v) in [("position", b.position), ("velocity", b.velocity), ("rotation_deg", b.rotation_deg)] {
                if !finite3(v) {
                    return Err(self.err(format!("{entry}.{field}"), "must be finite"));
                }
            }
            if let Some(m) = b.mass_kg {
                if !(m.is_finite() && m > 0.0) {
                    return Err(self.err(format!("{entry}.mass_kg"), format!("{m} must be positive and finite")));
                }
            }
            let rot = rotation(b.rotation_deg);
            let (pos, vel) = (DVec3::from_array(b.position), DVec3::from_array(b.velocity));
            items.push(Item { entry, class, shape, pos, vel, rot, mass: b.mass_kg, owner: b.owner.map(ClientId) });
        }
        Ok(())
    }

    /// `[[array]]` entries: a lattice of items each.
    fn arrays(
        &self,
        def: &SceneFile,
        w: &WorldKeys,
        classes: &Classes,
        items: &mut Vec<Item>,
    ) -> Result<(), SceneError> {
        for (k, a) in def.arrays.iter().enumerate() {
            let entry = format!("array[{k}]");
            let (class, shape) = self.class_and_shape(classes, &a.class, &a.shape, &entry)?;
            if !finite3(a.origin) || !finite3(a.spacing_m) || !finite3(a.velocity) || !finite3(a.rotation_deg) {
                return Err(self.err(entry, "origin, spacing_m, velocity and rotation_deg must be finite"));
            }
            let rot = rotation(a.rotation_deg);
            // Counted before anything is built: 10 x 888,888 x 2 bricks took 3.4 GB (fuzzing).
            let n = a.count.iter().fold(1u64, |acc, &c| acc.saturating_mul(u64::from(c)));
            self.room(items.len(), n, &entry, w.max_bodies)?;
            for z in 0..a.count[2] {
                for y in 0..a.count[1] {
                    for x in 0..a.count[0] {
                        let p = DVec3::from_array(a.origin)
                            + DVec3::new(x as f64, y as f64, z as f64) * DVec3::from_array(a.spacing_m);
                        items.push(Item::generated(&entry, class, &shape, p, DVec3::from_array(a.velocity), rot));
                    }
                }
            }
        }
        Ok(())
    }

    /// `[[scatter]]` entries: items placed by a seeded generator.
    fn scatters(
        &self,
        def: &SceneFile,
        w: &WorldKeys,
        classes: &Classes,
        items: &mut Vec<Item>,
    ) -> Result<(), SceneError> {
        for (k, s) in def.scatters.iter().enumerate() {
            let entry = format!("scatter[{k}]");
            let (class, shape) = self.class_and_shape(classes, &s.class, &s.shape, &entry)?;
            self.room(items.len(), u64::from(s.count), &entry, w.max_bodies)?;
            let placed = random::scatter(s, &shape).map_err(|d| self.err(&entry, d))?;
            for (p, v) in placed {
                items.push(Item::generated(&entry, class, &shape, p, v, DQuat::IDENTITY));
            }
        }
        Ok(())
    }

    /// The items given ids in order: static ones into the static world (with its index and the
    /// terrain), the others into the bodies, with their masses.
    fn place(
        &self,
        items: Vec<Item>,
        classes: &Classes,
        immovable: &[bool],
        terrain: Option<Terrain>,
        next_id: &mut u32,
    ) -> Result<(StaticWorld, Bodies), SceneError> {
        let mut statics = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut bodies = Bodies::default();
        for Item { entry, class, shape, pos, vel, rot, mass, owner } in items {
            let id = EntityId(*next_id);
            *next_id += 1;
            if classes.props[class.0 as usize].is_static {
                if vel != DVec3::ZERO || owner.is_some() {
                    return Err(self.err(entry, "a static body cannot have a velocity or an owner"));
                }
                statics.5.push(shape.world_aabb(pos, rot));
                statics.0.push(id);
                statics.1.push(class);
                statics.2.push(shape);
                statics.3.push(pos);
                statics.4.push(rot);
            } else {
                let inv_mass = if immovable[class.0 as usize] {
                    0.0
                } else {
                    1.0 / mass.unwrap_or_else(|| classes.props[class.0 as usize].density_kg_m3 * shape.volume())
                };
                bodies.push(id, NewBody { class, shape, pos, vel, rot, inv_mass, owner });
            }
        }
        let index = StaticIndex::new(&statics.5);
        Ok((
            StaticWorld {
                id: statics.0,
                class: statics.1,
                shape: statics.2,
                pos: statics.3,
                rot: statics.4,
                aabb: statics.5,
                index,
                terrain,
            },
            bodies,
        ))
    }

    /// `[spawn]`: the avatar rule and the projectile class.
    fn spawn_rules(
        &self,
        def: &SceneFile,
        classes: &Classes,
    ) -> Result<(Option<AvatarRule>, Option<ClassId>), SceneError> {
        Ok(match &def.spawn {
            None => (None, None),
            Some(sp) => {
                let avatar = match (&sp.avatar_class, &sp.avatar_shape) {
                    (Some(c), Some(s)) => {
                        let class = self.class(classes, c, "spawn.avatar_class")?;
                        if classes.props[class.0 as usize].is_static {
                            return Err(self.err("spawn.avatar_class", "avatars cannot be static"));
                        }
                        let shape = self.shape(s, "spawn.avatar_shape", false)?;
                        Some(AvatarRule {
                            class,
                            shape,
                            region_min: DVec3::from_array(sp.region_min),
                            region_max: DVec3::from_array(sp.region_max),
                        })
                    }
                    (None, None) => None,
                    _ => return Err(self.err("spawn", "avatar_class and avatar_shape go together")),
                };
                let projectile = match &sp.projectile_class {
                    Some(c) => Some(self.class(classes, c, "spawn.projectile_class")?),
                    None => None,
                };
                (avatar, projectile)
            }
        })
    }
}

/// The core's configuration from `[world]`, the classes and the spawn rules.
fn sim_config(w: &WorldKeys, classes: Classes, bisect: BisectConfig, projectile_class: Option<ClassId>) -> SimConfig {
    let dt = 1.0 / f64::from(w.tick_hz);
    let window_ticks = crate::sim::world::window_ticks(w.rollback_ms, w.tick_hz);
    SimConfig {
        tick_hz: w.tick_hz,
        dt,
        gravity: DVec3::from_array(w.gravity),
        classes,
        bisect,
        contact_slop_m: w.contact_slop_m,
        bounce_threshold_mps: w.bounce_threshold_mps,
        max_resolutions_per_tick: w.max_resolutions_per_tick,
        friction: w.friction,
        sleep_speed_mps: w.sleep_speed_mps,
        // At least one tick, so "0.5 s" never rounds to "never"; 0 alone disables.
        sleep_after_ticks: if w.sleep_after_s == 0.0 {
            0
        } else {
            ((w.sleep_after_s * f64::from(w.tick_hz)).ceil() as u32).max(1)
        },
        partial_sleep: w.partial_sleep,
        max_bodies: w.max_bodies,
        window_ticks,
        input_lead_ticks: w.input_lead_ticks,
        max_rewind_ticks: crate::sim::world::window_ticks(w.max_rewind_ms, w.tick_hz),
        projectile_class,
    }
}

fn rule_of(
    kind: ResponseKind,
    restitution: f64,
    destroy: Option<DestroyWhich>,
    destroy_bounce: Option<f64>,
) -> Option<Rule> {
    Some(match kind {
        ResponseKind::Ignore => Rule::Ignore,
        ResponseKind::Trigger => Rule::Trigger,
        ResponseKind::Bounce => Rule::Bounce { restitution },
        ResponseKind::Slide => Rule::Slide,
        ResponseKind::Stop => Rule::Stop,
        ResponseKind::Destroy => match destroy? {
            DestroyWhich::First => Rule::Destroy { first: true, second: false, restitution: destroy_bounce },
            DestroyWhich::Second => Rule::Destroy { first: false, second: true, restitution: destroy_bounce },
            DestroyWhich::Both => Rule::Destroy { first: true, second: true, restitution: None },
        },
    })
}

/// Most height samples a terrain may have (32 MiB of heights): the fuzzer's `nz = 222222221`
/// asked for 11 G samples, and the loader tried to build them.
pub const MAX_TERRAIN_SAMPLES: u64 = 2048 * 2048;

/// The most `max_bodies` a scene may ask for (the benchmarks use 2,000,000): a scene file cannot
/// make the loader build billions of bodies.
pub const MAX_SCENE_BODIES: u32 = 4_000_000;

fn hills(h: &HillsDef) -> Vec<Vec<f64>> {
    let tau = std::f64::consts::TAU;
    (0..h.nz.max(2))
        .map(|z| {
            (0..h.nx.max(2))
                .map(|x| {
                    let (x, z) = (f64::from(x), f64::from(z));
                    h.amplitude_m * (tau * x / h.wavelength_m).sin() * (tau * z / h.wavelength_m).cos()
                })
                .collect()
        })
        .collect()
}

/// A deterministic position for a new avatar: a random point of the region, from a generator
/// seeded by the client id, so the same client joining at the same tick lands in the same place.
pub fn avatar_position(rule: &AvatarRule, client: u32, tick: u32) -> DVec3 {
    let mut rng = SplitMix64::new(u64::from(client) << 32 | u64::from(tick));
    let u = DVec3::new(rng.unit(), rng.unit(), rng.unit());
    rule.region_min + (rule.region_max - rule.region_min) * u
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> SceneError {
        Scene::parse(text, "test.toml").unwrap_err()
    }

    #[test]
    fn errors_name_the_file_and_the_entry() {
        let e = err("[world]\nname = \"a\"\n[[class]]\nname = \"ball\"\n[[body]]\nclass = \"bal\"\nshape = { type = \"sphere\", radius_m = 1.0 }\nposition = [0,0,0]\n");
        assert_eq!(e.file, "test.toml");
        assert_eq!(e.entry, "body[0].class");
        assert!(e.detail.contains("unknown class \"bal\"") && e.detail.contains("ball"), "{e}");

        let e = err("[world]\nname = \"a\"\n[[class]]\nname = \"ball\"\n[[body]]\nclass = \"ball\"\nshape = { type = \"sphere\", radius_m = -1.0 }\nposition = [0,0,0]\n");
        assert_eq!(e.entry, "body[0].shape.radius_m");

        let e = err("[world]\nname = \"a\"\nspeed = 3\n");
        assert!(e.entry.starts_with("line 3") && e.detail.contains("speed"), "{e}");

        let e = err("[world]\nname = \"Bad/Name\"\n[[class]]\nname = \"x\"\n");
        assert_eq!(e.entry, "world.name");

        let e = err("[world]\nname = \"a\"\n[[class]]\nname = \"wall\"\nstatic = true\n[[class]]\nname = \"ball\"\n[[response]]\nbetween = [\"ball\", \"wall\"]\nkind = \"destroy\"\ndestroy = \"second\"\n");
        assert_eq!(e.entry, "response[0].destroy");
        assert!(e.detail.contains("static"), "{e}");

        let e = err("[world]\nname = \"a\"\n[[class]]\nname = \"ball\"\n[[body]]\nclass = \"ball\"\nshape = { type = \"mesh\", vertices = [[0,0,0]], triangles = [[0,0,0]] }\nposition = [0,0,0]\n");
        assert!(e.detail.contains("static"), "{e}");

        let e = err("[world]\nname = \"a\"\nmax_bodies = 10\n[[class]]\nname = \"ball\"\n[[scatter]]\nclass = \"ball\"\nshape = { type = \"sphere\", radius_m = 0.5 }\ncount = 11\nmin = [0,0,0]\nmax = [100,100,100]\n");
        assert_eq!(e.entry, "world.max_bodies");
        // Found by fuzzing: an array of 17.8 million bricks was built (3.4 GB) before the count
        // was checked; it is refused at once now.
        let started = std::time::Instant::now();
        let e = err("[world]\nname = \"a\"\n[[class]]\nname = \"brick\"\n[[array]]\nclass = \"brick\"\nshape = { type = \"sphere\", radius_m = 0.4 }\norigin = [0,0,0]\ncount = [10, 888888, 2]\nspacing_m = [1,1,1]\n");
        assert_eq!(e.entry, "world.max_bodies");
        assert!(e.detail.contains("array[0]") && e.detail.contains("17777760"), "{e}");
        assert!(started.elapsed() < std::time::Duration::from_secs(1), "refused only after {:?}", started.elapsed());
        // Found by fuzzing: a lattice of more than 2^64 cells wrapped the index arithmetic.
        let e = err("[world]\nname = \"a\"\n[[class]]\nname = \"ball\"\n[[scatter]]\nclass = \"ball\"\nshape = { type = \"sphere\", radius_m = 1e-3 }\ncount = 1\nmin = [-1e30,-1e30,-1e30]\nmax = [1e30,1e30,1e30]\n");
        assert!(e.entry.starts_with("scatter[0]") && e.detail.contains("too many"), "{e}");
        // Found by fuzzing: hills of 50 x 222,222,221 samples were generated (for a minute, then
        // out of memory) instead of refused.
        let e = err("[world]\nname = \"a\"\n[[class]]\nname = \"g\"\nstatic = true\n[terrain]\nclass = \"g\"\norigin = [0,0,0]\ncell_m = [1,1]\nhills = { nx = 50, nz = 222222221, amplitude_m = 1.0, wavelength_m = 10.0 }\n");
        assert!(e.entry == "terrain" && e.detail.contains("at most"), "{e}");
        assert!(Scene::load(Path::new("/nonexistent/scene.toml")).unwrap_err().entry == "file");
    }

    #[test]
    fn a_minimal_scene_loads_with_defaults() {
        let s = Scene::parse("[world]\nname = \"mini\"\n[[class]]\nname = \"ball\"\n[[body]]\nclass = \"ball\"\nshape = { type = \"sphere\", radius_m = 0.5 }\nposition = [1,2,3]\n", "x").unwrap();
        assert_eq!(s.world.config.tick_hz, 64);
        assert_eq!(s.world.config.dt, 1.0 / 64.0);
        assert_eq!(s.world.config.window_ticks, 16);
        assert_eq!(s.world.bodies.len(), 1);
        assert_eq!(s.world.bodies.id[0], EntityId(0));
    }

    #[test]
    fn every_bundled_scene_loads() {
        for name in ["arena", "breakout", "corridor", "terrain", "bullets"] {
            let s = Scene::load(&Scene::bundled_path(name)).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(s.name.as_str(), name);
        }
    }
}
