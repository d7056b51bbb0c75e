//! Rollback: inputs that arrive late are simulated as if they had arrived on time.
//!
//! A [`Session`] owns the present world and a bounded [`History`] of the last `W` ticks (the
//! world at the start of each, its inputs, its published events). An input stamped with a past
//! tick inside the window is inserted at that tick; at the next [`Session::advance`] the world is
//! rewound to the earliest changed tick and re-simulated to the present, however many late inputs
//! arrived. Each re-simulated tick's events are reconciled with what was published for it
//! ([`reconcile`]): retracted, amended or added, with a new revision. A tick leaving the window is
//! final, and its events are published as confirmed, exactly once.
//!
//! Because the core is deterministic, re-simulating a tick with the same inputs reproduces it
//! bit for bit; the self-check mode verifies that every tick, like ggrs's `SyncTestSession`.
//! Hitscan is lag-compensated for free: a ray is cast when its tick is (re-)simulated, against
//! the world as it was at that tick.

pub mod history;
pub mod hitscan;
pub mod log;
pub mod reconcile;
pub mod selective;
pub mod seq_window;

use history::{Frame, History};
use impact_core::sim::input;
use impact_core::sim::output::Skipped;
use impact_core::sim::{Plan, Stepper, SystemAction, TickInput, TickOutput, World};
use impact_protocol::{
    ClientId, ClientInput, CollisionEvent, CorrectionBatch, EventBatch, EventStatus, RayResult, RejectReason, Tick,
};
use std::collections::{BTreeMap, BTreeSet};

/// What to do with an input older than the window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StalePolicy {
    /// Refuse it with `stale` and the oldest tick still accepted.
    Reject,
    /// Apply it at the oldest tick still in the window.
    Clamp,
}

/// Rollback settings.
#[derive(Clone, Debug)]
pub struct RollbackConfig {
    /// Ticks of history (the window). Inputs older than `now - window` are stale.
    pub window_ticks: u32,
    /// How far ahead of `now` an input may be stamped.
    pub lead_ticks: u32,
    /// Stale inputs: reject or clamp.
    pub stale: StalePolicy,
    /// Self-check: re-simulate this many past ticks every tick and count desyncs (0: off).
    pub self_check_ticks: u32,
    /// Re-simulate only the bodies a late input can reach, when that is provably equal (the
    /// default; off: every rollback re-simulates every body).
    pub selective: bool,
    /// Most inputs held for one tick (a bound on memory whatever clients send).
    pub max_inputs_per_tick: usize,
    /// The clients with the game-logic role: their inputs act on any body (logged with each
    /// input, so a follower or a replay needs no copy of this).
    pub logic_clients: BTreeSet<ClientId>,
}

impl RollbackConfig {
    /// The settings a world's scene asks for.
    pub fn for_world(w: &World) -> RollbackConfig {
        RollbackConfig {
            window_ticks: w.config.window_ticks,
            lead_ticks: w.config.input_lead_ticks,
            stale: StalePolicy::Reject,
            self_check_ticks: 0,
            selective: true,
            max_inputs_per_tick: 4096,
            logic_clients: BTreeSet::new(),
        }
    }
}

/// Why an input was refused.
#[derive(Clone, Debug, PartialEq)]
pub struct Refusal {
    /// The reason the client receives.
    pub reason: RejectReason,
    /// Detail for humans.
    pub detail: String,
    /// The oldest tick accepted now (with `stale`).
    pub oldest_tick: Option<Tick>,
    /// The newest tick accepted now (with `future`).
    pub newest_tick: Option<Tick>,
}

impl Refusal {
    fn new(reason: RejectReason, detail: String) -> Refusal {
        Refusal { reason, detail, oldest_tick: None, newest_tick: None }
    }
}

/// What one [`Session::advance`] produced.
#[derive(Clone, Debug, Default)]
pub struct Advance {
    /// The tick just simulated.
    pub tick: Tick,
    /// Its events (revision 0, provisional).
    pub events: Vec<CollisionEvent>,
    /// Corrections of earlier ticks, oldest first.
    pub corrections: Vec<CorrectionBatch>,
    /// The tick that left the window, with its final events.
    pub confirmed: Option<EventBatch>,
    /// Results of rays fired by inputs accepted since the last advance.
    pub rays: Vec<RayResult>,
    /// Inputs that could not apply when their tick was simulated.
    pub skipped: Vec<Skipped>,
    /// How many past ticks were re-simulated (0: no rollback).
    pub rollback_depth: u32,
    /// Avatars spawned at this tick: `(owner, entity)`.
    pub spawned: Vec<(ClientId, impact_protocol::EntityId)>,
    /// The tick that left the window with this advance: its inputs, actions and final hash.
    pub log: Option<log::ConfirmedTick>,
}

