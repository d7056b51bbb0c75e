//! Every message, in both encodings, decodes to exactly what was encoded. This is what lets a
//! client in another language trust the field names and types in PROTOCOL.md: a change to a
//! type that breaks the round trip (a renamed tag, a lossy float) fails here first.

mod strategies;

use impact_protocol::limits::{MAX_CLIENT_MESSAGE_BYTES, MAX_SERVER_MESSAGE_BYTES};
use impact_protocol::*;
use proptest::prelude::*;
use strategies::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn client_messages_round_trip(msg in client_message()) {
        for enc in [Encoding::MsgPack, Encoding::Json] {
            let bytes = encode(&msg, enc).unwrap();
            prop_assert!(bytes.len() <= MAX_CLIENT_MESSAGE_BYTES, "{} bytes in {enc}", bytes.len());
            let back: ClientMessage = decode(&bytes, enc, MAX_CLIENT_MESSAGE_BYTES).unwrap();
            prop_assert_eq!(&back, &msg);
        }
    }

    #[test]
    fn server_messages_round_trip(msg in server_message()) {
        for enc in [Encoding::MsgPack, Encoding::Json] {
            let bytes = encode(&msg, enc).unwrap();
            let back: ServerMessage = decode(&bytes, enc, MAX_SERVER_MESSAGE_BYTES).unwrap();
            prop_assert_eq!(&back, &msg);
        }
    }

    /// The state thread's own MessagePack writer gives the bytes serde gives, byte for byte,
    /// and so decodes to the same frame (with more bodies than a short array holds, too).
    #[test]
    fn a_state_frame_is_written_as_serde_writes_it(msg in state_frame()) {
        let ServerMessage::State(f) = msg else { unreachable!() };
        let mut long = f.clone();
        long.moved = f.moved.iter().cycle().take(17 * f.moved.len()).copied().collect();
        long.left = f.left.iter().cycle().take(17 * f.left.len()).copied().collect();
        for f in [f, long] {
            let mut hand = vec![0xff];
            f.encode_msgpack(&mut hand).unwrap();
            prop_assert_eq!(hand[0], 0xff, "written after what the buffer held");
            let msg = ServerMessage::State(f);
            prop_assert_eq!(&hand[1..], &encode(&msg, Encoding::MsgPack).unwrap()[..]);
        }
    }

    /// MessagePack and JSON carry the same structure: decoding the MessagePack bytes into a
    /// generic JSON value gives the same document as the JSON encoding.
    #[test]
    fn both_encodings_carry_the_same_document(msg in client_message()) {
        let mp = encode(&msg, Encoding::MsgPack).unwrap();
        let js = encode(&msg, Encoding::Json).unwrap();
        let from_mp: serde_json::Value = rmp_serde::from_slice(&mp).unwrap();
        let from_js: serde_json::Value = serde_json::from_slice(&js).unwrap();
        prop_assert_eq!(from_mp, from_js);
    }
}

#[test]
fn messages_are_tagged_maps() {
    let msg = ClientMessage::Input(ClientInput {
        aim_tick: None,
        view_tick: None,
        client: ClientId(7),
        seq: 1,
        tick: Tick(100),
        actions: vec![Action::Despawn { entity: EntityId(3) }],
    });
    let json: serde_json::Value = serde_json::from_slice(&encode(&msg, Encoding::Json).unwrap()).unwrap();
    assert_eq!(json["type"], "input");
    assert_eq!(json["actions"][0]["type"], "despawn");
    assert_eq!(json["tick"], 100);
}

/// The state writer refuses what `encode` refuses: a frame with a non-finite number.
#[test]
fn the_state_writer_refuses_a_non_finite_frame() {
    let frame = StateFrame {
        tick: Tick(3),
        frame: 1,
        full: false,
        entered: Vec::new(),
        moved: vec![BodyMotion(EntityId(4), [0.0, f32::NAN, 0.0], [0.0; 3], false)],
        left: Vec::new(),
        deferred: 0,
        centre: None,
        avatar: None,
    };
    let mut out = Vec::new();
    assert!(frame.encode_msgpack(&mut out).is_err());
    assert!(encode(&ServerMessage::State(frame), Encoding::MsgPack).is_err());
}
