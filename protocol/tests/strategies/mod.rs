//! proptest strategies for every wire type, shared by the protocol tests.
#![allow(dead_code)]

use impact_protocol::*;
use proptest::collection::{btree_map, vec};
use proptest::option;
use proptest::prelude::*;

pub fn coord() -> impl Strategy<Value = f64> {
    -1.0e7..1.0e7f64
}
pub fn vec3() -> impl Strategy<Value = [f64; 3]> {
    [coord(), coord(), coord()]
}
pub fn small3() -> impl Strategy<Value = [f64; 3]> {
    [-1.0e3..1.0e3f64, -1.0e3..1.0e3f64, -1.0e3..1.0e3f64]
}
pub fn unit3() -> impl Strategy<Value = [f64; 3]> {
    (-1.0..1.0f64, -1.0..1.0f64, 0.1..1.0f64).prop_map(|(x, y, z)| {
        let n = (x * x + y * y + z * z).sqrt();
        [x / n, y / n, z / n]
    })
}
pub fn dim() -> impl Strategy<Value = f64> {
    1.0e-3..1.0e3f64
}
pub fn tick() -> impl Strategy<Value = Tick> {
    any::<u32>().prop_map(Tick)
}
pub fn entity() -> impl Strategy<Value = EntityId> {
    any::<u32>().prop_map(EntityId)
}
pub fn client() -> impl Strategy<Value = ClientId> {
    any::<u32>().prop_map(ClientId)
}

pub fn shape() -> impl Strategy<Value = ShapeSpec> {
    prop_oneof![
        dim().prop_map(|radius_m| ShapeSpec::Sphere { radius_m }),
        (dim(), dim()).prop_map(|(half_height_m, radius_m)| ShapeSpec::Capsule { half_height_m, radius_m }),
        [dim(), dim(), dim()].prop_map(|half_extents_m| ShapeSpec::Cuboid { half_extents_m }),
    ]
}

pub fn action() -> impl Strategy<Value = Action> {
    prop_oneof![
        (entity(), small3()).prop_map(|(entity, velocity)| Action::SetVelocity { entity, velocity }),
        (entity(), small3()).prop_map(|(entity, impulse)| Action::ApplyImpulse { entity, impulse }),
        (shape(), vec3(), small3())
            .prop_map(|(shape, position, velocity)| { Action::SpawnProjectile { shape, position, velocity } }),
        (entity(), vec3(), unit3(), 0.1..1.0e4f64).prop_map(|(shooter, origin, direction, max_distance_m)| {
            Action::FireRay { shooter, origin, direction, max_distance_m }
        }),
        entity().prop_map(|entity| Action::Despawn { entity }),
        (entity(), small3(), any::<bool>()).prop_map(|(entity, direction, jump)| Action::Move {
            entity,
            direction,
            jump
        }),
        (entity(), vec3(), option::of(small3())).prop_map(|(entity, position, velocity)| Action::Teleport {
            entity,
            position,
            velocity
        }),
        (entity(), "[a-z]{1,16}").prop_map(|(entity, class)| Action::SetClass { entity, class }),
        (entity(), btree_map("[a-z]{1,16}", -1.0e6..1.0e6f64, 0..=limits::MAX_GAME_STATE_VALUES))
            .prop_map(|(entity, values)| Action::SetState { entity, values: GameState(values) }),
    ]
}

pub fn client_input() -> impl Strategy<Value = ClientInput> {
    (client(), any::<u32>(), tick(), vec(action(), 0..=limits::MAX_ACTIONS_PER_INPUT)).prop_map(
        |(client, seq, tick, actions)| {
            // Every other input says what its client was looking at.
            let view_tick = (seq % 2 == 0).then_some(Tick(tick.0 / 2));
            // And every fourth what it aimed at, further back.
            let aim_tick = (seq % 4 == 0).then_some(Tick(tick.0 / 3));
            ClientInput { client, seq, tick, view_tick, aim_tick, actions }
        },
    )
}

