//! A scene's rules and static world as the wire carries them ([`SceneDescription`], the answer
//! to `query/scene`) and back: [`Scene::rules`] takes them from a loaded scene,
//! [`Scene::describe`] writes them as data, [`SceneRules::from_description`] rebuilds them and
//! checks that the rebuilt world hashes to the server's `scene_hash`, so a client steps the
//! server's core on the server's bits without the scene file.

use super::{AvatarRule, Scene, SceneError};
use crate::broadphase::{BroadphaseKind, StaticIndex};
use crate::geometry::Shape;
use crate::sim::world::{
    Bodies, CharacterProps, ClassId, ClassProps, Classes, Rule, SimConfig, StaticWorld, Terrain, World,
};
use crate::sim::Plan;
use crate::terrain::heightfield::HeightField;
use crate::toi::bisect::BisectConfig;
use glam::{DQuat, DVec3};
use impact_protocol::scene::{
    AvatarSpec, CharacterRules, ClassRules, PairRule, PlanSpec, StaticBody, TerrainSpec, ToiRules, WorldRules,
};
use impact_protocol::{SceneDescription, Tick, WorldId};
use std::sync::Arc;

/// What a client steps its own avatar with: the world's rules and static geometry (no dynamic
/// bodies), the plan the server chose and the avatar rule.
#[derive(Clone, Debug)]
pub struct SceneRules {
    /// The world name.
    pub name: WorldId,
    /// The static world and the rules, at tick 0, with no dynamic bodies.
    pub world: World,
    /// The server's plan.
    pub plan: Plan,
    /// How avatars are made, if the world makes them.
    pub avatar: Option<AvatarRule>,
}

impl Scene {
    /// The scene's rules and static world, with the plan the server makes from the whole scene.
    pub fn rules(&self) -> SceneRules {
        let mut world = self.world.clone();
        world.bodies = Bodies::default();
        world.touching.clear();
        SceneRules { name: self.name.clone(), world, plan: Plan::for_world(&self.world), avatar: self.avatar.clone() }
    }

    /// The scene as `query/scene` answers it.
    pub fn describe(&self) -> SceneDescription {
        let w = &self.world;
        let cfg = &w.config;
        let st = &w.statics;
        let plan = Plan::for_world(w);
        let n = cfg.classes.props.len();
        SceneDescription {
            world: self.name.clone(),
            scene_hash: w.scene_hash(),
            rules: WorldRules {
                tick_hz: cfg.tick_hz,
                dt: cfg.dt,
                gravity: cfg.gravity.to_array(),
                contact_slop_m: cfg.contact_slop_m,
                bounce_threshold_mps: cfg.bounce_threshold_mps,
                max_resolutions_per_tick: cfg.max_resolutions_per_tick,
                friction: cfg.friction,
                sleep_speed_mps: cfg.sleep_speed_mps,
                sleep_after_ticks: cfg.sleep_after_ticks,
                partial_sleep: cfg.partial_sleep,
                max_bodies: cfg.max_bodies,
                window_ticks: cfg.window_ticks,
                input_lead_ticks: cfg.input_lead_ticks,
                max_rewind_ticks: cfg.max_rewind_ticks,
                projectile_class: cfg.projectile_class.map(|c| c.0),
                toi: ToiRules {
                    tolerance: cfg.bisect.tolerance,
                    tolerance_m: cfg.bisect.tolerance_m,
                    max_iterations: cfg.bisect.max_iterations,
                    max_samples: cfg.bisect.max_samples,
                },
            },
            classes: cfg
                .classes
                .props
                .iter()
                .map(|p| ClassRules {
                    name: p.name.clone(),
                    is_static: p.is_static,
                    max_speed_mps: p.max_speed_mps,
                    gravity: p.gravity,
                    density_kg_m3: p.density_kg_m3,
                    can_sleep: p.can_sleep,
                    character: p.character.map(|c| CharacterRules {
                        walk_speed_mps: c.walk_speed_mps,
                        jump_speed_mps: c.jump_speed_mps,
                        min_ground_normal_up: c.min_ground_normal_up,
                        step_height_m: c.step_height_m,
                        air_control: c.air_control,
                    }),
                })
                .collect(),
            pair_rules: (0..n * n)
                .map(|k| pair_rule(cfg.classes.rule(ClassId((k / n) as u16), ClassId((k % n) as u16))))
                .collect(),
            statics: (0..st.id.len())
                .map(|i| StaticBody {
                    entity: st.id[i],
                    class: st.class[i].0,
                    shape: st.shape[i].to_spec(),
                    position: st.pos[i].to_array(),
                    orientation: st.rot[i].to_array(),
                })
                .collect(),
            terrain: st.terrain.as_ref().map(|t| {
                let (columns, rows, heights) = t.field.samples();
                let (cell_x_m, cell_z_m) = t.field.cell_size();
                TerrainSpec {
                    entity: t.id,
                    class: t.class.0,
                    origin: t.field.origin().to_array(),
                    cell_x_m,
                    cell_z_m,
                    columns: columns as u32,
                    rows: rows as u32,
                    heights: heights.to_vec(),
                }
            }),
            avatar: self.avatar.as_ref().map(|a| AvatarSpec {
                class: a.class.0,
                shape: a.shape.to_spec(),
                region_min: a.region_min.to_array(),
                region_max: a.region_max.to_array(),
            }),
            plan: PlanSpec { ccd_sampling: plan.ccd_sampling, broadphase: plan.broadphase.name().to_string() },
        }
    }
}

