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
    let slop = line(&text, "contact_slop_m");
    assert!(slop.contains("0.003") && slop.contains("default: 1.25 ticks of free fall"), "{text}");
    assert!(line(&text, "sleep_after_s").contains("default: "), "{text}");
    let settings = text.lines().filter(|l| !l.trim_start().starts_with("warning[")).count();
    assert_eq!(settings, 17, "a heading and the 16 [world] keys:\n{text}");
    let flagged = explain(&["--tick-hz", "128"]);
    assert!(line(&flagged, "tick_hz").contains("128") && line(&flagged, "tick_hz").contains("--tick-hz"), "{flagged}");
    // The slop follows the flag's tick rate: 1.25 * 9.81 / 128^2 = 0.75 mm.
    assert!(line(&flagged, "contact_slop_m").contains("0.00075"), "{flagged}");
}

/// A pile written with gravity and shapes but no tuning keys loads with defaults that let it
/// rest, and no warning; with keys that keep it from resting, the server says at once why and
/// what would work, on stderr at load and in `--explain`.
#[test]
fn a_scene_that_cannot_rest_is_told_so_at_load() {
    let pile = |keys: &str| {
        let path = std::env::temp_dir().join(format!("impact-cli-pile-{}-{}.toml", std::process::id(), keys.len()));
        std::fs::write(
            &path,
            format!("[world]\nname = \"mypile\"\ngravity = [0.0, -9.81, 0.0]\n{keys}[[class]]\nname = \"ball\"\n\
             [[class]]\nname = \"floor\"\nstatic = true\n\
             [[body]]\nclass = \"floor\"\nshape = {{ type = \"cuboid\", half_extents_m = [10.0, 0.5, 10.0] }}\nposition = [0.0, -0.5, 0.0]\n\
             [[scatter]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = 0.25 }}\ncount = 50\nseed = 1\nmin = [-3.0, 1.0, -3.0]\nmax = [3.0, 8.0, 3.0]\n"),
        )
        .unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_impact-server"))
            .arg("--scene")
            .arg(&path)
            .arg("--explain")
            .output()
            .expect("impact-server runs");
        let _ = std::fs::remove_file(&path);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (stdout, stderr) = pile("");
    assert!(!stderr.contains("warning[") && !stdout.contains("warning["), "{stdout}{stderr}");
    assert!(line(&stdout, "restitution").contains("0.0") && line(&stdout, "friction").contains("0.5"), "{stdout}");
    let (stdout, stderr) = pile("restitution = 1.0\ncontact_slop_m = 0.0001\n");
    for name in ["slop_below_free_fall", "elastic_under_gravity"] {
        assert!(stderr.contains(&format!("warning[{name}]")), "{name} at load:\n{stderr}");
        assert!(stdout.contains(&format!("warning[{name}]")), "{name} in --explain:\n{stdout}");
    }
    assert!(stderr.contains("0.003 would work"), "{stderr}");
}

/// `systemctl stop`, `docker stop` and `kill` send SIGTERM: the server stops as on Ctrl-C, after
/// its current tick, with its last events confirmed, its recording flushed and its summary
/// printed, rather than dying mid-write.
#[test]
fn sigterm_stops_the_server_in_order() {
    use std::io::{BufRead, BufReader};
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let record = std::env::temp_dir().join(format!("impact-sigterm-{}.jsonl", std::process::id()));
    let mut server = Command::new(env!("CARGO_BIN_EXE_impact-server"))
        .arg("--scene")
        .arg(impact_core::scene::Scene::bundled_path("arena"))
        .args(["--listen", &format!("tcp/127.0.0.1:{port}"), "--quiet", "--record"])
        .arg(&record)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("impact-server runs");
    let (tx, rx) = std::sync::mpsc::channel();
    let out = server.stdout.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut seen = Vec::new();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    while !seen.iter().any(|l: &String| l.starts_with("listening on")) {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        seen.push(rx.recv_timeout(left).unwrap_or_else(|_| panic!("not listening: {seen:?}")));
    }
    std::thread::sleep(std::time::Duration::from_millis(500));
    let killed = Command::new("kill").args(["-TERM", &server.id().to_string()]).status().unwrap();
    assert!(killed.success());
    let status = server.wait().unwrap();
    seen.extend(rx.iter());
    assert!(status.success(), "{status:?}: {seen:?}");
    assert!(seen.iter().any(|l| l.contains("stopped: final confirmed events published")), "{seen:?}");
    let lines = std::fs::read_to_string(&record).unwrap().lines().count();
    assert!(lines > 10, "the recording holds the ticks it ran: {lines} lines");
    let _ = std::fs::remove_file(&record);
}
