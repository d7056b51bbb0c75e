//! The tick loop: one world's thread. Each tick it takes presence changes and inputs off the
//! queues, advances the rollback session, and publishes acks, events, corrections, the input log,
//! stats and the state capture; it also answers queries between ticks.

use super::standby::Published;
use super::{
    declare_primary, reject, send, ClientState, Control, Ingress, Primary, ServerOptions, Shared, Summary, TickThread,
    Wiring,
};
use crate::rollback::{RollbackConfig, Session};
use crate::runtime::egress::Out;
use crate::runtime::gate::TickGate;
use crate::runtime::metrics::WorldMetrics;
use crate::runtime::owner::{reachable, routed, ANNOUNCE_EVERY, HOLD_REACHABLE, HOLD_UNREACHABLE};
use crate::runtime::state::{Capture, StateCounters};
use crate::runtime::thread_clock::{ThreadClock, ThreadTimes};
use crate::runtime::timing::LeadEstimator;
use impact_core::scene::{avatar_position, AvatarRule, Scene};
use impact_core::sim::{Plan, SystemAction};
use impact_protocol::{
    keys, Admitted, ClientId, CollisionEvent, Encoding, EntityId, Epoch, EventBatch, InputAck, InputReject,
    LoggedInput, OwnerNotice, RejectReason, ServerMessage, Tick, TimePing, TimePong, Welcome, WorldClosed, WorldId,
};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender};
use std::sync::Arc;
use std::time::{Duration, Instant};

pub(super) struct TickLoop {
    pub(super) session: Session,
    pub(super) opts: ServerOptions,
    pub(super) world: WorldId,
    pub(super) avatar: Option<AvatarRule>,
    pub(super) egress: SyncSender<Out>,
    pub(super) shared: Arc<Shared>,
    pub(super) clients: BTreeMap<ClientId, ClientState>,
    /// The process had a router and has none now (see [`TickLoop::own_link`]): no client's
    /// grace runs out meanwhile.
    pub(super) cut_off: bool,
    /// A router was ever linked (a server clients reach through routers).
    pub(super) routed: bool,
    /// When the router link was last looked at.
    pub(super) link_checked: Option<Instant>,
    /// No absent client's grace ends before this tick ([`TickLoop::note_leave`]): until then
    /// [`TickLoop::presence`] does not look through every client for one whose grace ended.
    pub(super) leave_due: Option<u32>,
    pub(super) summary: Summary,
    /// This second's tick durations, ms (the stats message carries them).
    pub(super) tick_times: Vec<f64>,
    /// Every tick's duration, microseconds, for the run's percentiles.
    pub(super) all_tick_times: hdrhistogram::Histogram<u64>,
    /// Every tick's CPU time on the tick thread and its wait for a core, microseconds (empty
    /// where the system does not count them: see [`ThreadClock`]).
    pub(super) tick_cpu: (hdrhistogram::Histogram<u64>, hdrhistogram::Histogram<u64>),
    /// Core stage times and steps at the last stats message, for the period's means.
    pub(super) last_stages: (u64, Vec<Duration>),
    /// Where state captures go (`None`: no state streams).
    pub(super) state_tx: Option<SyncSender<Capture>>,
    pub(super) state_counters: Arc<StateCounters>,
    /// Raised while a tick is under way: the state and egress threads work between ticks.
    pub(super) tick_gate: Arc<TickGate>,
    /// The state frame the last capture was for.
    pub(super) state_frame: Option<u64>,
    pub(super) metrics: Option<WorldMetrics>,
    pub(super) period_events: u64,
    pub(super) period_rollbacks: u32,
    pub(super) period_depth: u32,
    pub(super) period_queue_max: u32,
    /// Rollbacks by depth (index: ticks re-simulated; bounded by the window).
    pub(super) depths: Vec<u64>,
    /// The declarations of the world's server (`None` while a standby follows).
    pub(super) primary: Option<Primary>,
    /// The `--record` file.
    pub(super) record: Option<crate::recording::Recorder>,
    /// Inputs acked and server actions queued in this tick: the `log/admitted` message.
    pub(super) admitted: Admitted,
    /// This tick's acks, held until `admitted` is out.
    pub(super) acks: Vec<(Arc<str>, ServerMessage, Encoding)>,
    /// Marks a standby that took over keeps of what its primary published, so it never publishes
    /// a tick twice (see [`Published`]).
    pub(super) earlier: Published,
    /// The confirmed batches of recent ticks, for `query/confirmed`.
    pub(super) recent: super::recent::Recent,
    /// The world's [`scene_hash`](impact_core::sim::World::scene_hash), sent in each welcome.
    pub(super) scene_hash: u64,
    /// The rules and static world, as `query/scene` answers them.
    pub(super) described: impact_protocol::SceneDescription,
}

