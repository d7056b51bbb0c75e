//! Prints one example message per direction in both encodings (hex and JSON), exactly as they
//! appear in PROTOCOL.md. Run: `cargo run -p impact-protocol --example wire_examples`.

use impact_protocol::*;

fn hex(bytes: &[u8]) -> String {
    let lines: Vec<String> =
        bytes.chunks(16).map(|c| c.iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ")).collect();
    lines.join("\n")
}

fn main() {
    // An ahead client: looking at tick 1188, it stamps 1188 + its lead of 12.
    let input = ClientMessage::Input(ClientInput {
        aim_tick: None,
        client: ClientId(7),
        seq: 42,
        tick: Tick(1200),
        view_tick: Some(Tick(1188)),
        actions: vec![
            Action::SetVelocity { entity: EntityId(19), velocity: [1.5, 0.0, -2.0] },
            Action::FireRay {
                shooter: EntityId(19),
                origin: [0.0, 1.0, 0.0],
                direction: [1.0, 0.0, 0.0],
                max_distance_m: 50.0,
            },
        ],
    });
    let events = ServerMessage::Events(EventBatch {
        tick: Tick(1200),
        revision: 0,
        events: vec![CollisionEvent {
            tick: Tick(1200),
            toi: 0.375,
            a: EntityId(3),
            b: EntityId(19),
            point: [10.25, 0.5, -4.0],
            normal: [1.0, 0.0, 0.0],
            depth_m: 0.0,
            closing_speed_mps: 3.5,
            phase: Phase::Begin,
            response: Response::Bounce,
            status: EventStatus::Provisional,
        }],
    });
    let reject = ServerMessage::Reject(InputReject {
        client: ClientId(7),
        seq: Some(43),
        tick: Some(Tick(1000)),
        reason: RejectReason::Stale,
        detail: "tick 1000 is older than the window (oldest 1184)".into(),
        oldest_tick: Some(Tick(1184)),
        newest_tick: None,
    });
    let ack = ServerMessage::Ack(InputAck {
        client: ClientId(7),
        seq: 42,
        tick: Tick(1200),
        applied_tick: Tick(1200),
        server_tick: Tick(1198),
        margin_ticks: 2,
        lead_ticks: 12,
        accepted_before: 0b1011,
    });
    // A client's state stream: a delta in which a ball entered its area, its own avatar moved,
    // and a bolt left.
    let state = ServerMessage::State(StateFrame {
        tick: Tick(1200),
        frame: 61,
        full: false,
        entered: vec![BodyInfo {
            entity: EntityId(3),
            class: "ball".into(),
            owner: None,
            shape: BodyShape::Sphere,
            half_extents_m: [0.5, 0.5, 0.5],
            offset_m: [0.0, 0.0, 0.0],
            fixed: false,
            rotation: None,
            local_shape: None,
            state: Default::default(),
            teleported: None,
        }],
        moved: vec![
            BodyMotion(EntityId(3), [10.25, 0.5, -4.0], [-3.5, 0.0, 0.0], false),
            BodyMotion(EntityId(19), [9.0, 1.0, -4.0], [1.5, 0.0, -2.0], false),
        ],
        left: vec![EntityId(2071)],
        deferred: 0,
        centre: Some([9.0, 1.0, -4.0]),
        avatar: None,
    });
    print("client -> server: input", &input);
    print("server -> client: ack", &ack);
    print("server -> client: events", &events);
    print("server -> client: reject", &reject);
    print("server -> client: state", &state);
}

fn print<T: serde::Serialize + Validate>(title: &str, msg: &T) {
    let mp = encode(msg, Encoding::MsgPack).expect("example encodes");
    let js = encode(msg, Encoding::Json).expect("example encodes");
    let json = String::from_utf8(js).expect("json is UTF-8");
    println!(
        "### {title}\n\nMessagePack, {} bytes:\n\n```hex\n{}\n```\n\nJSON:\n\n```json\n{}\n```\n",
        mp.len(),
        hex(&mp),
        json
    );
}
