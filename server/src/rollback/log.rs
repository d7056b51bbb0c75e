//! The input log in the core's terms: confirmed ticks to and from their wire form
//! ([`impact_protocol::log`]), and checkpoints of the complete world.
//!
//! A log entry holds what the core needs to step the tick again (inputs and server actions in
//! the order applied) and the hash it must reach. Rays' rewound hits are not logged: stepping the
//! tick inside a [`Session`](super::Session) casts them again against the same history.

use glam::{DQuat, DVec3};
use impact_core::geometry::Shape;
use impact_core::sim::input::RewoundRay;
use impact_core::sim::world::{ClassId, NewBody, SimConfig, Touch};
use impact_core::sim::{SystemAction, TickInput, World};
use impact_protocol::log::LoggedRay;
use impact_protocol::log::{CheckpointBody, CheckpointTouch};
use impact_protocol::{Checkpoint, LogTick, LoggedInput, LoggedSystem, ShapeSpec, Tick};

/// One confirmed tick: what was applied at it and the hash of the world after it.
#[derive(Clone, Debug)]
pub struct ConfirmedTick {
    /// The tick.
    pub tick: Tick,
    /// Server actions, in order.
    pub system: Vec<SystemAction>,
    /// Client inputs, in the order applied.
    pub inputs: Vec<TickInput>,
    /// State hash after the tick.
    pub state_hash: u64,
}

/// The class and shape the scene gives avatars (a logged spawn names only client and position).
pub type AvatarShape<'a> = Option<(ClassId, &'a Shape)>;

/// An input in its logged form (moved: the log entry is the last to need it).
pub fn logged_input(i: TickInput, tick: Tick) -> LoggedInput {
    LoggedInput {
        client: i.client,
        seq: i.seq,
        tick,
        view_tick: i.view_tick,
        actions: i.actions,
        rewound: i
            .rewound
            .into_iter()
            .map(|r| LoggedRay { action: r.action, view_tick: r.view_tick, clamped: r.clamped, hit: r.hit })
            .collect(),
        logic: i.logic,
    }
}

/// A confirmed input as the core applies it: its rays' outcomes as logged.
pub fn tick_input(l: LoggedInput) -> TickInput {
    TickInput {
        view_tick: l.view_tick,
        rewound: l
            .rewound
            .into_iter()
            .map(|r| RewoundRay { action: r.action, view_tick: r.view_tick, clamped: r.clamped, hit: r.hit })
            .collect(),
        logged: true,
        logic: l.logic,
        ..TickInput::new(l.client, l.seq, l.actions)
    }
}

/// An admitted input, not yet confirmed, as a standby that takes over applies it: its rays are
/// cast again when its tick is simulated (the standby holds the history they look at).
pub fn pending_input(l: LoggedInput) -> TickInput {
    TickInput { view_tick: l.view_tick, logic: l.logic, ..TickInput::new(l.client, l.seq, l.actions) }
}

/// A server action in its logged form.
pub fn logged_system(a: &SystemAction) -> LoggedSystem {
    match a {
        SystemAction::SpawnAvatar { client, pos, .. } => {
            LoggedSystem::SpawnAvatar { client: *client, position: pos.to_array() }
        }
        SystemAction::Remove { entity } => LoggedSystem::Remove { entity: *entity },
    }
}

/// A logged server action as the core applies it; a spawn needs the scene's avatar.
pub fn system_action(l: &LoggedSystem, avatar: AvatarShape<'_>) -> Result<SystemAction, String> {
    Ok(match l {
        LoggedSystem::SpawnAvatar { client, position } => {
            let (class, shape) = avatar
                .ok_or_else(|| format!("the log spawns client {client}'s avatar but the scene has no [avatar]"))?;
            SystemAction::SpawnAvatar {
                client: *client,
                class,
                shape: shape.clone(),
                pos: DVec3::from_array(*position),
            }
        }
        LoggedSystem::Remove { entity } => SystemAction::Remove { entity: *entity },
    })
}

impl ConfirmedTick {
    /// The wire form (the inputs moved into it, not copied: it is made once a tick, for the log).
    pub fn into_wire(self) -> LogTick {
        let tick = self.tick;
        LogTick {
            tick,
            system: self.system.iter().map(logged_system).collect(),
            inputs: self.inputs.into_iter().map(|i| logged_input(i, tick)).collect(),
            state_hash: self.state_hash,
        }
    }

    /// From the wire form.
    pub fn from_wire(l: LogTick, avatar: AvatarShape<'_>) -> Result<ConfirmedTick, String> {
        let system = l.system.iter().map(|s| system_action(s, avatar)).collect::<Result<_, _>>()?;
        if let Some(i) = l.inputs.iter().find(|i| i.tick != l.tick) {
            return Err(format!("log entry of tick {} holds an input of tick {}", l.tick, i.tick));
        }
        Ok(ConfirmedTick {
            tick: l.tick,
            system,
            inputs: l.inputs.into_iter().map(tick_input).collect(),
            state_hash: l.state_hash,
        })
    }
}