/// Counters since start.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RollbackStats {
    /// Rollbacks performed.
    pub rollbacks: u64,
    /// Deepest rollback, ticks.
    pub depth_max: u32,
    /// Ticks re-simulated in total.
    pub resimulated_ticks: u64,
    /// Correction batches published.
    pub corrections: u64,
    /// Rollbacks done selectively.
    pub selective_rollbacks: u64,
    /// Selective re-simulations attempted (the rest of the rollbacks went straight to the full
    /// one while failed attempts backed off).
    pub selective_attempts: u64,
    /// Self-check re-simulations run.
    pub self_checks: u64,
    /// Self-check re-simulations that did not reproduce the past exactly.
    pub desyncs: u64,
    /// Wall time of the last rollback (rewind and re-simulation), for benchmarks.
    pub last_rollback: std::time::Duration,
    /// Total wall time spent taking the per-tick snapshot (the history's copy of the world).
    pub snapshot_time: std::time::Duration,
    /// Ticks advanced.
    pub ticks: u64,
}

/// A world with history: the authoritative simulation the runtime drives.
#[derive(Debug)]
pub struct Session {
    stepper: Stepper,
    world: World,
    history: History,
    future: BTreeMap<u32, Vec<TickInput>>,
    /// How many inputs the last tick stepped held: a future tick's list starts with room for
    /// about as many (grown one push at a time, its copies were 4 % of the tick at 1,000 players).
    inputs_hint: usize,
    system: Vec<SystemAction>,
    /// Each client's accepted seqs (replay protection), until [`Session::forget_client`].
    windows: BTreeMap<ClientId, seq_window::SeqWindow>,
    fresh: BTreeSet<(ClientId, u32)>,
    dirty_from: Option<Tick>,
    cfg: RollbackConfig,
    out: TickOutput,
    /// Counters.
    pub stats: RollbackStats,
    planted_desync: bool,
    /// Selective attempts to skip before trying again, and the failures in a row that set it:
    /// where late inputs reach most of the world every tick, each failed attempt is pure cost.
    /// Which path runs never changes a result (selective equals full), only the time.
    selective_backoff: u32,
    selective_failures: u32,
}

/// The longest run of rollbacks done in full, without a selective attempt, after repeated
/// failures (at 64 Hz, about one attempt a second).
const SELECTIVE_BACKOFF_MAX: u32 = 64;

impl Session {
    /// A session starting from `world`.
    pub fn new(world: World, plan: Plan, cfg: RollbackConfig) -> Session {
        let capacity = cfg.window_ticks.max(1) as usize;
        Session {
            stepper: Stepper::new(plan, true),
            world,
            history: History::new(capacity),
            future: BTreeMap::new(),
            inputs_hint: 0,
            system: Vec::new(),
            windows: BTreeMap::new(),
            fresh: BTreeSet::new(),
            dirty_from: None,
            cfg,
            out: TickOutput::default(),
            stats: RollbackStats::default(),
            planted_desync: false,
            selective_backoff: 0,
            selective_failures: 0,
        }
    }

    /// A selective re-simulation unless recent attempts failed: after `k` failures in a row the
    /// next `min(2^k, 64)` rollbacks go straight to the full re-simulation.
    fn try_selective(&mut self, from: Tick, adv: &mut Advance) -> bool {
        if self.selective_backoff > 0 {
            self.selective_backoff -= 1;
            return false;
        }
        self.stats.selective_attempts += 1;
        if selective::resimulate(self, from, adv) {
            self.selective_failures = 0;
            true
        } else {
            self.selective_failures = self.selective_failures.saturating_add(1);
            self.selective_backoff =
                1u32.checked_shl(self.selective_failures).unwrap_or(u32::MAX).min(SELECTIVE_BACKOFF_MAX);
            false
        }
    }

    /// The next tick to simulate.
    pub fn now(&self) -> Tick {
        self.world.tick
    }

    /// The present world (at the start of [`Session::now`]).
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The settings.
    pub fn config(&self) -> &RollbackConfig {
        &self.cfg
    }

