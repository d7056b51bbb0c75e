//! Value checks run on every decoded message: finite numbers, ranges, counts. Errors name the
//! field by path (`actions[2].velocity[1]`) so a client developer can find the bug. The happy
//! path allocates nothing: paths are only built when a check fails.

use crate::error::ProtocolError;
use crate::event::CollisionEvent;
use crate::limits::*;
use crate::message::*;
use crate::state::StateFrame;

/// A decoded message that can check its own values.
pub trait Validate {
    /// `Ok` when every number is finite and in range and every count within its limit.
    fn validate(&self) -> Result<(), ProtocolError>;
}

fn finite(x: f64, path: impl Fn() -> String) -> Result<(), ProtocolError> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(ProtocolError::NonFinite { field: path() })
    }
}

fn vec3(v: &[f64; 3], max_norm: f64, what: &str, path: impl Fn() -> String) -> Result<(), ProtocolError> {
    for (i, x) in v.iter().enumerate() {
        finite(*x, || format!("{}[{i}]", path()))?;
    }
    let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if norm > max_norm {
        return Err(ProtocolError::OutOfRange {
            field: path(),
            detail: format!("{what} {norm:e} exceeds {max_norm:e}"),
        });
    }
    Ok(())
}

fn coord3(v: &[f64; 3], path: impl Fn() -> String) -> Result<(), ProtocolError> {
    for (i, x) in v.iter().enumerate() {
        finite(*x, || format!("{}[{i}]", path()))?;
        if x.abs() > MAX_ABS_COORD_M {
            return Err(ProtocolError::OutOfRange {
                field: format!("{}[{i}]", path()),
                detail: format!("|coordinate| {x:e} m exceeds {MAX_ABS_COORD_M:e} m"),
            });
        }
    }
    Ok(())
}

fn positive(x: f64, max: f64, path: impl Fn() -> String) -> Result<(), ProtocolError> {
    finite(x, &path)?;
    if x > 0.0 && x <= max {
        Ok(())
    } else {
        Err(ProtocolError::OutOfRange { field: path(), detail: format!("{x:e} not in (0, {max:e}]") })
    }
}

fn name(s: &str, path: impl Fn() -> String) -> Result<(), ProtocolError> {
    if s.is_empty() || s.len() > MAX_NAME_LEN {
        return Err(ProtocolError::OutOfRange {
            field: path(),
            detail: format!("a name of 1 to {MAX_NAME_LEN} bytes"),
        });
    }
    Ok(())
}

fn count(n: usize, max: usize, path: &str) -> Result<(), ProtocolError> {
    if n <= max {
        Ok(())
    } else {
        Err(ProtocolError::OutOfRange { field: path.into(), detail: format!("{n} items, at most {max}") })
    }
}

impl Validate for ShapeSpec {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.validate_at(&|| "shape".to_string())
    }
}

impl ShapeSpec {
    fn validate_at(&self, path: &dyn Fn() -> String) -> Result<(), ProtocolError> {
        let dims = |dims: &[f64], name: &str| {
            dims.iter()
                .enumerate()
                .try_for_each(|(i, h)| positive(*h, MAX_SHAPE_DIM_M, || format!("{}.{name}[{i}]", path())))
        };
        let points = |points: &[[f64; 3]], name: &str| {
            let far = "distance from the centre (m)";
            points
                .iter()
                .enumerate()
                .try_for_each(|(i, p)| vec3(p, MAX_SHAPE_DIM_M, far, || format!("{}.{name}[{i}]", path())))
        };
        match self {
            ShapeSpec::Sphere { radius_m } => positive(*radius_m, MAX_SHAPE_DIM_M, || format!("{}.radius_m", path())),
            ShapeSpec::Capsule { half_height_m, radius_m } => {
                positive(*radius_m, MAX_SHAPE_DIM_M, || format!("{}.radius_m", path()))?;
                positive(*half_height_m, MAX_SHAPE_DIM_M, || format!("{}.half_height_m", path()))
            }
            ShapeSpec::Cuboid { half_extents_m } => dims(half_extents_m, "half_extents_m"),
            ShapeSpec::Ellipsoid { radii_m } => dims(radii_m, "radii_m"),
            ShapeSpec::Convex { points: p } => points(p, "points"),
            ShapeSpec::Mesh { vertices, .. } => points(vertices, "vertices"),
        }
    }
}

