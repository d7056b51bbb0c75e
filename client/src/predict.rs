//! Prediction of the player's own avatar with the same deterministic core the server runs.
//!
//! The predictor holds a world of the scene's static geometry and terrain (as the server
//! describes it, `query/scene`, or from the game's own copy of the scene file, checked against
//! the server's by [`Predictor::scene_hash`]) and one dynamic body: the avatar. Each input is
//! applied at once at the tick it is stamped with, so the player sees its effect a frame later
//! instead of a round trip later. Twenty times a second
//! the client's state stream brings the avatar's authoritative state at a tick
//! ([`AvatarState`]: exact f64 position and velocity, sleep state, contacts); the predictor
//! compares it with what it predicted for that tick. Equal to the bit (the usual case: the core
//! is deterministic), nothing happens. Different (another body hit the avatar, which the
//! predictor does not simulate; an input the server had not applied yet), it rewinds to the
//! server's state, replays its inputs from there to the present, and eases the drawn difference
//! away ([`Predictor::drawn`]).
//!
//! Bounded: inputs and predicted states are kept for [`PredictConfig::history_ticks`] ticks; at
//! most [`PredictConfig::max_steps`] ticks are stepped per call (a client that fell far behind
//! jumps, it does not spiral).

use glam::{DQuat, DVec3};
use impact_core::geometry::Shape;
#[cfg(doc)]
use impact_core::scene::Scene;
use impact_core::scene::{SceneError, SceneRules};
use impact_core::sim::world::{ClassId, NewBody, Touch};
use impact_core::sim::{Stepper, TickInput, TickOutput, World};
use impact_protocol::{Action, AvatarState, ClientId, EntityId, Tick};
use std::collections::{BTreeMap, VecDeque};

/// How the predictor behaves.
#[derive(Clone, Debug, PartialEq)]
pub struct PredictConfig {
    /// Ticks of inputs and predicted states kept (default 256: 4 s at 64 Hz, far more than a
    /// state stream's round trip).
    pub history_ticks: u32,
    /// Most ticks stepped in one call (default 64).
    pub max_steps: u32,
    /// A drawn correction decays with this time constant, seconds (default 0.04)...
    pub smoothing_s: f64,
    /// ...but at least this fast, m/s, so that it ends instead of dwindling (default 1).
    pub min_correction_mps: f64,
    /// ...and at most this fast, m/s (default 2.95: just under 5 cm in a 60 Hz frame). So a
    /// correction of up to 0.6 m is gone within 250 ms; 0.6 to 1 m take up to a third of a
    /// second, held to the 5 cm a frame.
    pub max_correction_mps: f64,
    /// A correction larger than this is a teleport: drawn at once (default 1 m).
    pub snap_m: f64,
}

impl Default for PredictConfig {
    fn default() -> PredictConfig {
        PredictConfig {
            history_ticks: 256,
            max_steps: 64,
            smoothing_s: 0.04,
            min_correction_mps: 1.0,
            max_correction_mps: 2.95,
            snap_m: 1.0,
        }
    }
}

/// Why a predictor could not be made.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PredictError {
    /// The server's scene (`query/scene`) did not come: why.
    NoScene(String),
    /// The server's scene came but did not rebuild (a value out of range, another hash).
    Described(SceneError),
    /// The scene spawns no avatars: nothing to predict.
    NoAvatars,
    /// The server runs another scene (or other settings) than the one the client loaded.
    SceneMismatch {
        /// The client's hash.
        client: u64,
        /// The server's.
        server: u64,
    },
}

impl std::fmt::Display for PredictError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PredictError::NoScene(why) => write!(f, "the server's scene did not come ({why}): nothing to predict with"),
            PredictError::Described(e) => write!(f, "the server's scene did not rebuild: {e}"),
            PredictError::NoAvatars => {
                write!(f, "the scene spawns no avatars ([spawn] avatar_class): nothing to predict")
            }
            PredictError::SceneMismatch { client, server } => write!(
                f,
                "the server's world differs from the scene this client loaded (scene hash {server:016x} against \
                 {client:016x}): load the same scene file, with the server's --tick-hz and --rollback-ms"
            ),
        }
    }
}

