//! impact in Bevy: [`ImpactPlugin`] runs [`impact_client`] in Bevy's schedule, so the bodies of
//! an impact world appear, move and disappear as entities in the game's `World`, the player's own
//! avatar is predicted, and collision events, corrections and rejects arrive as Bevy messages.
//! Follows **Bevy 0.19** (needs Rust 1.95).
//!
//! ```no_run
//! use bevy::prelude::*;
//! use impact_bevy::{ImpactInput, ImpactPlugin, Interpolated, Predicted, ServerEntity};
//! use impact_client::transport::ConnectOptions;
//! use impact_protocol::{Action, ClientId, WorldId};
//!
//! let connect = ConnectOptions::new(vec!["tcp/127.0.0.1:7447".into()], WorldId::new("arena").unwrap(), ClientId(7));
//! App::new()
//!     .add_plugins((MinimalPlugins, bevy::state::app::StatesPlugin, ImpactPlugin::new(connect)))
//!     .add_systems(Update, steer)
//!     .run();
//!
//! // The game writes its inputs; the plugin sends them on the server's tick.
//! fn steer(avatar: Option<Single<&ServerEntity, With<Predicted>>>, mut input: ResMut<ImpactInput>) {
//!     if let Some(me) = avatar {
//!         input.push(Action::SetVelocity { entity: me.0, velocity: [2.0, 0.0, 0.0] });
//!     }
//! }
//! ```
//!
//! What the plugin does each frame, in `PreUpdate` ([`ImpactSystems::Receive`], then
//! [`ImpactSystems::Sync`]): hands the session what arrived, sets [`ImpactState`], writes the
//! messages ([`Collision`], [`Corrected`], [`Confirmed`], [`RayHit`], [`Answered`], [`Refused`],
//! [`Closed`]), and brings the entities in line with the remote world drawn at render time: one
//! entity per body in the player's area (a map from server entity to Bevy entity,
//! [`ImpactEntities`]), with [`ServerEntity`], [`BodyClass`], [`BodyOwner`], [`BodyShape`],
//! [`GameValues`], [`Velocity`], [`Asleep`] while asleep, and [`Predicted`] for the own avatar or
//! [`Interpolated`] for the rest; its `Transform` is where the body is drawn (remote bodies
//! interpolated between stream frames, the own avatar predicted at the tick an input made now
//! would be stamped with, so it moves smoothly between fixed steps). A game attaches its own
//! components (meshes, sounds) to these entities; the plugin only writes its own and `Transform`.
//!
//! Inputs: the game pushes actions into [`ImpactInput`] (any schedule); in `FixedPostUpdate`
//! ([`ImpactSystems::Send`]) the plugin sends what is there as one input and writes [`Sent`] with
//! its seq. `Time<Fixed>` follows the server's tick rate and the client's clock dilation, so a
//! game that pushes once per fixed step sends one input per tick the server steps.
//!
//! Connecting (finding the server, subscribing, declaring presence) runs on a thread of its own:
//! the app keeps running while [`ImpactState`] is `Joining`; a failure is `Lost` with the reason
//! in [`Impact::problem`].

use bevy::prelude::*;
use impact_client::remote::DrawnBody;
use impact_client::transport::{ConnectOptions, Connection, TransportError};
use impact_client::{Answer, EventNews, InputError, Outcome, Session, SessionConfig, Status};
use impact_protocol::{
    Action, BodyInfo, ClientId, CollisionEvent, CorrectionBatch, EntityId, GameState, RayResult, RejectReason,
    ShapeSpec, Tick, WorldClosed,
};
use std::collections::BTreeMap;
use std::sync::mpsc::{Receiver, TryRecvError};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Adds impact to an app (see the crate docs). Needs Bevy's `StatesPlugin` (in `DefaultPlugins`;
/// add it beside `MinimalPlugins`).
#[derive(Clone, Debug)]
pub struct ImpactPlugin {
    /// Where and how to connect (endpoints, world, client id, credentials, state stream).
    pub connect: ConnectOptions,
    /// The session's settings (ahead or behind, redundancy, interpolation delay, prediction).
    pub session: SessionConfig,
    /// A playing session that heard nothing from the server this long (while it streams state
    /// or awaits answers) is [`ImpactState::Reconnecting`].
    pub quiet_after: Duration,
    /// And after this long, [`ImpactState::Lost`].
    pub lost_after: Duration,
}