/// A game state's bounds: a few names of a few bytes, finite values.
fn game_state(g: &crate::GameState, path: &dyn Fn() -> String) -> Result<(), ProtocolError> {
    // The path is written only for an error: every body of every state frame passes here.
    if g.0.len() > MAX_GAME_STATE_VALUES {
        count(g.0.len(), MAX_GAME_STATE_VALUES, &path())?;
    }
    for (k, v) in &g.0 {
        if k.is_empty() || k.len() > MAX_GAME_STATE_NAME_LEN {
            return Err(ProtocolError::OutOfRange {
                field: path(),
                detail: format!("name {k:?}: 1 to {MAX_GAME_STATE_NAME_LEN} bytes"),
            });
        }
        finite(*v, || format!("{}.{k}", path()))?;
    }
    Ok(())
}

/// A reason's length.
fn reason(r: &str) -> Result<(), ProtocolError> {
    if r.len() > MAX_REASON_LEN {
        return Err(ProtocolError::OutOfRange {
            field: "reason".into(),
            detail: format!("{} bytes, at most {MAX_REASON_LEN}", r.len()),
        });
    }
    Ok(())
}

impl Validate for Action {
    fn validate(&self) -> Result<(), ProtocolError> {
        self.validate_at(&|| "action".to_string())
    }
}

impl Action {
    fn validate_at(&self, path: &dyn Fn() -> String) -> Result<(), ProtocolError> {
        let field = |name: &str| format!("{}.{name}", path());
        match self {
            Action::SetVelocity { velocity, .. } => vec3(velocity, MAX_SPEED_MPS, "speed (m/s)", || field("velocity")),
            Action::ApplyImpulse { impulse, .. } => vec3(impulse, MAX_IMPULSE_NS, "impulse (N*s)", || field("impulse")),
            Action::SpawnProjectile { shape, position, velocity } => {
                if !shape.spawnable() {
                    return Err(ProtocolError::OutOfRange {
                        field: field("shape"),
                        detail: "a client spawns a sphere, a capsule or a cuboid".into(),
                    });
                }
                shape.validate_at(&|| field("shape"))?;
                coord3(position, || field("position"))?;
                vec3(velocity, MAX_SPEED_MPS, "speed (m/s)", || field("velocity"))
            }
            Action::FireRay { origin, direction, max_distance_m, .. } => {
                coord3(origin, || field("origin"))?;
                vec3(direction, f64::MAX, "length", || field("direction"))?;
                let len2 = direction.iter().map(|x| x * x).sum::<f64>();
                // Components are finite (checked above), so len2 is a number; it may overflow to inf.
                if len2 <= 1e-24 || !len2.is_finite() {
                    return Err(ProtocolError::OutOfRange {
                        field: field("direction"),
                        detail: "direction must be non-zero".into(),
                    });
                }
                positive(*max_distance_m, MAX_RAY_DISTANCE_M, || field("max_distance_m"))
            }
            Action::Move { direction, .. } => vec3(direction, MAX_SPEED_MPS, "length", || field("direction")),
            Action::Teleport { position, velocity, .. } => {
                coord3(position, || field("position"))?;
                velocity.as_ref().map_or(Ok(()), |v| vec3(v, MAX_SPEED_MPS, "speed (m/s)", || field("velocity")))
            }
            Action::Spawn { class, shape, position, velocity, .. } => {
                name(class, || field("class"))?;
                if !shape.spawnable() {
                    return Err(ProtocolError::OutOfRange {
                        field: field("shape"),
                        detail: "a spawn is a sphere, a capsule or a cuboid".into(),
                    });
                }
                shape.validate_at(&|| field("shape"))?;
                coord3(position, || field("position"))?;
                vec3(velocity, MAX_SPEED_MPS, "speed (m/s)", || field("velocity"))
            }
            Action::SetClass { class, .. } => name(class, || field("class")),
            Action::SetState { values, .. } => game_state(values, &|| field("values")),
            Action::Despawn { .. } => Ok(()),
        }
    }
}