impl std::error::Error for PredictError {}

/// What happened when an authoritative state arrived.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reconciled {
    /// The prediction for that tick was exact to the bit.
    Exact,
    /// It differed by this distance, m: rewound and replayed.
    Corrected(f64),
    /// No prediction to compare (the first state, a new avatar, a tick outside the history):
    /// taken as it is.
    Taken,
    /// Game logic teleported the avatar (the state names a teleport the prediction did not
    /// have): taken, replayed, and drawn there at once; no misprediction, since no client could
    /// have known.
    Teleported,
}

/// The avatar's whole core state at the start of a tick.
#[derive(Clone, Debug, PartialEq)]
struct Snap {
    tick: Tick,
    pos: DVec3,
    vel: DVec3,
    asleep: bool,
    still: u16,
    touching: Vec<Touch>,
    class: ClassId,
    teleported: Option<Tick>,
}

impl Snap {
    /// The server's state; its class, if it names one of the `classes` there are, else `known`.
    fn of(s: &AvatarState, tick: Tick, known: ClassId, classes: usize) -> Snap {
        let me = s.entity;
        let mut touching: Vec<Touch> = s
            .touching
            .iter()
            .map(|t| Touch {
                a: me.min(t.other),
                b: me.max(t.other),
                normal: DVec3::from_array(t.normal),
                depth: t.depth_m,
                impulse: t.impulse,
                friction_impulse: DVec3::from_array(t.friction_impulse),
            })
            .collect();
        touching.sort_by_key(Touch::key);
        Snap {
            tick,
            pos: DVec3::from_array(s.position),
            vel: DVec3::from_array(s.velocity),
            asleep: s.asleep,
            still: s.still_ticks,
            touching,
            class: s.class.filter(|c| usize::from(*c) < classes).map_or(known, ClassId),
            teleported: s.teleported,
        }
    }
}

/// The avatar predicted (see the module docs).
#[derive(Debug)]
pub struct Predictor {
    cfg: PredictConfig,
    client: ClientId,
    world: World,
    stepper: Stepper,
    out: TickOutput,
    class: ClassId,
    shape: Shape,
    inv_mass: f64,
    avatar: Option<EntityId>,
    /// The client's inputs by tick (movement actions only).
    inputs: BTreeMap<u32, Vec<TickInput>>,
    /// The predicted state at the start of each tick, oldest first.
    history: VecDeque<Snap>,
    /// Drawn minus predicted, decaying to zero.
    offset: DVec3,
    scene_hash: u64,
}

impl Predictor {
    /// A predictor for `client` on `rules`: the server's (from `query/scene`,
    /// [`SceneRules::from_description`]) or the game's own copy of the scene ([`Scene::rules`]).
    pub fn new(rules: &SceneRules, client: ClientId, cfg: PredictConfig) -> Result<Predictor, PredictError> {
        let rule = rules.avatar.as_ref().ok_or(PredictError::NoAvatars)?;
        let mut world = rules.world.clone();
        world.bodies.remove_flagged(&vec![true; world.bodies.len()]);
        world.touching.clear();
        let density = world.config.classes.props[rule.class.0 as usize].density_kg_m3;
        Ok(Predictor {
            cfg,
            client,
            scene_hash: rules.world.scene_hash(),
            inv_mass: 1.0 / (density * rule.shape.volume()),
            class: rule.class,
            shape: rule.shape.clone(),
            world,
            stepper: Stepper::new(rules.plan.clone(), false),
            out: TickOutput::default(),
            avatar: None,
            inputs: BTreeMap::new(),
            history: VecDeque::new(),
            offset: DVec3::ZERO,
        })
    }

    /// Whether the avatar is a character (its class has `character` rules): it moves by `move`
    /// only, and a game sends intents instead of velocities.
    pub fn is_character(&self) -> bool {
        self.world.config.classes.props[self.class.0 as usize].character.is_some()
    }

