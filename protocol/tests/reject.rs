//! What the decoder refuses, and that it never panics. Each case is a payload a hostile or
//! buggy client could send: the server must get a typed error it can turn into a reject reason,
//! never a crash and never a value that is NaN or out of range.

mod strategies;

use impact_protocol::limits::*;
use impact_protocol::*;
use proptest::prelude::*;

fn input(actions: Vec<Action>) -> ClientMessage {
    ClientMessage::Input(ClientInput {
        aim_tick: None,
        view_tick: None,
        client: ClientId(1),
        seq: 9,
        tick: Tick(5),
        actions,
    })
}

fn decode_client(bytes: &[u8], enc: Encoding) -> Result<ClientMessage, ProtocolError> {
    decode(bytes, enc, MAX_CLIENT_MESSAGE_BYTES)
}

#[test]
fn oversized_is_refused_before_decoding() {
    // Valid JSON padded with spaces past the limit: only the size check can refuse it.
    let mut bytes = encode(&input(vec![]), Encoding::Json).unwrap();
    bytes.resize(MAX_CLIENT_MESSAGE_BYTES + 1, b' ');
    for enc in [Encoding::MsgPack, Encoding::Json] {
        let err = decode_client(&bytes, enc).unwrap_err();
        assert_eq!(err, ProtocolError::TooLarge { len: MAX_CLIENT_MESSAGE_BYTES + 1, limit: MAX_CLIENT_MESSAGE_BYTES });
        assert_eq!(err.reject_reason(), RejectReason::TooLarge);
    }
}

#[test]
fn too_many_actions_is_too_large() {
    let msg = input(vec![Action::Despawn { entity: EntityId(1) }; MAX_ACTIONS_PER_INPUT + 1]);
    let bytes = rmp_serde::to_vec_named(&msg).unwrap();
    let err = decode_client(&bytes, Encoding::MsgPack).unwrap_err();
    assert_eq!(err.reject_reason(), RejectReason::TooLarge, "{err}");
}

#[test]
fn truncated_is_malformed_at_every_cut() {
    let msg = input(vec![Action::SetVelocity { entity: EntityId(2), velocity: [1.0, 2.0, 3.0] }]);
    for enc in [Encoding::MsgPack, Encoding::Json] {
        let bytes = encode(&msg, enc).unwrap();
        for cut in 0..bytes.len() {
            let err = decode_client(&bytes[..cut], enc).unwrap_err();
            assert!(matches!(err, ProtocolError::Malformed { .. }), "{enc} cut at {cut}: {err}");
        }
    }
}

#[test]
fn trailing_bytes_are_refused() {
    let msg = input(vec![]);
    for enc in [Encoding::MsgPack, Encoding::Json] {
        let mut bytes = encode(&msg, enc).unwrap();
        bytes.extend_from_slice(b"xy");
        assert_eq!(decode_client(&bytes, enc).unwrap_err(), ProtocolError::TrailingBytes { extra: 2 }, "{enc}");
    }
    // Whitespace after a JSON document is not "trailing bytes": JSON allows it.
    let mut json = encode(&msg, Encoding::Json).unwrap();
    json.extend_from_slice(b"\n");
    assert!(decode_client(&json, Encoding::Json).is_ok());
}

#[test]
fn non_finite_floats_are_refused_with_the_field_path() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let msg = input(vec![
            Action::Despawn { entity: EntityId(1) },
            Action::SetVelocity { entity: EntityId(2), velocity: [0.0, bad, 0.0] },
        ]);
        // Encode refuses to produce it...
        assert_eq!(
            encode(&msg, Encoding::MsgPack).unwrap_err(),
            ProtocolError::NonFinite { field: "actions[1].velocity[1]".into() }
        );
        // ...and decode refuses it when another implementation does produce it.
        let bytes = rmp_serde::to_vec_named(&msg).unwrap();
        let err = decode_client(&bytes, Encoding::MsgPack).unwrap_err();
        assert_eq!(err, ProtocolError::NonFinite { field: "actions[1].velocity[1]".into() });
        assert_eq!(err.reject_reason(), RejectReason::InvalidNumber);
    }
}

