//! The web viewer in a real browser, and the metrics endpoint scraped and parsed.
//!
//! `the_viewer_draws_the_arena_in_chromium` starts `impact-server` on the arena, players on it,
//! and `impact-inspect web`, opens the page in headless Chromium over the DevTools protocol, and
//! waits for it to draw the bodies and flash events; it pauses and rewinds through the server's
//! rollback window, and saves a screenshot (`target/viewer.png`; `IMPACT_UPDATE_SCREENSHOT=1`
//! writes `docs/viewer.png`, the README's). Needs Chromium (`.ci/run` installs Debian's).

mod common;

use common::browser::{http_get, keep_screenshot, Browser};
use common::free_port;
use common::process::{binary, server_binary, Proc};
use impact_client::netsim::Link;
use impact_client_sim::load::{self, Behaviour, LoadConfig};
use impact_client_sim::timing::Timing;
use impact_protocol::WorldId;
use std::collections::BTreeMap;
use std::process::Command;
use std::time::Duration;

/// A server on the arena; `name` names its log (each test its own: they run side by side).
fn start_server(name: &str, extra: &[&str]) -> (Proc, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut cmd = Command::new(server_binary());
    cmd.arg("--scene").arg(impact_core::scene::Scene::bundled_path("arena"));
    cmd.args(["--listen", &endpoint, "--quiet"]).args(extra);
    let server = Proc::spawn(name, cmd);
    assert!(server.wait_for_output("listening on", Duration::from_secs(30)), "{}", server.output());
    (server, endpoint)
}

/// Players on the arena for `seconds`, in the background.
fn players(
    endpoint: &str,
    clients: u32,
    seconds: u64,
    first: u32,
) -> std::thread::JoinHandle<impact_client_sim::report::Report> {
    let cfg = LoadConfig {
        connect: vec![endpoint.to_string()],
        zenoh_config: None,
        mode: Default::default(),
        world: WorldId::new("arena").unwrap(),
        clients,
        first_client: first,
        sessions: 1,
        users: None,
        duration: Duration::from_secs(seconds),
        uplink: Link { latency: Duration::from_millis(20), jitter: Duration::from_millis(5), loss: 0.0 },
        downlink: Link { latency: Duration::from_millis(20), jitter: Duration::from_millis(5), loss: 0.0 },
        behaviour: Behaviour::Mixed,
        timing: Timing::Ahead,
        input_hz: 10.0,
        encoding: Default::default(),
        seed: 7,
        settle: Duration::from_millis(500),
        progress: false,
        faults: Default::default(),
        state: true,
        predict: 0,
        scene: None,
    };
    std::thread::spawn(move || load::run(&cfg).expect("the load runs"))
}

#[test]
fn the_viewer_draws_the_arena_in_chromium() {
    let (_server, endpoint) = start_server("viewer-server", &[]);
    let load = players(&endpoint, 24, 25, 7000);
    let port = free_port();
    let mut cmd = Command::new(binary("impact-inspect"));
    // No --world: the viewer finds the one world served there.
    cmd.args(["--connect", &endpoint, "web", "--listen", &format!("127.0.0.1:{port}")]);
    let web = Proc::spawn("viewer-web", cmd);
    assert!(web.wait_for_output("viewer of world arena at", Duration::from_secs(20)), "{}", web.output());

    let mut b = Browser::launch(1400, 860);
    b.goto(&format!("http://127.0.0.1:{port}/"));
    let show = "JSON.stringify({status: document.getElementById('status').textContent, \
                drawn: document.getElementById('view').dataset.eventsDrawn, \
                bodies: document.getElementById('view').dataset.bodiesDrawn, \
                drawMs: document.getElementById('view').dataset.drawMs})";
    // The arena's 2,000 balls, six walls and the players, drawn with a tick.
    let drawn = b.wait_for(
        "/^tick \\d+ · \\d+ bodies$/.test(document.getElementById('status').textContent) && \
         Number(document.getElementById('view').dataset.bodiesDrawn) >= 2006",
        show,
        Duration::from_secs(30),
    );
    let drawn = drawn.unwrap_or_else(|v| panic!("the page did not draw the world: {v}\n{}", web.output()));
    eprintln!("drawn: {drawn}");
    // Collision events flash (the page counts the ones it drew).
    let flashed =
        b.wait_for("Number(document.getElementById('view').dataset.eventsDrawn) > 50", show, Duration::from_secs(20));
    let flashed = flashed.unwrap_or_else(|v| panic!("no events were drawn: {v}"));
    eprintln!("flashed: {flashed}");
    // Smooth with 2,000 bodies: drawing a frame (a moving average) fits well inside 60 Hz.
    let draw_ms: f64 = b.eval("Number(document.getElementById('view').dataset.drawMs)").as_f64().unwrap_or(f64::MAX);
    assert!(draw_ms < 16.0, "a frame takes {draw_ms} ms to draw");
    // Let a few frames run for the screenshot, then keep it.
    std::thread::sleep(Duration::from_millis(1500));
    let target = keep_screenshot(&b.screenshot(), "viewer.png");
    eprintln!("screenshot: {}", target.display());

    // The server's plots filled from its stats.
    let stats = b.wait_for(
        "document.getElementById('v-tick').textContent.startsWith('p50')",
        "document.getElementById('v-tick').textContent",
        Duration::from_secs(5),
    );
    assert!(stats.is_ok(), "no stats plotted: {stats:?}");

    // Pause, rewind 5 ticks from the server's present (the window moves on while the page is
    // paused): the page asks the server's state query and draws that tick.
    b.eval("document.getElementById('pause').click()");
    let paused = b.eval("document.getElementById('status').textContent");
    b.eval(
        "(() => { const s = document.getElementById('scrub'); s.value = -5; s.dispatchEvent(new Event('input')); })()",
    );
    let rewound = b.wait_for(
        "document.getElementById('scrub-label').textContent.includes('5 back')",
        "document.getElementById('scrub-label').textContent + ' | ' + document.getElementById('status').textContent",
        Duration::from_secs(10),
    );
    let rewound = rewound.unwrap_or_else(|v| panic!("rewinding failed (paused at {paused}): {v}"));
    assert!(rewound.as_str().unwrap_or("").contains("rewound"), "{rewound}");
    b.eval("document.getElementById('pause').click()");
    // Clicking a body lists its recent events: click one that just collided.
    let clicked = b.eval(
        "(() => { const r = document.getElementById('view').getBoundingClientRect(); \
           const e = [...recent].reverse().find((e) => live.bodies.has(e.a) && !live.bodies.get(e.a).info.fixed); \
           if (!e) return 'no event'; const p = placed(live.bodies.get(e.a), live); \
           const [x, y] = toScreen(p[0], p[2], r); \
           const at = { clientX: r.left + x, clientY: r.top + y, bubbles: true }; \
           document.getElementById('view').dispatchEvent(new MouseEvent('mousedown', at)); \
           window.dispatchEvent(new MouseEvent('mouseup', at)); return String(e.a); })()",
    );
    let listed = b.wait_for(
        "document.querySelectorAll('#sel-events li').length > 0",
        "document.getElementById('selected').textContent",
        Duration::from_secs(5),
    );
    let listed = listed.unwrap_or_else(|v| panic!("clicking entity {clicked} listed nothing: {v}"));
    assert!(listed.as_str().unwrap_or("").starts_with("entity "), "{listed}");
    drop(b);
    let report = load.join().expect("the load thread");
    assert!(report.state_frames > 0, "the players' own state streams ran too");
}

