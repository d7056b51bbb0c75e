//! Headless Chromium driven over the DevTools protocol (a WebSocket), for tests of the web
//! viewer in a real browser. Chromium is Debian's `chromium` package (`.ci/run` installs it), or
//! the binary named by `IMPACT_CHROMIUM`.

use super::process::Proc;
use base64::Engine;
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// The Chromium binary, or `None` when there is none.
pub fn chromium() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("IMPACT_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    ["chromium", "chromium-browser", "google-chrome"].iter().find_map(|name| {
        let out = Command::new("sh").arg("-c").arg(format!("command -v {name}")).output().ok()?;
        let path = String::from_utf8_lossy(&out.stdout).trim().to_string();
        (out.status.success() && !path.is_empty()).then(|| PathBuf::from(path))
    })
}

/// A headless browser with one page.
pub struct Browser {
    _proc: Proc,
    ws: WebSocket<MaybeTlsStream<TcpStream>>,
    next: u64,
    _profile: PathBuf,
}

impl Browser {
    /// Starts Chromium headless with a fresh profile and connects to its page.
    pub fn launch(width: u32, height: u32) -> Browser {
        let bin = chromium().expect(
            "the viewer tests need Chromium: `apt-get install chromium` (.ci/run installs it), or set IMPACT_CHROMIUM",
        );
        // A profile of its own: a test may run two browsers (two players) at once.
        static LAUNCHED: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = LAUNCHED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let profile = std::env::temp_dir().join(format!("impact-chromium-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&profile);
        let mut cmd = Command::new(bin);
        cmd.args(["--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-extensions"])
            .arg("--remote-debugging-port=0")
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(format!("--window-size={width},{height}"))
            .arg("about:blank");
        let proc = Proc::spawn("chromium", cmd);
        assert!(
            proc.wait_for_output("DevTools listening on ws://", Duration::from_secs(30)),
            "Chromium did not start:\n{}",
            proc.output()
        );
        let out = proc.output();
        let line = out.lines().find(|l| l.contains("DevTools listening on ws://")).expect("the line");
        let url = &line[line.find("ws://").expect("ws url")..];
        let host = url.trim_start_matches("ws://").split('/').next().expect("host:port").to_string();
        // The page target's socket, from /json/list.
        let end = Instant::now() + Duration::from_secs(10);
        let page = loop {
            let list: Value = serde_json::from_str(&http_get(&host, "/json/list")).unwrap_or(Value::Null);
            let page = list.as_array().and_then(|a| {
                a.iter()
                    .find(|t| t["type"] == "page")
                    .and_then(|t| t["webSocketDebuggerUrl"].as_str().map(String::from))
            });
            if let Some(p) = page {
                break p;
            }
            assert!(Instant::now() < end, "Chromium shows no page: {list}");
            std::thread::sleep(Duration::from_millis(200));
        };
        let (ws, _) = tungstenite::connect(page.as_str()).expect("the DevTools socket");
        let mut b = Browser { _proc: proc, ws, next: 1, _profile: profile };
        b.call("Page.enable", json!({}));
        b.call("Runtime.enable", json!({}));
        b
    }

    /// Sends a DevTools command and returns its result (events in between are skipped).
    pub fn call(&mut self, method: &str, params: Value) -> Value {
        let id = self.next;
        self.next += 1;
        let msg = json!({"id": id, "method": method, "params": params}).to_string();
        self.ws.send(Message::text(msg)).expect("DevTools send");
        loop {
            let m = self.ws.read().expect("DevTools read");
            let Message::Text(t) = m else { continue };
            let v: Value = serde_json::from_str(t.as_str()).expect("DevTools JSON");
            if v["id"] == id {
                assert!(v.get("error").is_none(), "{method}: {}", v["error"]);
                return v["result"].clone();
            }
        }
    }

    /// Opens `url`.
    pub fn goto(&mut self, url: &str) {
        self.call("Page.navigate", json!({"url": url}));
    }

    /// The value of a JavaScript expression in the page, or the exception it threw.
    pub fn try_eval(&mut self, expr: &str) -> Result<Value, Value> {
        let r = self.call("Runtime.evaluate", json!({"expression": expr, "returnByValue": true, "awaitPromise": true}));
        match r.get("exceptionDetails") {
            Some(e) => Err(e.clone()),
            None => Ok(r["result"]["value"].clone()),
        }
    }

    /// The value of a JavaScript expression in the page (panics on an exception).
    pub fn eval(&mut self, expr: &str) -> Value {
        self.try_eval(expr).unwrap_or_else(|e| panic!("{expr}: {e}"))
    }

    /// Waits until `expr` is true in the page (a page still loading counts as false), returning
    /// the value of `show` then, or at the timeout as the error.
    pub fn wait_for(&mut self, expr: &str, show: &str, timeout: Duration) -> Result<Value, Value> {
        let end = Instant::now() + timeout;
        loop {
            if self.try_eval(expr) == Ok(Value::Bool(true)) {
                return Ok(self.eval(show));
            }
            if Instant::now() > end {
                return Err(self.try_eval(show).unwrap_or_else(|e| e));
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Presses (`down`) or releases a key, as a keyboard does (`key` as `KeyboardEvent.key`: a
    /// letter).
    pub fn key(&mut self, key: &str, down: bool) {
        let code = format!("Key{}", key.to_ascii_uppercase());
        let kind = if down { "keyDown" } else { "keyUp" };
        self.call("Input.dispatchKeyEvent", json!({"type": kind, "key": key, "code": code}));
    }

    /// Clicks the left button at (`x`, `y`), CSS pixels from the page's top left.
    pub fn click(&mut self, x: f64, y: f64) {
        self.call("Input.dispatchMouseEvent", json!({"type": "mouseMoved", "x": x, "y": y}));
        for kind in ["mousePressed", "mouseReleased"] {
            self.call(
                "Input.dispatchMouseEvent",
                json!({"type": kind, "x": x, "y": y, "button": "left", "clickCount": 1}),
            );
        }
    }

    /// A PNG of the page.
    pub fn screenshot(&mut self) -> Vec<u8> {
        let r = self.call("Page.captureScreenshot", json!({"format": "png"}));
        base64::engine::general_purpose::STANDARD.decode(r["data"].as_str().expect("png data")).expect("base64")
    }
}

/// Keeps a picture a browser test took: `<target dir>/<name>`, and `docs/<name>` (the one the
/// README shows) when `IMPACT_UPDATE_SCREENSHOT` is set. Returns the first path.
pub fn keep_screenshot(png: &[u8], name: &str) -> PathBuf {
    assert!(png.starts_with(b"\x89PNG") && png.len() > 20_000, "a real picture ({} bytes)", png.len());
    let target =
        super::process::binary("impact-server").parent().and_then(|p| p.parent()).expect("target dir").join(name);
    std::fs::write(&target, png).expect("writing the screenshot");
    if std::env::var_os("IMPACT_UPDATE_SCREENSHOT").is_some() {
        let docs = impact_core::scene::checkout().join("docs").join(name);
        std::fs::write(&docs, png).expect("writing the screenshot into docs/");
    }
    target
}

/// A plain HTTP GET on loopback; the body (read to its `Content-Length`, or to the close).
pub fn http_get(host: &str, path: &str) -> String {
    let Ok(mut c) = TcpStream::connect(host) else { return String::new() };
    let _ = c.set_read_timeout(Some(Duration::from_secs(10)));
    let _ = write!(c, "GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n");
    let mut buf = Vec::new();
    let mut chunk = [0u8; 8192];
    loop {
        if let Some(at) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            let head = String::from_utf8_lossy(&buf[..at]).to_ascii_lowercase();
            let len = head.lines().find_map(|l| l.strip_prefix("content-length:").and_then(|v| v.trim().parse().ok()));
            if len.is_some_and(|n: usize| buf.len() >= at + 4 + n) {
                return String::from_utf8_lossy(&buf[at + 4..at + 4 + len.unwrap_or(0)]).into_owned();
            }
        }
        match c.read(&mut chunk) {
            Ok(0) | Err(_) => break,
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
        }
    }
    let text = String::from_utf8_lossy(&buf).into_owned();
    text.split_once("\r\n\r\n").map(|(_, b)| b.to_string()).unwrap_or_default()
}