#[test]
fn out_of_range_values_are_refused() {
    let cases = [
        (Action::SetVelocity { entity: EntityId(1), velocity: [MAX_SPEED_MPS * 2.0, 0.0, 0.0] }, "actions[0].velocity"),
        (
            Action::FireRay { shooter: EntityId(1), origin: [0.0; 3], direction: [0.0; 3], max_distance_m: 10.0 },
            "actions[0].direction",
        ),
        (
            Action::FireRay {
                shooter: EntityId(1),
                origin: [0.0; 3],
                direction: [1.0, 0.0, 0.0],
                max_distance_m: -1.0,
            },
            "actions[0].max_distance_m",
        ),
        (
            Action::SpawnProjectile {
                shape: ShapeSpec::Sphere { radius_m: 0.0 },
                position: [0.0; 3],
                velocity: [0.0; 3],
            },
            "actions[0].shape.radius_m",
        ),
        (
            Action::SpawnProjectile {
                shape: ShapeSpec::Sphere { radius_m: 1.0 },
                position: [0.0, 2.0 * MAX_ABS_COORD_M, 0.0],
                velocity: [0.0; 3],
            },
            "actions[0].position[1]",
        ),
    ];
    for (action, field) in cases {
        let bytes = rmp_serde::to_vec_named(&input(vec![action])).unwrap();
        match decode_client(&bytes, Encoding::MsgPack).unwrap_err() {
            ProtocolError::OutOfRange { field: got, .. } => assert_eq!(got, field),
            other => panic!("expected OutOfRange for {field}, got {other}"),
        }
    }
}

#[test]
fn unknown_variants_and_fields_of_the_wrong_type_are_malformed() {
    let cases: [&[u8]; 5] = [
        br#"{"type":"teleport","client":1,"seq":1,"tick":1,"actions":[]}"#,
        br#"{"type":"input","client":1,"seq":1,"tick":1,"actions":[{"type":"explode","entity":1}]}"#,
        br#"{"type":"input","client":-1,"seq":1,"tick":1,"actions":[]}"#,
        br#"{"type":"input","client":1,"seq":1,"tick":4294967296,"actions":[]}"#,
        br#"{"client":1,"seq":1,"tick":1,"actions":[]}"#,
    ];
    for json in cases {
        let err = decode_client(json, Encoding::Json).unwrap_err();
        assert!(matches!(err, ProtocolError::Malformed { .. }), "{}: {err}", String::from_utf8_lossy(json));
        // The same document in MessagePack is refused the same way.
        let value: serde_json::Value = serde_json::from_slice(json).unwrap();
        let mp = rmp_serde::to_vec_named(&value).unwrap();
        let err = decode_client(&mp, Encoding::MsgPack).unwrap_err();
        assert!(matches!(err, ProtocolError::Malformed { .. }), "msgpack {}: {err}", String::from_utf8_lossy(json));
    }
}

#[test]
fn a_depth_bomb_is_refused() {
    // 1,000 nested one-element arrays: must be refused, not recurse until the stack overflows.
    let mut bytes = vec![0x91u8; 1000];
    bytes.push(0xc0);
    assert!(decode_client(&bytes, Encoding::MsgPack).is_err());
    let json = format!("{}{}", "[".repeat(1000), "]".repeat(1000));
    assert!(decode_client(json.as_bytes(), Encoding::Json).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Random bytes never panic either decoder, in either direction.
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        for enc in [Encoding::MsgPack, Encoding::Json] {
            let _ = decode::<ClientMessage>(&bytes, enc, MAX_CLIENT_MESSAGE_BYTES);
            let _ = decode::<ServerMessage>(&bytes, enc, MAX_SERVER_MESSAGE_BYTES);
        }
    }

    /// Valid messages with random bytes flipped never panic, and whatever decodes is valid.
    #[test]
    fn mutated_messages_never_panic(msg in strategies::client_message(), flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8)) {
        let mut bytes = encode(&msg, Encoding::MsgPack).unwrap();
        for (at, b) in flips {
            let i = at % bytes.len();
            bytes[i] = b;
        }
        if let Ok(decoded) = decode::<ClientMessage>(&bytes, Encoding::MsgPack, MAX_CLIENT_MESSAGE_BYTES) {
            prop_assert!(decoded.validate().is_ok());
        }
    }
}

#[test]
fn a_refused_input_is_matched_by_its_header() {
    // Values out of range: the structure decodes, so the header does.
    let mut too_many = input(vec![Action::Despawn { entity: EntityId(1) }; MAX_ACTIONS_PER_INPUT + 1]);
    let ClientMessage::Input(i) = &mut too_many else { panic!("an input") };
    i.seq = 77;
    let bytes = rmp_serde::to_vec_named(&too_many).unwrap();
    let err = decode_client(&bytes, Encoding::MsgPack).unwrap_err();
    assert_eq!(err.to_string(), "input carries 17 actions, at most 16 are allowed");
    assert_eq!(input_header(&bytes, Encoding::MsgPack, MAX_CLIENT_MESSAGE_BYTES), Some((ClientId(1), 77, Tick(5))));
    // Malformed further in: an action type that does not exist.
    let json = br#"{"type":"input","client":3,"seq":8,"tick":40,"actions":[{"type":"teleport"}]}"#;
    assert!(decode_client(json, Encoding::Json).is_err());
    assert_eq!(input_header(json, Encoding::Json, MAX_CLIENT_MESSAGE_BYTES), Some((ClientId(3), 8, Tick(40))));
    // Unreadable: no header, the documented nil placeholder.
    assert_eq!(input_header(&bytes[..10], Encoding::MsgPack, MAX_CLIENT_MESSAGE_BYTES), None);
    // Found by fuzzing: serde also reads a positional array as an input; its header must be
    // readable the same way (it was not: the header decoder wanted a map with a string tag).
    let positional = [0x96, 0x00, 0x00, 0x00, 0x00, 0x20, 0x90];
    let decoded: ClientMessage = decode_unchecked(&positional, Encoding::MsgPack, MAX_CLIENT_MESSAGE_BYTES).unwrap();
    let ClientMessage::Input(d) = decoded else { panic!("read as an input: {decoded:?}") };
    assert_eq!(input_header(&positional, Encoding::MsgPack, MAX_CLIENT_MESSAGE_BYTES), Some((d.client, d.seq, d.tick)));
}