    /// The clients with the game-logic role from now on ([`RollbackConfig::logic_clients`]).
    pub fn set_logic_clients(&mut self, clients: impl IntoIterator<Item = ClientId>) {
        self.cfg.logic_clients = clients.into_iter().collect();
    }

    /// Runs the core's parallel stages, re-simulation included, on `pool` (results do not
    /// change).
    pub fn set_pool(&mut self, pool: impact_core::par::Pool) {
        self.stepper.set_pool(pool);
    }

    /// The stepper (its plan, stage statistics and pool).
    pub fn stepper(&self) -> &Stepper {
        &self.stepper
    }

    /// The oldest tick an input may be stamped with now.
    pub fn oldest_accepted(&self) -> Tick {
        self.history.oldest().unwrap_or(self.world.tick)
    }

    /// The newest tick an input may be stamped with now.
    pub fn newest_accepted(&self) -> Tick {
        Tick(self.world.tick.0.saturating_add(self.cfg.lead_ticks))
    }

    /// The history frame of a past tick (its start state, inputs and events), if still held.
    pub fn frame(&self, tick: Tick) -> Option<&Frame> {
        self.history.get(tick)
    }

    /// The history ring.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// Queues a server action for the next tick (avatars joining or leaving).
    pub fn submit_system(&mut self, action: SystemAction) {
        self.system.push(action);
    }

    /// Publishes every tick still in the window as confirmed (the server is stopping: nothing
    /// can change them any more). Oldest first.
    pub fn finish(&mut self) -> Vec<(EventBatch, log::ConfirmedTick)> {
        let mut out = Vec::new();
        let ticks: Vec<Tick> = self.history.iter().map(|f| f.tick).collect();
        for t in ticks {
            let f = self.history.get(t).expect("held");
            let mut events = f.events.clone();
            for e in &mut events {
                e.status = EventStatus::Confirmed;
            }
            let after = self.history.get(t.next()).map_or_else(|| self.world.state_hash(), |n| n.state.state_hash());
            let log =
                log::ConfirmedTick { tick: t, system: f.system.clone(), inputs: f.inputs.clone(), state_hash: after };
            out.push((EventBatch { tick: t, revision: f.revision, events }, log));
        }
        out
    }

    /// Queues a logged tick's server actions and inputs for the present tick, as the log says
    /// they were applied (no window, lead or rate checks: the primary made them), and records the
    /// seqs against replay. The next [`Session::advance`] steps it. `tick` must be the present.
    pub fn follow(&mut self, tick: Tick, system: Vec<SystemAction>, inputs: Vec<TickInput>) -> Result<(), String> {
        if tick < self.world.tick || (tick != self.world.tick && !system.is_empty()) {
            return Err(format!("log tick {} does not follow tick {}", tick.0, self.world.tick.0.wrapping_sub(1)));
        }
        for i in &inputs {
            self.windows.entry(i.client).or_default().accept(i.seq);
        }
        self.future.entry(tick.0).or_default().extend(inputs);
        self.system.extend(system);
        Ok(())
    }

    /// Takes over what another server published for `tick` (a standby taking over: `published`
    /// at `revision` is what clients hold) and returns the correction from it to what this
    /// session simulated, if they differ: clients see a takeover as one more rollback.
    pub fn adopt(&mut self, tick: Tick, published: Vec<CollisionEvent>, revision: u32) -> Vec<CorrectionBatch> {
        let Some(frame) = self.history.get_mut(tick) else { return Vec::new() };
        let simulated = std::mem::replace(&mut frame.events, published);
        frame.revision = revision;
        let mut adv = Advance::default();
        self.publish_resimulated(tick, simulated, &mut adv);
        adv.corrections
    }

    /// The complete state after the last confirmed tick (the start of the oldest tick held),
    /// with every client's replay window: what a standby starts from.
    pub fn checkpoint(&self) -> Result<impact_protocol::Checkpoint, String> {
        let start = self.history.oldest().and_then(|t| self.history.get(t)).map_or(&self.world, |f| &f.state);
        let mut c = log::checkpoint_world(start)?;
        c.clients = self
            .windows
            .iter()
            .map(|(client, w)| {
                let (highest_seq, seq_bits) = w.parts();
                impact_protocol::log::CheckpointClient { client: *client, avatar: None, highest_seq, seq_bits }
            })
            .collect();
        Ok(c)
    }