impl ImpactPlugin {
    /// Connects with `connect`, with the session's defaults (ahead, predicting from the server's
    /// scene), reconnecting after 1 s of silence and lost after 10 s.
    pub fn new(connect: ConnectOptions) -> ImpactPlugin {
        let session = SessionConfig::new(connect.client);
        ImpactPlugin { connect, session, quiet_after: Duration::from_secs(1), lost_after: Duration::from_secs(10) }
    }
}

/// The connection's state: the game shows a menu, a spinner or the world by it.
#[derive(States, Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ImpactState {
    /// Finding the server, joining, measuring the round trip.
    #[default]
    Joining,
    /// Inputs are stamped on time; the world streams in.
    Playing,
    /// The server went quiet (a dropped link Zenoh is restoring, a server failing over): inputs
    /// are still sent and resent.
    Reconnecting,
    /// Connecting failed, or the server has been quiet for [`ImpactPlugin::lost_after`]:
    /// [`Impact::problem`] says why.
    Lost,
    /// The world closed ([`Closed`] says where its players go next).
    Closed,
}

/// The plugin's systems, for ordering a game's own around them.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ImpactSystems {
    /// `PreUpdate`: what arrived is handed to the session; state and messages are written.
    Receive,
    /// `PreUpdate`, after `Receive`: entities and their `Transform`s follow the drawn world.
    Sync,
    /// `FixedPostUpdate`: the game's [`ImpactInput`] is sent.
    Send,
}

/// The server's id of the body an entity stands for.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ServerEntity(pub EntityId);

/// The player's own avatar, drawn where the prediction has it.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Predicted;

/// A body drawn from the state stream, interpolated between its frames.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Interpolated;

/// The body's class from the scene (game logic may change it).
#[derive(Component, Clone, Debug, PartialEq, Eq)]
pub struct BodyClass(pub String);

/// The client that owns the body, if any.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct BodyOwner(pub Option<ClientId>);

/// The body's shape, for drawing.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct BodyShape {
    /// Its shape in its own frame (a sphere, capsule, cuboid or ellipsoid with its dimensions;
    /// `None` for hulls, meshes and terrain, drawn by their bounds).
    pub local: Option<ShapeSpec>,
    /// Half extents of its world-frame bounding box, metres.
    pub half_extents: Vec3,
    /// That box's centre relative to the body's position, metres.
    pub offset: Vec3,
    /// Static: never moves.
    pub fixed: bool,
}

/// The body's game state (health, team, score), as game logic set it.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct GameValues(pub GameState);

/// The body's velocity as drawn, m/s.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Velocity(pub Vec3);

/// The body sleeps in the server's world.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Asleep;

/// The game's inputs for the next fixed step: actions pushed here are sent together as one input
/// (at most [`impact_protocol::limits::MAX_ACTIONS_PER_INPUT`]; more are refused with
/// [`Refused`]).
#[derive(Resource, Clone, Debug, Default)]
pub struct ImpactInput {
    /// The actions, in order.
    pub actions: Vec<Action>,
}

impl ImpactInput {
    /// Adds an action to the next input.
    pub fn push(&mut self, action: Action) {
        self.actions.push(action);
    }
}

/// Server entities and the Bevy entities that stand for them.
#[derive(Resource, Clone, Debug, Default)]
pub struct ImpactEntities {
    map: BTreeMap<EntityId, Entity>,
}

impl ImpactEntities {
    /// The Bevy entity of server entity `id`, if in the player's area.
    pub fn get(&self, id: EntityId) -> Option<Entity> {
        self.map.get(&id).copied()
    }

    /// Bodies mapped.
    pub fn len(&self) -> usize {
        self.map.len()
    }

    /// Whether none is.
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }
}

/// A provisional collision event, as the server first published it.
#[derive(Message, Clone, Debug, PartialEq)]
pub struct Collision(pub CollisionEvent);

/// A re-simulation changed a tick's events (retracted, amended, added: match by
/// `CollisionEvent::key`).
#[derive(Message, Clone, Debug, PartialEq)]
pub struct Corrected(pub CorrectionBatch);

/// A tick's events are final; `matched`: the view as it stood equalled the server's record.
#[derive(Message, Clone, Copy, Debug, PartialEq, Eq)]
pub struct Confirmed {
    /// The tick.
    pub tick: Tick,
    /// The view equalled the confirmed batch.
    pub matched: bool,
}

/// A ray the player fired, judged by the server against what the player saw.
#[derive(Message, Clone, Debug, PartialEq)]
pub struct RayHit(pub RayResult);