fn pair_rule(r: Rule) -> PairRule {
    match r {
        Rule::Ignore => PairRule::Ignore,
        Rule::Trigger => PairRule::Trigger,
        Rule::Bounce { restitution } => PairRule::Bounce { restitution },
        Rule::Slide => PairRule::Slide,
        Rule::Stop => PairRule::Stop,
        Rule::Destroy { first, second, restitution } => PairRule::Destroy { first, second, restitution },
    }
}

fn rule(r: PairRule) -> Rule {
    match r {
        PairRule::Ignore => Rule::Ignore,
        PairRule::Trigger => Rule::Trigger,
        PairRule::Bounce { restitution } => Rule::Bounce { restitution },
        PairRule::Slide => Rule::Slide,
        PairRule::Stop => Rule::Stop,
        PairRule::Destroy { first, second, restitution } => Rule::Destroy { first, second, restitution },
    }
}

impl SceneRules {
    /// The rules and static world a `query/scene` answer describes. Refused with the field at
    /// fault when a value is out of range (a class id past the table, a shape or a height field
    /// that does not build, a number that is not finite) or when the rebuilt world does not hash
    /// to the description's `scene_hash` (a server of another version, a value that did not
    /// survive the trip). Never panics, whatever the description holds.
    pub fn from_description(d: &SceneDescription) -> Result<SceneRules, SceneError> {
        let read = Reader { classes: d.classes.len() };
        let config = read.config(d)?;
        let statics = read.statics(d)?;
        let avatar = d.avatar.as_ref().map(|a| read.avatar(a)).transpose()?;
        let next_entity = statics.id.iter().chain(statics.terrain.as_ref().map(|t| &t.id)).map(|e| e.0).max();
        let world = World {
            tick: Tick(0),
            bodies: Bodies::default(),
            next_entity: next_entity.map_or(0, |e| e.saturating_add(1)),
            touching: Vec::new(),
            statics: Arc::new(statics),
            config: Arc::new(config),
        };
        let hash = world.scene_hash();
        if hash != d.scene_hash {
            return Err(error(
                "scene_hash",
                format!(
                    "the rebuilt world hashes to {hash:016x}, the server's to {:016x}: a value did not survive \
                     the trip, or the server runs another version",
                    d.scene_hash
                ),
            ));
        }
        let broadphase = BroadphaseKind::from_name(&d.plan.broadphase).ok_or_else(|| {
            error("plan.broadphase", format!("{:?} is no broadphase this version knows", d.plan.broadphase))
        })?;
        let plan = Plan { broadphase, ccd_sampling: d.plan.ccd_sampling, ..Plan::for_world(&world) };
        Ok(SceneRules { name: d.world.clone(), world, plan, avatar })
    }
}

fn error(entry: impl Into<String>, detail: impl Into<String>) -> SceneError {
    SceneError { file: "query/scene".into(), entry: entry.into(), detail: detail.into() }
}

fn finite(v: &[f64], entry: &str) -> Result<(), SceneError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(error(entry, format!("{v:?} is not finite")))
    }
}

/// Reads a description's parts, checking each value before it is used.
struct Reader {
    classes: usize,
}

impl Reader {
    fn class(&self, c: u16, entry: &str) -> Result<ClassId, SceneError> {
        if usize::from(c) < self.classes {
            Ok(ClassId(c))
        } else {
            Err(error(entry, format!("class {c} is past the {} classes", self.classes)))
        }
    }