    /// A session continuing from a checkpoint: `scene` gives the statics and settings.
    pub fn restore(
        scene: &World,
        c: &impact_protocol::Checkpoint,
        plan: Plan,
        cfg: RollbackConfig,
    ) -> Result<Session, String> {
        let world = log::restore_world(scene, c)?;
        let mut s = Session::new(world, plan, cfg);
        for cl in &c.clients {
            let w = seq_window::SeqWindow::from_parts(cl.highest_seq, &cl.seq_bits)
                .ok_or_else(|| format!("client {}'s replay window has {} words", cl.client, cl.seq_bits.len()))?;
            s.windows.insert(cl.client, w);
        }
        Ok(s)
    }

    /// Accepts an input for its tick (or refuses it with a reason the client receives). A past
    /// tick is re-simulated at the next [`Session::advance`]. Returns the tick it will apply at.
    pub fn submit(&mut self, input: ClientInput) -> Result<Tick, Refusal> {
        let now = self.world.tick;
        let oldest = self.oldest_accepted();
        let newest = self.newest_accepted();
        let mut tick = input.tick;
        if tick < oldest {
            match self.cfg.stale {
                StalePolicy::Reject => {
                    return Err(Refusal {
                        oldest_tick: Some(oldest),
                        ..Refusal::new(
                            RejectReason::Stale,
                            format!("tick {} is older than the rollback window (oldest accepted {oldest})", tick.0),
                        )
                    })
                }
                StalePolicy::Clamp => tick = oldest,
            }
        }
        if tick > newest {
            return Err(Refusal {
                newest_tick: Some(newest),
                ..Refusal::new(
                    RejectReason::Future,
                    format!("tick {} is more than {} ticks ahead of the server ({now})", tick.0, self.cfg.lead_ticks),
                )
            });
        }
        let id = (input.client, input.seq);
        let window = self.windows.get(&input.client);
        if let Err(r) = window.map_or(Ok(()), |w| w.check(input.seq)) {
            let detail = match r {
                seq_window::Replay::Seen => {
                    format!("input {} of client {} was already accepted", input.seq, input.client)
                }
                seq_window::Replay::BelowFloor { floor } => format!(
                    "seq {} is at or below {floor}, the floor of client {}'s replay window of {} seqs",
                    input.seq,
                    input.client,
                    seq_window::WINDOW
                ),
            };
            return Err(Refusal::new(RejectReason::Duplicate, detail));
        }
        let logic = self.cfg.logic_clients.contains(&input.client);
        input::check_as(&self.world, input::Sender { client: input.client, logic }, &input.actions)
            .map_err(|(reason, detail)| Refusal::new(reason, detail))?;
        let entry = TickInput {
            view_tick: input.rewind_tick(),
            logic,
            ..TickInput::new(input.client, input.seq, input.actions)
        };
        let held = if tick < now {
            &mut self.history.get_mut(tick).expect("ticks in [oldest, now) are in the history").inputs
        } else {
            let room = self.inputs_hint + self.inputs_hint / 4;
            self.future.entry(tick.0).or_insert_with(|| Vec::with_capacity(room.min(self.cfg.max_inputs_per_tick)))
        };
        if held.len() >= self.cfg.max_inputs_per_tick {
            return Err(Refusal::new(
                RejectReason::QueueFull,
                format!("tick {} already holds {} inputs", tick.0, held.len()),
            ));
        }
        held.push(entry);
        if tick < now {
            self.dirty_from = Some(self.dirty_from.map_or(tick, |d| d.min(tick)));
        }
        self.windows.entry(input.client).or_default().accept(input.seq);
        self.fresh.insert(id);
        Ok(tick)
    }

