//! The command line as an operator meets it: a gateway nobody could log in to, and a guest world
//! that is not a world name, end with a message that says what to give, not a panic or a hang.
//!
//! Being an integration test of this package also makes `cargo test --workspace` build the
//! binary, which the play page's browser test in `tests/` starts as a process.

use std::process::Command;

fn run(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_impact-gateway"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .output()
        .expect("the binary runs");
    (out.status.code(), format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)))
}

#[test]
fn a_gateway_nobody_could_log_in_to_says_what_to_give() {
    let (code, text) = run(&["--listen", "127.0.0.1:0"]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("nobody could play") && text.contains("--guests WORLD"), "{text}");
}

#[test]
fn a_guest_world_must_be_a_world_name() {
    let (code, text) = run(&["--listen", "127.0.0.1:0", "--guests", "no such/world"]);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("--guests"), "the message names the flag: {text}");
}
