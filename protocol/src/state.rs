//! The state streams: where the bodies are, for drawing and interpolation.
//!
//! A stream is a sequence of [`StateFrame`]s numbered by `frame`. A full frame lists every body
//! the stream shows; a delta lists what changed since the frame before it: bodies that entered
//! the view (with what never changes about them), bodies whose motion changed, bodies that left.
//! A receiver that sees a gap in `frame` (a frame lost to congestion) ignores deltas until the
//! next full frame. Positions and velocities are `f32`: enough to draw and interpolate; the
//! authoritative state (f64, with its hash) is the state query.

use crate::ids::{ClientId, EntityId, Tick};
use serde::{Deserialize, Serialize};

/// The shape family of a body, for drawing. Its own type beside [`crate::ShapeSpec`] because a
/// state stream sends the family and the bounds, not the dimensions, and because terrain, which
/// is no body shape, is drawn too; the server converts the core's shape kind into it in one
/// place (`runtime/state.rs`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BodyShape {
    /// A sphere: its radius is `half_extents_m[0]`.
    Sphere,
    /// A capsule along its local y axis.
    Capsule,
    /// A box.
    Cuboid,
    /// An ellipsoid.
    Ellipsoid,
    /// A convex hull.
    Convex,
    /// A static triangle mesh.
    Trimesh,
    /// Height-field terrain.
    Terrain,
}

/// What never changes about a body, sent when it enters a stream's view.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BodyInfo {
    /// The body.
    pub entity: EntityId,
    /// Its class name from the scene.
    pub class: String,
    /// Owning client, if any.
    pub owner: Option<ClientId>,
    /// Shape family.
    pub shape: BodyShape,
    /// Half extents of its world-frame bounding box, metres (orientations are fixed).
    pub half_extents_m: [f32; 3],
    /// Centre of that box relative to the body's position, metres (zero but for meshes).
    pub offset_m: [f32; 3],
    /// Static: never moves.
    pub fixed: bool,
    /// Its orientation, a unit quaternion `[x, y, z, w]`, fixed for its life; absent: the
    /// identity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<[f32; 4]>,
    /// Its shape in its own frame, for drawing: a sphere, capsule, cuboid or ellipsoid with its
    /// dimensions (hulls, meshes and terrain are drawn by their bounds: absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local_shape: Option<crate::ShapeSpec>,
    /// Its game state, as game logic set it (absent: none).
    #[serde(default, skip_serializing_if = "GameState::is_empty")]
    pub state: GameState,
    /// The tick game logic last teleported it at (absent: never): its path breaks there, so a
    /// receiver draws it on its old path up to that tick (a tick's state is before its inputs)
    /// and on its new one after, never between.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub teleported: Option<Tick>,
}

/// A body's game state: a few named numbers game logic keeps on it (health, team, score), at
/// most [`MAX_GAME_STATE_VALUES`](crate::limits::MAX_GAME_STATE_VALUES) names of at most
/// [`MAX_GAME_STATE_NAME_LEN`](crate::limits::MAX_GAME_STATE_NAME_LEN) bytes each. Part of the
/// world: it rolls back and replays with the bodies, is in the state hash, and the state
/// streams carry it to the players whose area the body is in. A map on the wire
/// (`{"health": 75, "team": 1}`), in name order.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct GameState(pub std::collections::BTreeMap<String, f64>);

impl GameState {
    /// Whether it holds no value.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The value named `name`.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.0.get(name).copied()
    }

    /// `values` merged into this state (each name set; a name not given is kept), or `None` if
    /// the result would hold more than the bound of names.
    pub fn merged(&self, values: &GameState) -> Option<GameState> {
        let mut out = self.clone();
        out.0.extend(values.0.iter().map(|(k, v)| (k.clone(), *v)));
        (out.0.len() <= crate::limits::MAX_GAME_STATE_VALUES).then_some(out)
    }
}

impl<const N: usize> From<[(&str, f64); N]> for GameState {
    fn from(values: [(&str, f64); N]) -> GameState {
        GameState(values.into_iter().map(|(k, v)| (k.to_string(), v)).collect())
    }
}

/// Where a body is and how it moves, as an array `[entity, [x, y, z], [vx, vy, vz], asleep]`
/// to keep frames small (about 40 bytes in MessagePack).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BodyMotion(
    /// The body.
    pub EntityId,
    /// Centre, world frame, metres.
    pub [f32; 3],
    /// Velocity, m/s.
    pub [f32; 3],
    /// Asleep (a sleeping body's velocity is zero).
    pub bool,
);