    fn config(&self, d: &SceneDescription) -> Result<SimConfig, SceneError> {
        let (r, n) = (&d.rules, self.classes);
        if r.tick_hz == 0 || !(r.dt.is_finite() && r.dt > 0.0) {
            return Err(error("rules", format!("tick_hz {} with dt {} s is no clock", r.tick_hz, r.dt)));
        }
        finite(&r.gravity, "rules.gravity")?;
        let t = &r.toi;
        finite(
            &[r.contact_slop_m, r.bounce_threshold_mps, r.friction, r.sleep_speed_mps, t.tolerance, t.tolerance_m],
            "rules",
        )?;
        if n == 0 || n > usize::from(u16::MAX) || d.pair_rules.len() != n * n {
            let rules = d.pair_rules.len();
            return Err(error("pair_rules", format!("{rules} rules for {n} classes (needs {n} x {n})")));
        }
        let mut props = Vec::with_capacity(n);
        for (k, p) in d.classes.iter().enumerate() {
            finite(&[p.max_speed_mps, p.density_kg_m3], &format!("classes[{k}]"))?;
            let character = p.character.as_ref().map(|c| CharacterProps {
                walk_speed_mps: c.walk_speed_mps,
                jump_speed_mps: c.jump_speed_mps,
                min_ground_normal_up: c.min_ground_normal_up,
                step_height_m: c.step_height_m,
                air_control: c.air_control,
            });
            if let Some(c) = &character {
                let v = [c.walk_speed_mps, c.jump_speed_mps, c.min_ground_normal_up, c.step_height_m, c.air_control];
                finite(&v, &format!("classes[{k}].character"))?;
            }
            props.push(ClassProps {
                name: p.name.clone(),
                is_static: p.is_static,
                max_speed_mps: p.max_speed_mps,
                gravity: p.gravity,
                density_kg_m3: p.density_kg_m3,
                can_sleep: p.can_sleep,
                character,
            });
        }
        let mut classes = Classes::new(props, Rule::Ignore);
        for (k, p) in d.pair_rules.iter().enumerate() {
            if let PairRule::Bounce { restitution } | PairRule::Destroy { restitution: Some(restitution), .. } = p {
                finite(&[*restitution], &format!("pair_rules[{k}]"))?;
            }
            // Both orders are given: each entry is set as it is.
            classes.set_one(ClassId((k / n) as u16), ClassId((k % n) as u16), rule(*p));
        }
        Ok(SimConfig {
            tick_hz: r.tick_hz,
            dt: r.dt,
            gravity: DVec3::from_array(r.gravity),
            classes,
            bisect: BisectConfig {
                tolerance: t.tolerance,
                tolerance_m: t.tolerance_m,
                max_iterations: t.max_iterations,
                max_samples: t.max_samples,
            },
            contact_slop_m: r.contact_slop_m,
            bounce_threshold_mps: r.bounce_threshold_mps,
            max_resolutions_per_tick: r.max_resolutions_per_tick,
            friction: r.friction,
            sleep_speed_mps: r.sleep_speed_mps,
            sleep_after_ticks: r.sleep_after_ticks,
            partial_sleep: r.partial_sleep,
            max_bodies: r.max_bodies,
            window_ticks: r.window_ticks,
            input_lead_ticks: r.input_lead_ticks,
            max_rewind_ticks: r.max_rewind_ticks,
            projectile_class: r.projectile_class.map(|c| self.class(c, "rules.projectile_class")).transpose()?,
        })
    }

    fn statics(&self, d: &SceneDescription) -> Result<StaticWorld, SceneError> {
        let n = d.statics.len();
        let mut st = StaticWorld {
            id: Vec::with_capacity(n),
            class: Vec::with_capacity(n),
            shape: Vec::with_capacity(n),
            pos: Vec::with_capacity(n),
            rot: Vec::with_capacity(n),
            aabb: Vec::with_capacity(n),
            index: StaticIndex::new(&[]),
            terrain: None,
        };
        for (k, s) in d.statics.iter().enumerate() {
            let entry = format!("statics[{k}]");
            if st.id.last().is_some_and(|last| *last >= s.entity) {
                return Err(error(entry, format!("entity {} does not ascend", s.entity.0)));
            }
            finite(&s.position, &format!("{entry}.position"))?;
            finite(&s.orientation, &format!("{entry}.orientation"))?;
            let shape =
                Shape::from_spec(&s.shape).map_err(|e| error(format!("{entry}.shape.{}", e.field), e.detail))?;
            let (pos, rot) = (DVec3::from_array(s.position), DQuat::from_array(s.orientation));
            st.class.push(self.class(s.class, &format!("{entry}.class"))?);
            st.aabb.push(shape.world_aabb(pos, rot));
            st.id.push(s.entity);
            st.shape.push(shape);
            st.pos.push(pos);
            st.rot.push(rot);
        }
        st.index = StaticIndex::new(&st.aabb);
        if let Some(t) = &d.terrain {
            finite(&t.origin, "terrain.origin")?;
            let (nx, nz) = (t.columns as usize, t.rows as usize);
            if nx.checked_mul(nz) != Some(t.heights.len()) || nx == 0 {
                let h = t.heights.len();
                return Err(error("terrain.heights", format!("{h} heights for {nx} x {nz} samples")));
            }
            let rows: Vec<Vec<f64>> = t.heights.chunks(nx).map(<[f64]>::to_vec).collect();
            let field = HeightField::new(DVec3::from_array(t.origin), t.cell_x_m, t.cell_z_m, &rows)
                .map_err(|e| error("terrain", e.to_string()))?;
            st.terrain = Some(Terrain { id: t.entity, class: self.class(t.class, "terrain.class")?, field });
        }
        Ok(st)
    }

