//! Walking characters: bodies of a class with `character` rules, moved by the server from the
//! intents clients send (`move`), never by a velocity a client sets.
//!
//! A character's whole state is what every body has, position, velocity and the contacts it
//! ended the last tick with, so a client predicts one with nothing more than its state stream
//! carries. The controller is two small steps:
//!
//! - **`move`, at the input's tick** (`apply_move`): on walkable ground the horizontal velocity
//!   becomes the intent (its direction across gravity, its length the fraction of the walk
//!   speed), and a jump sets the speed up to the class's jump speed; in the air the horizontal
//!   velocity moves `air_control` of the way to the intent and a jump does nothing.
//! - **every tick, before gravity** (`control`): a character touching a surface steeper than
//!   its slope limit (a wall) loses the part of its horizontal velocity that goes into it, so
//!   walking cannot climb it; one standing on walkable ground and not leaving it follows the
//!   ground: its horizontal velocity is kept and its vertical one is the ground's slope times it,
//!   and gravity does not pull it (it neither slides down a walkable slope nor presses into the
//!   floor). One that walked into a ledge no higher than its step height, with walkable ground
//!   on top, rises onto it (`step_up`). Off the ground gravity acts as on any body.
//!
//! "Walkable" is a contact whose normal (pointing at the character) has at least the class's
//! `min_ground_normal_up` along up; up is opposite gravity, or +y in a world without gravity.
//! Contacts are the world's touching list, written at the end of the tick before.

use crate::sim::world::{CharacterProps, World};
use glam::DVec3;
use impact_protocol::EntityId;

/// Up: opposite gravity, or +y in a world without.
pub fn up(gravity: DVec3) -> DVec3 {
    if gravity == DVec3::ZERO {
        DVec3::Y
    } else {
        -gravity.normalize()
    }
}

/// The contacts of `id` in the touching list, each normal pointing at `id`, in list order.
fn contacts(w: &World, id: EntityId) -> impl Iterator<Item = DVec3> + '_ {
    w.touching.iter().filter_map(move |t| {
        if t.a == id {
            Some(-t.normal)
        } else if t.b == id {
            Some(t.normal)
        } else {
            None
        }
    })
}

/// The walkable ground `id` stands on: of its contacts at least `min_up` along `up`, the one
/// most along it (the first of equals).
fn ground(w: &World, id: EntityId, up: DVec3, min_up: f64) -> Option<DVec3> {
    contacts(w, id).filter(|n| n.dot(up) >= min_up).fold(None, |best: Option<DVec3>, n| match best {
        Some(b) if b.dot(up) >= n.dot(up) => Some(b),
        _ => Some(n),
    })
}

/// The character's props, if the body in `slot` is one.
pub(crate) fn props(w: &World, slot: usize) -> Option<CharacterProps> {
    w.config.classes.props[w.bodies.class[slot].0 as usize].character
}

/// Applies a `move` to the character in `slot` (see the module docs).
pub(crate) fn apply_move(w: &mut World, slot: usize, direction: [f64; 3], jump: bool) {
    let Some(c) = props(w, slot) else { return };
    let up = up(w.config.gravity);
    let v = w.bodies.vel[slot];
    let dir = DVec3::from_array(direction);
    let across = dir - up * dir.dot(up);
    let len = across.length();
    let intent = if len > 0.0 { across * (len.min(1.0) * c.walk_speed_mps / len) } else { DVec3::ZERO };
    let vertical = up * v.dot(up);
    let horizontal = v - vertical;
    let on_ground = ground(w, w.bodies.id[slot], up, c.min_ground_normal_up).is_some_and(|n| v.dot(n) <= 0.0);
    w.bodies.vel[slot] = if on_ground {
        intent + if jump { up * c.jump_speed_mps } else { vertical }
    } else {
        horizontal + (intent - horizontal) * c.air_control + vertical
    };
}

/// What [`control`] works in, kept by the stepper so a tick allocates nothing.
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    /// Characters standing on walkable ground this tick, by slot: gravity skips them.
    pub grounded: Vec<bool>,
    /// The walkable contact each stands on (the most along up).
    floor: Vec<Option<DVec3>>,
    /// The velocity a character had before a wall took the part going into it.
    blocked: Vec<Option<DVec3>>,
    /// Static bodies near a step being tried.
    near: Vec<u32>,
    /// The characters that stepped up this tick.
    stepped: Vec<EntityId>,
}