/// One frame of a state stream (`state`, or `client/{id}/state`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StateFrame {
    /// The tick the positions are at (the server's present, provisional tick).
    pub tick: Tick,
    /// Frame number on this stream: one more than the frame before.
    pub frame: u32,
    /// A full frame: the receiver drops what it holds and keeps exactly these bodies.
    pub full: bool,
    /// Bodies that entered the view, with what never changes about them (each also in `moved`).
    pub entered: Vec<BodyInfo>,
    /// Bodies whose motion changed since the last frame that carried them.
    pub moved: Vec<BodyMotion>,
    /// Bodies no longer shown: out of the area of interest, or removed from the world.
    pub left: Vec<EntityId>,
    /// Bodies in the area of interest held back by the byte budget this frame (the farthest
    /// first; they come in later frames). Always 0 on the world stream.
    pub deferred: u32,
    /// The point a client's stream is centred on (its avatar), `None` on the world stream.
    pub centre: Option<[f32; 3]>,
    /// On a client's stream: its avatar's authoritative state at `tick`, exact (f64, and what the
    /// core carries between ticks), so the client can check and correct its prediction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub avatar: Option<AvatarState>,
}

/// A body's whole state in the core at the start of a tick: what a client needs to step its own
/// avatar exactly as the server does (PROTOCOL.md, "Prediction").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AvatarState {
    /// The body.
    pub entity: EntityId,
    /// Centre, world frame, metres (the exact f64).
    pub position: [f64; 3],
    /// Velocity, m/s (the exact f64).
    pub velocity: [f64; 3],
    /// Asleep.
    pub asleep: bool,
    /// Consecutive ticks it has ended slower than the sleep speed (its sleep countdown).
    pub still_ticks: u16,
    /// Its contacts with static geometry and terrain at the end of the tick before (the resting
    /// contact solver starts from them), by ascending other entity.
    pub touching: Vec<AvatarTouch>,
    /// Its class id (an index into `query/scene`'s classes): game logic may change it (nil from
    /// a server that does not say).
    #[serde(default)]
    pub class: Option<u16>,
    /// The tick game logic last teleported it at (absent: never): a prediction from before it
    /// is no misprediction but a jump the client could not know.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub teleported: Option<Tick>,
}

/// One resting contact of an avatar with static geometry (see [`AvatarState::touching`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AvatarTouch {
    /// The static body or terrain.
    pub other: EntityId,
    /// Unit contact normal, world frame, from the lower entity id to the higher.
    pub normal: [f64; 3],
    /// Overlap, m.
    pub depth_m: f64,
    /// Normal impulse the contact last needed, N s.
    pub impulse: f64,
    /// Friction impulse it last needed, N s, world frame.
    pub friction_impulse: [f64; 3],
}

impl StateFrame {
    /// The frame as a `state` message in MessagePack, onto the end of `out`: the bytes
    /// [`encode_into`](crate::encode_into)`(&ServerMessage::State(frame), Encoding::MsgPack, out)`
    /// writes, after the same validation, but written directly where a frame is mostly made of
    /// (its fields, `moved`, `left`, the entered bodies' infos but for their local shapes); the
    /// avatar's state goes through serde. The server's state thread encodes twenty thousand
    /// frames a second with it.
    pub fn encode_msgpack(&self, out: &mut Vec<u8>) -> Result<(), crate::ProtocolError> {
        use crate::Validate;
        let malformed = |e: rmp_serde::encode::Error| crate::ProtocolError::Malformed {
            encoding: "msgpack",
            detail: e.to_string(),
        };
        self.validate()?;
        // The fields as serde names and orders them: the tag first, `avatar` only when present.
        mp::map_len(out, 9 + usize::from(self.avatar.is_some()));
        mp::str(out, "type");
        mp::str(out, "state");
        mp::str(out, "tick");
        mp::uint(out, self.tick.0);
        mp::str(out, "frame");
        mp::uint(out, self.frame);
        mp::str(out, "full");
        mp::bool(out, self.full);
        mp::str(out, "entered");
        mp::array_len(out, self.entered.len());
        for info in &self.entered {
            info.encode_msgpack(out).map_err(malformed)?;
        }
        mp::str(out, "moved");
        mp::array_len(out, self.moved.len());
        for BodyMotion(entity, position, velocity, asleep) in &self.moved {
            mp::array_len(out, 4);
            mp::uint(out, entity.0);
            mp::f32s(out, position);
            mp::f32s(out, velocity);
            mp::bool(out, *asleep);
        }
        mp::str(out, "left");
        mp::array_len(out, self.left.len());
        for entity in &self.left {
            mp::uint(out, entity.0);
        }
        mp::str(out, "deferred");
        mp::uint(out, self.deferred);
        mp::str(out, "centre");
        match &self.centre {
            Some(c) => mp::f32s(out, c),
            None => out.push(mp::NIL),
        }
        if let Some(avatar) = &self.avatar {
            mp::str(out, "avatar");
            rmp_serde::encode::write_named(out, avatar).map_err(malformed)?;
        }
        Ok(())
    }
}