impl TickLoop {
    pub(super) fn new(
        scene: Scene,
        opts: ServerOptions,
        world: WorldId,
        egress: SyncSender<Out>,
        shared: Arc<Shared>,
    ) -> TickLoop {
        let described = scene.describe();
        let w = scene.world;
        let mut rb = opts.rollback.clone().unwrap_or_else(|| RollbackConfig::for_world(&w));
        rb.window_ticks = rb.window_ticks.max(1);
        rb.logic_clients.extend(opts.logic_clients.iter().copied());
        if let Some(users) = &opts.users {
            rb.logic_clients.extend(users.logic_clients());
        }
        let plan = Plan::for_world(&w);
        let scene_hash = w.scene_hash();
        let mut session = Session::new(w, plan, rb);
        session.set_pool(opts.pool.clone());
        let metrics = opts.metrics.as_ref().map(|m| m.world(world.as_str()));
        TickLoop {
            session,
            scene_hash,
            described,
            opts,
            world,
            avatar: scene.avatar,
            egress,
            shared,
            clients: BTreeMap::new(),
            summary: Summary::default(),
            tick_times: Vec::with_capacity(128),
            // 1 us to 1 h at three significant figures: the bounds cannot be out of range.
            all_tick_times: micros(),
            tick_cpu: (micros(), micros()),
            last_stages: (0, Vec::new()),
            state_tx: None,
            state_counters: Arc::new(StateCounters::default()),
            tick_gate: Arc::new(TickGate::default()),
            state_frame: None,
            metrics,
            period_events: 0,
            period_rollbacks: 0,
            period_depth: 0,
            depths: Vec::new(),
            period_queue_max: 0,
            primary: None,
            record: None,
            admitted: Admitted { tick: Tick(0), system: Vec::new(), inputs: Vec::new() },
            acks: Vec::new(),
            earlier: Published::default(),
            recent: Default::default(),
            cut_off: false,
            routed: false,
            link_checked: None,
            leave_due: None,
        }
    }

    /// Hands `msg` to the egress thread, which encodes and publishes it.
    pub(super) fn put(&self, key: impl Into<Arc<str>>, msg: ServerMessage, encoding: Encoding) {
        send(&self.egress, &self.shared, key.into(), msg, encoding);
    }

    /// Publishes on the log streams: in order with everything else, but never dropped by
    /// congestion (a standby that misses an entry must start again from a checkpoint).
    fn put_log(&self, key: String, msg: ServerMessage) {
        let (encoding, dropped_before) = (self.opts.encoding, self.shared.keyed_dropped.load(Ordering::Relaxed));
        if self.egress.try_send(Out::Log { key: key.into(), msg: Box::new(msg), encoding, dropped_before }).is_err() {
            self.shared.dropped_for_key();
        }
    }

    /// A client's `client/{id}/ack` key (formatted once, when the client was first seen).
    fn ack_key(&self, client: ClientId) -> Arc<str> {
        self.clients
            .get(&client)
            .map_or_else(|| keys::CLIENT_ACK.key(&self.world, Some(client)).into(), |c| c.ack_key.clone())
    }

    /// A client's `client/{id}/events` key, likewise.
    fn events_key(&self, client: ClientId) -> Arc<str> {
        self.clients
            .get(&client)
            .map_or_else(|| keys::CLIENT_EVENTS.key(&self.world, Some(client)).into(), |c| c.events_key.clone())
    }

