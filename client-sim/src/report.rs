//! The load test's report: a human summary, a JSON document, and an SVG histogram of latency.

use serde::Serialize;
use std::collections::BTreeMap;

/// Everything a load run measured.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Report {
    /// Simulated clients.
    pub clients: u32,
    /// Zenoh sessions they shared.
    pub sessions: u32,
    /// Seconds of load.
    pub duration_s: f64,
    /// Clients that were welcomed with an avatar.
    pub clients_welcomed: u32,
    /// Inputs the clients produced.
    pub inputs_sent: u64,
    /// Inputs dropped by the simulated uplink loss.
    pub inputs_lost_in_network: u64,
    /// Inputs delivered to the server.
    pub inputs_delivered: u64,
    /// Acks received.
    pub acks: u64,
    /// Rejects received, by reason.
    pub rejects: BTreeMap<String, u64>,
    /// Inputs delivered but neither acked nor rejected (should be 0 once settled).
    pub inputs_unanswered: u64,
    /// Inputs delivered a second time (the fault `duplicate`).
    pub inputs_duplicated: u64,
    /// Answers for which no delivery was owed (an input answered twice), and, while duplicates
    /// are injected, second acks of one seq (a duplicate accepted). Should be 0.
    pub answers_unexpected: u64,
    /// Times the server process was stalled (SIGSTOP) by the fault injection.
    pub server_stalls: u64,
    /// Input to ack latency, ms: median (round trip through the simulated network and the tick).
    pub latency_ms_p50: f64,
    /// 99th percentile, ms.
    pub latency_ms_p99: f64,
    /// Maximum, ms.
    pub latency_ms_max: f64,
    /// Events received on the clients' own streams.
    pub events_received: u64,
    /// Per second, over the load.
    pub events_per_s: f64,
    /// Correction batches received.
    pub corrections: u64,
    /// Per second.
    pub corrections_per_s: f64,
    /// How far back corrections reached, ticks: median.
    pub correction_depth_p50: f64,
    /// Deepest correction, ticks.
    pub correction_depth_max: f64,
    /// 99th percentile, ticks.
    pub correction_depth_p99: f64,
    /// Confirmed ticks whose client view equalled the confirmed stream.
    pub views_matched: u64,
    /// Confirmed ticks whose view did not.
    pub views_mismatched: u64,
    /// The server's tick time over the load, ms: percentiles of every tick its stats messages
    /// reported while the clients ran.
    pub server_tick_ms_p50: f64,
    /// 99th percentile.
    pub server_tick_ms_p99: f64,
    /// Longest.
    pub server_tick_ms_max: f64,
    /// Ticks those percentiles are over.
    pub server_ticks_measured: u64,
    /// State stream frames the clients received over the load (`--state`).
    pub state_frames: u64,
    /// State stream bytes per client per second over the load (`--state`).
    pub state_bytes_per_client_s: f64,
    /// The server's last reported overruns.
    pub server_overruns: u64,
    /// Rollbacks the server reported over the load.
    pub server_rollbacks: u64,
    /// Per second.
    pub server_rollbacks_per_s: f64,
    /// The deepest the server's ingress queue got over the run (from its stats).
    pub server_queue_depth_max: u32,
    /// The deepest rollback the server reported over the load, ticks.
    pub server_rollback_depth_max: u32,
    /// Times a client's tick clock was re-anchored because the server's batches showed it more
    /// than [`impact_client::clock::RESYNC_TICKS`] off (the server stalled, or dropped a backlog).
    pub clock_resyncs: u64,
    /// How the clients stamped their inputs.
    pub timing: Option<crate::timing::Timing>,
    /// Arrival margin over every acked input, ticks (`applied_tick - server_tick`: negative is
    /// late): 1st percentile.
    pub margin_ticks_p1: i32,
    /// Median.
    pub margin_ticks_p50: i32,
    /// 99th percentile.
    pub margin_ticks_p99: i32,
    /// Acked inputs that arrived late, each a rollback on the server.
    pub rollbacks_caused: u64,
    /// Per second of load.
    pub rollbacks_caused_per_s: f64,
    /// The same per client.
    pub per_client: Vec<ClientTiming>,
    /// Latency histogram: `(upper bound ms, count)` per 5 ms bucket.
    pub latency_histogram: Vec<(f64, u64)>,
}

