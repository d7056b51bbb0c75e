//! Client inputs inside the core: the check the runtime runs before accepting an input (so the
//! client gets a reason), and the application at the start of a tick.
//!
//! Inputs apply sorted by `(client, seq)`, so arrival order never reaches the result. An input
//! applies whole or not at all: if any action fails the check at apply time (its entity was
//! destroyed in a re-simulated past, say), the input is skipped and reported.

use crate::geometry::Shape;
use crate::sim::output::{Skipped, TickOutput};
use crate::sim::ray;
use crate::sim::world::{NewBody, Rule, World};
use glam::{DQuat, DVec3};
use impact_protocol::{
    Action, ClientId, CollisionEvent, EntityId, EventStatus, Phase, RayResult, RejectReason, Response, ShapeSpec, Tick,
};

/// The inputs one client sent for one tick.
#[derive(Clone, Debug, PartialEq)]
pub struct TickInput {
    /// The sender.
    pub client: ClientId,
    /// Its sequence number.
    pub seq: u32,
    /// The actions, in order.
    pub actions: Vec<Action>,
    /// The tick the client was looking at (`None`: the input's own tick).
    pub view_tick: Option<Tick>,
    /// Its hitscan rays as cast against the world at their view tick, by action index. The core
    /// keeps no history, so the rollback session fills this before the tick is simulated (and
    /// again whenever it is re-simulated); a ray with no entry is cast against the tick's own
    /// world.
    pub rewound: Vec<RewoundRay>,
    /// `rewound` came from the input log (a follower, a replay): it is used as it is, never cast
    /// again (the worlds it was cast against may be older than the follower's history).
    pub logged: bool,
    /// Sent by a game-logic client (the server decides who is one, and logs it with the input):
    /// its actions may act on any dynamic body, and only it may teleport, spawn any class and
    /// change a body's class.
    pub logic: bool,
}

impl TickInput {
    /// An input with no view tick of its own.
    pub fn new(client: ClientId, seq: u32, actions: Vec<Action>) -> TickInput {
        TickInput { client, seq, actions, view_tick: None, rewound: Vec::new(), logged: false, logic: false }
    }
}

/// A hitscan ray cast against a past world (lag compensation).
#[derive(Clone, Debug, PartialEq)]
pub struct RewoundRay {
    /// Index of the `FireRay` action in the input.
    pub action: u32,
    /// The tick whose world (at its start) the ray was tested against.
    pub view_tick: Tick,
    /// The requested view tick was further back than allowed and was clamped.
    pub clamped: bool,
    /// What it hit there.
    pub hit: Option<impact_protocol::RayHit>,
}

/// A change the server itself makes at a tick (not a client input): avatars appearing and
/// leaving. Kept in the history with the tick's inputs, so a re-simulation makes the same
/// change at the same tick.
#[derive(Clone, Debug)]
pub enum SystemAction {
    /// Spawn an avatar owned by `client`.
    SpawnAvatar {
        /// The owner.
        client: ClientId,
        /// Class.
        class: crate::sim::world::ClassId,
        /// Shape.
        shape: Shape,
        /// Position, m.
        pos: DVec3,
    },
    /// Remove a body.
    Remove {
        /// The body.
        entity: EntityId,
    },
}

/// Applies the tick's system actions, in order, before any client input.
pub(crate) fn apply_system(w: &mut World, system: &[SystemAction], out: &mut TickOutput) {
    let mut removed = Vec::new();
    for a in system {
        match a {
            SystemAction::SpawnAvatar { client, class, shape, pos } => {
                let props = &w.config.classes.props[class.0 as usize];
                let inv_mass = 1.0 / (props.density_kg_m3 * shape.volume());
                let body = NewBody {
                    class: *class,
                    shape: shape.clone(),
                    pos: *pos,
                    vel: DVec3::ZERO,
                    rot: DQuat::IDENTITY,
                    inv_mass,
                    owner: Some(*client),
                };
                if let Some(id) = w.spawn(body) {
                    out.spawned.push((*client, id));
                }
            }
            SystemAction::Remove { entity } => {
                if w.bodies.slot(*entity).is_some() {
                    removed.push(*entity);
                }
            }
        }
    }
    if !removed.is_empty() {
        remove(w, &removed, out);
    }
}