    fn avatar(&self, a: &AvatarSpec) -> Result<AvatarRule, SceneError> {
        finite(&a.region_min, "avatar.region_min")?;
        finite(&a.region_max, "avatar.region_max")?;
        Ok(AvatarRule {
            class: self.class(a.class, "avatar.class")?,
            shape: Shape::from_spec(&a.shape).map_err(|e| error(format!("avatar.shape.{}", e.field), e.detail))?,
            region_min: DVec3::from_array(a.region_min),
            region_max: DVec3::from_array(a.region_max),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundled(name: &str) -> Scene {
        Scene::load(&Scene::bundled_path(name)).unwrap()
    }

    /// Every bundled scene survives the trip through both encodings: the rebuilt world hashes
    /// to the server's, with the same plan and avatar rule.
    #[test]
    fn every_bundled_scene_rebuilds_from_its_description() {
        for name in [
            "arena", "breakout", "bullets", "corridor", "field", "hillside", "pile", "ramp", "stack", "standing",
            "terrain", "yard",
        ] {
            let scene = bundled(name);
            let d = scene.describe();
            for enc in [impact_protocol::Encoding::MsgPack, impact_protocol::Encoding::Json] {
                let msg = impact_protocol::ServerMessage::Scene(Box::new(d.clone()));
                let bytes = impact_protocol::encode(&msg, enc).unwrap();
                let Ok(impact_protocol::ServerMessage::Scene(back)) =
                    impact_protocol::decode(&bytes, enc, impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES)
                else {
                    panic!("{name}: the scene did not decode in {enc:?}");
                };
                let r = SceneRules::from_description(&back).unwrap_or_else(|e| panic!("{name} ({enc:?}): {e}"));
                let want = scene.rules();
                assert_eq!(r.world.scene_hash(), scene.world.scene_hash(), "{name}");
                assert_eq!(r.plan.ccd_sampling, want.plan.ccd_sampling, "{name}");
                assert_eq!(r.plan.broadphase, want.plan.broadphase, "{name}");
                assert_eq!(r.avatar.as_ref().map(|a| a.class), want.avatar.as_ref().map(|a| a.class), "{name}");
                assert_eq!(format!("{:?}", r.world.config), format!("{:?}", want.world.config), "{name}");
            }
        }
    }

    /// PROTOCOL.md's example `scene` is one a client rebuilds to its hash: the document shows
    /// values that survive the trip, in the form this code reads.
    #[test]
    fn the_protocols_example_scene_rebuilds() {
        // cargo runs a test in its package's directory (a path built in would name the clone it was built in)
        let doc = std::fs::read_to_string("../PROTOCOL.md").unwrap();
        let block = doc
            .split("```json\n")
            .skip(1)
            .map(|b| b.split("```").next().unwrap_or(""))
            .find(|b| b.trim_start().starts_with(r#"{"type":"scene""#))
            .expect("PROTOCOL.md has an example scene");
        let limit = impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES;
        let Ok(impact_protocol::ServerMessage::Scene(d)) =
            impact_protocol::decode(block.trim().as_bytes(), impact_protocol::Encoding::Json, limit)
        else {
            panic!("the example scene does not decode")
        };
        let r = SceneRules::from_description(&d).unwrap();
        assert_eq!(r.world.statics.id.len(), 2);
        assert!(r.avatar.is_some());
    }

    /// A changed value is caught by the hash, and out-of-range ids are refused by name, not
    /// indexed.
    #[test]
    fn a_wrong_description_is_refused_with_the_field() {
        let d = bundled("arena").describe();
        let mut moved = d.clone();
        moved.statics[0].position[0] += 1e-9;
        assert_eq!(SceneRules::from_description(&moved).unwrap_err().entry, "scene_hash");
        let mut bad = d.clone();
        bad.statics[0].class = 999;
        assert_eq!(SceneRules::from_description(&bad).unwrap_err().entry, "statics[0].class");
        let mut short = d.clone();
        short.pair_rules.pop();
        assert_eq!(SceneRules::from_description(&short).unwrap_err().entry, "pair_rules");
        let mut nan = d;
        nan.rules.gravity[1] = f64::NAN;
        assert_eq!(SceneRules::from_description(&nan).unwrap_err().entry, "rules.gravity");
    }
}
