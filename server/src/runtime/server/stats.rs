//! What the tick loop reports: the stats message once a second and the Prometheus series.

use super::{ServerMessage, TickLoop, Totals};
use impact_protocol::{keys, RejectReason, ServerStats};
use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::time::Duration;

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() as f64 - 1.0) * q).round() as usize]
}

impl TickLoop {
    /// Inputs rejected since start, by reason: the tick thread's count and the callbacks'.
    fn rejected(&self) -> BTreeMap<String, u64> {
        let mut rejected = self.summary.inputs_rejected.clone();
        for (k, r) in RejectReason::ALL.iter().enumerate() {
            let n = self.shared.rejected_in_callbacks[k].load(Ordering::Relaxed);
            if n > 0 {
                *rejected.entry(r.name().to_string()).or_insert(0) += n;
            }
        }
        rejected
    }

    /// Publishes the stats message and brings the metrics up to date (once a second).
    pub(super) fn publish_stats(&mut self) {
        let mut times = std::mem::take(&mut self.tick_times);
        let tick_ms: Vec<f32> = times.iter().map(|&t| t as f32).collect();
        times.sort_by(f64::total_cmp);
        let w = self.session.world();
        let rejected = self.rejected();
        // Mean time per core step of each stage since the last message.
        let core = &self.session.stepper().stats;
        let stages = core.stages();
        let (last_steps, last) = &self.last_stages;
        let steps = core.ticks.saturating_sub(*last_steps).max(1) as f64;
        let stage_ms = stages
            .iter()
            .enumerate()
            .map(|(k, (n, d))| {
                let before = last.get(k).copied().unwrap_or_default();
                (n.to_string(), d.saturating_sub(before).as_secs_f64() * 1e3 / steps)
            })
            .collect();
        let present = self.clients.values().filter(|c| c.present).count();
        let stats = ServerStats {
            tick: w.tick,
            tick_ms_p50: percentile(&times, 0.5),
            tick_ms_p99: percentile(&times, 0.99),
            tick_ms_max: times.last().copied().unwrap_or(0.0),
            overruns: self.summary.overruns,
            bodies: w.bodies.len() as u32,
            pairs_tested: core.pairs_tested,
            rollbacks: self.period_rollbacks,
            rollback_depth_max: self.period_depth,
            inputs_accepted: self.summary.inputs_accepted,
            inputs_rejected: rejected.clone(),
            inputs_repeated: self.summary.inputs_repeated,
            events_per_s: self.period_events as f64,
            queue_depth_max: self.period_queue_max,
            tick_ms,
            stage_ms,
            clients: present as u32,
        };
        let (awake, asleep) = w.awake_asleep();
        if self.opts.verbose {
            eprintln!(
                "  tick {} | tick ms p50 {:.3} p99 {:.3} | bodies {} ({} awake, {} asleep) | clients {} | inputs {} | rollbacks {} (depth {}) | events/s {}",
                stats.tick, stats.tick_ms_p50, stats.tick_ms_p99, stats.bodies, awake, asleep, self.clients.len(), stats.inputs_accepted, stats.rollbacks, stats.rollback_depth_max, stats.events_per_s
            );
        }
        let stage_s: Vec<(&'static str, f64)> = stages.iter().map(|(n, d)| (*n, d.as_secs_f64())).collect();
        self.last_stages = (core.ticks, stages.iter().map(|(_, d)| *d).collect::<Vec<Duration>>());
        if let Some(m) = self.metrics.as_mut() {
            let c = &self.state_counters;
            let load = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
            m.gauges(present, awake, asleep, self.period_queue_max);
            m.sync(&Totals {
                overruns: self.summary.overruns,
                stage_s,
                steps: core.ticks,
                accepted: self.summary.inputs_accepted,
                rejected,
                events: self.summary.events,
                confirmed: self.summary.confirmed_events,
                corrections: self.summary.corrections,
                egress_dropped: self.shared.egress_dropped.load(Ordering::Relaxed),
                state_bytes: [load(&c.world_bytes), load(&c.client_bytes)],
                state_frames: [load(&c.world_frames), load(&c.client_frames)],
                state_deferred: load(&c.deferred),
                state_skipped: load(&c.skipped),
            });
        }
        self.put(keys::STATS.key(&self.world, None), ServerMessage::Stats(stats), self.opts.encoding);
        self.period_events = 0;
        self.period_rollbacks = 0;
        self.period_depth = 0;
        self.period_queue_max = 0;
    }
}