/// The per-tick step for every awake character (see the module docs): one pass over the
/// touching list in its order (walls, floors), then one over the characters (steps, ground).
/// Leaves in `s.grounded` the characters gravity must not pull this tick.
pub(crate) fn control(w: &mut World, s: &mut Scratch) {
    let n = w.bodies.len();
    s.grounded.clear();
    s.grounded.resize(n, false);
    s.floor.clear();
    s.floor.resize(n, None);
    s.blocked.clear();
    s.blocked.resize(n, None);
    let up = up(w.config.gravity);
    let (b, classes) = (&mut w.bodies, &w.config.classes);
    let character = |class: crate::sim::world::ClassId| classes.props[class.0 as usize].character;
    let mut cursor = 0;
    for t in &w.touching {
        for (id, normal) in [(t.a, -t.normal), (t.b, t.normal)] {
            let Some(i) = b.slot_from(&mut cursor, id) else { continue };
            let Some(c) = character(b.class[i]) else { continue };
            if b.asleep[i] {
                continue;
            }
            let along = normal.dot(up);
            if along >= c.min_ground_normal_up {
                if s.floor[i].is_none_or(|f| along > f.dot(up)) {
                    s.floor[i] = Some(normal);
                }
                continue;
            }
            // A wall, or an overhang: walking does not push into it.
            let across = normal - up * along;
            let len = across.length();
            if len > 1e-9 {
                let into = b.vel[i].dot(across / len);
                if into < 0.0 {
                    s.blocked[i].get_or_insert(b.vel[i]);
                    b.vel[i] -= across / len * into;
                }
            }
        }
    }
    for i in 0..n {
        let Some(f) = s.floor[i] else { continue };
        if let (Some(wanted), Some(c)) = (s.blocked[i], character(w.bodies.class[i])) {
            // Walking into a wall from the ground: a ledge no higher than the step height is
            // stepped onto, and the walk goes on.
            if let Some(rise) = step_up(w, i, wanted - up * wanted.dot(up), up, &c, &mut s.near) {
                let b = &mut w.bodies;
                b.pos[i] += up * rise;
                b.vel[i] = wanted - up * wanted.dot(up);
                s.grounded[i] = true;
                s.stepped.push(b.id[i]);
                continue;
            }
        }
        let b = &mut w.bodies;
        let v = b.vel[i];
        if v.dot(f) <= 0.0 {
            let horizontal = v - up * v.dot(up);
            b.vel[i] = horizontal - up * (f.dot(horizontal) / f.dot(up));
            s.grounded[i] = true;
        }
    }
    // A character that stepped up left its contacts where it was: the wall it walked into must
    // not hold it back (the resting contacts are solved next), and what it touches now is found
    // at the end of the tick.
    if !s.stepped.is_empty() {
        let stepped = &s.stepped;
        w.touching.retain(|t| !stepped.contains(&t.a) && !stepped.contains(&t.b));
        s.stepped.clear();
    }
}

/// Halvings of the step height when searching how far up a ledge's top is.
const STEP_SEARCH: u32 = 20;