    /// The hash of the rules and static world this predictor runs on, to compare with the
    /// welcome's `scene_hash`.
    pub fn scene_hash(&self) -> u64 {
        self.scene_hash
    }

    /// `Ok` when the server's hash (from the welcome) is this predictor's, or was not sent.
    pub fn check(&self, server_hash: u64) -> Result<(), PredictError> {
        if server_hash == 0 || server_hash == self.scene_hash {
            Ok(())
        } else {
            Err(PredictError::SceneMismatch { client: self.scene_hash, server: server_hash })
        }
    }

    /// The tick the predicted state is at (its start), once an authoritative state arrived.
    pub fn tick(&self) -> Option<Tick> {
        self.avatar.map(|_| self.world.tick)
    }

    /// The client's input `seq` stamped `tick`: its movement (`set_velocity`, `apply_impulse`,
    /// a character's `move`) is predicted; shots and spawns are the server's to resolve. An input for a tick already
    /// predicted is applied by replaying from that tick.
    pub fn input(&mut self, tick: Tick, seq: u32, actions: &[Action]) {
        let moves: Vec<Action> = actions
            .iter()
            .filter(|a| matches!(a, Action::SetVelocity { .. } | Action::ApplyImpulse { .. } | Action::Move { .. }))
            .cloned()
            .collect();
        if moves.is_empty() {
            return;
        }
        self.inputs.entry(tick.0).or_default().push(TickInput::new(self.client, seq, moves));
        let oldest = tick.0.saturating_sub(self.cfg.history_ticks);
        while self.inputs.first_key_value().is_some_and(|(t, _)| *t < oldest) {
            self.inputs.pop_first();
        }
        self.replay_from(tick);
    }

    /// The server answered input `seq`: applied at `applied` (`None`: refused). An input the
    /// server applied at another tick than it was stamped for (a stale one clamped into its
    /// window) moves there; a refused one is forgotten. Either way the prediction is replayed
    /// from the earlier tick, so it follows what the server does rather than waiting for the
    /// state that shows it.
    pub fn answered(&mut self, seq: u32, applied: Option<Tick>) {
        let found = self.inputs.iter().find_map(|(&t, v)| v.iter().position(|i| i.seq == seq).map(|k| (t, k)));
        let Some((tick, k)) = found else { return };
        if applied == Some(Tick(tick)) {
            return;
        }
        let list = self.inputs.get_mut(&tick).expect("found above");
        let input = list.remove(k);
        if list.is_empty() {
            self.inputs.remove(&tick);
        }
        let mut from = tick;
        if let Some(at) = applied {
            self.inputs.entry(at.0).or_default().push(input);
            from = from.min(at.0);
        }
        self.replay_from(Tick(from));
    }

    /// Re-predicts from `tick` when it is already past (its inputs changed), keeping the drawn
    /// avatar where it was: the difference is eased away.
    fn replay_from(&mut self, tick: Tick) {
        if self.avatar.is_some() && tick < self.world.tick {
            if let Some(snap) = self.history.iter().find(|h| h.tick == tick).cloned() {
                let present = self.world.tick;
                let before = self.position();
                self.set(snap);
                self.advance_to(present);
                self.offset += before - self.position();
            }
        }
    }

    fn position(&self) -> DVec3 {
        self.world.bodies.pos.first().copied().unwrap_or(DVec3::ZERO)
    }

    /// The avatar's state now, as a snapshot.
    fn snap(&self) -> Snap {
        let (w, b) = (&self.world, &self.world.bodies);
        Snap {
            tick: w.tick,
            pos: b.pos[0],
            vel: b.vel[0],
            asleep: b.asleep[0],
            still: b.still_ticks[0],
            touching: w.touching.clone(),
            class: b.class[0],
            teleported: b.teleported[0],
        }
    }