impl BodyInfo {
    /// The info as serde writes it in MessagePack (a map of its fields in order, those absent
    /// left out), onto the end of `out`; its local shape through serde.
    fn encode_msgpack(&self, out: &mut Vec<u8>) -> Result<(), rmp_serde::encode::Error> {
        let present = [self.rotation.is_some(), self.local_shape.is_some(), !self.state.is_empty()];
        let fields = 7 + present.iter().filter(|p| **p).count() + usize::from(self.teleported.is_some());
        mp::map_len(out, fields);
        mp::str(out, "entity");
        mp::uint(out, self.entity.0);
        mp::str(out, "class");
        mp::text(out, &self.class);
        mp::str(out, "owner");
        match self.owner {
            Some(c) => mp::uint(out, c.0),
            None => out.push(mp::NIL),
        }
        mp::str(out, "shape");
        mp::str(out, self.shape.name());
        mp::str(out, "half_extents_m");
        mp::f32s(out, &self.half_extents_m);
        mp::str(out, "offset_m");
        mp::f32s(out, &self.offset_m);
        mp::str(out, "fixed");
        mp::bool(out, self.fixed);
        if let Some(r) = &self.rotation {
            mp::str(out, "rotation");
            mp::array_len(out, 4);
            for x in r {
                out.push(0xca);
                out.extend_from_slice(&x.to_be_bytes());
            }
        }
        if let Some(shape) = &self.local_shape {
            mp::str(out, "local_shape");
            rmp_serde::encode::write_named(out, shape)?;
        }
        if !self.state.is_empty() {
            mp::str(out, "state");
            mp::map_len(out, self.state.0.len());
            for (name, value) in &self.state.0 {
                mp::text(out, name);
                out.push(0xcb);
                out.extend_from_slice(&value.to_be_bytes());
            }
        }
        if let Some(t) = self.teleported {
            mp::str(out, "teleported");
            mp::uint(out, t.0);
        }
        Ok(())
    }
}

impl BodyShape {
    /// Its name on the wire.
    fn name(self) -> &'static str {
        match self {
            BodyShape::Sphere => "sphere",
            BodyShape::Capsule => "capsule",
            BodyShape::Cuboid => "cuboid",
            BodyShape::Ellipsoid => "ellipsoid",
            BodyShape::Convex => "convex",
            BodyShape::Trimesh => "trimesh",
            BodyShape::Terrain => "terrain",
        }
    }
}

/// The few MessagePack forms a state frame is written in, each in its shortest form, as
/// `rmp-serde` writes them (the MessagePack specification, "Formats").
mod mp {
    pub(super) const NIL: u8 = 0xc0;

    pub(super) fn bool(out: &mut Vec<u8>, b: bool) {
        out.push(if b { 0xc3 } else { 0xc2 });
    }

    pub(super) fn uint(out: &mut Vec<u8>, n: u32) {
        match n {
            0..0x80 => out.push(n as u8),
            0x80..0x100 => out.extend_from_slice(&[0xcc, n as u8]),
            0x100..0x1_0000 => {
                out.push(0xcd);
                out.extend_from_slice(&(n as u16).to_be_bytes());
            }
            _ => {
                out.push(0xce);
                out.extend_from_slice(&n.to_be_bytes());
            }
        }
    }