impl Validate for ClientInput {
    fn validate(&self) -> Result<(), ProtocolError> {
        if self.actions.len() > MAX_ACTIONS_PER_INPUT {
            // Too many actions is a size problem, reported as such.
            return Err(ProtocolError::TooManyActions { count: self.actions.len(), limit: MAX_ACTIONS_PER_INPUT });
        }
        for (i, a) in self.actions.iter().enumerate() {
            a.validate_at(&|| format!("actions[{i}]"))?;
        }
        Ok(())
    }
}

impl InputBatch {
    /// The batch's own bounds, apart from its inputs' (a receiver answers each input on its
    /// own): 1 to [`MAX_INPUTS_PER_MESSAGE`] inputs, each naming the batch's client.
    pub fn validate_envelope(&self) -> Result<(), ProtocolError> {
        if self.inputs.is_empty() || self.inputs.len() > MAX_INPUTS_PER_MESSAGE {
            return Err(ProtocolError::OutOfRange {
                field: "inputs".into(),
                detail: format!("{} inputs, not 1 to {MAX_INPUTS_PER_MESSAGE}", self.inputs.len()),
            });
        }
        match self.inputs.iter().position(|i| i.client != self.client) {
            Some(i) => Err(ProtocolError::OutOfRange {
                field: format!("inputs[{i}].client"),
                detail: format!("{} differs from the batch's client {}", self.inputs[i].client, self.client),
            }),
            None => Ok(()),
        }
    }
}

impl Validate for ClientMessage {
    fn validate(&self) -> Result<(), ProtocolError> {
        match self {
            ClientMessage::Input(input) => input.validate(),
            ClientMessage::Inputs(batch) => {
                batch.validate_envelope()?;
                batch.inputs.iter().try_for_each(Validate::validate)
            }
            ClientMessage::Ping(_) | ClientMessage::FullFrame(_) => Ok(()),
            ClientMessage::World(WorldCommand::Open { scene }) => name(scene, || "scene".into()),
            ClientMessage::World(WorldCommand::Close { reason: r, .. }) => reason(r),
        }
    }
}

impl Validate for CollisionEvent {
    fn validate(&self) -> Result<(), ProtocolError> {
        let CollisionEvent { toi, point, normal, depth_m, closing_speed_mps, .. } = self;
        finite(*toi, || "toi".into())?;
        if !(0.0..=1.0).contains(toi) {
            return Err(ProtocolError::OutOfRange { field: "toi".into(), detail: format!("{toi} not in [0, 1]") });
        }
        coord3(point, || "point".into())?;
        vec3(normal, 1.0 + 1e-6, "length", || "normal".into())?;
        finite(*depth_m, || "depth_m".into())?;
        finite(*closing_speed_mps, || "closing_speed_mps".into())
    }
}

fn events(list: &[CollisionEvent]) -> Result<(), ProtocolError> {
    list.iter().try_for_each(Validate::validate)
}