    /// Sets the avatar's state to `s` and forgets the predictions from its tick on.
    fn set(&mut self, s: Snap) {
        let w = &mut self.world;
        w.tick = s.tick;
        w.bodies.pos[0] = s.pos;
        w.bodies.vel[0] = s.vel;
        w.bodies.asleep[0] = s.asleep;
        w.bodies.still_ticks[0] = s.still;
        w.touching.clone_from(&s.touching);
        if w.bodies.class[0] != s.class {
            // Game logic changed it (a ghost, a pickup taken): the rules it moves by change too.
            w.bodies.set_class(0, s.class);
        }
        if w.bodies.teleported[0] != s.teleported {
            w.bodies.set_teleported(0, s.teleported);
        }
        while self.history.back().is_some_and(|h| h.tick >= s.tick) {
            self.history.pop_back();
        }
        self.history.push_back(s);
    }

    /// The server's state of the avatar at the start of `tick`: compared with the prediction
    /// for that tick; on a difference the predictor rewinds to it and replays its inputs to where
    /// it was, and the drawn avatar eases the difference away (or snaps past
    /// [`PredictConfig::snap_m`]).
    pub fn authoritative(&mut self, tick: Tick, s: &AvatarState) -> Reconciled {
        let (pos, vel) = (DVec3::from_array(s.position), DVec3::from_array(s.velocity));
        if self.avatar != Some(s.entity) {
            self.world.bodies.remove_flagged(&vec![true; self.world.bodies.len()]);
            self.world.bodies.push(
                s.entity,
                NewBody {
                    class: self.class,
                    shape: self.shape.clone(),
                    pos,
                    vel,
                    rot: DQuat::IDENTITY,
                    inv_mass: self.inv_mass,
                    owner: Some(self.client),
                },
            );
            self.avatar = Some(s.entity);
            self.history.clear();
            self.offset = DVec3::ZERO;
            let classes = self.world.config.classes.props.len();
            self.set(Snap::of(s, tick, self.class, classes));
            return Reconciled::Taken;
        }
        let classes = self.world.config.classes.props.len();
        let theirs = Snap::of(s, tick, self.world.bodies.class[0], classes);
        let predicted = self.history.iter().find(|h| h.tick == tick);
        let present = self.world.tick;
        let before = self.position();
        let result = match predicted {
            Some(ours) if *ours == theirs => return Reconciled::Exact,
            Some(ours) if ours.teleported != theirs.teleported => Reconciled::Teleported,
            Some(ours) => Reconciled::Corrected((ours.pos - pos).length()),
            None => Reconciled::Taken,
        };
        let replay = predicted.is_some() || tick < present;
        self.set(theirs);
        if replay {
            self.advance_to(present);
        }
        let jump = before - self.position();
        self.offset += jump;
        if self.offset.length() > self.cfg.snap_m || result == Reconciled::Teleported {
            self.offset = DVec3::ZERO;
        }
        result
    }

    /// Steps the prediction to the start of `tick` (at most [`PredictConfig::max_steps`]
    /// ticks; further, it jumps the rest without stepping).
    pub fn advance_to(&mut self, tick: Tick) {
        if self.avatar.is_none() {
            return;
        }
        if tick.0.saturating_sub(self.world.tick.0) > self.cfg.max_steps {
            self.world.tick = Tick(tick.0 - self.cfg.max_steps);
        }
        while self.world.tick < tick {
            let t = self.world.tick;
            let inputs = self.inputs.get(&t.0).map_or(&[][..], Vec::as_slice);
            self.stepper.step(&mut self.world, inputs, &mut self.out);
            if self.world.bodies.is_empty() {
                // Only a destroy rule against static geometry removes it: the server will say.
                self.avatar = None;
                return;
            }
            let snap = self.snap();
            self.history.push_back(snap);
            while self.history.len() > self.cfg.history_ticks as usize {
                self.history.pop_front();
            }
        }
    }