    /// Simulates the next tick, after re-simulating from the earliest tick that received a late
    /// input since the last call.
    pub fn advance(&mut self) -> Advance {
        let mut adv = Advance::default();
        if let Some(from) = self.dirty_from.take() {
            adv.rollback_depth = self.now().0 - from.0;
            self.stats.rollbacks += 1;
            self.stats.depth_max = self.stats.depth_max.max(adv.rollback_depth);
            self.stats.resimulated_ticks += u64::from(adv.rollback_depth);
            let started = std::time::Instant::now();
            let done = self.cfg.selective && self.try_selective(from, &mut adv);
            if done {
                self.stats.selective_rollbacks += 1;
            } else {
                self.resimulate(from, &mut adv);
            }
            self.stats.last_rollback = started.elapsed();
            self.stats.corrections += adv.corrections.len() as u64;
        } else if self.cfg.self_check_ticks > 0 {
            self.self_check();
        }

        // The present tick.
        let tick = self.world.tick;
        let mut inputs = self.future.remove(&tick.0).unwrap_or_default();
        self.inputs_hint = inputs.len();
        let history = &self.history;
        hitscan::rewind_rays(
            tick,
            &mut inputs,
            self.world.config.max_rewind_ticks,
            history.oldest().unwrap_or(tick),
            None,
            &self.world,
            |t| history.get(t).map(|f| (&f.state, f.ray_index())),
        );
        let system = std::mem::take(&mut self.system);
        let snap = std::time::Instant::now();
        let state = self.world.clone();
        self.stats.snapshot_time += snap.elapsed();
        self.stats.ticks += 1;
        let caps = self.stepper.stats.resolution_cap_hits;
        self.stepper.step_with(&mut self.world, &system, &inputs, &mut self.out);
        let capped = self.stepper.stats.resolution_cap_hits != caps;
        adv.spawned.append(&mut self.out.spawned);
        let paths = if self.cfg.selective { self.stepper.last_paths().to_vec() } else { Vec::new() };
        adv.tick = tick;
        adv.events = self.out.events.clone();
        // The present tick is simulated for the first time: every ray in it is answered now,
        // those of inputs that arrived early (ahead) included, not only the fresh ones.
        adv.rays.append(&mut self.out.rays);
        adv.skipped.append(&mut self.out.skipped);
        let resolutions = self.stepper.stats.resolutions;
        let frame =
            Frame { inputs, system, events: adv.events.clone(), paths, capped, resolutions, ..Frame::at(tick, state) };
        if let Some(old) = self.history.push(frame) {
            // The state after the confirmed tick is the start of the oldest tick still held.
            let after = self.history.oldest().and_then(|t| self.history.get(t)).map_or(0, |f| f.state.state_hash());
            adv.log =
                Some(log::ConfirmedTick { tick: old.tick, system: old.system, inputs: old.inputs, state_hash: after });
            let mut events = old.events;
            for e in &mut events {
                e.status = EventStatus::Confirmed;
            }
            adv.confirmed = Some(EventBatch { tick: old.tick, revision: old.revision, events });
        }
        self.fresh.clear();
        adv
    }

    /// Ray results of a re-simulated tick, for inputs accepted since the last advance (late
    /// ones: older ones were answered when first simulated; a re-simulation changes their hits
    /// through event corrections).
    fn take_rays(&mut self, adv: &mut Advance) {
        for r in self.out.rays.drain(..) {
            if self.fresh.contains(&(r.client, r.seq)) {
                adv.rays.push(r);
            }
        }
    }

    /// Full re-simulation from `from` to the present.
    fn resimulate(&mut self, from: Tick, adv: &mut Advance) {
        let now = self.world.tick;
        let mut w = self.history.get(from).expect("rollback start is in the history").state.clone();
        for k in from.0..now.0 {
            let tick = Tick(k);
            // Rays rewound to a view tick see that tick as this re-simulation left it (those
            // looking before `from` see what they saw).
            let mut inputs = std::mem::take(&mut self.history.get_mut(tick).expect("held").inputs);
            let history = &self.history;
            let oldest = history.oldest().unwrap_or(tick);
            let max_rewind = w.config.max_rewind_ticks;
            hitscan::rewind_rays(tick, &mut inputs, max_rewind, oldest, Some(from), &w, |t| {
                history.get(t).map(|f| (&f.state, f.ray_index()))
            });
            self.history.get_mut(tick).expect("held").inputs = inputs;
            let frame = self.history.get(tick).expect("ticks in the window are held");
            let caps = self.stepper.stats.resolution_cap_hits;
            self.stepper.step_with(&mut w, &frame.system, &frame.inputs, &mut self.out);
            self.out.spawned.clear();
            let capped = self.stepper.stats.resolution_cap_hits != caps;
            let selective = self.cfg.selective;
            let resolutions = self.stepper.stats.resolutions;
            let frame = self.history.get_mut(tick).expect("held");
            frame.capped = capped;
            frame.resolutions = resolutions;
            if selective {
                let paths = frame.paths_mut();
                paths.clear();
                paths.extend_from_slice(self.stepper.last_paths());
            }
            let events = std::mem::take(&mut self.out.events);
            self.take_rays(adv);
            adv.skipped.append(&mut self.out.skipped);
            self.publish_resimulated(tick, events, adv);
            if k + 1 < now.0 {
                *self.history.get_mut(Tick(k + 1)).expect("held").state_mut() = w.clone();
            }
        }
        self.world = w;
    }