/// Who sent an input: a player acts on what it owns, game logic on any body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sender {
    /// The client.
    pub client: ClientId,
    /// It has the game-logic role.
    pub logic: bool,
}

impl Sender {
    /// A player.
    pub fn player(client: ClientId) -> Sender {
        Sender { client, logic: false }
    }
}

/// The slot of `e`, if `who` may act on it: its owner, or game logic.
fn owned(w: &World, who: Sender, e: EntityId) -> Result<usize, (RejectReason, String)> {
    match w.bodies.slot(e) {
        None => Err((RejectReason::UnknownEntity, format!("entity {e} does not exist"))),
        Some(s) if !who.logic && w.bodies.owner[s] != Some(who.client) => {
            Err((RejectReason::NotOwner, format!("entity {e} is not owned by client {}", who.client)))
        }
        Some(s) => Ok(s),
    }
}

/// `Ok` for game logic; a player is told the action is not its to send.
fn logic_only(who: Sender, action: &str) -> Result<(), (RejectReason, String)> {
    if who.logic {
        return Ok(());
    }
    Err((RejectReason::NotAllowed, format!("`{action}` is game logic's: client {} has no game-logic role", who.client)))
}

/// An action's field, as a reject names it: `actions[k].name` (written out only for a reject).
#[derive(Clone, Copy, Debug)]
struct Field(usize, &'static str);

impl std::fmt::Display for Field {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "actions[{}].{}", self.0, self.1)
    }
}

/// The dynamic class named `name`.
fn dynamic_class(w: &World, name: &str, field: Field) -> Result<crate::sim::world::ClassId, (RejectReason, String)> {
    let props = &w.config.classes.props;
    match props.iter().position(|p| p.name == name) {
        Some(k) if !props[k].is_static => Ok(crate::sim::world::ClassId(k as u16)),
        Some(_) => Err((RejectReason::OutOfRange, format!("{field}: class {name:?} is static"))),
        None => Err((RejectReason::OutOfRange, format!("{field}: the scene has no class {name:?}"))),
    }
}

fn speed_ok(
    w: &World,
    slot_class: crate::sim::world::ClassId,
    v: [f64; 3],
    field: Field,
) -> Result<(), (RejectReason, String)> {
    let max = w.config.classes.props[slot_class.0 as usize].max_speed_mps;
    let s = DVec3::from_array(v).length();
    if s > max {
        return Err((RejectReason::OutOfRange, format!("{field}: speed {s:.3} m/s exceeds the class limit {max} m/s")));
    }
    Ok(())
}

/// Whether the body in `slot` takes `action` by its class: a character moves by `move` only,
/// and `move` moves characters only.
fn allowed(w: &World, slot: usize, action: &str) -> Result<(), (RejectReason, String)> {
    let props = &w.config.classes.props[w.bodies.class[slot].0 as usize];
    let character = props.character.is_some();
    if character == (action == "move") {
        return Ok(());
    }
    let why = if character {
        format!("{} is a character (class {:?}): it moves by `move`, not `{action}`", w.bodies.id[slot], props.name)
    } else {
        format!("{} is not a character (class {:?}): `move` moves characters only", w.bodies.id[slot], props.name)
    };
    Err((RejectReason::NotAllowed, why))
}

/// Whether a client may spawn a body of `shape` (`field` names it in the reason).
fn spawnable(shape: &ShapeSpec, field: Field) -> Result<(), (RejectReason, String)> {
    if !shape.spawnable() {
        return Err((RejectReason::OutOfRange, format!("{field}: a client spawns a sphere, a capsule or a cuboid")));
    }
    Shape::from_spec(shape).map(drop).map_err(|e| (RejectReason::OutOfRange, format!("{field}.{e}")))
}

