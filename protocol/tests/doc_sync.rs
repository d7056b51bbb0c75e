//! PROTOCOL.md is the contract a client in another language is written from, so it must match
//! the code: every key pattern the code builds is documented, and every example payload in the
//! file decodes (and validates) with today's types. A renamed field or key breaks this test.

use impact_protocol::limits::{MAX_CLIENT_MESSAGE_BYTES, MAX_SERVER_MESSAGE_BYTES};
use impact_protocol::*;

fn doc() -> String {
    // cargo runs a test in its package's directory (a path built in would name the clone it was built in)
    std::fs::read_to_string("../PROTOCOL.md").expect("PROTOCOL.md at the repository root")
}

/// The bodies of every fenced block with the given info string.
fn blocks(doc: &str, info: &str) -> Vec<String> {
    let open = format!("```{info}\n");
    doc.split(&open).skip(1).map(|rest| rest.split("```").next().unwrap_or("").to_string()).collect()
}

fn decodes_either(bytes: &[u8], enc: Encoding) -> bool {
    decode::<ClientMessage>(bytes, enc, MAX_CLIENT_MESSAGE_BYTES).is_ok()
        || decode::<ServerMessage>(bytes, enc, MAX_SERVER_MESSAGE_BYTES).is_ok()
}

#[test]
fn every_key_pattern_is_documented() {
    let doc = doc();
    for p in keys::PATTERNS {
        assert!(
            doc.contains(&format!("`{}`", p.pattern)),
            "PROTOCOL.md does not document key {} ({})",
            p.name,
            p.pattern
        );
    }
}

#[test]
fn every_example_decodes() {
    let doc = doc();
    let hex_blocks = blocks(&doc, "hex");
    let json_blocks = blocks(&doc, "json");
    assert!(hex_blocks.len() >= 2 && json_blocks.len() >= 2, "examples for both directions are required");
    for block in &hex_blocks {
        let bytes: Vec<u8> = block.split_whitespace().map(|h| u8::from_str_radix(h, 16).expect("hex byte")).collect();
        assert!(decodes_either(&bytes, Encoding::MsgPack), "hex example does not decode:\n{block}");
    }
    for block in &json_blocks {
        assert!(decodes_either(block.trim().as_bytes(), Encoding::Json), "json example does not decode:\n{block}");
    }
}

#[test]
fn every_reject_reason_is_documented() {
    let doc = doc();
    for reason in RejectReason::ALL {
        let name = reason.name();
        // The wire name and `name()` are the same string.
        assert_eq!(serde_json::to_value(reason).unwrap(), name);
        assert!(doc.contains(&format!("| `{name}` |")), "reason {name} missing from PROTOCOL.md");
    }
}