    /// Where to draw the avatar at fractional tick `at` (the clock's present plus the lead, as
    /// inputs are stamped): the prediction stepped there, between its two ticks, plus what is
    /// left of the last corrections, eased by `frame_s` seconds since the last call. Returns the
    /// position and how far the easing moved it this frame.
    pub fn drawn(&mut self, at: f64, frame_s: f64) -> Option<([f64; 3], f64)> {
        self.avatar?;
        let whole = Tick(at.floor().max(0.0) as u32);
        self.advance_to(Tick(whole.0 + 1));
        let find = |t: Tick| self.history.iter().rev().find(|h| h.tick == t).map(|h| h.pos);
        let (a, b) = (find(whole)?, find(Tick(whole.0 + 1))?);
        let f = at - at.floor();
        let decay = 1.0 - (-frame_s / self.cfg.smoothing_s.max(1e-6)).exp();
        let left = self.offset.length();
        let least = (self.cfg.min_correction_mps * frame_s).min(left);
        let most = self.cfg.max_correction_mps * frame_s;
        let step = self.offset.normalize_or_zero() * (left * decay).clamp(least, most.max(least));
        self.offset -= step;
        if self.offset.length() < 1e-6 {
            self.offset = DVec3::ZERO;
        }
        Some(((a.lerp(b, f) + self.offset).to_array(), step.length()))
    }