/// Whether a player `client` may apply `actions` to the world as it is now ([`check_as`] for
/// game logic).
pub fn check(w: &World, client: ClientId, actions: &[Action]) -> Result<(), (RejectReason, String)> {
    check_as(w, Sender::player(client), actions)
}

/// Whether `who` may apply `actions` to the world as it is now. The runtime calls this on
/// arrival; [`apply`] calls it again at the input's tick.
pub fn check_as(w: &World, who: Sender, actions: &[Action]) -> Result<(), (RejectReason, String)> {
    let mut spawns = 0usize;
    for (k, a) in actions.iter().enumerate() {
        match a {
            Action::SetVelocity { entity, velocity } => {
                let s = owned(w, who, *entity)?;
                if !who.logic {
                    allowed(w, s, "set_velocity")?;
                }
                speed_ok(w, w.bodies.class[s], *velocity, Field(k, "velocity"))?;
            }
            Action::ApplyImpulse { entity, .. } => {
                let s = owned(w, who, *entity)?;
                if !who.logic {
                    allowed(w, s, "apply_impulse")?;
                }
            }
            Action::Move { entity, .. } => {
                let s = owned(w, who, *entity)?;
                allowed(w, s, "move")?;
            }
            Action::Despawn { entity } | Action::Teleport { entity, .. } => {
                if matches!(a, Action::Teleport { .. }) {
                    logic_only(who, "teleport")?;
                }
                owned(w, who, *entity)?;
            }
            Action::SetState { entity, values } => {
                logic_only(who, "set_state")?;
                let s = owned(w, who, *entity)?;
                if w.bodies.game[s].merged(values).is_none() {
                    return Err((
                        RejectReason::OutOfRange,
                        format!(
                            "actions[{k}].values: {} would hold more than {} names",
                            entity,
                            impact_protocol::limits::MAX_GAME_STATE_VALUES
                        ),
                    ));
                }
            }
            Action::SetClass { entity, class } => {
                logic_only(who, "set_class")?;
                owned(w, who, *entity)?;
                dynamic_class(w, class, Field(k, "class"))?;
            }
            Action::Spawn { class, shape, .. } => {
                logic_only(who, "spawn")?;
                dynamic_class(w, class, Field(k, "class"))?;
                spawnable(shape, Field(k, "shape"))?;
                spawns += 1;
                if w.bodies.len() + spawns > w.config.max_bodies as usize {
                    return Err((
                        RejectReason::OutOfRange,
                        format!("the world is full ({} bodies)", w.config.max_bodies),
                    ));
                }
            }
            Action::FireRay { shooter, .. } => {
                owned(w, who, *shooter)?;
            }
            Action::SpawnProjectile { shape, velocity, .. } => {
                spawnable(shape, Field(k, "shape"))?;
                let class = w.config.projectile_class.ok_or_else(|| {
                    (RejectReason::OutOfRange, "this scene has no projectile class: spawning is disabled".to_string())
                })?;
                speed_ok(w, class, *velocity, Field(k, "velocity"))?;
                spawns += 1;
                if w.bodies.len() + spawns > w.config.max_bodies as usize {
                    return Err((
                        RejectReason::OutOfRange,
                        format!("the world is full ({} bodies)", w.config.max_bodies),
                    ));
                }
            }
        }
    }
    Ok(())
}

fn clamp_speed(v: DVec3, max: f64) -> DVec3 {
    let s = v.length();
    if s > max {
        v * (max / s)
    } else {
        v
    }
}

/// Applies the tick's inputs, sorted by client, then each client's in the order it numbered
/// them (seqs in serial order: the one after `u32::MAX` comes after it).
pub fn apply(w: &mut World, inputs: &[TickInput], out: &mut TickOutput) {
    if inputs.is_empty() {
        return;
    }
    let mut order: Vec<usize> = (0..inputs.len()).collect();
    order.sort_by(|&a, &b| {
        let (a, b) = (&inputs[a], &inputs[b]);
        a.client.cmp(&b.client).then_with(|| impact_protocol::serial::cmp(a.seq, b.seq))
    });
    let mut removed: Vec<EntityId> = Vec::new();
    for k in order {
        let input = &inputs[k];
        let who = Sender { client: input.client, logic: input.logic };
        if let Err((reason, detail)) = check_as(w, who, &input.actions) {
            out.skipped.push(Skipped { client: input.client, seq: input.seq, tick: w.tick, reason, detail });
            continue;
        }
        for (index, a) in input.actions.iter().enumerate() {
            apply_action(w, input, index, a, out, &mut removed);
        }
    }
    if !removed.is_empty() {
        remove(w, &removed, out);
    }
}