impl Validate for ServerMessage {
    fn validate(&self) -> Result<(), ProtocolError> {
        match self {
            ServerMessage::Events(b) | ServerMessage::Confirmed(b) => events(&b.events),
            ServerMessage::Corrections(c) => {
                events(&c.retracted)?;
                events(&c.amended)?;
                events(&c.added)
            }
            ServerMessage::History(h) => events(&h.events),
            ServerMessage::RayResult(r) => match &r.hit {
                Some(hit) => {
                    coord3(&hit.point, || "hit.point".into())?;
                    vec3(&hit.normal, 1.0 + 1e-6, "length", || "hit.normal".into())?;
                    finite(hit.distance_m, || "hit.distance_m".into())
                }
                None => Ok(()),
            },
            ServerMessage::Snapshot(s) => {
                for (i, b) in s.bodies.iter().enumerate() {
                    coord3(&b.position, || format!("bodies[{i}].position"))?;
                    vec3(&b.velocity, f64::MAX, "speed", || format!("bodies[{i}].velocity"))?;
                    count(b.class.len(), MAX_NAME_LEN, "class")?;
                }
                Ok(())
            }
            ServerMessage::Stats(s) => {
                for (name, x) in [
                    ("tick_ms_p50", s.tick_ms_p50),
                    ("tick_ms_p99", s.tick_ms_p99),
                    ("tick_ms_max", s.tick_ms_max),
                    ("events_per_s", s.events_per_s),
                ] {
                    finite(x, || name.into())?;
                }
                for (i, t) in s.tick_ms.iter().enumerate() {
                    finite(f64::from(*t), || format!("tick_ms[{i}]"))?;
                }
                for (i, (name, t)) in s.stage_ms.iter().enumerate() {
                    count(name.len(), MAX_NAME_LEN, "stage name")?;
                    finite(*t, || format!("stage_ms[{i}]"))?;
                }
                Ok(())
            }
            ServerMessage::Closed(c) => reason(&c.reason),
            ServerMessage::Owner(_) => Ok(()),
            ServerMessage::World(a) => match &a.outcome {
                WorldOutcome::Refused { detail, .. } => count(detail.len(), 4096, "detail"),
                _ => Ok(()),
            },
            ServerMessage::State(f) => f.validate(),
            ServerMessage::Ack(_)
            | ServerMessage::Reject(_)
            | ServerMessage::Welcome(_)
            | ServerMessage::QueryError(_)
            | ServerMessage::Log(_)
            | ServerMessage::Admitted(_)
            | ServerMessage::Checkpoint(_)
            | ServerMessage::Pong(_) => Ok(()),
            // Checked where it is rebuilt (`impact_core::scene::describe`): a static floor may
            // be larger than anything a client may spawn, and the rebuilt world must hash to
            // `scene_hash`.
            ServerMessage::Scene(_) => Ok(()),
        }
    }
}

impl Validate for StateFrame {
    fn validate(&self) -> Result<(), ProtocolError> {
        let f = self;
        let f32s = |v: &[f32; 3], path: &dyn Fn() -> String| {
            v.iter().enumerate().try_for_each(|(k, x)| finite(f64::from(*x), || format!("{}[{k}]", path())))
        };
        if let Some(c) = &f.centre {
            f32s(c, &|| "centre".into())?;
        }
        for (i, b) in f.entered.iter().enumerate() {
            count(b.class.len(), MAX_NAME_LEN, "class")?;
            f32s(&b.half_extents_m, &|| format!("entered[{i}].half_extents_m"))?;
            f32s(&b.offset_m, &|| format!("entered[{i}].offset_m"))?;
            if let Some(r) = &b.rotation {
                r.iter().try_for_each(|x| finite(f64::from(*x), || format!("entered[{i}].rotation")))?;
            }
            // Any size a scene may hold (static ground can be kilometres): finite only.
            let sizes: Vec<f64> = match &b.local_shape {
                Some(ShapeSpec::Sphere { radius_m }) => vec![*radius_m],
                Some(ShapeSpec::Capsule { half_height_m, radius_m }) => vec![*half_height_m, *radius_m],
                Some(ShapeSpec::Cuboid { half_extents_m: d } | ShapeSpec::Ellipsoid { radii_m: d }) => d.to_vec(),
                Some(ShapeSpec::Convex { .. } | ShapeSpec::Mesh { .. }) | None => Vec::new(),
            };
            sizes.iter().try_for_each(|x| finite(*x, || format!("entered[{i}].local_shape")))?;
            game_state(&b.state, &|| format!("entered[{i}].state"))?;
        }
        for (i, m) in f.moved.iter().enumerate() {
            f32s(&m.1, &|| format!("moved[{i}].position"))?;
            f32s(&m.2, &|| format!("moved[{i}].velocity"))?;
        }
        if let Some(a) = &f.avatar {
            coord3(&a.position, || "avatar.position".into())?;
            vec3(&a.velocity, f64::MAX, "speed", || "avatar.velocity".into())?;
            for (i, t) in a.touching.iter().enumerate() {
                vec3(&t.normal, 1.0 + 1e-6, "length", || format!("avatar.touching[{i}].normal"))?;
                finite(t.depth_m, || format!("avatar.touching[{i}].depth_m"))?;
                finite(t.impulse, || format!("avatar.touching[{i}].impulse"))?;
                vec3(&t.friction_impulse, f64::MAX, "size", || format!("avatar.touching[{i}].friction_impulse"))?;
            }
        }
        Ok(())
    }
}
