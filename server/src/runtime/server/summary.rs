//! What a run did: the summary a world prints when it stops.

use impact_protocol::Tick;
use std::collections::BTreeMap;

/// What a run did, printed at shutdown.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Ticks simulated.
    pub ticks: u64,
    /// Ticks that missed their deadline.
    pub overruns: u64,
    /// Longest tick, ms.
    pub tick_ms_max: f64,
    /// Median tick, ms (over the whole run).
    pub tick_ms_p50: f64,
    /// Mean tick, ms.
    pub tick_ms_mean: f64,
    /// 99th percentile tick, ms.
    pub tick_ms_p99: f64,
    /// What the tick thread itself spent on its ticks and waited for a core (`None` where the
    /// system does not count them): the server's cost apart from the machine's.
    pub tick_thread: Option<TickThread>,
    /// Inputs accepted.
    pub inputs_accepted: u64,
    /// Inputs rejected, by reason.
    pub inputs_rejected: BTreeMap<String, u64>,
    /// Inputs skipped as repeats of accepted ones (redundant copies, resends).
    pub inputs_repeated: u64,
    /// Inputs that reached the tick thread but were dropped inside the server (never: kept to
    /// prove it).
    pub inputs_lost: u64,
    /// Events published (provisional).
    pub events: u64,
    /// Events confirmed.
    pub confirmed_events: u64,
    /// Correction batches published.
    pub corrections: u64,
    /// Messages the egress queue had to drop.
    pub egress_dropped: u64,
    /// Rollbacks and the deepest.
    pub rollbacks: u64,
    /// Rollbacks done selectively (`--resimulate selective`): only what the late inputs could
    /// reach.
    pub selective_rollbacks: u64,
    /// Deepest rollback, ticks.
    pub rollback_depth_max: u32,
    /// Median rollback depth, ticks (over the ticks that rolled back).
    pub rollback_depth_p50: u32,
    /// 99th percentile rollback depth, ticks.
    pub rollback_depth_p99: u32,
    /// Core steps run (ticks and their re-simulations) and the mean time of each stage per
    /// step, ms, in tick order: what the core costs beside what the runtime around it does.
    pub core_steps: u64,
    /// `(stage, mean ms per step)`.
    pub core_stage_ms: Vec<(&'static str, f64)>,
    /// Clients seen.
    pub clients: u64,
    /// Seconds from the start of the first tick to the end of the last (shutdown excluded).
    pub run_s: f64,
    /// As a standby: confirmed ticks followed from the primary's log, and those whose state
    /// hash differed from the log's (never, unless the two processes run different scenes).
    pub followed_ticks: u64,
    /// Followed ticks whose hash differed.
    pub desyncs: u64,
    /// As a standby that took over: the tick it took over at and the ticks it re-simulated from
    /// the last confirmed one (acked inputs re-applied).
    pub promoted_at: Option<Tick>,
    /// Another server took the world over (its epoch): this one stopped publishing and ended it.
    pub fenced_by: Option<impact_protocol::Epoch>,
    /// Time spent holding every publication after the process stood still for longer than its
    /// lease, ms.
    pub held_ms: f64,
    /// Ticks re-simulated at the takeover.
    pub caught_up_ticks: u32,
    /// Acked inputs re-applied at the takeover.
    pub reapplied_inputs: u64,
    /// State streams: frames on client streams.
    pub state_client_frames: u64,
    /// Bytes on client streams.
    pub state_client_bytes: u64,
    /// Bytes on the world stream.
    pub state_world_bytes: u64,
    /// Client-seconds served by the client streams (each frame counts 1/hz s of a listening
    /// client).
    pub state_client_s: f64,
    /// Seconds the state thread spent building, encoding and publishing.
    pub state_busy_s: f64,
    /// Seconds the state thread waited for ticks under way to end.
    pub state_waited_s: f64,
    /// Seconds the tick thread spent copying the state for it.
    pub state_capture_s: f64,
    /// Captures skipped because the state thread was busy.
    pub state_skipped: u64,
}