    /// The state of a client first seen now.
    pub(super) fn new_client(
        &self,
        client: ClientId,
        present: bool,
        leave_at: Option<u32>,
        encoding: Encoding,
    ) -> ClientState {
        ClientState {
            avatar: None,
            present,
            leave_at,
            tokens: f64::from(self.opts.inputs_per_client_per_s),
            encoding,
            timing: LeadEstimator::default(),
            ack_key: keys::CLIENT_ACK.key(&self.world, Some(client)).into(),
            events_key: keys::CLIENT_EVENTS.key(&self.world, Some(client)).into(),
            want_full: false,
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn run(
        &mut self,
        stop: &AtomicBool,
        zs: &zenoh::Session,
        wiring: &Wiring,
        follower: Option<super::standby::Follower>,
        ingress: Receiver<Ingress>,
        control: Receiver<Control>,
        queries: Receiver<zenoh::query::Query>,
    ) -> Summary {
        if let Some(f) = follower {
            if !self.follow(f, stop, zs, &control) {
                return self.finish();
            }
            match declare_primary(zs, &self.world, wiring) {
                Ok(p) => self.primary = Some(p),
                Err(e) => {
                    eprintln!("impact-server: world {}: taking over failed: {e}", self.world);
                    return self.finish();
                }
            }
            self.reanchor();
        }
        let hz = self.session.world().config.tick_hz;
        let dt = Duration::from_secs_f64(1.0 / f64::from(hz));
        let started = Instant::now();
        let mut next = started;
        let mut last_stats = Instant::now();
        let mut last_announce: Option<Instant> = None;
        let mut clock = ThreadClock::of_this_thread();
        let mut last_pass = (Instant::now(), clock.read());
        let gate = self.tick_gate.clone();
        self.first_in_line();
        loop {
            if stop.load(Ordering::SeqCst) || self.opts.max_ticks.is_some_and(|m| self.summary.ticks >= m) {
                break;
            }
            if let Some(newer) = self.shared.owner.fenced() {
                self.fence(newer);
                break;
            }
            // Stood still for longer than the lease: a standby may own the world now.
            let pass = (Instant::now(), clock.read());
            last_pass = match stood_still(last_pass, pass) {
                Some(stalled) if !self.hold_after_stall(zs, stop, stalled) => continue, // fenced, or stopping
                Some(_) => {
                    self.welcome_again();
                    (Instant::now(), clock.read())
                }
                None => pass,
            };
            if self.primary.is_some() && last_announce.is_none_or(|t| t.elapsed() >= ANNOUNCE_EVERY) {
                last_announce = Some(Instant::now());
                self.announce();
            }
            self.watch_own_link(zs);
            // Deadline schedule. Behind by more than 4 ticks: drop the backlog and start a new
            // schedule from now (catching up by running ticks back to back would only make the
            // world run fast for a while); each dropped deadline counts as an overrun.
            let now = Instant::now();
            // On schedule, the tick goes first on its core (`TickGate`); behind it, it does not
            // hold the state and egress threads back.
            let on_time = now < next;
            if on_time {
                std::thread::sleep(next - now);
            } else if now - next > dt * 4 {
                let missed = ((now - next).as_secs_f64() / dt.as_secs_f64()) as u64;
                self.summary.overruns += missed;
                next = now;
            }
            next += dt;
            let before = clock.read();
            let t0 = Instant::now();
            let ticking = on_time.then(|| gate.enter());
            self.tick(&ingress, &control, &queries);
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let after = clock.read();
            drop(ticking);
            if let (Some(b), Some(a)) = (before, after) {
                let spent = a.since(b);
                let _ = self.tick_cpu.0.record((spent.run_ns / 1000).max(1));
                let _ = self.tick_cpu.1.record((spent.wait_ns / 1000).max(1));
            }
            if t0.elapsed() > dt {
                self.summary.overruns += 1;
            }
            self.tick_times.push(ms);
            let _ = self.all_tick_times.record((ms * 1e3).round().max(1.0) as u64);
            if let Some(m) = &self.metrics {
                m.tick(ms / 1e3);
            }
            self.summary.tick_ms_max = self.summary.tick_ms_max.max(ms);
            if last_stats.elapsed() >= Duration::from_secs(1) {
                last_stats = Instant::now();
                self.publish_stats();
            }
        }
        self.summary.run_s = started.elapsed().as_secs_f64();
        if self.summary.fenced_by.is_some() {
            // Another server owns the world: what this one still holds is not the world's.
            return self.finish();
        }
        // Shutdown: everything still in the window is final now.
        for (batch, log) in self.session.finish() {
            if self.earlier.confirmed(batch.tick) {
                continue;
            }
            self.put(keys::CONFIRMED.key(&self.world, None), ServerMessage::Confirmed(batch), self.opts.encoding);
            if self.earlier.logged(log.tick) {
                continue;
            }
            let entry = log.into_wire();
            if let Some(r) = self.record.as_mut() {
                r.write(&entry);
            }
            self.put_log(keys::LOG.key(&self.world, None), ServerMessage::Log(entry));
        }
        // Closed for good: every client is told, after the last events.
        let closing = self.shared.closing.lock().ok().and_then(|mut c| c.take());
        if let Some((next, reason)) = closing {
            let tick = self.session.now();
            let notice = ServerMessage::Closed(WorldClosed { world: self.world.clone(), tick, next, reason });
            for c in self.clients.values() {
                self.put(c.ack_key.clone(), notice.clone(), c.encoding);
            }
        }
        self.finish()
    }

    /// Says who owns the world, on `owner` (see [`crate::runtime::owner`]).
    fn announce(&self) {
        if let Some(epoch) = self.shared.owner.epoch() {
            let notice = ServerMessage::Owner(OwnerNotice { epoch, tick: self.session.now() });
            self.put(keys::OWNER.key(&self.world, None), notice, self.opts.encoding);
        }
    }

    /// A newer owner was heard: this server publishes nothing more for the world (its egress
    /// and state threads withhold everything from the moment it was heard) and ends it.
    fn fence(&mut self, newer: Epoch) {
        let own = self.shared.owner.epoch().unwrap_or_default();
        self.summary.fenced_by = Some(newer);
        eprintln!(
            "impact-server: world {}: another server owns it now (epoch {newer}, this one's {own}); stopped \
             publishing at tick {} and ending it (start this process again with --standby to follow the new owner)",
            self.world,
            self.session.now().0
        );
    }

    /// After the process stood still for `stalled` (longer than its lease): holds every
    /// publication until it has been reachable for [`HOLD_REACHABLE`] without hearing a newer
    /// owner (or reached nobody for [`HOLD_UNREACHABLE`]). Returns whether it still owns the
    /// world; `false` when a newer owner was heard (or the server is stopping).
    fn hold_after_stall(&mut self, zs: &zenoh::Session, stop: &AtomicBool, stalled: Duration) -> bool {
        let owner = self.shared.owner.clone();
        owner.hold(true);
        eprintln!(
            "impact-server: world {}: this process stood still for {:.1} s, longer than its lease: holding its \
             messages until it knows no other server took the world over",
            self.world,
            stalled.as_secs_f64()
        );
        let t0 = Instant::now();
        let mut reachable_since: Option<Instant> = None;
        let owned = loop {
            if stop.load(Ordering::SeqCst) || owner.fenced().is_some() {
                break false;
            }
            if reachable(zs) {
                if reachable_since.get_or_insert_with(Instant::now).elapsed() >= HOLD_REACHABLE {
                    break true;
                }
            } else {
                reachable_since = None;
                if t0.elapsed() >= HOLD_UNREACHABLE {
                    break true;
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        self.summary.held_ms += t0.elapsed().as_secs_f64() * 1e3;
        if owned {
            owner.hold(false);
            eprintln!(
                "impact-server: world {}: no newer owner heard in {:.1} s: publishing again",
                self.world,
                t0.elapsed().as_secs_f64()
            );
        }
        owned
    }

    /// After a hold that kept the world: every present client is welcomed again (PROTOCOL.md,
    /// "The server hangs and comes back"). Its clock re-anchors on the server's present, which
    /// the stall and the hold put seconds behind its own (it would stamp every input `future`
    /// until its clock followed), and the welcome's `next_seq` lets it find the inputs it sent
    /// into the silence that never arrived, once its next is acked.
    fn welcome_again(&self) {
        for (client, s) in self.clients.iter().filter(|(_, s)| s.present && self.primary.is_some()) {
            self.welcome(*client, s.avatar);
        }
    }

    /// Raises the tick thread's priority as [`ServerOptions::tick_nice`] says; a refusal is
    /// said once per process (every world's tick thread would meet the same).
    fn first_in_line(&self) {
        static SAID: std::sync::Once = std::sync::Once::new();
        let nice = self.opts.tick_nice;
        if nice == 0 {
            return;
        }
        if let Err(e) = crate::runtime::thread_clock::set_nice(nice) {
            SAID.call_once(|| {
                eprintln!(
                    "impact-server: the tick thread keeps its priority (nice {nice}: {e}; below 0 needs \
                     CAP_SYS_NICE, e.g. systemd's AmbientCapabilities=CAP_SYS_NICE, or --tick-nice 0 to not ask)"
                );
            });
        }
    }

    /// The run's summary (after the last tick).
    fn finish(&mut self) -> Summary {
        if let Some(r) = self.record.as_mut() {
            if let Err(e) = r.flush() {
                eprintln!("impact-server: world {}: {e}", self.world);
            }
        }
        let h = &self.all_tick_times;
        self.summary.tick_ms_p50 = h.value_at_quantile(0.5) as f64 / 1e3;
        self.summary.tick_ms_p99 = h.value_at_quantile(0.99) as f64 / 1e3;
        self.summary.tick_ms_mean = h.mean() / 1e3;
        let (cpu, wait) = &self.tick_cpu;
        if !cpu.is_empty() {
            self.summary.tick_thread = Some(TickThread {
                cpu_ms_p50: cpu.value_at_quantile(0.5) as f64 / 1e3,
                cpu_ms_p99: cpu.value_at_quantile(0.99) as f64 / 1e3,
                cpu_ms_max: cpu.max() as f64 / 1e3,
                wait_ms_p99: wait.value_at_quantile(0.99) as f64 / 1e3,
                wait_ms_max: wait.max() as f64 / 1e3,
                waited_over_1ms: wait.count_between(1000, wait.max().max(1000)),
            });
        }
        self.summary.egress_dropped = self.shared.egress_dropped.load(Ordering::Relaxed);
        for (k, r) in RejectReason::ALL.iter().enumerate() {
            let n = self.shared.rejected_in_callbacks[k].load(Ordering::Relaxed);
            if n > 0 {
                *self.summary.inputs_rejected.entry(r.name().to_string()).or_insert(0) += n;
            }
        }
        self.summary.rollbacks = self.session.stats.rollbacks;
        self.summary.selective_rollbacks = self.session.stats.selective_rollbacks;
        self.summary.rollback_depth_max = self.session.stats.depth_max;
        let core = &self.session.stepper().stats;
        self.summary.core_steps = core.ticks;
        let steps = core.ticks.max(1) as f64;
        self.summary.core_stage_ms = core.stages().iter().map(|(n, d)| (*n, d.as_secs_f64() * 1e3 / steps)).collect();
        // Depth percentiles over the ticks that rolled back.
        let total: u64 = self.depths.iter().sum();
        let at = |q: f64| {
            let rank = ((q * total as f64).ceil() as u64).max(1);
            let mut seen = 0;
            self.depths.iter().position(|c| {
                seen += c;
                seen >= rank
            })
        };
        if total > 0 {
            self.summary.rollback_depth_p50 = at(0.5).unwrap_or(0) as u32;
            self.summary.rollback_depth_p99 = at(0.99).unwrap_or(0) as u32;
        }
        self.summary.clone()
    }

    fn count_reject(&mut self, reason: RejectReason) {
        *self.summary.inputs_rejected.entry(reason.name().to_string()).or_insert(0) += 1;
    }

    fn tick(
        &mut self,
        ingress: &Receiver<Ingress>,
        control: &Receiver<Control>,
        queries: &Receiver<zenoh::query::Query>,
    ) {
        self.presence(control);
        self.ingest(ingress);
        self.publish_admitted();
        self.step();
        self.capture_state();
        // Queries, answered from the history.
        while let Ok(q) = queries.try_recv() {
            self.answer(q);
        }
    }

    /// Joins and leaves; avatars whose client's grace ended are removed. A standby only keeps
    /// track (its primary's log carries the spawns and removals).
    pub(super) fn presence(&mut self, control: &Receiver<Control>) {
        let now = self.session.now();
        while let Ok(c) = control.try_recv() {
            match c {
                Control::Join(client) => self.join(client),
                Control::Leave(client) => {
                    let at = now.0 + self.opts.grace_ticks;
                    if let Some(s) = self.clients.get_mut(&client) {
                        s.present = false;
                        s.leave_at = Some(at);
                    }
                    self.note_leave(at);
                }
            }
        }
        if self.leave_due.is_none_or(|t| t > now.0) || self.primary.is_none() || self.cut_off {
            return;
        }
        let mut leaving = Vec::new();
        self.leave_due = None;
        for (c, s) in self.clients.iter().filter(|(_, s)| !s.present) {
            match s.leave_at {
                Some(t) if t <= now.0 => leaving.push(*c),
                Some(t) => self.leave_due = Some(self.leave_due.map_or(t, |d| d.min(t))),
                None => {}
            }
        }
        for c in leaving {
            self.session.forget_client(c);
            if let Some(s) = self.clients.remove(&c) {
                if let Some(entity) = s.avatar {
                    self.submit_system(SystemAction::Remove { entity });
                }
            }
        }
    }

    /// An absent client's grace now ends at `at`: [`TickLoop::presence`] looks for it then. Every
    /// `leave_at` set to a tick calls this.
    pub(super) fn note_leave(&mut self, at: u32) {
        self.leave_due = Some(self.leave_due.map_or(at, |d| d.min(at)));
    }

    /// [`TickLoop::own_link`], four times a second; a standby watches it while it follows, so
    /// one that takes over while the router is down starts cut off.
    pub(super) fn watch_own_link(&mut self, zs: &zenoh::Session) {
        if self.link_checked.is_none_or(|t| t.elapsed() >= ANNOUNCE_EVERY) {
            self.link_checked = Some(Instant::now());
            self.own_link(routed(zs));
        }
    }

    /// The process's own link to a router (`up`), looked at four times a second, once it has had
    /// one. While it has none (a restarted router), it cannot hear a client come back, so no
    /// client's grace runs out; once it has one again, every client still away gets a whole
    /// grace period from then: a client whose session dropped just before the router went (its
    /// token gone from the server's view) and came back while the server itself was cut off
    /// keeps its avatar, as one back within the grace period does. A server no router ever
    /// linked (clients as its peers) is never cut off.
    fn own_link(&mut self, up: bool) {
        self.routed |= up;
        if !self.routed {
            return;
        }
        if up && self.cut_off {
            let back = self.session.now().0 + self.opts.grace_ticks;
            for s in self.clients.values_mut().filter(|s| !s.present && s.leave_at.is_some()) {
                s.leave_at = Some(back);
            }
            self.note_leave(back);
        }
        self.cut_off = !up;
    }

    /// Queues a server action for the present tick, and for the admitted log.
    fn submit_system(&mut self, a: SystemAction) {
        self.admitted.system.push(crate::rollback::log::logged_system(&a));
        self.session.submit_system(a);
    }

    /// Inputs: every one queued now (the queue is bounded, so this is too).
    fn ingest(&mut self, ingress: &Receiver<Ingress>) {
        let now = self.session.now();
        let per_tick = f64::from(self.opts.inputs_per_client_per_s) / f64::from(self.session.world().config.tick_hz);
        for c in self.clients.values_mut() {
            c.tokens = (c.tokens + per_tick).min(f64::from(self.opts.inputs_per_client_per_s));
        }
        let mut queued = 0u32;
        while let Ok(item) = ingress.try_recv() {
            queued += 1;
            let (input, encoding, copy) = match item {
                Ingress::Input { input, encoding, copy } => (input, encoding, copy),
                Ingress::Ping { ping, encoding } => {
                    self.pong(ping, encoding);
                    continue;
                }
                Ingress::FullFrame(client) => {
                    // Costs a token, as a probe does; from a client the server does not know, or
                    // out of tokens, it is dropped (the client asks again).
                    if let Some(s) = self.clients.get_mut(&client).filter(|s| s.tokens >= 1.0) {
                        s.tokens -= 1.0;
                        s.want_full = true;
                    }
                    continue;
                }
            };
            let (client, seq, tick) = (input.client, input.seq, input.tick);
            if self.session.already_accepted(client, seq) {
                // A redundant copy or a resend: it applied once, it is not applied again, and it
                // is no reject either (PROTOCOL.md, "Redundancy").
                self.summary.inputs_repeated += 1;
                continue;
            }
            if !self.clients.contains_key(&client) {
                if self.clients.len() >= self.opts.max_clients {
                    // Every client costs a little state until its grace ends: an input from yet
                    // another id (never present) must not grow it without bound.
                    self.count_reject(RejectReason::QueueFull);
                    let detail = format!("the server already serves its maximum of {} clients", self.opts.max_clients);
                    let msg = reject(client, Some((seq, tick)), RejectReason::QueueFull, detail);
                    self.put(self.ack_key(client), msg, encoding);
                    continue;
                }
                let state = self.new_client(client, false, Some(now.0 + self.opts.grace_ticks), encoding);
                self.clients.insert(client, state);
                self.note_leave(now.0 + self.opts.grace_ticks);
            }
            let state = self.clients.get_mut(&client).expect("inserted above");
            let ack_key = state.ack_key.clone();
            state.encoding = encoding;
            // Game logic speaks for every player (a match starting puts them all back at once):
            // the ingress queue and the inputs held per tick bound it, not the per-player rate.
            let logic = self.session.config().logic_clients.contains(&client);
            if state.tokens < 1.0 && !logic {
                self.count_reject(RejectReason::RateLimited);
                let msg = reject(
                    client,
                    Some((seq, tick)),
                    RejectReason::RateLimited,
                    format!("more than {} inputs per second", self.opts.inputs_per_client_per_s),
                );
                self.put(ack_key, msg, encoding);
                continue;
            }
            state.tokens = (state.tokens - 1.0).max(0.0);
            let view = input.view_tick.unwrap_or(tick);
            let logged = LoggedInput {
                client,
                seq,
                tick,
                view_tick: input.rewind_tick(),
                actions: input.actions.clone(),
                rewound: Vec::new(),
                logic: self.session.config().logic_clients.contains(&client),
            };
            match self.session.submit(input) {
                Ok(applied) => {
                    self.summary.inputs_accepted += 1;
                    self.admitted.inputs.push(LoggedInput { tick: applied, ..logged });
                    // A copy whose first message was lost arrived an input later than the path
                    // takes: no lead would have made it on time, and raising everyone's lead for
                    // it pushes their next inputs past the ticks accepted ahead (`future`).
                    let accepted_ahead = self.session.config().lead_ticks;
                    let lead_ticks = if copy {
                        state.timing.lead(accepted_ahead)
                    } else {
                        state.timing.observe(now, view, accepted_ahead)
                    };
                    let margin_ticks = (i64::from(applied.0) - i64::from(now.0)).clamp(-1 << 30, 1 << 30) as i32;
                    let ack = ServerMessage::Ack(InputAck {
                        client,
                        seq,
                        tick,
                        applied_tick: applied,
                        server_tick: now,
                        margin_ticks,
                        lead_ticks,
                        accepted_before: self.session.accepted_before(client, seq),
                    });
                    // Sent after the admitted log (see `publish_admitted`).
                    self.acks.push((ack_key, ack, encoding));
                }
                Err(r) => {
                    self.count_reject(r.reason);
                    let msg = ServerMessage::Reject(InputReject {
                        client,
                        seq: Some(seq),
                        tick: Some(tick),
                        reason: r.reason,
                        detail: r.detail,
                        oldest_tick: r.oldest_tick,
                        newest_tick: r.newest_tick,
                    });
                    self.put(ack_key, msg, encoding);
                }
            }
        }
        self.period_queue_max = self.period_queue_max.max(queued);
    }

    /// Answers a time-sync probe from a present client with the current tick; a probe costs one
    /// of the client's input tokens (so probes cannot flood the egress queue), and one from a
    /// client the server does not know, or out of tokens, is dropped (the client probes again).
    fn pong(&mut self, ping: TimePing, encoding: Encoding) {
        let Some(state) = self.clients.get_mut(&ping.client) else { return };
        if state.tokens < 1.0 {
            return;
        }
        state.tokens -= 1.0;
        let pong = ServerMessage::Pong(TimePong { client: ping.client, id: ping.id, server_tick: self.session.now() });
        let key = state.ack_key.clone();
        self.put(key, pong, encoding);
    }

    /// Publishes what this tick admitted (a standby re-applies it if this process dies before
    /// the tick is confirmed), then the acks: a client never holds an ack for an input a standby
    /// could not know of. Nothing admitted: nothing sent.
    fn publish_admitted(&mut self) {
        let now = self.session.now();
        if !self.admitted.inputs.is_empty() || !self.admitted.system.is_empty() {
            self.admitted.tick = now;
            let msg = ServerMessage::Admitted(std::mem::replace(
                &mut self.admitted,
                Admitted { tick: now, system: Vec::new(), inputs: Vec::new() },
            ));
            self.put_log(keys::LOG_ADMITTED.key(&self.world, None), msg);
        }
        // Drained, not taken: the buffer keeps its capacity from tick to tick.
        let mut acks = std::mem::take(&mut self.acks);
        for (key, ack, encoding) in acks.drain(..) {
            self.put(key, ack, encoding);
        }
        self.acks = acks;
    }

    /// Steps the present tick and publishes what it produced: events, corrections, the tick
    /// that left the window (confirmed events and its log entry), ray results, skips, welcomes.
    fn step(&mut self) {
        let adv = self.session.advance();
        self.publish(adv);
    }

    /// Publishes what one advance produced.
    pub(super) fn publish(&mut self, mut adv: crate::rollback::Advance) {
        self.summary.ticks += 1;
        if adv.rollback_depth > 0 {
            if let Some(m) = &self.metrics {
                m.rollback(adv.rollback_depth);
            }
            self.period_rollbacks += 1;
            self.period_depth = self.period_depth.max(adv.rollback_depth);
            let d = adv.rollback_depth as usize;
            if self.depths.len() <= d {
                self.depths.resize(d + 1, 0);
            }
            self.depths[d] += 1;
        }
        let enc = self.opts.encoding;
        if !adv.events.is_empty() {
            self.summary.events += adv.events.len() as u64;
            self.period_events += adv.events.len() as u64;
            let batch = EventBatch { tick: adv.tick, revision: 0, events: adv.events.clone() };
            let owners = self.owners(&batch.events, adv.tick);
            self.per_client(&batch.events, &owners, |events| {
                ServerMessage::Events(EventBatch { tick: batch.tick, revision: 0, events })
            });
            self.put(keys::EVENTS.key(&self.world, None), ServerMessage::Events(batch), enc);
        }
        for c in &adv.corrections {
            self.summary.corrections += 1;
            let all: Vec<CollisionEvent> = c.retracted.iter().chain(&c.amended).chain(&c.added).cloned().collect();
            let cc = c.clone();
            self.per_client(&all, &self.owners(&all, c.tick), move |events| {
                let keep = |v: &[CollisionEvent]| {
                    v.iter().filter(|e| events.iter().any(|x| x.key() == e.key())).cloned().collect()
                };
                ServerMessage::Corrections(impact_protocol::CorrectionBatch {
                    tick: cc.tick,
                    revision: cc.revision,
                    retracted: keep(&cc.retracted),
                    amended: keep(&cc.amended),
                    added: keep(&cc.added),
                })
            });
            self.put(keys::CORRECTIONS.key(&self.world, None), ServerMessage::Corrections(c.clone()), enc);
        }
        // A standby that took over re-simulates ticks its primary already logged or confirmed:
        // they were published then, and are not again.
        if let Some(log) = adv.log.take().filter(|l| !self.earlier.logged(l.tick)) {
            let entry = log.into_wire();
            if let Some(r) = self.record.as_mut() {
                r.write(&entry);
            }
            self.put_log(keys::LOG.key(&self.world, None), ServerMessage::Log(entry));
        }
        if let Some(c) = adv.confirmed.take() {
            // Kept for `query/confirmed`: a tick its primary confirmed was kept as heard, and
            // stays; one the primary published was published then, and is not again.
            let (keep, publish) = (!self.recent.has(c.tick), !self.earlier.confirmed(c.tick));
            let owners = if keep || publish { self.owners(&c.events, c.tick) } else { Vec::new() };
            if publish {
                self.summary.confirmed_events += c.events.len() as u64;
                if !c.events.is_empty() {
                    self.per_client(&c.events, &owners, |events| {
                        ServerMessage::Confirmed(EventBatch { tick: c.tick, revision: c.revision, events })
                    });
                }
                self.put(keys::CONFIRMED.key(&self.world, None), ServerMessage::Confirmed(c.clone()), enc);
            }
            if keep {
                self.recent.keep(c, owners);
            }
        }
        for r in &adv.rays {
            let e = self.clients.get(&r.client).map_or(enc, |c| c.encoding);
            self.put(self.ack_key(r.client), ServerMessage::RayResult(r.clone()), e);
        }
        for s in &adv.skipped {
            self.count_reject(s.reason);
            let e = self.clients.get(&s.client).map_or(enc, |c| c.encoding);
            self.put(self.ack_key(s.client), reject(s.client, Some((s.seq, s.tick)), s.reason, s.detail.clone()), e);
        }
        for (client, entity) in &adv.spawned {
            if let Some(c) = self.clients.get_mut(client) {
                c.avatar = Some(*entity);
            }
            if self.primary.is_some() {
                self.welcome(*client, Some(*entity));
            }
        }
    }

    pub(super) fn welcome(&self, client: ClientId, avatar: Option<EntityId>) {
        let cfg = &self.session.world().config;
        let msg = ServerMessage::Welcome(Welcome {
            client,
            avatar,
            tick: self.session.now(),
            tick_hz: cfg.tick_hz,
            window_ticks: cfg.window_ticks,
            input_lead_ticks: self.session.config().lead_ticks,
            max_rewind_ticks: cfg.max_rewind_ticks.min(self.session.config().window_ticks),
            next_seq: self.session.next_seq(client),
            scene_hash: self.scene_hash,
        });
        let e = self.clients.get(&client).map_or(self.opts.encoding, |c| c.encoding);
        self.put(self.ack_key(client), msg, e);
    }

    pub(super) fn join(&mut self, client: ClientId) {
        let now = self.session.now();
        if self.primary.is_none() {
            // A standby: remember the client is there; its primary spawns the avatar.
            let state = self.new_client(client, true, None, self.opts.encoding);
            let s = self.clients.entry(client).or_insert(state);
            s.present = true;
            s.leave_at = None;
            return;
        }
        if let Some(s) = self.clients.get_mut(&client) {
            s.present = true;
            s.leave_at = None;
            if s.avatar.is_some() {
                let a = s.avatar;
                self.welcome(client, a);
                return;
            }
        }
        if self.clients.len() >= self.opts.max_clients && !self.clients.contains_key(&client) {
            // Told, rather than left waiting for a welcome that will not come.
            let why = format!("the server already serves its maximum of {} clients", self.opts.max_clients);
            self.put(self.ack_key(client), reject(client, None, RejectReason::QueueFull, why), self.opts.encoding);
            return;
        }
        self.summary.clients += 1;
        let state = self.new_client(client, true, None, self.opts.encoding);
        let had = self.clients.insert(client, state).is_some();
        // Game logic plays no body of its own.
        let logic = self.session.config().logic_clients.contains(&client);
        match (&self.avatar, had) {
            (Some(rule), _) if !logic => {
                let pos = avatar_position(rule, client.0, now.0);
                let (class, shape) = (rule.class, rule.shape.clone());
                self.submit_system(SystemAction::SpawnAvatar { client, class, shape, pos });
            }
            _ => self.welcome(client, None),
        }
    }

    /// Publishes, for each client owning an entity in `events` (`owners` per event, from
    /// [`Self::owners`]), the batch `make` builds from the events that concern it.
    fn per_client(
        &self,
        events: &[CollisionEvent],
        owners: &[[Option<ClientId>; 2]],
        make: impl Fn(Vec<CollisionEvent>) -> ServerMessage,
    ) {
        for (client, mine) in super::recent::by_owner(events, owners) {
            let e = self.clients.get(&client).map_or(self.opts.encoding, |c| c.encoding);
            self.put(self.events_key(client), make(mine), e);
        }
    }

    /// The clients owning the two bodies of each event of `tick`: as the world has them now, or
    /// as it had them at `tick` for a body gone since.
    pub(super) fn owners(&self, events: &[CollisionEvent], tick: Tick) -> Vec<[Option<ClientId>; 2]> {
        let w = self.session.world();
        let past = self.session.frame(tick).map(|f| &f.state);
        let owner = |id: EntityId| {
            w.bodies
                .slot(id)
                .and_then(|s| w.bodies.owner[s])
                .or_else(|| past.and_then(|p| p.bodies.slot(id).and_then(|s| p.bodies.owner[s])))
        };
        events.iter().map(|e| [owner(e.a), owner(e.b)]).collect()
    }
}

/// A histogram of microseconds from 1 us to 1 h at three significant figures.
fn micros() -> hdrhistogram::Histogram<u64> {
    hdrhistogram::Histogram::new_with_bounds(1, 3_600_000_000, 3).expect("the bounds are valid")
}

/// How long the process stood still between two passes of the tick loop, when that is longer
/// than the server's lease: the wall time the tick thread neither ran nor waited for a core (a
/// process stopped, a host or VM paused). A tick that was merely slow ran all along, so it is not
/// a stall; where the system does not count a thread's times, the whole gap is taken.
fn stood_still(before: (Instant, Option<ThreadTimes>), now: (Instant, Option<ThreadTimes>)) -> Option<Duration> {
    let gap = now.0.saturating_duration_since(before.0);
    let busy = match (before.1, now.1) {
        (Some(b), Some(a)) => {
            let t = a.since(b);
            Duration::from_nanos(t.run_ns.saturating_add(t.wait_ns))
        }
        _ => Duration::ZERO,
    };
    let still = gap.saturating_sub(busy);
    (still > crate::runtime::zenoh_config::SERVER_LEASE).then_some(still)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stall is wall time the thread neither ran nor waited for a core, longer than the lease:
    /// a process stopped for 4 s is one, a 4 s tick that ran all along is not.
    #[test]
    fn a_stall_is_time_the_thread_did_not_run() {
        let t0 = Instant::now();
        let at = |s: f64| t0 + Duration::from_secs_f64(s);
        let times = |run_s: f64, wait_s: f64| {
            Some(ThreadTimes { run_ns: (run_s * 1e9) as u64, wait_ns: (wait_s * 1e9) as u64 })
        };
        let stopped = stood_still((at(0.0), times(1.0, 0.1)), (at(4.0), times(1.01, 0.1)));
        assert!(stopped.is_some_and(|d| d > Duration::from_millis(3900)), "{stopped:?}");
        assert_eq!(stood_still((at(0.0), times(1.0, 0.0)), (at(4.0), times(4.5, 0.4))), None, "a slow tick");
        assert_eq!(stood_still((at(0.0), times(1.0, 0.0)), (at(0.016), times(1.001, 0.0))), None, "a tick");
        assert!(stood_still((at(0.0), None), (at(2.0), None)).is_some(), "no thread times: the gap decides");
    }
}