    /// Records a re-simulated tick's events, publishing a correction if they changed.
    pub(crate) fn publish_resimulated(&mut self, tick: Tick, mut events: Vec<CollisionEvent>, adv: &mut Advance) {
        let frame = self.history.get_mut(tick).expect("held");
        let d = reconcile::diff(&frame.events, &events);
        if d.is_empty() {
            return;
        }
        frame.revision += 1;
        let changed: BTreeSet<_> = d.amended.iter().chain(&d.added).map(CollisionEvent::key).collect();
        let before: BTreeMap<_, _> = frame.events.iter().map(|e| (e.key(), e.status)).collect();
        for e in &mut events {
            e.status = if changed.contains(&e.key()) {
                EventStatus::Corrected
            } else {
                before.get(&e.key()).copied().unwrap_or(EventStatus::Provisional)
            };
        }
        let mark = |mut v: Vec<CollisionEvent>| {
            for e in &mut v {
                e.status = EventStatus::Corrected;
            }
            v
        };
        adv.corrections.push(CorrectionBatch {
            tick,
            revision: frame.revision,
            retracted: d.retracted,
            amended: mark(d.amended),
            added: mark(d.added),
        });
        frame.events = events;
    }

    /// Self-check: re-simulate the last ticks with nothing changed and require the same states
    /// and events, bit for bit.
    fn self_check(&mut self) {
        let now = self.world.tick.0;
        let from = now.saturating_sub(self.cfg.self_check_ticks).max(self.oldest_accepted().0);
        if from >= now {
            return;
        }
        self.stats.self_checks += 1;
        let mut w = self.history.get(Tick(from)).expect("held").state.clone();
        if self.planted_desync {
            // The planted fault for the negative test: one ulp on one body.
            if let Some(v) = w.bodies.vel.first_mut() {
                v.x = f64::from_bits(v.x.to_bits() ^ 1);
            }
        }
        let mut ok = true;
        for k in from..now {
            let frame = self.history.get(Tick(k)).expect("held");
            self.stepper.step_with(&mut w, &frame.system, &frame.inputs, &mut self.out);
            if !reconcile::diff(&frame.events, &self.out.events).is_empty() {
                ok = false;
            }
            let expect = if k + 1 < now {
                self.history.get(Tick(k + 1)).map(|f| f.state.state_hash())
            } else {
                Some(self.world.state_hash())
            };
            if Some(w.state_hash()) != expect {
                ok = false;
            }
        }
        self.out.rays.clear();
        self.out.skipped.clear();
        if !ok {
            self.stats.desyncs += 1;
        }
    }

    /// Plants a non-determinism in the next self-checks (tests only: proves the check catches
    /// one).
    #[doc(hidden)]
    pub fn plant_desync(&mut self) {
        self.planted_desync = true;
    }

    /// Clients with a replay window (each a fixed size; one per client until forgotten).
    pub fn replay_windows(&self) -> usize {
        self.windows.len()
    }

    /// The lowest seq `client` may send next (0 for a client never seen).
    pub fn next_seq(&self, client: ClientId) -> u32 {
        self.windows.get(&client).map_or(0, seq_window::SeqWindow::next_seq)
    }

    /// Which of `client`'s 64 seqs below `seq` were accepted: bit `k` is seq `seq - 1 - k`
    /// (an ack carries it, so a lost ack is recovered from the next).
    pub fn accepted_before(&self, client: ClientId, seq: u32) -> u64 {
        self.windows.get(&client).map_or(0, |w| w.accepted_before(seq))
    }

    /// Whether `seq` of `client` was accepted already (and is still told apart by its replay
    /// window): a repeat the runtime skips without an answer, as the redundant copies in an
    /// input batch are. A seq below the window's floor is not a repeat: [`Session::submit`]
    /// refuses it as a duplicate, since the window can no longer tell.
    pub fn already_accepted(&self, client: ClientId, seq: u32) -> bool {
        self.windows.get(&client).is_some_and(|w| w.check(seq) == Err(seq_window::Replay::Seen))
    }

    /// Drops `client`'s replay window: the runtime calls it when the client's presence is over
    /// (left, and the grace period passed). A client that returns later starts from seq 0.
    pub fn forget_client(&mut self, client: ClientId) {
        self.windows.remove(&client);
    }

    /// Ticks holding future inputs (bounded by the lead).
    pub fn future_ticks(&self) -> usize {
        self.future.len()
    }
}
