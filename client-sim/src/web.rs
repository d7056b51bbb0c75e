//! The live web viewer behind `impact-inspect web` (and `impact-sim --demo`): a page served from
//! this process (its HTML, script and style are compiled into the binary) that draws one world
//! from its streams.
//!
//! ```text
//!  zenoh: state, events, corrections, confirmed, stats ──▶ hub ──▶ /stream (server-sent events, JSON)
//!  zenoh: query/state?tick=T                            ◀── /api/state?tick=T (scrubbing)
//! ```
//!
//! The hub keeps the world as the state stream last described it, so a page that connects gets
//! a full frame at once and the deltas after it, and fans every message out to each page through
//! a bounded queue (a page that cannot keep up loses messages, counted, and waits for the next
//! full frame as any state receiver does).

use crate::net;
use impact_protocol::{keys, BodyInfo, BodyMotion, EntityId, ServerMessage, StateFrame, Tick, WorldId};
use impact_server::runtime::http::{self, Request, Response};
use std::collections::BTreeMap;
use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use zenoh::Wait;

const INDEX: &str = include_str!("../web/index.html");
const SCRIPT: &str = include_str!("../web/viewer.js");
const STYLE: &str = include_str!("../web/viewer.css");

/// Messages queued for one page before it starts losing them.
const PAGE_QUEUE: usize = 512;

/// The world as the state stream described it, and the pages listening.
#[derive(Default)]
struct Hub {
    pages: Vec<SyncSender<Arc<str>>>,
    /// Each body's info, its last sample, and when that sample came.
    bodies: BTreeMap<EntityId, (BodyInfo, BodyMotion, Instant)>,
    frame: Option<u32>,
    synced: bool,
    tick: Tick,
    /// When the newest frame came.
    at: Option<Instant>,
    stats: Option<Arc<str>>,
}

impl Hub {
    /// Applies a state frame, come at `now`, to the world held (PROTOCOL.md, "State streams").
    fn apply(&mut self, f: &StateFrame, now: Instant) {
        if f.full {
            self.bodies.clear();
            self.synced = true;
        } else if self.frame.is_none_or(|p| p.wrapping_add(1) != f.frame) {
            self.synced = false;
        }
        self.frame = Some(f.frame);
        self.tick = f.tick;
        self.at = Some(now);
        if !self.synced {
            return;
        }
        for e in &f.left {
            self.bodies.remove(e);
        }
        let mut infos: BTreeMap<EntityId, &BodyInfo> = f.entered.iter().map(|i| (i.entity, i)).collect();
        for m in &f.moved {
            match infos.remove(&m.0) {
                Some(i) => {
                    self.bodies.insert(m.0, (i.clone(), *m, now));
                }
                None => {
                    if let Some(b) = self.bodies.get_mut(&m.0) {
                        (b.1, b.2) = (*m, now);
                    }
                }
            }
        }
    }

    /// The world held, as a full frame numbered like the last one (the deltas after it apply):
    /// each body carried from its last sample at its velocity to the newest frame (a frame
    /// carries only the bodies whose motion changed), by the time between their arrivals.
    fn full_frame(&self) -> Option<StateFrame> {
        let frame = self.frame.filter(|_| self.synced)?;
        let at = self.at?;
        let carried = |(_, m, came): &(BodyInfo, BodyMotion, Instant)| {
            let s = at.saturating_duration_since(*came).as_secs_f32();
            BodyMotion(m.0, std::array::from_fn(|k| m.1[k] + m.2[k] * s), m.2, m.3)
        };
        Some(StateFrame {
            tick: self.tick,
            frame,
            full: true,
            entered: self.bodies.values().map(|b| b.0.clone()).collect(),
            moved: self.bodies.values().map(carried).collect(),
            left: Vec::new(),
            deferred: 0,
            centre: None,
            avatar: None,
        })
    }

