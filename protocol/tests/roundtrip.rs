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
