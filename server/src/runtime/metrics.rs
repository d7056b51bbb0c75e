//! Prometheus metrics (`impact-server --metrics 127.0.0.1:9898`, text format at `/metrics`).
//!
//! One registry per process, every series labelled with its `world`. The tick thread observes
//! each tick's duration and each rollback's depth as they happen; the counters it keeps for its
//! own stats (inputs, rejects, events, stage times, egress drops, the state streams) are
//! carried over once a second, so scraping never touches the tick.

use super::http;
use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::Registry;
use std::collections::BTreeMap;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

type Labels = Vec<(&'static str, String)>;
type Hist = Family<Labels, Histogram, fn() -> Histogram>;
type FCounter = Family<Labels, Counter<f64, AtomicU64>>;

fn tick_buckets() -> Histogram {
    // 0.125 ms .. 256 ms.
    Histogram::new(exponential_buckets(0.000_125, 2.0, 12))
}

fn depth_buckets() -> Histogram {
    // 1 .. 128 ticks.
    Histogram::new(exponential_buckets(1.0, 2.0, 8))
}

/// The process's metrics: a registry and its families. Cheap to clone (every part is shared).
#[derive(Clone, Debug)]
pub struct Metrics {
    registry: Arc<Mutex<Registry>>,
    tick: Hist,
    overruns: Family<Labels, Counter>,
    stage: FCounter,
    steps: Family<Labels, Counter>,
    rollbacks: Family<Labels, Counter>,
    depth: Hist,
    inputs: Family<Labels, Counter>,
    events: Family<Labels, Counter>,
    corrections: Family<Labels, Counter>,
    clients: Family<Labels, Gauge>,
    bodies: Family<Labels, Gauge>,
    queue: Family<Labels, Gauge>,
    egress_dropped: Family<Labels, Counter>,
    state_bytes: Family<Labels, Counter>,
    state_frames: Family<Labels, Counter>,
    state_deferred: Family<Labels, Counter>,
    state_skipped: Family<Labels, Counter>,
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}

impl Metrics {
    /// An empty registry with impact's families.
    pub fn new() -> Metrics {
        let mut r = Registry::default();
        let m = Metrics {
            registry: Arc::new(Mutex::new(Registry::default())),
            tick: Family::new_with_constructor(tick_buckets),
            overruns: Family::default(),
            stage: Family::default(),
            steps: Family::default(),
            rollbacks: Family::default(),
            depth: Family::new_with_constructor(depth_buckets),
            inputs: Family::default(),
            events: Family::default(),
            corrections: Family::default(),
            clients: Family::default(),
            bodies: Family::default(),
            queue: Family::default(),
            egress_dropped: Family::default(),
            state_bytes: Family::default(),
            state_frames: Family::default(),
            state_deferred: Family::default(),
            state_skipped: Family::default(),
        };
        r.register("impact_tick_duration_seconds", "Time to run one server tick", m.tick.clone());
        r.register("impact_tick_overruns", "Ticks that missed their deadline", m.overruns.clone());
        r.register(
            "impact_stage_seconds",
            "Time spent in each stage of the core step (ticks and re-simulations)",
            m.stage.clone(),
        );
        r.register("impact_core_steps", "Core steps run: ticks and their re-simulations", m.steps.clone());
        r.register("impact_rollbacks", "Ticks that rolled back to re-simulate late inputs", m.rollbacks.clone());
        r.register("impact_rollback_depth_ticks", "Ticks re-simulated by each rollback", m.depth.clone());
        r.register("impact_inputs", "Client inputs by result and reject reason", m.inputs.clone());
        r.register("impact_events", "Collision events published, by status", m.events.clone());
        r.register("impact_corrections", "Correction batches published", m.corrections.clone());
        r.register("impact_clients", "Clients present", m.clients.clone());
        r.register("impact_bodies", "Dynamic bodies, awake and asleep", m.bodies.clone());
        r.register("impact_queue_depth", "Deepest a queue got in the last second", m.queue.clone());
        r.register("impact_egress_dropped", "Messages dropped by a full egress queue", m.egress_dropped.clone());
        r.register("impact_state_bytes", "Bytes published on the state streams", m.state_bytes.clone());
        r.register("impact_state_frames", "Frames published on the state streams", m.state_frames.clone());
        r.register(
            "impact_state_deferred_bodies",
            "Bodies in a client's area of interest held back by its byte budget",
            m.state_deferred.clone(),
        );
        r.register(
            "impact_state_skipped_frames",
            "State frames skipped because the state thread was busy",
            m.state_skipped.clone(),
        );
        *m.registry.lock().unwrap_or_else(|p| p.into_inner()) = r;
        m
    }

    /// The handles of one world.
    pub fn world(&self, world: &str) -> WorldMetrics {
        let w = WorldMetrics { m: self.clone(), world: world.to_string(), last: Totals::default() };
        // Series that may stay at zero are there from the start: a scrape tells "none" from
        // "not exported", and `rate()` has a first sample.
        drop(self.rollbacks.get_or_create(&w.l()));
        drop(self.egress_dropped.get_or_create(&w.l()));
        w
    }

    /// The text exposition of every series.
    pub fn render(&self) -> String {
        let mut out = String::new();
        let r = self.registry.lock().unwrap_or_else(|p| p.into_inner());
        // Writing to a String cannot fail.
        let _ = encode(&mut out, &r);
        out
    }

    /// Serves `/metrics` on `addr` until the handle is dropped.
    pub fn serve(&self, addr: &str) -> std::io::Result<http::Server> {
        let m = self.clone();
        http::Server::start(
            addr,
            "impact-metrics",
            Arc::new(move |req: &http::Request| match req.path.as_str() {
                "/metrics" => http::Response::ok("text/plain; version=0.0.4; charset=utf-8", m.render().into_bytes()),
                "/" => http::Response::ok("text/plain; charset=utf-8", b"impact metrics: see /metrics\n".to_vec()),
                _ => http::Response::not_found(),
            }),
        )
    }
}

/// Running totals a world keeps; [`WorldMetrics::sync`] adds what grew since the last call.
#[derive(Clone, Debug, Default)]
pub struct Totals {
    /// Ticks that missed their deadline.
    pub overruns: u64,
    /// Core stage times, seconds.
    pub stage_s: Vec<(&'static str, f64)>,
    /// Core steps.
    pub steps: u64,
    /// Inputs accepted.
    pub accepted: u64,
    /// Inputs rejected by reason.
    pub rejected: BTreeMap<String, u64>,
    /// Provisional events.
    pub events: u64,
    /// Confirmed events.
    pub confirmed: u64,
    /// Correction batches.
    pub corrections: u64,
    /// Egress drops.
    pub egress_dropped: u64,
    /// State stream bytes: world stream, client streams.
    pub state_bytes: [u64; 2],
    /// State frames: world stream, client streams.
    pub state_frames: [u64; 2],
    /// Bodies deferred by budgets.
    pub state_deferred: u64,
    /// Captures skipped.
    pub state_skipped: u64,
}

/// One world's series.
#[derive(Debug)]
pub struct WorldMetrics {
    m: Metrics,
    world: String,
    last: Totals,
}

impl WorldMetrics {
    fn l(&self) -> Labels {
        vec![("world", self.world.clone())]
    }

    fn l2(&self, k: &'static str, v: &str) -> Labels {
        vec![("world", self.world.clone()), (k, v.to_string())]
    }

    /// One tick took `seconds`.
    pub fn tick(&self, seconds: f64) {
        self.m.tick.get_or_create(&self.l()).observe(seconds);
    }

    /// A tick rolled back `depth` ticks.
    pub fn rollback(&self, depth: u32) {
        self.m.rollbacks.get_or_create(&self.l()).inc();
        self.m.depth.get_or_create(&self.l()).observe(f64::from(depth));
    }

    /// Gauges of the moment: clients, bodies awake and asleep, the deepest the ingress queue got.
    pub fn gauges(&self, clients: usize, awake: usize, asleep: usize, ingress_max: u32) {
        self.m.clients.get_or_create(&self.l()).set(clients as i64);
        self.m.bodies.get_or_create(&self.l2("state", "awake")).set(awake as i64);
        self.m.bodies.get_or_create(&self.l2("state", "asleep")).set(asleep as i64);
        self.m.queue.get_or_create(&self.l2("queue", "ingress")).set(i64::from(ingress_max));
    }

    /// Adds what the totals gained since the last call.
    pub fn sync(&mut self, now: &Totals) {
        let grow = |c: &Counter, new: u64, old: u64| {
            c.inc_by(new.saturating_sub(old));
        };
        let last = std::mem::take(&mut self.last);
        grow(&self.m.overruns.get_or_create(&self.l()), now.overruns, last.overruns);
        grow(&self.m.steps.get_or_create(&self.l()), now.steps, last.steps);
        for (name, s) in &now.stage_s {
            let before = last.stage_s.iter().find(|(n, _)| n == name).map_or(0.0, |x| x.1);
            self.m.stage.get_or_create(&self.l2("stage", name)).inc_by((s - before).max(0.0));
        }
        let inputs = |result: &str, reason: &str| {
            vec![("world", self.world.clone()), ("result", result.to_string()), ("reason", reason.to_string())]
        };
        grow(&self.m.inputs.get_or_create(&inputs("accepted", "")), now.accepted, last.accepted);
        for (reason, n) in &now.rejected {
            let before = last.rejected.get(reason).copied().unwrap_or(0);
            grow(&self.m.inputs.get_or_create(&inputs("rejected", reason)), *n, before);
        }
        grow(&self.m.events.get_or_create(&self.l2("status", "provisional")), now.events, last.events);
        grow(&self.m.events.get_or_create(&self.l2("status", "confirmed")), now.confirmed, last.confirmed);
        grow(&self.m.corrections.get_or_create(&self.l()), now.corrections, last.corrections);
        grow(&self.m.egress_dropped.get_or_create(&self.l()), now.egress_dropped, last.egress_dropped);
        for (k, stream) in ["world", "clients"].iter().enumerate() {
            grow(
                &self.m.state_bytes.get_or_create(&self.l2("stream", stream)),
                now.state_bytes[k],
                last.state_bytes[k],
            );
            grow(
                &self.m.state_frames.get_or_create(&self.l2("stream", stream)),
                now.state_frames[k],
                last.state_frames[k],
            );
        }
        grow(&self.m.state_deferred.get_or_create(&self.l()), now.state_deferred, last.state_deferred);
        grow(&self.m.state_skipped.get_or_create(&self.l()), now.state_skipped, last.state_skipped);
        self.last = now.clone();
    }
}