pub fn client_message() -> impl Strategy<Value = ClientMessage> {
    prop_oneof![
        3 => client_input().prop_map(ClientMessage::Input),
        // A batch: one client's inputs, by ascending seq, at most four actions each so the
        // message stays within its size limit.
        1 => (client(), any::<u32>(), tick(), vec(vec(action(), 0..=4), 1..=limits::MAX_INPUTS_PER_MESSAGE)).prop_map(
            |(client, seq, tick, actions)| {
                let inputs = actions
                    .into_iter()
                    .enumerate()
                    .map(|(k, actions)| ClientInput {
                        client,
                        seq: seq.wrapping_add(k as u32),
                        tick: Tick(tick.0.wrapping_add(k as u32)),
                        view_tick: None,
                        aim_tick: None,
                        actions,
                    })
                    .collect();
                ClientMessage::Inputs(InputBatch { client, inputs })
            }
        ),
        1 => (client(), any::<u32>()).prop_map(|(client, id)| ClientMessage::Ping(TimePing { client, id })),
        1 => client().prop_map(|client| ClientMessage::FullFrame(FullFrameRequest { client })),
    ]
}

pub fn event() -> impl Strategy<Value = CollisionEvent> {
    (
        (tick(), 0.0..=1.0f64, entity(), entity()),
        (vec3(), unit3(), 0.0..10.0f64, -100.0..100.0f64),
        (
            prop_oneof![Just(Phase::Begin), Just(Phase::End), Just(Phase::Hit)],
            prop_oneof![
                Just(Response::Bounce),
                Just(Response::Slide),
                Just(Response::Stop),
                Just(Response::Destroy),
                Just(Response::Trigger)
            ],
            prop_oneof![Just(EventStatus::Provisional), Just(EventStatus::Corrected), Just(EventStatus::Confirmed)],
        ),
    )
        .prop_map(|((tick, toi, a, b), (point, normal, depth_m, closing_speed_mps), (phase, response, status))| {
            CollisionEvent { tick, toi, a, b, point, normal, depth_m, closing_speed_mps, phase, response, status }
        })
}

fn events() -> impl Strategy<Value = Vec<CollisionEvent>> {
    vec(event(), 0..6)
}

pub fn reason() -> impl Strategy<Value = RejectReason> {
    proptest::sample::select(RejectReason::ALL.to_vec())
}

fn batch() -> impl Strategy<Value = EventBatch> {
    (tick(), any::<u32>(), events()).prop_map(|(tick, revision, events)| EventBatch { tick, revision, events })
}

pub fn server_message() -> impl Strategy<Value = ServerMessage> {
    prop_oneof![
        batch().prop_map(ServerMessage::Events),
        batch().prop_map(ServerMessage::Confirmed),
        corrections(),
        ack(),
        reject(),
        ray_result(),
        welcome(),
        snapshot(),
        (tick(), tick(), events()).prop_map(|(from, to, events)| ServerMessage::History(EventHistory {
            from,
            to,
            events
        })),
        stats(),
        state_frame(),
        scene(),
        "[a-z ]{0,40}".prop_map(|detail| ServerMessage::QueryError(QueryError { detail })),
    ]
}

fn corrections() -> impl Strategy<Value = ServerMessage> {
    (tick(), any::<u32>(), events(), events(), events()).prop_map(|(tick, revision, retracted, amended, added)| {
        ServerMessage::Corrections(CorrectionBatch { tick, revision, retracted, amended, added })
    })
}

fn ack() -> impl Strategy<Value = ServerMessage> {
    (client(), any::<u32>(), tick(), tick(), tick(), any::<u64>()).prop_map(
        |(client, seq, tick, applied_tick, server_tick, accepted_before)| {
            ServerMessage::Ack(InputAck {
                client,
                seq,
                tick,
                applied_tick,
                server_tick,
                margin_ticks: applied_tick.0.wrapping_sub(server_tick.0) as i32,
                lead_ticks: seq % 17,
                accepted_before,
            })
        },
    )
}

fn reject() -> impl Strategy<Value = ServerMessage> {
    (client(), option::of((any::<u32>(), tick())), reason(), "[a-z ]{0,40}", option::of(tick()), option::of(tick()))
        .prop_map(|(client, header, reason, detail, oldest_tick, newest_tick)| {
            let (seq, tick) = (header.map(|h| h.0), header.map(|h| h.1));
            ServerMessage::Reject(InputReject { client, seq, tick, reason, detail, oldest_tick, newest_tick })
        })
}

fn ray_result() -> impl Strategy<Value = ServerMessage> {
    (client(), any::<u32>(), tick(), entity(), option::of((entity(), vec3(), unit3(), 0.0..1.0e4f64))).prop_map(
        |(client, seq, tick, shooter, hit)| {
            ServerMessage::RayResult(RayResult {
                client,
                seq,
                tick,
                view_tick: Tick(tick.0 / 2),
                clamped: seq % 3 == 0,
                shooter,
                hit: hit.map(|(entity, point, normal, distance_m)| RayHit { entity, point, normal, distance_m }),
            })
        },
    )
}

