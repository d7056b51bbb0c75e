//! The play page in a real browser: two people play the arena against a live server through
//! `impact-gateway --guests arena`, each in a headless Chromium of its own, driven over the
//! DevTools protocol with keys and clicks as a person would. Both avatars move under WASD; one
//! player walks up to the other and clicks on it until the server says it hit; both pages saw
//! that hit; neither page's event view differed from a confirmed tick. The picture of the
//! shooter's page is `target/play.png` (`IMPACT_UPDATE_SCREENSHOT=1` writes `docs/play.png`, the
//! README's). Needs Chromium (`.ci/run` installs Debian's). Every wait is bounded.

mod common;

use common::browser::{http_get, keep_screenshot, Browser};
use common::process::{binary, Proc};
use common::server;
use impact_core::scene::Scene;
use serde_json::Value;
use std::process::Command;
use std::time::{Duration, Instant};

/// One person's page.
struct Page(Browser);

impl Page {
    fn open(url: &str) -> Page {
        let mut b = Browser::launch(1100, 640);
        b.goto(url);
        let playing = b.wait_for(
            "document.getElementById('status').textContent.startsWith('playing') \
             && document.getElementById('status').dataset.x !== undefined",
            "document.getElementById('status').textContent",
            Duration::from_secs(30),
        );
        assert!(playing.is_ok(), "the page did not start playing: {playing:?}");
        Page(b)
    }

    /// `#status`'s data attributes.
    fn status(&mut self) -> Value {
        self.0.eval(
            "({...document.getElementById('status').dataset, text: document.getElementById('status').textContent})",
        )
    }

    fn num(&mut self, name: &str) -> f64 {
        let s = self.status();
        s[name].as_str().and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("data-{name} in {s}"))
    }

    fn position(&mut self) -> [f64; 3] {
        [self.num("x"), self.num("y"), self.num("z")]
    }

    /// Holds the keys that move toward `delta` (x, y, z) on the axes where it is past `slack`,
    /// releasing the others.
    fn steer(&mut self, delta: [f64; 3], slack: f64) {
        for (axis, (minus, plus)) in [("a", "d"), ("q", "e"), ("w", "s")].into_iter().enumerate() {
            self.0.key(minus, delta[axis] < -slack);
            self.0.key(plus, delta[axis] > slack);
        }
    }

    fn stop(&mut self) {
        self.steer([0.0; 3], 1.0);
    }

    /// Clicks where the page draws the point (x, z) of the world.
    fn click_at(&mut self, x: f64, z: f64) {
        let me = self.position();
        let scale = self.num("scale");
        let r = self.0.eval(
            "(() => { const r = document.getElementById('view').getBoundingClientRect(); \
             return [r.left + r.width / 2, r.top + r.height / 2]; })()",
        );
        let (cx, cy) = (r[0].as_f64().unwrap(), r[1].as_f64().unwrap());
        self.0.click(cx + (x - me[0]) * scale, cy + (z - me[2]) * scale);
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q) * (p - q)).sum::<f64>().sqrt()
}

#[test]
fn two_people_play_the_arena_in_chromium() {
    let (_server, endpoint) = server(Scene::load(&Scene::bundled_path("arena")).unwrap(), |_| {});
    let mut cmd = Command::new(binary("impact-gateway"));
    cmd.args(["--listen", "127.0.0.1:0", "--connect", &endpoint, "--guests", "arena", "--report-s", "0"]);
    let gateway = Proc::spawn("impact-gateway (play)", cmd);
    assert!(gateway.wait_for_output("play: http://", Duration::from_secs(30)), "{}", gateway.output());
    let out = gateway.output();
    let line = out.lines().find(|l| l.starts_with("play: http://")).expect("the play line");
    let url = line.split_whitespace().nth(1).expect("the address").to_string();
    let host = url.trim_start_matches("http://").trim_end_matches('/').to_string();
    assert!(http_get(&host, "/").contains("<canvas id=\"view\">"), "the page is served");

    let mut a = Page::open(&url);
    let mut b = Page::open(&url);
    let (sa, sb) = (a.status(), b.status());
    assert_ne!(sa["avatar"], sb["avatar"], "two guests, two avatars: {sa} {sb}");

    // Both move under their keys: toward the middle of the arena, a second's walk.
    for p in [&mut a, &mut b] {
        let from = p.position();
        p.steer([-from[0], 0.0, -from[2]], 0.5);
        std::thread::sleep(Duration::from_millis(1000));
        p.stop();
        let to = p.position();
        assert!(distance(from, to) > 2.0, "the avatar moved from {from:?} to {to:?}");
    }

    // The shooter walks up to the other (who stands) and clicks on it until the server says the
    // other was hit: close, so that balls rarely come between (one may; it walks up again).
    let target = b.num("avatar");
    let end = Instant::now() + Duration::from_secs(60);
    let mut shots = 0;
    while b.num("hits") < 1.0 {
        assert!(Instant::now() < end, "{shots} shots, no hit on the other: {} {}", a.status(), b.status());
        let (pa, pb) = (a.position(), b.position());
        if distance(pa, pb) > 6.0 {
            a.steer([pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]], 1.5);
            std::thread::sleep(Duration::from_millis(150));
            continue;
        }
        a.stop();
        std::thread::sleep(Duration::from_millis(300));
        let rays = a.num("rays");
        let pb = b.position();
        a.click_at(pb[0], pb[2]);
        shots += 1;
        let answered = Instant::now() + Duration::from_secs(3);
        while a.num("rays") <= rays && Instant::now() < answered {
            std::thread::sleep(Duration::from_millis(50));
        }
        std::thread::sleep(Duration::from_millis(300));
    }
    let (sa, sb) = (a.status(), b.status());
    // The shooter's page draws the other (a picture of two players mid-game).
    let drawn = a.0.wait_for(
        "Number(document.getElementById('status').dataset.players) >= 1",
        "document.getElementById('status').dataset.players",
        Duration::from_secs(5),
    );
    assert!(drawn.is_ok(), "the shooter's page does not draw the other: {} {}", a.status(), b.status());
    let picture = a.0.screenshot();
    assert_eq!(sb["hitBy"], sa["avatar"], "the other was hit by the shooter: {sb}");
    assert!(a.num("hits") >= 1.0, "the shooter saw its hit: {sa}");
    assert_eq!(a.num("hitLast"), target, "the shooter's last hit is the other: {sa}");

    // Their views were compared with the confirmed ticks, and none differed.
    std::thread::sleep(Duration::from_millis(1000));
    for (name, p) in [("shooter", &mut a), ("target", &mut b)] {
        let s = p.status();
        assert!(p.num("confirmed") > 0.0 && p.num("mismatched") == 0.0, "the {name}'s view: {s}");
        assert!(p.num("acked") > 0.0 && p.num("rejects") == 0.0, "the {name}'s inputs: {s}");
    }
    eprintln!("screenshot: {}", keep_screenshot(&picture, "play.png").display());
}