fn apply_action(
    w: &mut World,
    input: &TickInput,
    index: usize,
    a: &Action,
    out: &mut TickOutput,
    removed: &mut Vec<EntityId>,
) {
    let classes = &w.config.classes;
    match a {
        Action::SetVelocity { entity, velocity } => {
            if let Some(s) = w.bodies.slot(*entity) {
                let max = classes.props[w.bodies.class[s].0 as usize].max_speed_mps;
                w.bodies.vel[s] = clamp_speed(DVec3::from_array(*velocity), max);
            }
        }
        Action::ApplyImpulse { entity, impulse } => {
            if let Some(s) = w.bodies.slot(*entity) {
                let max = classes.props[w.bodies.class[s].0 as usize].max_speed_mps;
                let v = w.bodies.vel[s] + DVec3::from_array(*impulse) * w.bodies.inv_mass[s];
                w.bodies.vel[s] = clamp_speed(v, max);
            }
        }
        Action::SpawnProjectile { shape, position, velocity } => {
            let Some(class) = w.config.projectile_class else {
                return;
            };
            let props = &classes.props[class.0 as usize];
            // `check` built it already: a shape that does not build never reaches here.
            let Ok(shape) = Shape::from_spec(shape) else { return };
            let inv_mass = 1.0 / (props.density_kg_m3 * shape.volume());
            let vel = clamp_speed(DVec3::from_array(*velocity), props.max_speed_mps);
            let body = NewBody {
                class,
                shape,
                pos: DVec3::from_array(*position),
                vel,
                rot: DQuat::IDENTITY,
                inv_mass,
                owner: Some(input.client),
            };
            w.spawn(body);
        }
        Action::FireRay { shooter, origin, direction, max_distance_m } => {
            // Rewound (lag compensation): tested where the shooter saw the world, and what it
            // hit happens now, at the input's tick.
            let (hit, view_tick, clamped) = match input.rewound.iter().find(|r| r.action as usize == index) {
                Some(r) => (r.hit.clone(), r.view_tick, r.clamped),
                None => {
                    let dir = DVec3::from_array(*direction).normalize();
                    (ray::cast(w, DVec3::from_array(*origin), dir, *max_distance_m, Some(*shooter)), w.tick, false)
                }
            };
            // A rewound hit on a body gone by now (destroyed since the view tick) is reported to
            // the shooter but changes nothing: there is nothing left to hit.
            let classes = hit.as_ref().and_then(|h| Some((w.class_of(*shooter)?, w.class_of(h.entity)?)));
            if let (Some(h), Some((ca, cb))) = (&hit, classes) {
                let rule = w.config.classes.rule(ca, cb);
                let response = match rule {
                    Rule::Destroy { second: true, .. } if w.bodies.slot(h.entity).is_some() => {
                        removed.push(h.entity);
                        Response::Destroy
                    }
                    _ => Response::Trigger,
                };
                if rule != Rule::Ignore {
                    out.events.push(CollisionEvent {
                        tick: w.tick,
                        toi: 0.0,
                        a: *shooter,
                        b: h.entity,
                        point: h.point,
                        normal: h.normal,
                        depth_m: 0.0,
                        closing_speed_mps: 0.0,
                        phase: Phase::Hit,
                        response,
                        status: EventStatus::Provisional,
                    });
                }
            }
            out.rays.push(RayResult {
                client: input.client,
                seq: input.seq,
                tick: w.tick,
                view_tick,
                clamped,
                shooter: *shooter,
                hit,
            });
        }
        Action::Teleport { .. } | Action::SetClass { .. } | Action::SetState { .. } | Action::Spawn { .. } => {
            apply_logic_action(w, a);
        }
        Action::Move { entity, direction, jump } => {
            if let Some(s) = w.bodies.slot(*entity) {
                crate::sim::character::apply_move(w, s, *direction, *jump);
            }
        }
        Action::Despawn { entity } => removed.push(*entity),
    }
}