fn welcome() -> impl Strategy<Value = ServerMessage> {
    (client(), option::of(entity()), tick(), 1..1000u32, 0..1000u32).prop_map(
        |(client, avatar, tick, tick_hz, window_ticks)| {
            ServerMessage::Welcome(Welcome {
                client,
                avatar,
                tick,
                tick_hz,
                window_ticks,
                input_lead_ticks: window_ticks / 2,
                max_rewind_ticks: window_ticks,
                next_seq: tick.0 / 3,
                scene_hash: u64::from(tick.0) * 0x9e37_79b9,
            })
        },
    )
}

fn snapshot() -> impl Strategy<Value = ServerMessage> {
    (tick(), any::<u64>(), vec((entity(), "[a-z]{1,10}", option::of(client()), vec3(), small3()), 0..5)).prop_map(
        |(tick, state_hash, bodies)| {
            ServerMessage::Snapshot(WorldSnapshot {
                tick,
                state_hash,
                bodies: bodies
                    .into_iter()
                    .map(|(entity, class, owner, position, velocity)| BodyState {
                        entity,
                        class,
                        owner,
                        position,
                        velocity,
                    })
                    .collect(),
            })
        },
    )
}

fn stats() -> impl Strategy<Value = ServerMessage> {
    (
        tick(),
        (0.0..100.0f64, 0.0..100.0f64, 0.0..100.0f64),
        any::<u64>(),
        any::<u32>(),
        btree_map("[a-z_]{1,12}", any::<u64>(), 0..4),
        0.0..1e6f64,
    )
        .prop_map(|(tick, (p50, p99, max), overruns, bodies, rejected, eps)| {
            ServerMessage::Stats(ServerStats {
                tick,
                tick_ms_p50: p50,
                tick_ms_p99: p99,
                tick_ms_max: max,
                overruns,
                bodies,
                pairs_tested: bodies / 2,
                rollbacks: 3,
                rollback_depth_max: 7,
                inputs_accepted: overruns / 2,
                inputs_rejected: rejected,
                inputs_repeated: overruns / 3,
                events_per_s: eps,
                queue_depth_max: 9,
                tick_ms: vec![p50 as f32, p99 as f32],
                stage_ms: vec![("broadphase".into(), p50 / 3.0)],
                clients: bodies / 3,
            })
        })
}

pub fn state_frame() -> impl Strategy<Value = ServerMessage> {
    (
        tick(),
        any::<u32>(),
        any::<bool>(),
        vec((entity(), "[a-z]{1,10}|[a-z]{32,40}", option::of(client()), 0..7u8, small3()), 0..4),
        vec((entity(), small3(), small3(), any::<bool>()), 0..6),
        vec(entity(), 0..3),
        option::of(small3()),
    )
        .prop_map(|(tick, frame, full, entered, moved, left, centre)| {
            let f3 = |v: [f64; 3]| v.map(|x| x as f32);
            let shapes = [
                BodyShape::Sphere,
                BodyShape::Capsule,
                BodyShape::Cuboid,
                BodyShape::Ellipsoid,
                BodyShape::Convex,
                BodyShape::Trimesh,
                BodyShape::Terrain,
            ];
            ServerMessage::State(StateFrame {
                tick,
                frame,
                full,
                entered: entered
                    .into_iter()
                    .map(|(entity, class, owner, shape, half)| BodyInfo {
                        entity,
                        class,
                        owner,
                        shape: shapes[usize::from(shape)],
                        half_extents_m: f3(half),
                        offset_m: [0.0; 3],
                        fixed: owner.is_none(),
                        rotation: (shape % 2 == 0).then_some([0.0, 0.382_683_43, 0.0, 0.923_879_5]),
                        local_shape: (shape < 3)
                            .then(|| ShapeSpec::Capsule { half_height_m: half[1], radius_m: half[0] }),
                        state: if shape % 3 == 0 {
                            GameState::from([("health", half[0]), ("team", 1.0)])
                        } else {
                            GameState::default()
                        },
                        teleported: (shape == 1).then_some(tick),
                    })
                    .collect(),
                moved: moved.into_iter().map(|(e, p, v, a)| BodyMotion(e, f3(p), f3(v), a)).collect(),
                left,
                deferred: frame % 5,
                centre: centre.map(f3),
                // A client's stream carries its avatar's exact state, with a contact now and then.
                avatar: centre.map(|c| AvatarState {
                    entity: EntityId(frame),
                    position: c,
                    velocity: [c[2], -c[1], 0.125],
                    asleep: frame % 3 == 0,
                    still_ticks: (frame % 700) as u16,
                    touching: (0..frame % 3)
                        .map(|k| AvatarTouch {
                            other: EntityId(k),
                            normal: [0.0, 1.0, 0.0],
                            depth_m: c[0].abs() * 1e-3,
                            impulse: c[1],
                            friction_impulse: [c[2], 0.0, -c[0]],
                        })
                        .collect(),
                    class: (frame % 2 == 0).then_some((frame % 5) as u16),
                    teleported: (frame % 4 == 1).then_some(tick),
                }),
            })
        })
}