/// One sample line of the text format: `name{label="value",...} number`.
fn sample(line: &str) -> Option<(String, BTreeMap<String, String>, f64)> {
    let (head, value) = line.rsplit_once(' ')?;
    let value: f64 = value.parse().ok()?;
    let (name, labels) = match head.split_once('{') {
        Some((n, rest)) => (n, rest.strip_suffix('}')?),
        None => (head, ""),
    };
    if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':') {
        return None;
    }
    let mut map = BTreeMap::new();
    for kv in labels.split(',').filter(|s| !s.is_empty()) {
        let (k, v) = kv.split_once('=')?;
        map.insert(k.to_string(), v.strip_prefix('"')?.strip_suffix('"')?.to_string());
    }
    Some((name.to_string(), map, value))
}

#[test]
fn metrics_are_served_in_the_prometheus_text_format() {
    let port = free_port();
    let (server, endpoint) = start_server("metrics-server", &["--metrics", &format!("127.0.0.1:{port}")]);
    assert!(server.output().contains(&format!("metrics: http://127.0.0.1:{port}/metrics")), "{}", server.output());
    let report = players(&endpoint, 12, 4, 7100).join().expect("the load");
    assert!(report.acks > 0);
    // The tick loop carries its counters over once a second.
    std::thread::sleep(Duration::from_millis(1300));
    let text = http_get(&format!("127.0.0.1:{port}"), "/metrics");
    let mut samples = Vec::new();
    let mut types = BTreeMap::new();
    for line in text.lines().filter(|l| !l.is_empty()) {
        if let Some(rest) = line.strip_prefix("# TYPE ") {
            let (name, kind) = rest.split_once(' ').expect("# TYPE name kind");
            types.insert(name.to_string(), kind.to_string());
        } else if !line.starts_with("# HELP ") && line != "# EOF" {
            samples.push(sample(line).unwrap_or_else(|| panic!("not a sample line: {line:?}")));
        }
    }
    let get = |name: &str, with: &[(&str, &str)]| -> f64 {
        samples
            .iter()
            .filter(|(n, l, _)| n == name && with.iter().all(|(k, v)| l.get(*k).map(String::as_str) == Some(*v)))
            .map(|(_, _, v)| v)
            .sum()
    };
    let arena = [("world", "arena")];
    assert_eq!(types.get("impact_tick_duration_seconds").map(String::as_str), Some("histogram"), "{types:?}");
    assert!(get("impact_tick_duration_seconds_count", &arena) > 100.0, "{text}");
    assert!(get("impact_tick_duration_seconds_bucket", &[("world", "arena"), ("le", "+Inf")]) > 100.0);
    let accepted = get("impact_inputs_total", &[("world", "arena"), ("result", "accepted")]);
    assert!(accepted >= report.acks as f64 * 0.9, "accepted {accepted}, acks {}", report.acks);
    assert!(get("impact_events_total", &[("world", "arena"), ("status", "provisional")]) > 0.0);
    assert!(get("impact_stage_seconds_total", &[("world", "arena"), ("stage", "broadphase")]) > 0.0);
    assert!(get("impact_core_steps_total", &arena) > 100.0);
    assert!(get("impact_state_bytes_total", &[("world", "arena"), ("stream", "clients")]) > 0.0);
    for name in [
        "impact_clients",
        "impact_bodies",
        "impact_queue_depth",
        "impact_egress_dropped_total",
        "impact_rollbacks_total",
    ] {
        assert!(
            samples.iter().any(|(n, l, _)| n == name && l.get("world").map(String::as_str) == Some("arena")),
            "{name} missing"
        );
    }
    assert!(http_get(&format!("127.0.0.1:{port}"), "/nothing").contains("not found"));
}
