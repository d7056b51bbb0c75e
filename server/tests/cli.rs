//! The server's command line as a user meets it: `--explain` prints every `[world]` value a
//! scene runs with and where it came from, and a flag that overrides one says so.

use std::process::Command;

fn explain(args: &[&str]) -> String {
    let scene = impact_core::scene::Scene::bundled_path("standing");
    let out = Command::new(env!("CARGO_BIN_EXE_impact-server"))
        .arg("--scene")
        .arg(scene)
        .arg("--explain")
        .args(args)
        .output()
        .expect("impact-server runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).expect("utf-8")
}

fn line<'a>(text: &'a str, key: &str) -> &'a str {
    text.lines().find(|l| l.split_whitespace().next() == Some(key)).unwrap_or_else(|| panic!("no {key} in\n{text}"))
}

#[test]
fn explain_says_where_every_world_value_came_from() {
    let text = explain(&[]);
    assert!(text.starts_with("world standing ("), "{text}");
    // standing.toml sets friction and gravity; it leaves the slop and the sleep keys out.
    assert!(line(&text, "friction").ends_with("scene"), "{text}");
    assert!(line(&text, "gravity").contains("[0.0, -9.81, 0.0]"), "{text}");
    assert!(line(&text, "contact_slop_m").contains("0.0001") && line(&text, "contact_slop_m").contains("default: "));
    assert!(line(&text, "sleep_after_s").contains("default: "), "{text}");
    assert_eq!(text.lines().count(), 16, "a heading and the 15 [world] keys:\n{text}");
    let flagged = explain(&["--tick-hz", "128"]);
    assert!(line(&flagged, "tick_hz").contains("128") && line(&flagged, "tick_hz").contains("--tick-hz"), "{flagged}");
}