/// The dynamic part of `w` (bodies, contacts, ids) as a checkpoint without clients.
pub fn checkpoint_world(w: &World) -> Result<Checkpoint, String> {
    let b = &w.bodies;
    let bodies = (0..b.len())
        .map(|i| {
            Ok(CheckpointBody {
                entity: b.id[i],
                class: b.class[i].0,
                shape: b.shape[i].to_spec(),
                position: b.pos[i].to_array(),
                velocity: b.vel[i].to_array(),
                rotation: b.rot[i].to_array(),
                inv_mass: b.inv_mass[i],
                owner: b.owner[i],
                asleep: b.asleep[i],
                still_ticks: b.still_ticks[i],
                game: impact_protocol::GameState::clone(&b.game[i]),
                teleported: b.teleported[i],
            })
        })
        .collect::<Result<_, String>>()?;
    let touching = w
        .touching
        .iter()
        .map(|t| CheckpointTouch {
            a: t.a,
            b: t.b,
            normal: t.normal.to_array(),
            depth: t.depth,
            impulse: t.impulse,
            friction_impulse: t.friction_impulse.to_array(),
        })
        .collect();
    Ok(Checkpoint {
        tick: w.tick,
        next_entity: w.next_entity,
        bodies,
        touching,
        clients: Vec::new(),
        state_hash: w.state_hash(),
        settings: settings(&w.config),
    })
}

/// What a checkpoint says of the settings `cfg` runs with: every value a step depends on that
/// the scene's `[world]` resolves (and the class rules), as text.
fn settings(cfg: &SimConfig) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = [
        ("tick_hz", cfg.tick_hz.to_string()),
        ("gravity", format!("{:?}", cfg.gravity.to_array())),
        ("contact_slop_m", cfg.contact_slop_m.to_string()),
        ("bounce_threshold_mps", cfg.bounce_threshold_mps.to_string()),
        ("friction", cfg.friction.to_string()),
        ("sleep_speed_mps", cfg.sleep_speed_mps.to_string()),
        ("sleep_after_ticks", cfg.sleep_after_ticks.to_string()),
        ("partial_sleep", cfg.partial_sleep.to_string()),
        ("window_ticks", cfg.window_ticks.to_string()),
        ("toi_tolerance", cfg.bisect.tolerance.to_string()),
        ("max_resolutions_per_tick", cfg.max_resolutions_per_tick.to_string()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let n = cfg.classes.props.len();
    for a in 0..n {
        for b in a..n {
            let rule = cfg.classes.rule(ClassId(a as u16), ClassId(b as u16));
            out.push((format!("rule {a}-{b}"), format!("{rule:?}")));
        }
    }
    out
}

/// `scene` (its statics and settings) with the dynamic state of `c`, checked against its hash.
pub fn restore_world(scene: &World, c: &Checkpoint) -> Result<World, String> {
    if !c.settings.is_empty() {
        let here = settings(&scene.config);
        let differ: Vec<String> = c
            .settings
            .iter()
            .zip(&here)
            .filter(|(a, b)| a != b)
            .map(|((k, theirs), (_, ours))| format!("{k}: {theirs} vs {ours}"))
            .collect();
        if !differ.is_empty() || c.settings.len() != here.len() {
            return Err(format!(
                "the checkpoint's world runs with other settings than this server's scene (theirs vs here: {}): \
                 a build with other defaults? run the same build, or write the keys in the scene",
                if differ.is_empty() { "another class table".to_string() } else { differ.join(", ") }
            ));
        }
    }
    let mut w = World { tick: c.tick, next_entity: c.next_entity, touching: Vec::new(), ..scene.clone() };
    w.bodies = Default::default();
    let classes = w.config.classes.props.len();
    for (i, b) in c.bodies.iter().enumerate() {
        if usize::from(b.class) >= classes {
            return Err(format!("body {} has class {} but the scene has {classes} classes", b.entity, b.class));
        }
        if w.bodies.id.last().is_some_and(|&last| last >= b.entity) {
            return Err(format!("checkpoint bodies are not in ascending id order at {}", b.entity));
        }
        if matches!(b.shape, ShapeSpec::Mesh { .. }) {
            return Err(format!("checkpoint body {} is a mesh: a mesh belongs to a static class", b.entity));
        }
        let shape = Shape::from_spec(&b.shape).map_err(|e| format!("checkpoint body {}: shape.{e}", b.entity))?;
        w.bodies.push(
            b.entity,
            NewBody {
                class: ClassId(b.class),
                shape,
                pos: DVec3::from_array(b.position),
                vel: DVec3::from_array(b.velocity),
                rot: DQuat::from_array(b.rotation),
                inv_mass: b.inv_mass,
                owner: b.owner,
            },
        );
        w.bodies.asleep[i] = b.asleep;
        w.bodies.still_ticks[i] = b.still_ticks;
        if !b.game.is_empty() {
            w.bodies.set_game(i, b.game.clone());
        }
        if let Some(t) = b.teleported {
            w.bodies.set_teleported(i, t);
        }
    }
    w.touching = c
        .touching
        .iter()
        .map(|t| Touch {
            a: t.a,
            b: t.b,
            normal: DVec3::from_array(t.normal),
            depth: t.depth,
            impulse: t.impulse,
            friction_impulse: DVec3::from_array(t.friction_impulse),
        })
        .collect();
    let h = w.state_hash();
    if h != c.state_hash {
        return Err(format!(
            "the checkpoint of tick {} restores to hash {h:#018x}, not {:#018x}: a different scene file?",
            c.tick, c.state_hash
        ));
    }
    Ok(w)
}