/// Game logic's own actions (checked: only game logic sends them).
fn apply_logic_action(w: &mut World, a: &Action) {
    let classes = &w.config.classes;
    match a {
        Action::Teleport { entity, position, velocity } => {
            if let Some(s) = w.bodies.slot(*entity) {
                w.bodies.pos[s] = DVec3::from_array(*position);
                if let Some(v) = velocity {
                    w.bodies.vel[s] = DVec3::from_array(*v);
                }
                w.bodies.set_teleported(s, w.tick);
                // Where it was touching is no longer where it is.
                let id = *entity;
                w.touching.retain(|t| t.a != id && t.b != id);
                crate::sim::island::Islands::default().wake(w, &[s as u32]);
            }
        }
        Action::SetClass { entity, class } => {
            let found = w.config.classes.props.iter().position(|p| &p.name == class);
            if let (Some(s), Some(k)) = (w.bodies.slot(*entity), found) {
                w.bodies.set_class(s, crate::sim::world::ClassId(k as u16));
                crate::sim::island::Islands::default().wake(w, &[s as u32]);
            }
        }
        Action::SetState { entity, values } => {
            if let Some(s) = w.bodies.slot(*entity) {
                if let Some(state) = w.bodies.game[s].merged(values) {
                    w.bodies.set_game(s, state);
                }
            }
        }
        Action::Spawn { class, shape, position, velocity, owner } => {
            let Some(k) = w.config.classes.props.iter().position(|p| &p.name == class) else { return };
            let props = &classes.props[k];
            let Ok(shape) = Shape::from_spec(shape) else { return };
            let inv_mass = 1.0 / (props.density_kg_m3 * shape.volume());
            let vel = clamp_speed(DVec3::from_array(*velocity), props.max_speed_mps);
            let body = NewBody {
                class: crate::sim::world::ClassId(k as u16),
                shape,
                pos: DVec3::from_array(*position),
                vel,
                rot: DQuat::IDENTITY,
                inv_mass,
                owner: *owner,
            };
            w.spawn(body);
        }
        _ => {}
    }
}