/// An input was sent: its seq, and the actions it carried.
#[derive(Message, Clone, Debug, PartialEq)]
pub struct Sent {
    /// The input's seq (answers name it).
    pub seq: u32,
    /// Its actions.
    pub actions: Vec<Action>,
}

/// The server answered an input: accepted at a tick, or refused with a typed reason.
#[derive(Message, Clone, Copy, Debug, PartialEq)]
pub struct Answered(pub Answer);

/// An input was refused: by the server (`reason`), or by the session before sending
/// (`local`: not joined, the world closed, too many actions).
#[derive(Message, Clone, Debug, PartialEq)]
pub struct Refused {
    /// The input's seq, if it was sent.
    pub seq: Option<u32>,
    /// The server's reason.
    pub reason: Option<RejectReason>,
    /// Why the session did not send it.
    pub local: Option<InputError>,
}

/// The world closed; its players go to `next`, if game logic named one.
#[derive(Message, Clone, Debug, PartialEq)]
pub struct Closed(pub WorldClosed);

/// The connection: opening, open, or failed.
#[derive(Debug)]
enum Link {
    Opening(Receiver<Result<Connection, TransportError>>),
    Open(Box<Connection>),
    Failed,
}

/// The client: its [`Session`] and connection, and the world drawn this frame.
#[derive(Resource, Debug)]
pub struct Impact {
    session: Session,
    link: Mutex<Link>,
    drawn: Vec<DrawnBody>,
    avatar_at: Option<[f64; 3]>,
    problem: Option<String>,
    quiet_after: Duration,
    lost_after: Duration,
    streams_state: bool,
}

impl Impact {
    /// The session: status, stats, the views, the clock.
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// The session, to call it directly (`input` beside [`ImpactInput`], `take_*`; what the
    /// plugin takes each frame is gone by the game's `Update`).
    pub fn session_mut(&mut self) -> &mut Session {
        &mut self.session
    }

    /// Calls `f` with the connection, once open (for queries beside the protocol, what it
    /// dropped, [`impact_client::report::PlayReport`]).
    pub fn with_connection<R>(&self, f: impl FnOnce(&Connection, &Session) -> R) -> Option<R> {
        match &*self.link.lock().ok()? {
            Link::Open(c) => Some(f(c, &self.session)),
            Link::Opening(_) | Link::Failed => None,
        }
    }

    /// The remote world drawn this frame (every body in the area, the own avatar as the
    /// stream has it), by ascending id.
    pub fn drawn(&self) -> &[DrawnBody] {
        &self.drawn
    }

    /// The own avatar as drawn this frame, predicted (`None` without prediction).
    pub fn avatar_position(&self) -> Option<[f64; 3]> {
        self.avatar_at
    }

    /// Why the state is [`ImpactState::Lost`].
    pub fn problem(&self) -> Option<&str> {
        self.problem.as_deref()
    }
}

impl Plugin for ImpactPlugin {
    fn build(&self, app: &mut App) {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let opts = self.connect.clone();
        // Finding the server takes up to `find_server`: off the app's thread.
        let spawned = std::thread::Builder::new().name("impact-connect".into()).spawn(move || {
            let _ = tx.send(Connection::open(&opts));
        });
        let (link, problem) = match spawned {
            Ok(_) => (Link::Opening(rx), None),
            Err(e) => (Link::Failed, Some(format!("starting the connection thread: {e}"))),
        };
        app.insert_resource(Impact {
            session: Session::new(self.session.clone()),
            link: Mutex::new(link),
            drawn: Vec::new(),
            avatar_at: None,
            problem,
            quiet_after: self.quiet_after,
            lost_after: self.lost_after,
            streams_state: self.connect.state,
        })
        .init_resource::<ImpactInput>()
        .init_resource::<ImpactEntities>()
        .init_state::<ImpactState>()
        .add_message::<Collision>()
        .add_message::<Corrected>()
        .add_message::<Confirmed>()
        .add_message::<RayHit>()
        .add_message::<Sent>()
        .add_message::<Answered>()
        .add_message::<Refused>()
        .add_message::<Closed>()
        .configure_sets(PreUpdate, (ImpactSystems::Receive, ImpactSystems::Sync).chain())
        .add_systems(PreUpdate, (receive, follow_clock).chain().in_set(ImpactSystems::Receive))
        .add_systems(PreUpdate, sync_bodies.in_set(ImpactSystems::Sync))
        .add_systems(FixedPostUpdate, send_inputs.in_set(ImpactSystems::Send));
    }
}