    /// Three `f32`s as an array.
    pub(super) fn f32s(out: &mut Vec<u8>, v: &[f32; 3]) {
        let [a, b, c] = v.map(f32::to_be_bytes);
        out.extend_from_slice(&[0x93, 0xca, a[0], a[1], a[2], a[3], 0xca, b[0], b[1], b[2], b[3], 0xca]);
        out.extend_from_slice(&c);
    }

    /// A length: `fix` ORed with it under 16, else the 16- or 32-bit form.
    fn len(out: &mut Vec<u8>, n: usize, fix: u8, forms: [u8; 2]) {
        if n < 16 {
            out.push(fix | n as u8);
        } else if n <= 0xffff {
            out.push(forms[0]);
            out.extend_from_slice(&(n as u16).to_be_bytes());
        } else {
            out.push(forms[1]);
            out.extend_from_slice(&(n as u32).to_be_bytes());
        }
    }

    pub(super) fn array_len(out: &mut Vec<u8>, n: usize) {
        len(out, n, 0x90, [0xdc, 0xdd]);
    }

    pub(super) fn map_len(out: &mut Vec<u8>, n: usize) {
        len(out, n, 0x80, [0xde, 0xdf]);
    }

    /// A field name: under 32 bytes, all of them.
    pub(super) fn str(out: &mut Vec<u8>, s: &str) {
        debug_assert!(s.len() < 32);
        out.push(0xa0 | s.len() as u8);
        out.extend_from_slice(s.as_bytes());
    }

    /// A string of any length: the 8-, 16- or 32-bit form past 31 bytes.
    pub(super) fn text(out: &mut Vec<u8>, s: &str) {
        let n = s.len();
        if n < 32 {
            out.push(0xa0 | n as u8);
        } else if n < 0x100 {
            out.extend_from_slice(&[0xd9, n as u8]);
        } else if n < 0x1_0000 {
            out.push(0xda);
            out.extend_from_slice(&(n as u16).to_be_bytes());
        } else {
            out.push(0xdb);
            out.extend_from_slice(&(n as u32).to_be_bytes());
        }
        out.extend_from_slice(s.as_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::mp;

    /// Each form at the edges of its sizes, as `rmp-serde` writes it.
    #[test]
    fn the_frame_writer_forms_are_rmp_serdes() {
        for n in [0u32, 1, 127, 128, 255, 256, 65_535, 65_536, u32::MAX] {
            let mut out = Vec::new();
            mp::uint(&mut out, n);
            assert_eq!(out, rmp_serde::to_vec(&n).unwrap(), "{n}");
        }
        for n in [0usize, 15, 16, 65_535, 65_536] {
            let (mut array, mut map) = (Vec::new(), Vec::new());
            mp::array_len(&mut array, n);
            mp::map_len(&mut map, n);
            let seq = rmp_serde::to_vec(&vec![0u8; n]).unwrap();
            let keys: std::collections::BTreeMap<u32, u8> = (0..n as u32).map(|k| (k, 0)).collect();
            assert_eq!(array, seq[..array.len()], "array of {n}");
            assert_eq!(map, rmp_serde::to_vec(&keys).unwrap()[..map.len()], "map of {n}");
        }
        for v in [[0.0f32, -1.5, f32::MAX], [f32::MIN_POSITIVE, 3.25e-7, -0.0]] {
            let mut out = Vec::new();
            mp::f32s(&mut out, &v);
            assert_eq!(out, rmp_serde::to_vec(&v).unwrap());
        }
        for s in ["", "type", "a name of thirty-one bytes, max"] {
            let mut out = Vec::new();
            mp::str(&mut out, s);
            assert_eq!(out, rmp_serde::to_vec(s).unwrap(), "{s:?}");
        }
        for n in [0, 31, 32, 255, 256, 65_535, 65_536] {
            let (s, mut out) = ("x".repeat(n), Vec::new());
            mp::text(&mut out, &s);
            assert_eq!(out, rmp_serde::to_vec(&s).unwrap(), "a string of {n} bytes");
        }
    }

    /// Each body shape's name is the one serde gives it.
    #[test]
    fn body_shape_names_are_serdes() {
        use super::BodyShape as B;
        for b in [B::Sphere, B::Capsule, B::Cuboid, B::Ellipsoid, B::Convex, B::Trimesh, B::Terrain] {
            assert_eq!(serde_json::to_value(b).unwrap(), b.name(), "{b:?}");
        }
    }
}
