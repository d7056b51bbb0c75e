//! Fuzz target: the server's input decoder, in both encodings, exactly as the runtime calls it.
//!
//! A crash is a panic anywhere in decoding, validation or the header fallback. Beyond "no
//! panic" it checks the codec's promises: whatever decodes and validates re-encodes and decodes
//! to the same message; a single input that decodes has a readable header with the same `client`,
//! `seq` and `tick`; nothing over the size limit is ever accepted.

use impact_protocol::limits::MAX_CLIENT_MESSAGE_BYTES;
use impact_protocol::{decode, decode_unchecked, encode, input_header, ClientMessage, Encoding, Validate};

fn check(bytes: &[u8], encoding: Encoding) {
    let header = input_header(bytes, encoding, MAX_CLIENT_MESSAGE_BYTES);
    let Ok(msg) = decode_unchecked::<ClientMessage>(bytes, encoding, MAX_CLIENT_MESSAGE_BYTES) else {
        return;
    };
    assert!(bytes.len() <= MAX_CLIENT_MESSAGE_BYTES);
    if let ClientMessage::Input(input) = &msg {
        assert_eq!(header, Some((input.client, input.seq, input.tick)), "a decoded input has a readable header");
    }
    if msg.validate().is_err() {
        return;
    }
    let again = encode(&msg, encoding).expect("a valid message encodes");
    let back: ClientMessage = decode(&again, encoding, usize::MAX).expect("what we encode decodes");
    assert_eq!(back, msg, "encode then decode is the identity");
}

fn main() {
    afl::fuzz!(|data: &[u8]| {
        check(data, Encoding::MsgPack);
        check(data, Encoding::Json);
    });
}