    fn broadcast(&mut self, json: Arc<str>, dropped: &AtomicU64) {
        self.pages.retain(|p| match p.try_send(json.clone()) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                dropped.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Disconnected(_)) => false,
        });
    }
}

/// A running viewer: the page's server and the subscriptions feeding it.
pub struct Viewer {
    http: http::Server,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    dropped: Arc<AtomicU64>,
}

impl std::fmt::Debug for Viewer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Viewer").field("addr", &self.http.addr()).finish()
    }
}

impl Viewer {
    /// Serves the viewer of `world` on `listen` (`host:port`), fed by `session`.
    pub fn start(session: &zenoh::Session, world: &WorldId, listen: &str) -> anyhow::Result<Viewer> {
        let hub = Arc::new(Mutex::new(Hub::default()));
        let dropped = Arc::new(AtomicU64::new(0));
        let mut subscribers = Vec::new();
        for pattern in [keys::STATE, keys::EVENTS, keys::CORRECTIONS, keys::CONFIRMED, keys::STATS] {
            let (hub, dropped) = (hub.clone(), dropped.clone());
            let sub = session
                .declare_subscriber(pattern.key(world, None))
                .callback(move |sample| {
                    let Ok(msg) = net::decode_server(&sample) else { return };
                    let Ok(json) = serde_json::to_string(&msg) else { return };
                    let json: Arc<str> = json.into();
                    let mut h = hub.lock().unwrap_or_else(|p| p.into_inner());
                    match &msg {
                        ServerMessage::State(f) => h.apply(f, Instant::now()),
                        ServerMessage::Stats(_) => h.stats = Some(json.clone()),
                        _ => {}
                    }
                    h.broadcast(json, &dropped);
                })
                .wait()
                .map_err(|e| anyhow::anyhow!("subscribing to {}: {e}", pattern.name))?;
            subscribers.push(sub);
        }
        let state_key = keys::QUERY_STATE.key(world, None);
        let (session, name) = (session.clone(), world.to_string());
        let handler: http::Handler = Arc::new(move |req: &Request| match req.path.as_str() {
            "/" | "/index.html" => {
                Response::ok("text/html; charset=utf-8", INDEX.replace("{world}", &name).into_bytes())
            }
            "/viewer.js" => Response::ok("text/javascript; charset=utf-8", SCRIPT.as_bytes().to_vec()),
            "/viewer.css" => Response::ok("text/css; charset=utf-8", STYLE.as_bytes().to_vec()),
            "/stream" => stream(&hub),
            "/api/state" => past_state(&session, &state_key, req.param("tick")),
            _ => Response::not_found(),
        });
        let http = http::Server::start(listen, "impact-web", handler)
            .map_err(|e| anyhow::anyhow!("the viewer cannot listen on {listen}: {e}"))?;
        Ok(Viewer { http, _subscribers: subscribers, dropped })
    }

    /// The page's address.
    pub fn url(&self) -> String {
        format!("http://{}/", self.http.addr())
    }