/// One client's timing figures.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ClientTiming {
    /// The client id.
    pub client: u32,
    /// Arrival margin, ticks: 1st percentile.
    pub margin_ticks_p1: i32,
    /// Median.
    pub margin_ticks_p50: i32,
    /// 99th percentile.
    pub margin_ticks_p99: i32,
    /// Its inputs that arrived late.
    pub rollbacks_caused: u64,
    /// Correction batches it received.
    pub corrections: u64,
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "impact-sim: {} clients over {} sessions for {:.1} s ({} welcomed)",
            self.clients, self.sessions, self.duration_s, self.clients_welcomed
        )?;
        writeln!(
            f,
            "  inputs   sent {} | lost in the network {} | delivered {} ({} twice) | acked {} | unanswered {} | answered unexpectedly {}",
            self.inputs_sent, self.inputs_lost_in_network, self.inputs_delivered, self.inputs_duplicated, self.acks, self.inputs_unanswered, self.answers_unexpected
        )?;
        let rejects: Vec<String> = self.rejects.iter().map(|(k, v)| format!("{k} {v}")).collect();
        writeln!(f, "  rejects  {}", if rejects.is_empty() { "none".into() } else { rejects.join(", ") })?;
        writeln!(
            f,
            "  latency  input -> ack  p50 {:.1} ms  p99 {:.1} ms  max {:.1} ms",
            self.latency_ms_p50, self.latency_ms_p99, self.latency_ms_max
        )?;
        writeln!(
            f,
            "  events   {} ({:.0}/s) | corrections {} ({:.1}/s), depth p50 {:.0} p99 {:.0} max {:.0} ticks",
            self.events_received,
            self.events_per_s,
            self.corrections,
            self.corrections_per_s,
            self.correction_depth_p50,
            self.correction_depth_p99,
            self.correction_depth_max
        )?;
        let timing = match self.timing {
            Some(crate::timing::Timing::Ahead) => "ahead",
            Some(crate::timing::Timing::Behind) => "behind",
            None => "-",
        };
        writeln!(
            f,
            "  timing   {timing} | arrival margin p1 {} p50 {} p99 {} ticks | late (rollbacks caused) {} ({:.1}/s)",
            self.margin_ticks_p1,
            self.margin_ticks_p50,
            self.margin_ticks_p99,
            self.rollbacks_caused,
            self.rollbacks_caused_per_s
        )?;
        if let Some(worst) = self.per_client.iter().max_by_key(|c| (c.rollbacks_caused, std::cmp::Reverse(c.client))) {
            writeln!(
                f,
                "           per client (--report has each): most late: client {} with {}, margin p1 {} p50 {} p99 {}, {} corrections",
                worst.client,
                worst.rollbacks_caused,
                worst.margin_ticks_p1,
                worst.margin_ticks_p50,
                worst.margin_ticks_p99,
                worst.corrections
            )?;
        }
        writeln!(f, "  views    {} confirmed ticks matched, {} differed", self.views_matched, self.views_mismatched)?;
        if self.state_frames > 0 {
            writeln!(
                f,
                "  state    {} frames, {:.0} bytes per client per second",
                self.state_frames, self.state_bytes_per_client_s
            )?;
        }
        write!(
            f,
            "  server   under load: tick p50 {:.3} p99 {:.3} max {:.3} ms over {} ticks, rollbacks {:.1}/s \
             (deepest {}) | overruns {} | client clocks resynced {}",
            self.server_tick_ms_p50,
            self.server_tick_ms_p99,
            self.server_tick_ms_max,
            self.server_ticks_measured,
            self.server_rollbacks_per_s,
            self.server_rollback_depth_max,
            self.server_overruns,
            self.clock_resyncs
        )
    }
}

/// The latency histogram as an SVG bar chart.
pub fn latency_svg(r: &Report) -> String {
    let (w, h, l, b, t) = (640.0, 360.0, 60.0, 50.0, 40.0);
    let max = r.latency_histogram.iter().map(|x| x.1).max().unwrap_or(1).max(1) as f64;
    let n = r.latency_histogram.len().max(1) as f64;
    let bw = (w - l - 20.0) / n;
    let mut s = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="{w}" height="{h}" fill="white"/>"#
    );
    s += &format!(
        r#"<text x="{}" y="22" font-size="15" text-anchor="middle">input to ack latency, {} clients (p50 {:.1} ms, p99 {:.1} ms)</text>"#,
        w / 2.0,
        r.clients,
        r.latency_ms_p50,
        r.latency_ms_p99
    );
    for (k, (upper, count)) in r.latency_histogram.iter().enumerate() {
        let bh = (*count as f64 / max) * (h - t - b);
        let x = l + k as f64 * bw;
        s += &format!(
            r##"<rect x="{x:.1}" y="{:.1}" width="{:.1}" height="{bh:.1}" fill="#1f77b4"/>"##,
            h - b - bh,
            (bw - 1.0).max(0.5)
        );
        if k % (r.latency_histogram.len() / 8).max(1) == 0 {
            s += &format!(r#"<text x="{x:.1}" y="{}" text-anchor="middle">{upper:.0}</text>"#, h - b + 16.0);
        }
    }
    s += &format!(r#"<text x="{}" y="{}" text-anchor="middle">ms</text>"#, l + (w - l) / 2.0, h - 12.0);
    s += &format!(
        r#"<text x="16" y="{}" transform="rotate(-90 16 {})" text-anchor="middle">inputs</text></svg>"#,
        h / 2.0,
        h / 2.0
    );
    s + "\n"
}