/// The tick thread's CPU time per tick and its wait for a core, from the scheduler's own
/// counts: a tick's wall time is its CPU time, plus the wait, plus any blocking. A wall-time p99
/// well above the CPU time's is the machine (other processes or threads on the tick's core), not
/// the server's work.
#[derive(Clone, Debug, Default)]
pub struct TickThread {
    /// Median CPU time of a tick, ms.
    pub cpu_ms_p50: f64,
    /// 99th percentile CPU time of a tick, ms.
    pub cpu_ms_p99: f64,
    /// Longest CPU time of a tick, ms.
    pub cpu_ms_max: f64,
    /// 99th percentile of a tick's wait for a core, ms.
    pub wait_ms_p99: f64,
    /// Longest wait for a core in one tick, ms.
    pub wait_ms_max: f64,
    /// Ticks that waited 1 ms or more for a core.
    pub waited_over_1ms: u64,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "ticks {} (overruns {}), tick ms p50 {:.3} p99 {:.3} max {:.3}",
            self.ticks, self.overruns, self.tick_ms_p50, self.tick_ms_p99, self.tick_ms_max
        )?;
        if let Some(t) = &self.tick_thread {
            writeln!(
                f,
                "tick thread: cpu ms p50 {:.3} p99 {:.3} max {:.3}; waited for a core p99 {:.3} max {:.3} ms ({} ticks 1 ms or more)",
                t.cpu_ms_p50, t.cpu_ms_p99, t.cpu_ms_max, t.wait_ms_p99, t.wait_ms_max, t.waited_over_1ms
            )?;
        }
        writeln!(
            f,
            "clients {}, inputs accepted {} (repeats skipped {}), lost inside the server {}",
            self.clients, self.inputs_accepted, self.inputs_repeated, self.inputs_lost
        )?;
        let rejected: Vec<String> = self.inputs_rejected.iter().map(|(k, v)| format!("{k} {v}")).collect();
        writeln!(f, "inputs rejected: {}", if rejected.is_empty() { "none".into() } else { rejected.join(", ") })?;
        writeln!(
            f,
            "events {}, correction batches {}, rollbacks {} ({:.1}/s; depth p50 {} p99 {} max {} ticks)",
            self.events,
            self.corrections,
            self.rollbacks,
            self.rollbacks as f64 / self.run_s.max(1e-9),
            self.rollback_depth_p50,
            self.rollback_depth_p99,
            self.rollback_depth_max
        )?;
        if self.selective_rollbacks > 0 {
            writeln!(f, "selective rollbacks {} of {}", self.selective_rollbacks, self.rollbacks)?;
        }
        if self.core_steps > 0 {
            let stages: Vec<String> = self.core_stage_ms.iter().map(|(n, ms)| format!("{n} {ms:.3}")).collect();
            let total: f64 = self.core_stage_ms.iter().map(|(_, ms)| ms).sum();
            writeln!(
                f,
                "core: {} steps for {} ticks, {:.3} ms per step ({})",
                self.core_steps,
                self.ticks,
                total,
                stages.join(", ")
            )?;
        }
        if self.followed_ticks > 0 || self.promoted_at.is_some() {
            writeln!(
                f,
                "standby: followed {} confirmed ticks ({} hashes differed)",
                self.followed_ticks, self.desyncs
            )?;
        }
        if let Some(t) = self.promoted_at {
            writeln!(
                f,
                "took over at tick {} ({} ticks re-simulated from the last confirmed one, {} acked inputs re-applied)",
                t.0, self.caught_up_ticks, self.reapplied_inputs
            )?;
        }
        if self.held_ms > 0.0 {
            writeln!(f, "held every message for {:.0} ms after standing still longer than the lease", self.held_ms)?;
        }
        if let Some(e) = self.fenced_by {
            writeln!(f, "fenced: another server owns the world at epoch {e}; this one stopped publishing")?;
        }
        if self.state_client_frames > 0 || self.state_world_bytes > 0 {
            let tick_s = self.tick_ms_mean * self.ticks as f64 / 1e3;
            writeln!(
                f,
                "state streams: {:.0} bytes per client per second ({} client frames), world stream {:.0} bytes/s; \
                 state thread {:.1} % of a core (and {:.1} % of the time waiting for ticks to end), copying {:.2} % \
                 of tick time, {} captures skipped",
                self.state_client_bytes as f64 / self.state_client_s.max(1e-9),
                self.state_client_frames,
                self.state_world_bytes as f64 / self.run_s.max(1e-9),
                100.0 * self.state_busy_s / self.run_s.max(1e-9),
                100.0 * self.state_waited_s / self.run_s.max(1e-9),
                100.0 * self.state_capture_s / tick_s.max(1e-9),
                self.state_skipped
            )?;
        }
        write!(f, "egress messages dropped {}", self.egress_dropped)
    }
}