    /// The predicted position at the start of `tick`, if held.
    pub fn predicted_at(&self, tick: Tick) -> Option<[f64; 3]> {
        self.history.iter().find(|h| h.tick == tick).map(|h| h.pos.to_array())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use impact_core::scene::Scene;
    use impact_core::sim::{Plan, SystemAction};

    /// A ground, a wall, gravity, and capsule avatars: resting contacts, sliding along a wall.
    const SCENE: &str = r#"
        [world]
        name = "yard"
        tick_hz = 64
        gravity = [0.0, -9.81, 0.0]

        [[class]]
        name = "player"
        max_speed_mps = 10.0

        [[class]]
        name = "ground"
        static = true

        [[body]]
        class = "ground"
        shape = { type = "cuboid", half_extents_m = [20.0, 0.5, 20.0] }
        position = [0.0, -0.5, 0.0]

        [[body]]
        class = "ground"
        shape = { type = "cuboid", half_extents_m = [0.5, 2.0, 20.0] }
        position = [3.0, 2.0, 0.0]
        rotation_deg = [0.0, 20.0, 0.0]

        [spawn]
        avatar_class = "player"
        avatar_shape = { type = "capsule", half_height_m = 0.5, radius_m = 0.3 }
        region_min = [0.0, 1.2, 0.0]
        region_max = [0.0, 1.2, 0.0]
    "#;

    const ME: ClientId = ClientId(1);

    /// The server's side: the scene's world with the avatar spawned as the runtime spawns it.
    struct Server {
        world: World,
        stepper: Stepper,
        avatar: EntityId,
    }

    impl Server {
        fn new(scene: &Scene) -> Server {
            let mut world = scene.world.clone();
            let mut stepper = Stepper::new(Plan::for_world(&world), false);
            let rule = scene.avatar.as_ref().unwrap();
            let spawn = SystemAction::SpawnAvatar {
                client: ME,
                class: rule.class,
                shape: rule.shape.clone(),
                pos: rule.region_min,
            };
            let mut out = TickOutput::default();
            stepper.step_with(&mut world, &[spawn], &[], &mut out);
            let avatar = out.spawned[0].1;
            Server { world, stepper, avatar }
        }

        fn step(&mut self, inputs: &[TickInput]) {
            let mut out = TickOutput::default();
            self.stepper.step(&mut self.world, inputs, &mut out);
            assert!(out.skipped.is_empty(), "{:?}", out.skipped);
        }

        /// What the server's state stream says of the avatar.
        fn state(&self) -> AvatarState {
            let (w, b) = (&self.world, &self.world.bodies);
            let i = b.slot(self.avatar).unwrap();
            let touching = w
                .touching
                .iter()
                .filter(|t| t.a == self.avatar || t.b == self.avatar)
                .map(|t| impact_protocol::AvatarTouch {
                    other: if t.a == self.avatar { t.b } else { t.a },
                    normal: t.normal.to_array(),
                    depth_m: t.depth,
                    impulse: t.impulse,
                    friction_impulse: t.friction_impulse.to_array(),
                })
                .collect();
            AvatarState {
                entity: self.avatar,
                position: b.pos[i].to_array(),
                velocity: b.vel[i].to_array(),
                asleep: b.asleep[i],
                still_ticks: b.still_ticks[i],
                touching,
                class: Some(b.class[i].0),
                teleported: b.teleported[i],
            }
        }
    }

    fn walk(avatar: EntityId, k: u32) -> Vec<Action> {
        // Into the wall at an angle, turning: it lands, slides along the wall, stops, walks on.
        let a = f64::from(k) * 0.05;
        vec![Action::SetVelocity { entity: avatar, velocity: [3.0 * a.cos(), 0.0, 2.0 * a.sin()] }]
    }

    /// The avatar lands, rests on the ground (its contacts carried in the state), walks into a
    /// wall and slides along it: the predictor, fed the inputs ahead of the server and its
    /// state every third tick, predicted every one of those ticks to the bit. Built from the
    /// scene file, or from the scene as the server describes it over the wire (a tilted wall:
    /// its quaternion, not its degrees).
    #[test]
    fn the_prediction_equals_the_server_to_the_bit() {
        let scene = Scene::parse(SCENE, "<yard>").unwrap();
        let msg = impact_protocol::ServerMessage::Scene(Box::new(scene.describe()));
        let bytes = impact_protocol::encode(&msg, impact_protocol::Encoding::MsgPack).unwrap();
        let Ok(impact_protocol::ServerMessage::Scene(described)) =
            impact_protocol::decode(&bytes, impact_protocol::Encoding::MsgPack, usize::MAX)
        else {
            panic!("the description did not decode")
        };
        let from_wire = SceneRules::from_description(&described).unwrap();
        for rules in [scene.rules(), from_wire] {
            predicts_exactly(&scene, &rules, walk);
        }
    }

    /// A character (moved by the server's controller from `move` intents: walking into the
    /// wall, along the ground, jumping now and then) is predicted to the bit as well.
    #[test]
    fn a_character_is_predicted_to_the_bit() {
        let text = SCENE.replace("max_speed_mps = 10.0", "character = { walk_speed_mps = 4.0, jump_height_m = 1.0 }");
        let scene = Scene::parse(&text, "<yard>").unwrap();
        let intent = |avatar, k: u32| {
            let a = f64::from(k) * 0.05;
            vec![Action::Move { entity: avatar, direction: [a.cos(), 0.0, 0.7 * a.sin()], jump: k % 40 == 39 }]
        };
        predicts_exactly(&scene, &scene.rules(), intent);
    }

    /// Walks the avatar for 240 ticks while game logic acts on it once, at the 120th, and
    /// returns what each authoritative state (every third tick) did to the prediction.
    fn logic_acts_once(scene: &Scene, logic: impl Fn(EntityId) -> Action) -> Vec<Reconciled> {
        let mut server = Server::new(scene);
        let mut p = Predictor::new(&scene.rules(), ME, PredictConfig::default()).unwrap();
        p.authoritative(server.world.tick, &server.state());
        let mut seen = Vec::new();
        for k in 0..240u32 {
            let tick = server.world.tick;
            let actions = walk(server.avatar, k);
            p.input(tick, k + 1, &actions);
            p.advance_to(Tick(tick.0 + 2));
            let mut inputs = vec![TickInput::new(ME, k + 1, actions)];
            if k == 120 {
                inputs.push(TickInput { logic: true, ..TickInput::new(ClientId(900), 1, vec![logic(server.avatar)]) });
            }
            server.step(&inputs);
            if k % 3 == 2 {
                seen.push(p.authoritative(server.world.tick, &server.state()));
            }
        }
        seen
    }

    /// Game logic turns the avatar into a ghost (no gravity, through everything) mid-walk: the
    /// state after says so (`class`), the predictor takes it, and predicts the ghost exactly.
    #[test]
    fn a_class_change_by_game_logic_is_followed() {
        let ghost = "[[class]]\n        name = \"ghost\"\n        gravity = false\n\n        [[class]]\n        name = \"ground\"";
        let text = SCENE.replacen("[[class]]\n        name = \"ground\"", ghost, 1);
        let scene = Scene::parse(&text, "<yard>").unwrap();
        let seen = logic_acts_once(&scene, |avatar| Action::SetClass { entity: avatar, class: "ghost".into() });
        let other = seen.iter().filter(|r| **r != Reconciled::Exact).count();
        assert_eq!(other, 1, "only the state that showed the change: {seen:?}");
    }

    /// Game logic teleports the avatar mid-walk: the state after names the teleport, which the
    /// predictor takes as a jump (not a misprediction), drawn there at once; every other state
    /// is exact.
    #[test]
    fn a_teleport_by_game_logic_is_a_jump_not_a_misprediction() {
        let scene = Scene::parse(SCENE, "<yard>").unwrap();
        let to = [3.0, 1.2, -2.0];
        let seen = logic_acts_once(&scene, |avatar| Action::Teleport { entity: avatar, position: to, velocity: None });
        assert_eq!(seen.iter().filter(|r| **r == Reconciled::Teleported).count(), 1, "{seen:?}");
        assert!(seen.iter().all(|r| matches!(r, Reconciled::Exact | Reconciled::Teleported)), "{seen:?}");
    }

    fn predicts_exactly(scene: &Scene, rules: &SceneRules, act: impl Fn(EntityId, u32) -> Vec<Action>) {
        let mut server = Server::new(scene);
        let mut p = Predictor::new(rules, ME, PredictConfig::default()).unwrap();
        assert_eq!(p.check(scene.world.scene_hash()), Ok(()));
        assert_eq!(p.authoritative(server.world.tick, &server.state()), Reconciled::Taken);
        let (mut exact, mut touching) = (0, 0);
        for k in 0..300u32 {
            let tick = server.world.tick;
            // Stamped two ticks ahead, as an ahead client does; applied at its tick on both.
            let actions = act(server.avatar, k);
            p.input(tick, k + 1, &actions);
            p.advance_to(Tick(tick.0 + 2));
            server.step(&[TickInput::new(ME, k + 1, actions)]);
            if k % 3 == 2 {
                let state = server.state();
                touching += usize::from(!state.touching.is_empty());
                assert_eq!(p.authoritative(server.world.tick, &state), Reconciled::Exact, "tick {}", server.world.tick);
                exact += 1;
            }
        }
        assert_eq!(exact, 100);
        assert!(touching > 30, "the avatar rested on the ground and the wall: {touching}");
    }

    /// The server refused one input and applied another two ticks after its stamp: told so by
    /// their answers, the predictor replays as the server did and its next states are exact,
    /// before any authoritative state showed the difference.
    #[test]
    fn answers_move_or_forget_predicted_inputs() {
        let scene = Scene::parse(SCENE, "<yard>").unwrap();
        let mut server = Server::new(&scene);
        let mut p = Predictor::new(&scene.rules(), ME, PredictConfig::default()).unwrap();
        p.authoritative(server.world.tick, &server.state());
        let t0 = server.world.tick.0;
        let (refused, moved) = (walk(server.avatar, 10), walk(server.avatar, 30));
        p.input(Tick(t0 + 2), 1, &refused);
        p.input(Tick(t0 + 4), 2, &moved);
        p.advance_to(Tick(t0 + 10));
        p.answered(1, None);
        p.answered(2, Some(Tick(t0 + 6)));
        p.advance_to(Tick(t0 + 12));
        for k in 0..12 {
            let inputs =
                if server.world.tick.0 == t0 + 6 { vec![TickInput::new(ME, 2, moved.clone())] } else { vec![] };
            server.step(&inputs);
            if k % 3 == 2 {
                assert_eq!(p.authoritative(server.world.tick, &server.state()), Reconciled::Exact, "k {k}");
            }
        }
    }

    /// The server's avatar is pushed (a body the predictor does not simulate): the prediction is
    /// corrected at that tick and replays to the present; the drawn avatar eases the difference
    /// away at most 5 cm a 60 Hz frame and has converged within 250 ms; a jump past 1 m snaps.
    #[test]
    fn a_correction_is_replayed_and_eased_and_a_teleport_snaps() {
        let scene = Scene::parse(SCENE, "<yard>").unwrap();
        let mut server = Server::new(&scene);
        let mut p = Predictor::new(&scene.rules(), ME, PredictConfig::default()).unwrap();
        p.authoritative(server.world.tick, &server.state());
        for _ in 0..64 {
            server.step(&[]);
        }
        assert_eq!(p.authoritative(server.world.tick, &server.state()), Reconciled::Taken, "ahead of the prediction");
        let t0 = server.world.tick;
        p.advance_to(Tick(t0.0 + 8));
        // Pushed sideways at 3 m/s at t0: by t0 + 4 the server has it about 19 cm from the
        // prediction.
        let i = server.world.bodies.slot(server.avatar).unwrap();
        server.world.bodies.vel[i].z = 3.0;
        for _ in 0..4 {
            server.step(&[]);
        }
        let Reconciled::Corrected(e) = p.authoritative(server.world.tick, &server.state()) else { panic!("corrected") };
        assert!((0.1..0.3).contains(&e), "{e}");
        // Replayed to t0 + 8 from the server's state: the predicted present is the server's
        // future, exactly.
        let mut ahead = Server {
            world: server.world.clone(),
            stepper: Stepper::new(Plan::for_world(&scene.world), false),
            avatar: server.avatar,
        };
        for _ in 0..4 {
            ahead.step(&[]);
        }
        assert_eq!(p.predicted_at(ahead.world.tick), Some(ahead.state().position));
        // Drawn: eased at most 5 cm a frame, converged within 250 ms (15 frames).
        let frame = 1.0 / 60.0;
        let at = f64::from(t0.0 + 7);
        let target = p.predicted_at(Tick(t0.0 + 7)).unwrap();
        let mut last: [f64; 3] = std::array::from_fn(|k| target[k] + p.offset[k]);
        assert!((0.25..0.6).contains(&p.offset.length()), "the drawn difference {}", p.offset.length());
        for _ in 0..15 {
            let (now, moved) = p.drawn(at, frame).unwrap();
            let d = (0..3).map(|k| (now[k] - last[k]).powi(2)).sum::<f64>().sqrt();
            assert!(d <= 0.05 && moved <= 0.05, "{d} {moved}");
            last = now;
        }
        let left = (0..3).map(|k| (last[k] - target[k]).powi(2)).sum::<f64>().sqrt();
        assert!(left < 1e-3, "converged: {left} m left");
        // A teleport: 5 m off.
        let i = server.world.bodies.slot(server.avatar).unwrap();
        server.world.bodies.pos[i].x -= 5.0;
        let mut s = server.state();
        s.touching.clear();
        assert!(matches!(p.authoritative(server.world.tick, &s), Reconciled::Corrected(e) if e > 4.0));
        let (drawn, _) = p.drawn(at, frame).unwrap();
        assert_eq!(drawn, p.predicted_at(Tick(t0.0 + 7)).unwrap(), "snapped, not eased");
    }

    /// A scene hash that differs (another scene, or another tick rate) is refused with a reason.
    #[test]
    fn another_scene_is_refused() {
        let scene = Scene::parse(SCENE, "<yard>").unwrap();
        let faster = Scene::parse(&SCENE.replace("tick_hz = 64", "tick_hz = 128"), "<yard>").unwrap();
        let p = Predictor::new(&scene.rules(), ME, PredictConfig::default()).unwrap();
        let e = p.check(faster.world.scene_hash()).unwrap_err();
        assert!(e.to_string().contains("--tick-hz"), "{e}");
        assert_eq!(p.check(0), Ok(()), "a server that sends no hash");
    }
}
