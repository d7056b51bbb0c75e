//! The command lines as a user meets them: wrong arguments and an unreachable server end with a
//! message that says what is wrong, not a panic or a hang.
//!
//! Being an integration test of this package also makes `cargo test --workspace` build its
//! binaries, which the deployment tests in `tests/` start as processes.

use std::process::Command;
use std::time::{Duration, Instant};

fn run(bin: &str, args: &[&str]) -> (Option<i32>, String, Duration) {
    let started = Instant::now();
    let out = Command::new(bin).args(args).env_remove("RUST_BACKTRACE").output().expect("the binary runs");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.code(), text, started.elapsed())
}

#[test]
fn zero_clients_is_refused_before_connecting() {
    let (code, text, _) = run(env!("CARGO_BIN_EXE_impact-sim"), &["--clients", "0"]);
    assert_eq!(code, Some(2), "{text}");
    assert!(text.contains("--clients"), "the message names the flag: {text}");
}

#[test]
fn an_unreachable_server_is_named_in_the_error() {
    // A port nothing listens on: bind one, then let it go.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let sim = [env!("CARGO_BIN_EXE_impact-sim"), "--connect", &endpoint, "--duration", "1s"];
    let inspect = [env!("CARGO_BIN_EXE_impact-inspect"), "--connect", &endpoint];
    for cmd in [&sim[..], &inspect[..]] {
        let bin = cmd[0];
        let (code, text, took) = run(bin, &cmd[1..]);
        assert_eq!(code, Some(1), "{bin}: {text}");
        assert!(text.contains(&endpoint), "{bin}: the error names the endpoint: {text}");
        assert!(!text.contains("panicked"), "{bin}: {text}");
        assert!(took < Duration::from_secs(30), "{bin} took {took:?} to give up");
    }
}