/// The messages a frame writes.
#[derive(bevy::ecs::system::SystemParam)]
struct Writers<'w> {
    collisions: MessageWriter<'w, Collision>,
    corrected: MessageWriter<'w, Corrected>,
    confirmed: MessageWriter<'w, Confirmed>,
    rays: MessageWriter<'w, RayHit>,
    answered: MessageWriter<'w, Answered>,
    refused: MessageWriter<'w, Refused>,
    closed: MessageWriter<'w, Closed>,
}

/// Takes the connection once open, hands the session what arrived, sends what it gives, and
/// writes the state and the messages.
fn receive(
    mut impact: ResMut<'_, Impact>,
    state: Res<'_, State<ImpactState>>,
    mut next: ResMut<'_, NextState<ImpactState>>,
    mut out: Writers<'_>,
) {
    let now = Instant::now();
    let impact = &mut *impact;
    let pumped = {
        let Ok(mut link) = impact.link.lock() else { return };
        if let Link::Opening(rx) = &*link {
            match rx.try_recv() {
                Ok(Ok(c)) => *link = Link::Open(Box::new(c)),
                Ok(Err(e)) => {
                    impact.problem = Some(e.to_string());
                    *link = Link::Failed;
                }
                Err(TryRecvError::Empty) => {}
                Err(TryRecvError::Disconnected) => {
                    impact.problem = Some("the connection thread ended without a connection".into());
                    *link = Link::Failed;
                }
            }
        }
        match &*link {
            Link::Open(c) => Some(c.pump(&mut impact.session, now)),
            Link::Opening(_) | Link::Failed => None,
        }
    };
    if let Some(Err(e)) = pumped {
        impact.problem = Some(e.to_string());
    }
    let s = &mut impact.session;
    for news in s.take_event_news() {
        match news {
            EventNews::Event(e) => {
                out.collisions.write(Collision(e));
            }
            EventNews::Corrected(c) => {
                out.corrected.write(Corrected(c));
            }
            EventNews::Confirmed { tick, matched } => {
                out.confirmed.write(Confirmed { tick, matched });
            }
        }
    }
    for r in s.take_ray_results() {
        out.rays.write(RayHit(r));
    }
    for a in s.take_answers() {
        if let Outcome::Rejected(reason) = a.outcome {
            out.refused.write(Refused { seq: Some(a.seq), reason: Some(reason), local: None });
        }
        out.answered.write(Answered(a));
    }
    let failed = impact.link.lock().map_or(true, |l| matches!(*l, Link::Failed));
    let was_closed = *state.get() == ImpactState::Closed;
    let now_state = impact.state(failed, now);
    if now_state == ImpactState::Closed && !was_closed {
        if let Some(c) = impact.session.closed() {
            out.closed.write(Closed(c.clone()));
        }
    }
    if now_state != *state.get() {
        next.set(now_state);
    }
}

impl Impact {
    /// The state at `now` (see [`ImpactState`]).
    fn state(&mut self, failed: bool, now: Instant) -> ImpactState {
        if failed {
            return ImpactState::Lost;
        }
        match self.session.status() {
            Status::Joining | Status::Syncing => ImpactState::Joining,
            Status::Closed => ImpactState::Closed,
            Status::Playing => {
                let listening = self.streams_state || self.session.pending_inputs() > 0;
                let quiet = self.session.last_heard().map_or(Duration::ZERO, |h| now.saturating_duration_since(h));
                if listening && quiet >= self.lost_after {
                    self.problem = Some(format!("nothing from the server for {:.0} s", quiet.as_secs_f64()));
                    ImpactState::Lost
                } else if listening && quiet >= self.quiet_after {
                    ImpactState::Reconnecting
                } else {
                    ImpactState::Playing
                }
            }
        }
    }
}

/// `Time<Fixed>` steps once per tick an input is stamped with: the server's tick rate, run fast
/// or slow by the clock's dilation while the lead moves.
fn follow_clock(impact: Res<'_, Impact>, mut fixed: ResMut<'_, Time<Fixed>>) {
    let s = &impact.session;
    let Some(hz) = s.clock().tick_hz() else { return };
    let rate = s.clock().stamp_rate(s.config().ahead);
    let step = Duration::from_secs_f64(1.0 / (f64::from(hz) * rate));
    if fixed.timestep() != step {
        fixed.set_timestep(step);
    }
}

fn vec3(p: [f64; 3]) -> Vec3 {
    Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32)
}

fn vec3f(p: [f32; 3]) -> Vec3 {
    Vec3::from_array(p)
}