fn scene() -> impl Strategy<Value = ServerMessage> {
    use impact_protocol::scene::*;
    (
        any::<u64>(),
        (1..64u32, dim(), vec3()),
        vec(("[a-z]{1,10}", any::<bool>(), dim()), 1..4),
        vec((0..6u8, dim()), 16),
        vec((entity(), shape(), vec3(), unit3()), 0..4),
        option::of((entity(), 2..4u32, vec(-10.0..10.0f64, 16))),
        option::of((shape(), small3())),
    )
        .prop_map(|(hash, (tick_hz, dt, gravity), classes, rules, statics, terrain, avatar)| {
            let n = classes.len();
            let class = |k: u16| k % n as u16;
            let pair = |(kind, r): (u8, f64)| match kind {
                0 => PairRule::Ignore,
                1 => PairRule::Trigger,
                2 => PairRule::Bounce { restitution: r.min(1.0) },
                3 => PairRule::Slide,
                4 => PairRule::Stop,
                _ => PairRule::Destroy { first: r > 0.5, second: true, restitution: (r < 1.0).then_some(r) },
            };
            ServerMessage::Scene(Box::new(SceneDescription {
                world: WorldId::new("arena").unwrap(),
                scene_hash: hash,
                rules: WorldRules {
                    tick_hz,
                    dt,
                    gravity,
                    contact_slop_m: 0.003,
                    bounce_threshold_mps: dt,
                    max_resolutions_per_tick: tick_hz * 100,
                    friction: 0.5,
                    sleep_speed_mps: 0.05,
                    sleep_after_ticks: tick_hz / 2,
                    partial_sleep: tick_hz % 2 == 0,
                    max_bodies: 100_000,
                    window_ticks: 16,
                    input_lead_ticks: 8,
                    max_rewind_ticks: 16,
                    projectile_class: (n > 1).then_some(1),
                    toi: ToiRules {
                        tolerance: 1.0 / 32768.0,
                        tolerance_m: 1e-4,
                        max_iterations: 32,
                        max_samples: 4096,
                    },
                },
                pair_rules: rules.into_iter().cycle().take(n * n).map(pair).collect(),
                classes: classes
                    .into_iter()
                    .map(|(name, is_static, speed)| ClassRules {
                        name,
                        is_static,
                        max_speed_mps: speed,
                        gravity: !is_static,
                        density_kg_m3: 1000.0,
                        can_sleep: true,
                        character: (!is_static).then_some(CharacterRules {
                            walk_speed_mps: speed,
                            jump_speed_mps: 4.85,
                            min_ground_normal_up: 0.707,
                            step_height_m: 0.3,
                            air_control: 0.1,
                        }),
                    })
                    .collect(),
                statics: statics
                    .into_iter()
                    .enumerate()
                    .map(|(k, (entity, shape, position, axis))| StaticBody {
                        entity,
                        class: class(k as u16),
                        shape,
                        position,
                        orientation: [axis[0] * 0.6, axis[1] * 0.6, axis[2] * 0.6, 0.8],
                    })
                    .collect(),
                terrain: terrain.map(|(entity, columns, heights)| TerrainSpec {
                    entity,
                    class: class(0),
                    origin: [-8.0, 0.0, -8.0],
                    cell_x_m: 1.0,
                    cell_z_m: 2.0,
                    columns,
                    rows: heights.len() as u32 / columns,
                    heights,
                }),
                avatar: avatar.map(|(shape, at)| AvatarSpec { class: class(0), shape, region_min: at, region_max: at }),
                plan: PlanSpec { ccd_sampling: tick_hz > 32, broadphase: "grid".into() },
            }))
        })
}