/// How far the character in `slot` must rise to walk on at `walk` (horizontal) over what
/// blocks it: `None` when the way is still blocked the step height up (a wall, not a step),
/// when what it would stand on is not walkable (a steep slope is not a flight of steps), or when
/// nothing blocks it ahead. Tested against the static world and the terrain, one body width
/// ahead (where it would stand on the ledge's top, past its edge): the least rise there that
/// overlaps nothing, found by halving, plus half the contact slop.
fn step_up(w: &World, slot: usize, walk: DVec3, up: DVec3, c: &CharacterProps, near: &mut Vec<u32>) -> Option<f64> {
    let max_rise = c.step_height_m;
    let speed = walk.length();
    if max_rise <= 0.0 || speed == 0.0 {
        return None;
    }
    let (b, st) = (&w.bodies, &w.statics);
    let (shape, rot) = (&b.shape[slot], b.rot[slot]);
    let slop = w.config.contact_slop_m;
    // Ahead by this tick's walk (and the slop, so a body touching the wall is moved into it)
    // and by its own width, so that raised it stands over the ledge's top, not its edge.
    let dir = walk / speed;
    let half = shape.world_aabb(DVec3::ZERO, rot).max;
    let width = (half * dir.abs()).element_sum();
    let ahead = b.pos[slot] + dir * (speed * w.config.dt + slop + width);
    let reach = shape.world_aabb(ahead, rot);
    let lift = up * max_rise;
    let reach = crate::geometry::Aabb { min: reach.min.min(reach.min + lift), max: reach.max.max(reach.max + lift) };
    near.clear();
    st.index.query(&reach, near);
    // The deepest overlap at `at`, its normal pointing at the character.
    let deepest = |at: DVec3| {
        let statics = near.iter().filter_map(|&k| {
            let k = k as usize;
            crate::narrow::contact(shape, rot, &st.shape[k], st.rot[k], st.pos[k] - at, 0.0)
        });
        let terrain = st.terrain.as_ref().and_then(|t| crate::narrow::terrain_contact(shape, rot, at, &t.field, 0.0));
        statics
            .chain(terrain)
            .filter(|c| c.depth > 0.0)
            .fold(None, |best: Option<crate::narrow::Contact>, c| match best {
                Some(b) if b.depth >= c.depth => Some(b),
                _ => Some(c),
            })
            .map(|c| -c.normal)
    };
    let blocked = |at: DVec3| deepest(at).is_some();
    if !blocked(ahead) || blocked(ahead + lift) {
        return None;
    }
    let (mut lo, mut hi) = (0.0, max_rise);
    for _ in 0..STEP_SEARCH {
        let mid = 0.5 * (lo + hi);
        if blocked(ahead + up * mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    // What it would stand on must be walkable: a steep slope is not a flight of steps.
    if deepest(ahead + up * lo).is_none_or(|n| n.dot(up) < c.min_ground_normal_up) {
        return None;
    }
    Some(hi + 0.5 * slop)
}

#[cfg(test)]
mod tests {
    use crate::scene::Scene;
    use crate::sim::{Plan, Stepper, SystemAction, TickInput, TickOutput, World};
    use glam::DVec3;
    use impact_protocol::{Action, ClientId, EntityId, RejectReason};

    const ME: ClientId = ClientId(1);

    /// Level ground (top at y = 0) with `more` static bodies on it, and a capsule character
    /// (1.6 m tall) with a 45 degree limit, a 1.2 m jump and a 0.3 m step, standing at x = 0.
    fn start(more: &str) -> (World, Stepper, EntityId) {
        let text = format!(
            r#"
            [world]
            name = "yard"
            tick_hz = 64
            gravity = [0.0, -9.81, 0.0]

            [[class]]
            name = "player"
            character = {{ walk_speed_mps = 4.0, jump_height_m = 1.2, max_slope_deg = 45.0, step_height_m = 0.3 }}

            [[class]]
            name = "ground"
            static = true

            [[body]]
            class = "ground"
            shape = {{ type = "cuboid", half_extents_m = [30.0, 0.5, 30.0] }}
            position = [0.0, -0.5, 0.0]
            {more}

            [spawn]
            avatar_class = "player"
            avatar_shape = {{ type = "capsule", half_height_m = 0.5, radius_m = 0.3 }}
            region_min = [0.0, 0.8, 0.0]
            region_max = [0.0, 0.8, 0.0]
            "#
        );
        let scene = Scene::parse(&text, "<yard>").unwrap();
        let rule = scene.avatar.clone().unwrap();
        let mut world = scene.world;
        let mut stepper = Stepper::new(Plan::for_world(&world), false);
        assert!(stepper.plan().characters);
        let spawn =
            SystemAction::SpawnAvatar { client: ME, class: rule.class, shape: rule.shape, pos: rule.region_min };
        let mut out = TickOutput::default();
        stepper.step_with(&mut world, &[spawn], &[], &mut out);
        let me = out.spawned[0].1;
        // Settle on the ground.
        for _ in 0..32 {
            stepper.step(&mut world, &[], &mut TickOutput::default());
        }
        (world, stepper, me)
    }

    /// From x = 2 on, a ramp rising at `slope_deg` (its top face passes through (2, 0)).
    fn yard(slope_deg: f64) -> (World, Stepper, EntityId) {
        let (s, c) = slope_deg.to_radians().sin_cos();
        let u = -8.0; // the ramp's top face meets the ground 8 m from its centre along the face
        let (x, y) = (2.0 - (u * c - 0.5 * s), -(u * s + 0.5 * c));
        start(&format!(
            r#"
            [[body]]
            class = "ground"
            shape = {{ type = "cuboid", half_extents_m = [10.0, 0.5, 3.0] }}
            position = [{x}, {y}, 0.0]
            rotation_deg = [0.0, 0.0, {slope_deg}]
            "#
        ))
    }

    fn pos(w: &World, e: EntityId) -> DVec3 {
        w.bodies.pos[w.bodies.slot(e).unwrap()]
    }

    /// Holds `move` toward +x (jumping if `jump`) for `ticks`, and returns the highest the
    /// character's centre got and where it ended.
    fn hold(w: &mut World, st: &mut Stepper, me: EntityId, ticks: u32, jump: bool) -> (f64, DVec3) {
        let mut top = f64::MIN;
        for k in 0..ticks {
            let walk = Action::Move { entity: me, direction: [1.0, 0.0, 0.0], jump };
            let mut out = TickOutput::default();
            st.step(w, &[TickInput::new(ME, k + 1, vec![walk])], &mut out);
            assert!(out.skipped.is_empty(), "{:?}", out.skipped);
            top = top.max(pos(w, me).y);
        }
        (top, pos(w, me))
    }

    /// Standing on level ground it does not sink or slide; held, `move` walks it at the walk
    /// speed along the ground, gravity not pressing it into the floor.
    #[test]
    fn a_character_stands_and_walks_at_its_speed() {
        let (mut w, mut st, me) = yard(30.0);
        let rest = pos(&w, me);
        assert!((rest.y - 0.8).abs() < 0.01, "stands on the floor: {rest}");
        for _ in 0..64 {
            st.step(&mut w, &[], &mut TickOutput::default());
        }
        assert_eq!(pos(&w, me), rest, "still");
        let mut before = pos(&w, me);
        for k in 0..20 {
            let walk = Action::Move { entity: me, direction: [0.0, 0.0, -1.0], jump: false };
            st.step(&mut w, &[TickInput::new(ME, k + 1, vec![walk])], &mut TickOutput::default());
            let now = pos(&w, me);
            assert!((now.z - before.z + 4.0 / 64.0).abs() < 1e-9, "4 m/s: {before} -> {now}");
            assert!((now.y - rest.y).abs() < 1e-9, "level: {now}");
            before = now;
        }
    }

    /// Jump held down: it bounces from the floor again and again and never rises above the
    /// jump height, but does reach most of it.
    #[test]
    fn holding_jump_stays_within_the_jump_height() {
        let (mut w, mut st, me) = yard(30.0);
        let rest = pos(&w, me).y;
        // Jumping on the spot (a zero direction), three seconds.
        let mut top = f64::MIN;
        let (mut takeoffs, mut rising) = (0, false);
        for k in 0..192u32 {
            let jump = Action::Move { entity: me, direction: [0.0; 3], jump: true };
            st.step(&mut w, &[TickInput::new(ME, k + 1, vec![jump])], &mut TickOutput::default());
            top = top.max(pos(&w, me).y);
            let up = w.bodies.vel[w.bodies.slot(me).unwrap()].y > 0.0;
            takeoffs += usize::from(up && !rising);
            rising = up;
        }
        let rise = top - rest;
        assert!(rise <= 1.2, "rose {rise} m, over the 1.2 m jump height");
        assert!(rise > 1.1, "rose only {rise} m");
        assert!(takeoffs >= 3, "it landed and jumped again, each time: {takeoffs} take-offs in 3 s");
    }

    /// A 30 degree ramp is walked up; a 60 degree one (over the 45 degree limit) is a wall.
    #[test]
    fn a_character_walks_up_a_slope_below_the_limit_and_not_above() {
        let (mut w, mut st, me) = yard(30.0);
        let (_, end) = hold(&mut w, &mut st, me, 192, false);
        assert!(end.y > 2.5, "3 s at 4 m/s from 2 m before a 30 degree ramp climbs it: {end}");
        let (mut w, mut st, me) = yard(60.0);
        let (top, end) = hold(&mut w, &mut st, me, 192, false);
        assert!(top < 0.8 + 0.05, "a 60 degree ramp is not climbed: top {top}, end {end}");
        assert!(end.x < 2.0, "it stays at the foot: {end}");
    }

    /// A ledge no higher than the step height (0.3 m) is walked onto; one higher stops the walk.
    #[test]
    fn a_character_steps_up_a_ledge_below_the_step_height_and_not_above() {
        for (height, climbs) in [(0.25, true), (0.4, false)] {
            // A block across the way from x = 1.5.
            let (mut w, mut st, me) = start(&format!(
                r#"
                [[body]]
                class = "ground"
                shape = {{ type = "cuboid", half_extents_m = [3.0, {half}, 3.0] }}
                position = [4.5, {half}, 0.0]
                "#,
                half = height / 2.0
            ));
            let (_, end) = hold(&mut w, &mut st, me, 96, false);
            if climbs {
                assert!((end.y - (0.8 + height)).abs() < 0.01, "{height} m: on top of the ledge: {end}");
                assert!(end.x > 3.0, "{height} m: and walked on: {end}");
            } else {
                assert!((end.y - 0.8).abs() < 0.01 && end.x < 1.5, "{height} m: stopped at its foot: {end}");
            }
        }
    }

    /// A client cannot set a character's velocity (it would fly), nor `move` a body that is no
    /// character: both refused with `not_allowed`.
    #[test]
    fn set_velocity_on_a_character_is_refused() {
        let (w, _, me) = yard(30.0);
        let up = Action::SetVelocity { entity: me, velocity: [0.0, 20.0, 0.0] };
        let push = Action::ApplyImpulse { entity: me, impulse: [0.0, 500.0, 0.0] };
        for a in [up, push] {
            let (reason, detail) = crate::sim::input::check(&w, ME, &[a]).unwrap_err();
            assert_eq!(reason, RejectReason::NotAllowed);
            assert!(detail.contains("`move`"), "{detail}");
        }
        assert_eq!(
            crate::sim::input::check(&w, ME, &[Action::Move { entity: me, direction: [1.0; 3], jump: true }]),
            Ok(())
        );
    }
}