/// What an entity carries for a body, from its info.
fn described(info: &BodyInfo) -> (BodyClass, BodyOwner, BodyShape, GameValues) {
    (
        BodyClass(info.class.clone()),
        BodyOwner(info.owner),
        BodyShape {
            local: info.local_shape.clone(),
            half_extents: vec3f(info.half_extents_m),
            offset: vec3f(info.offset_m),
            fixed: info.fixed,
        },
        GameValues(info.state.clone()),
    )
}

/// What `sync_bodies` keeps up to date on a mapped entity.
type Mapped = (
    &'static mut Transform,
    &'static mut Velocity,
    &'static mut BodyClass,
    &'static mut GameValues,
    Has<Asleep>,
    Has<Predicted>,
);

/// The entities follow the remote world drawn now: spawned for bodies that came into the area,
/// moved, described again when their info changed, despawned when they left it.
fn sync_bodies(
    mut commands: Commands<'_, '_>,
    mut impact: ResMut<'_, Impact>,
    mut map: ResMut<'_, ImpactEntities>,
    mut bodies: Query<'_, '_, Mapped>,
) {
    let now = Instant::now();
    let impact = &mut *impact;
    let mut drawn = std::mem::take(&mut impact.drawn);
    impact.session.draw_remote(now, &mut drawn);
    impact.avatar_at = impact.session.draw_avatar(now);
    let avatar = impact.session.avatar();
    let Some(remote) = impact.session.remote() else {
        impact.drawn = drawn;
        return;
    };
    for d in &drawn {
        let Some(info) = remote.info(d.entity) else { continue };
        let mine = avatar == Some(d.entity);
        let position = match (mine, impact.avatar_at) {
            (true, Some(p)) => p,
            _ => d.position,
        };
        let rotation = info.rotation.map_or(Quat::IDENTITY, Quat::from_array);
        let transform = Transform::from_translation(vec3(position)).with_rotation(rotation);
        let velocity = Velocity(vec3(d.velocity));
        match map.map.get(&d.entity).copied() {
            Some(e) => {
                let Ok((mut t, mut v, mut class, mut values, asleep, predicted)) = bodies.get_mut(e) else {
                    continue;
                };
                // Prediction starts once the server's scene came: the avatar changes marker then.
                if mine && impact.avatar_at.is_some() && !predicted {
                    commands.entity(e).remove::<Interpolated>().insert(Predicted);
                }
                if *t != transform {
                    *t = transform;
                }
                if *v != velocity {
                    *v = velocity;
                }
                if class.0 != info.class {
                    *class = BodyClass(info.class.clone());
                }
                if values.0 != info.state {
                    *values = GameValues(info.state.clone());
                }
                match (asleep, d.asleep) {
                    (false, true) => {
                        commands.entity(e).insert(Asleep);
                    }
                    (true, false) => {
                        commands.entity(e).remove::<Asleep>();
                    }
                    _ => {}
                }
            }
            None => {
                let mut e = commands.spawn((ServerEntity(d.entity), transform, velocity, described(info)));
                if mine && impact.avatar_at.is_some() {
                    e.insert(Predicted);
                } else {
                    e.insert(Interpolated);
                }
                if d.asleep {
                    e.insert(Asleep);
                }
                map.map.insert(d.entity, e.id());
            }
        }
    }
    // Bodies the remote world no longer holds left the area (or the world).
    map.map.retain(|id, e| {
        let held = remote.info(*id).is_some();
        if !held {
            commands.entity(*e).despawn();
        }
        held
    });
    impact.drawn = drawn;
}

/// Sends what the game pushed into [`ImpactInput`] as one input, and at once (not at the next
/// frame's pump).
fn send_inputs(
    mut impact: ResMut<'_, Impact>,
    mut input: ResMut<'_, ImpactInput>,
    mut sent: MessageWriter<'_, Sent>,
    mut refused: MessageWriter<'_, Refused>,
) {
    if input.actions.is_empty() {
        return;
    }
    let actions = std::mem::take(&mut input.actions);
    let now = Instant::now();
    let impact = &mut *impact;
    match impact.session.input(actions.clone(), now) {
        Ok(seq) => {
            sent.write(Sent { seq, actions });
        }
        Err(e) => {
            refused.write(Refused { seq: None, reason: None, local: Some(e) });
            return;
        }
    }
    if let Ok(link) = impact.link.lock() {
        if let Link::Open(c) = &*link {
            if let Err(e) = c.pump(&mut impact.session, now) {
                impact.problem = Some(e.to_string());
            }
        }
    }
}