proptest! {
    #[test]
    fn every_decodable_input_has_its_header(i in strategies::client_input()) {
        for enc in [Encoding::MsgPack, Encoding::Json] {
            let bytes = encode(&ClientMessage::Input(i.clone()), enc).unwrap();
            prop_assert_eq!(input_header(&bytes, enc, MAX_CLIENT_MESSAGE_BYTES), Some((i.client, i.seq, i.tick)));
        }
    }
}

/// Shapes are one vocabulary, but a client spawns only a sphere, a capsule or a cuboid: an
/// ellipsoid, a hull or a mesh in a spawn decodes and is refused by value, naming the field, and
/// an unknown field in a shape is refused when decoded (a misspelt key never becomes a default).
#[test]
fn a_spawn_takes_only_the_simple_shapes() {
    let spawn = |shape| input(vec![Action::SpawnProjectile { shape, position: [0.0; 3], velocity: [1.0, 0.0, 0.0] }]);
    let refused = [
        ShapeSpec::Ellipsoid { radii_m: [1.0, 2.0, 1.0] },
        ShapeSpec::Convex { points: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] },
        ShapeSpec::Mesh { vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], triangles: vec![[0, 1, 2]] },
    ];
    for shape in refused {
        // Written without `encode`, which checks values too: a client in another language can
        // send anything.
        let msgpack = rmp_serde::to_vec_named(&spawn(shape.clone())).unwrap();
        let json = serde_json::to_vec(&spawn(shape.clone())).unwrap();
        for (enc, bytes) in [(Encoding::MsgPack, msgpack), (Encoding::Json, json)] {
            let err = decode_client(&bytes, enc).unwrap_err();
            assert_eq!(err.reject_reason(), RejectReason::OutOfRange, "{enc} {shape:?}: {err}");
            assert!(err.to_string().contains("actions[0].shape"), "{err}");
        }
    }
    for shape in [
        ShapeSpec::Sphere { radius_m: 0.1 },
        ShapeSpec::Capsule { half_height_m: 0.5, radius_m: 0.2 },
        ShapeSpec::Cuboid { half_extents_m: [0.1, 0.2, 0.3] },
    ] {
        let bytes = encode(&spawn(shape), Encoding::MsgPack).unwrap();
        decode_client(&bytes, Encoding::MsgPack).unwrap();
    }
    let typo = br#"{"type":"input","client":1,"seq":9,"tick":5,"actions":[{"type":"spawn_projectile","shape":{"type":"sphere","radius_m":0.1,"colour":1},"position":[0,0,0],"velocity":[1,0,0]}]}"#;
    let err = decode_client(typo, Encoding::Json).unwrap_err();
    assert!(matches!(err, ProtocolError::Malformed { .. }) && err.to_string().contains("colour"), "{err}");
}

/// A checkpoint shape written before the shapes were one type (`radius`, `half_height`,
/// `half_extents`, `radii`) still reads, as the same shape.
#[test]
fn old_checkpoint_shape_names_are_read() {
    let old: [(&str, ShapeSpec); 4] = [
        (r#"{"type":"sphere","radius":0.5}"#, ShapeSpec::Sphere { radius_m: 0.5 }),
        (
            r#"{"type":"capsule","half_height":1.0,"radius":0.25}"#,
            ShapeSpec::Capsule { half_height_m: 1.0, radius_m: 0.25 },
        ),
        (r#"{"type":"cuboid","half_extents":[1.0,2.0,3.0]}"#, ShapeSpec::Cuboid { half_extents_m: [1.0, 2.0, 3.0] }),
        (r#"{"type":"ellipsoid","radii":[1.0,2.0,3.0]}"#, ShapeSpec::Ellipsoid { radii_m: [1.0, 2.0, 3.0] }),
    ];
    for (text, shape) in old {
        assert_eq!(serde_json::from_str::<ShapeSpec>(text).unwrap(), shape, "{text}");
    }
}