    /// Messages pages could not take in time.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// A page's stream: the world held as a full frame and the last stats, then everything as it
/// comes, as server-sent events.
fn stream(hub: &Arc<Mutex<Hub>>) -> Response {
    let (tx, rx) = sync_channel::<Arc<str>>(PAGE_QUEUE);
    {
        let mut h = hub.lock().unwrap_or_else(|p| p.into_inner());
        let first = h.full_frame().and_then(|f| serde_json::to_string(&ServerMessage::State(f)).ok());
        for m in first.map(Arc::from).into_iter().chain(h.stats.clone()) {
            let _ = tx.try_send(m);
        }
        h.pages.push(tx);
    }
    Response::events(Box::new(move |out: &mut dyn Write, stop: &AtomicBool| pump(rx, out, stop)))
}

fn pump(rx: Receiver<Arc<str>>, out: &mut dyn Write, stop: &AtomicBool) {
    while !stop.load(Ordering::SeqCst) {
        let written = match rx.recv_timeout(Duration::from_millis(500)) {
            Ok(m) => {
                out.write_all(b"data: ").and_then(|_| out.write_all(m.as_bytes())).and_then(|_| out.write_all(b"\n\n"))
            }
            Err(RecvTimeoutError::Timeout) => out.write_all(b": idle\n\n"),
            Err(RecvTimeoutError::Disconnected) => return,
        };
        if written.and_then(|_| out.flush()).is_err() {
            return;
        }
    }
}

/// The state query at a tick, as JSON (`snapshot`, or `query_error` with the window's bounds).
fn past_state(session: &zenoh::Session, key: &str, tick: Option<&str>) -> Response {
    let params = match tick.map(str::parse::<u32>) {
        Some(Ok(t)) => format!("tick={t}"),
        Some(Err(_)) => return Response::error(400, "tick must be a number\n"),
        None => String::new(),
    };
    let replies = match session.get(format!("{key}?{params}")).timeout(Duration::from_secs(3)).wait() {
        Ok(r) => r,
        Err(e) => return Response::error(502, &format!("query: {e}\n")),
    };
    while let Ok(reply) = replies.recv() {
        if let Ok(sample) = reply.result() {
            if let Ok(msg) = net::decode_server(sample) {
                if let Ok(json) = serde_json::to_string(&msg) {
                    return Response::ok("application/json", json.into_bytes());
                }
            }
        }
    }
    Response::error(504, "the server did not answer\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use impact_protocol::BodyShape;

    fn info(e: u32) -> BodyInfo {
        BodyInfo {
            entity: EntityId(e),
            class: "ball".into(),
            owner: None,
            shape: BodyShape::Sphere,
            half_extents_m: [0.5; 3],
            offset_m: [0.0; 3],
            fixed: false,
            rotation: None,
            local_shape: None,
            state: Default::default(),
            teleported: None,
        }
    }

    /// Frame `n` (at tick `n`), `moved` as (entity, x, x velocity).
    fn frame(n: u32, full: bool, entered: &[u32], moved: &[(u32, f32, f32)], left: &[u32]) -> StateFrame {
        StateFrame {
            tick: Tick(n),
            frame: n,
            full,
            entered: entered.iter().map(|e| info(*e)).collect(),
            moved: moved
                .iter()
                .map(|(e, x, v)| BodyMotion(EntityId(*e), [*x, 0.0, 0.0], [*v, 0.0, 0.0], false))
                .collect(),
            left: left.iter().map(|e| EntityId(*e)).collect(),
            deferred: 0,
            centre: None,
            avatar: None,
        }
    }

    #[test]
    fn the_hub_follows_the_stream_and_waits_for_a_full_frame_after_a_gap() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut h = Hub::default();
        assert!(h.full_frame().is_none(), "nothing to show before a full frame");
        h.apply(&frame(4, false, &[1], &[(1, 1.0, 0.0)], &[]), at(0));
        assert!(h.full_frame().is_none(), "a delta first is not enough");
        h.apply(&frame(5, true, &[1, 2], &[(1, 1.0, 2.0), (2, 2.0, 0.0)], &[]), at(50));
        // Body 1 flies on at 2 m/s: the next frame does not carry it, and a page that comes
        // after it is shown it where it flew to.
        h.apply(&frame(6, false, &[3], &[(3, 3.0, 0.0)], &[2]), at(550));
        let f = h.full_frame().unwrap();
        assert_eq!(f.frame, 6);
        assert_eq!(f.moved.iter().map(|m| (m.0 .0, m.1[0])).collect::<Vec<_>>(), vec![(1, 2.0), (3, 3.0)]);
        // Frame 8 after 6: a gap; nothing more until a full frame.
        h.apply(&frame(8, false, &[], &[(1, 9.0, 0.0)], &[]), at(600));
        assert!(h.full_frame().is_none());
        h.apply(&frame(9, true, &[7], &[(7, 7.0, 0.0)], &[]), at(650));
        assert_eq!(h.full_frame().unwrap().entered.len(), 1);
    }
}