/// Removes bodies before the step and ends their contacts.
fn remove(w: &mut World, removed: &[EntityId], out: &mut TickOutput) {
    let mut dead = vec![false; w.bodies.len()];
    for id in removed {
        if let Some(s) = w.bodies.slot(*id) {
            dead[s] = true;
        }
    }
    let tick = w.tick;
    let gone = |id: EntityId| removed.contains(&id);
    // What rested on a removed body wakes: its support is gone.
    let mut partners = Vec::new();
    for t in &w.touching {
        let (a, b) = t.key();
        if gone(a) || gone(b) {
            partners.extend([a, b].into_iter().filter(|id| !gone(*id)));
            out.events.push(CollisionEvent {
                tick,
                toi: 0.0,
                a,
                b,
                point: [0.0; 3],
                normal: [0.0, 1.0, 0.0],
                depth_m: 0.0,
                closing_speed_mps: 0.0,
                phase: Phase::End,
                response: Response::Destroy,
                status: EventStatus::Provisional,
            });
        }
    }
    w.touching.retain(|t| !gone(t.a) && !gone(t.b));
    w.bodies.remove_flagged(&dead);
    let seeds: Vec<u32> = partners.iter().filter_map(|id| w.bodies.slot(*id)).map(|s| s as u32).collect();
    if !seeds.is_empty() {
        crate::sim::island::Islands::default().wake(w, &seeds);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use crate::sim::{Plan, Stepper, SystemAction};

    const PLAYER: ClientId = ClientId(1);
    const LOGIC: ClientId = ClientId(900);

    /// A world with a player's avatar in it.
    fn world() -> (World, Stepper, EntityId) {
        let scene = Scene::parse(
            r#"
            [world]
            name = "game"
            tick_hz = 64

            [[class]]
            name = "player"

            [[class]]
            name = "ghost"

            [[class]]
            name = "wall"
            static = true

            [[body]]
            class = "wall"
            shape = { type = "cuboid", half_extents_m = [1.0, 1.0, 1.0] }
            position = [20.0, 0.0, 0.0]

            [spawn]
            avatar_class = "player"
            avatar_shape = { type = "sphere", radius_m = 0.5 }
            region_min = [0.0, 0.0, 0.0]
            region_max = [0.0, 0.0, 0.0]
            "#,
            "<game>",
        )
        .unwrap();
        let rule = scene.avatar.clone().unwrap();
        let mut w = scene.world;
        let mut st = Stepper::new(Plan::for_world(&w), false);
        let spawn =
            SystemAction::SpawnAvatar { client: PLAYER, class: rule.class, shape: rule.shape, pos: rule.region_min };
        let mut out = TickOutput::default();
        st.step_with(&mut w, &[spawn], &[], &mut out);
        let avatar = out.spawned[0].1;
        (w, st, avatar)
    }

    /// Game logic teleports, re-classes and pushes a body it does not own and spawns one of any
    /// dynamic class; a player may do none of it (typed `not_allowed`), nor act on another's
    /// body (`not_owner`).
    #[test]
    fn game_logic_acts_on_any_body_and_a_player_may_not() {
        let (mut w, mut st, avatar) = world();
        let logic = [
            Action::Teleport { entity: avatar, position: [5.0, 1.0, 0.0], velocity: Some([0.0, 0.0, 2.0]) },
            Action::SetClass { entity: avatar, class: "ghost".into() },
            Action::ApplyImpulse { entity: avatar, impulse: [0.0, 0.0, 0.0] },
            Action::Spawn {
                class: "player".into(),
                shape: ShapeSpec::Sphere { radius_m: 0.5 },
                position: [-5.0, 0.0, 0.0],
                velocity: [0.0; 3],
                owner: None,
            },
        ];
        for a in &logic[..2] {
            let (reason, detail) = check(&w, PLAYER, std::slice::from_ref(a)).unwrap_err();
            assert_eq!(reason, RejectReason::NotAllowed, "{a:?}: {detail}");
        }
        let stranger = Sender::player(ClientId(2));
        assert_eq!(check_as(&w, stranger, &logic[2..3]).unwrap_err().0, RejectReason::NotOwner);
        let wall = Action::SetClass { entity: avatar, class: "wall".into() };
        let boss = Sender { client: LOGIC, logic: true };
        assert_eq!(check_as(&w, boss, &[wall]).unwrap_err().0, RejectReason::OutOfRange, "not a static class");
        assert_eq!(check_as(&w, boss, &logic), Ok(()));

        let input = TickInput { logic: true, ..TickInput::new(LOGIC, 1, logic.to_vec()) };
        let mut out = TickOutput::default();
        st.step(&mut w, &[input], &mut out);
        assert!(out.skipped.is_empty(), "{:?}", out.skipped);
        let s = w.bodies.slot(avatar).unwrap();
        assert_eq!(w.bodies.pos[s], DVec3::new(5.0, 1.0, 2.0 / 64.0), "teleported, then moved a tick");
        assert_eq!(w.config.classes.props[w.bodies.class[s].0 as usize].name, "ghost");
        assert_eq!(w.bodies.len(), 2, "spawned");
        // The same input from the same client without the role is skipped at its tick.
        let forged = TickInput::new(LOGIC, 2, logic[..1].to_vec());
        let mut out = TickOutput::default();
        st.step(&mut w, &[forged], &mut out);
        assert_eq!(out.skipped.len(), 1);
        assert_eq!(out.skipped[0].reason, RejectReason::NotAllowed);
    }
}
