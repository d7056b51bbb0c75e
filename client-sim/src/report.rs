//! The load test's report: a human summary, a JSON document, and an SVG histogram of latency.

use serde::Serialize;
use std::collections::BTreeMap;

/// Answers not owed that a report describes one by one.
pub const UNEXPECTED_KEPT: usize = 8;

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
    /// Presence declarations repeated because a client's welcome had not come within
    /// `impact_client::transport::WELCOME_WAIT` (doubling).
    pub presence_repeats: u64,
    /// Inputs the clients produced (their sessions' keepalives included).
    pub inputs_sent: u64,
    /// Of them, inputs of no actions the sessions sent while the game's awaited answers
    /// (`impact_client::session::KEEPALIVE_AFTER`).
    pub keepalives: u64,
    /// Inputs none of whose copies reached the server (the simulated uplink loss took every
    /// message that carried them).
    pub inputs_lost_in_network: u64,
    /// Messages the simulated uplink loss dropped (each input rides in up to four).
    pub messages_lost_in_network: u64,
    /// Inputs delivered to the server (each counted once, however many copies arrived).
    pub inputs_delivered: u64,
    /// Copies of unanswered inputs sent again in later messages (redundancy against loss).
    pub input_copies_sent: u64,
    /// Inputs acked (those whose ack was lost and a later ack told included).
    pub acks: u64,
    /// Of them, inputs whose own ack was lost on the way and a later ack told accepted.
    pub acks_recovered: u64,
    /// Rejects received, by reason.
    pub rejects: BTreeMap<String, u64>,
    /// Inputs delivered but neither acked nor rejected (should be 0 once settled).
    pub inputs_unanswered: u64,
    /// Of the unanswered deliveries, the inputs their clients still await an answer for (the
    /// rest are copies of inputs that were answered: a rejected input owes an answer per copy,
    /// and a copy that died with a link never gets one).
    pub inputs_awaited: u64,
    /// Inputs the client library answered itself as lost at a reconnect: sent while the link
    /// was down, never accepted (`Outcome::Lost`).
    pub inputs_known_lost: u64,
    /// Inputs whose answers were lost with a link and a later welcome's `next_seq` told answered
    /// (accepted, refused or never heard: the next ack tells the client which).
    pub answered_by_welcome: u64,
    /// Inputs a world that closed never answered (void with it: PROTOCOL.md, "Worlds at run
    /// time").
    pub inputs_void_at_close: u64,
    /// Times the players followed a closed world to the next one game logic named.
    pub worlds_followed: u32,
    /// Messages delivered a second time (the fault `duplicate`).
    pub inputs_duplicated: u64,
    /// Answers for which no delivery was owed, and second acks of one seq (an input applied
    /// twice). Should be 0.
    pub answers_unexpected: u64,
    /// The first [`UNEXPECTED_KEPT`] of those, each told: when, which client and seq, what the
    /// answer said and what the client held of that seq then.
    pub unexpected: Vec<String>,
    /// Returning clients none of whose inputs after was accepted (the first
    /// [`UNEXPECTED_KEPT`]), each told.
    pub unresumed: Vec<String>,
    /// Returning drawing clients no full state frame came to after (the first
    /// [`UNEXPECTED_KEPT`]), each told.
    pub unframed: Vec<String>,
    /// Clients whose view of a confirmed tick differed (the first [`UNEXPECTED_KEPT`]), with the
    /// ticks.
    pub views_differed: Vec<String>,
    /// Answers the sessions matched to no input awaiting one (a reject of a copy sent before
    /// the first answer came counts here, and is expected).
    pub unmatched_answers: u64,
    /// Server messages the clients could not decode.
    pub malformed: u64,
    /// Server messages of an older owner than one the client had heard (a primary that resumed
    /// after its standby took over), dropped.
    pub stale_owner: u64,
    /// Server messages on the clients' keys that never arrived, known from a skip in a key's
    /// numbers (`SessionStats::messages_lost`): a skip on a client's events key leaves its ticks
    /// before it uncompared.
    pub messages_lost: u64,
    /// Times a Zenoh session of the load generator had its link back after losing it.
    pub links_restored: u64,
    /// Confirmed ticks not compared with a client's view, because its link was lost before them
    /// (what the server published meanwhile never arrived).
    pub views_unverified: u64,
    /// Sessions of the load generator closed and opened again by the fault injection.
    pub session_drops: u64,
    /// Clients back on a new session after theirs was dropped.
    pub returns: u64,
    /// Of them, welcomed again.
    pub returns_welcomed: u64,
    /// Of them, back well within the server's grace period (a quarter second inside it), having
    /// known an avatar (been welcomed) before they left.
    pub returns_in_grace: u64,
    /// Of those, welcomed to the avatar they had.
    pub returns_kept_avatar: u64,
    /// Returns of game clients (they read their state stream).
    pub returns_drawing: u64,
    /// Of them, given a full state frame after they came back.
    pub returns_full_frame: u64,
    /// Returns after which an input the client sent was accepted: it resumed its sequence.
    pub returns_resumed: u64,
    /// Confirmed batches of a tick a client already held that said something else. Should be 0:
    /// nothing a client saw confirmed changes.
    pub confirmed_changed: u64,
    /// Confirmed batches of a tick a client already held, the same.
    pub confirmed_repeated: u64,
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
    /// Ticks a client held events of when a later confirmation came (its batch missed) whose
    /// batch the server's `query/confirmed` brought back.
    pub views_recovered: u64,
    /// Such ticks given up on (no batch back in time): counted in `views_mismatched` too.
    pub views_given_up: u64,
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
    /// Bytes each client received per second over the load, on all its keys (answers, events,
    /// state).
    pub bytes_down_per_client_s: f64,
    /// Bytes each client's inputs put per second over the load (what reached the server: the
    /// simulated loss took the rest).
    pub bytes_up_per_client_s: f64,
    /// How late the load generator made an input after its client's turn, ms: 99th percentile.
    /// Past a tick (15.6 ms) it did not keep up, and the run measures it as much as the server.
    pub load_lag_ms_p99: f64,
    /// The latest.
    pub load_lag_ms_max: f64,
    /// Messages the load generator's inbox had no room for (it fell behind).
    pub load_inbox_dropped: u64,
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
    /// Of the acked inputs sent in each client's first two seconds of play, the share that
    /// arrived late (the clock had only the sync's estimate then).
    pub late_share_first_2s: Option<f64>,
    /// The same over the inputs sent after.
    pub late_share_steady: Option<f64>,
    /// Acked inputs sent in the first two seconds of play.
    pub acked_first_2s: u64,
    /// Per second of load.
    pub rollbacks_caused_per_s: f64,
    /// The same per client.
    pub per_client: Vec<ClientTiming>,
    /// The game clients' prediction and interpolation (`--predict`).
    #[serde(flatten)]
    pub prediction: Prediction,
    /// Latency histogram: `(upper bound ms, count)` per 5 ms bucket.
    pub latency_histogram: Vec<(f64, u64)>,
}

/// How the game clients' own avatars were predicted and their remote worlds drawn.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Prediction {
    /// Game clients (predicting, drawing).
    pub predicting_clients: u32,
    /// Of them, clients whose prediction stopped (the server runs another scene).
    pub prediction_stopped: u32,
    /// Authoritative avatar states compared with the prediction for their tick.
    pub prediction_states: u64,
    /// ...of which equal to the bit.
    pub prediction_exact: u64,
    /// States that named a teleport by game logic: taken as a jump, not compared.
    pub prediction_teleports: u64,
    /// The share of compared states that were not.
    pub prediction_mispredicted_share: Option<f64>,
    /// Mispredictions by cause (`other_body`, `input_late`, `unexplained`:
    /// `impact_client::session::PredictionStats`).
    pub prediction_causes: BTreeMap<String, u64>,
    /// Predicted minus authoritative position at the same tick, over every compared state, m.
    pub prediction_error_m_p50: Option<f64>,
    /// 99th percentile.
    pub prediction_error_m_p99: Option<f64>,
    /// Largest.
    pub prediction_error_m_max: Option<f64>,
    /// States no other body came near and no input was late for.
    pub prediction_untouched_states: u64,
    /// Their error's 99th percentile, m (the core is deterministic: 0).
    pub prediction_untouched_m_p99: Option<f64>,
    /// Their largest error, m.
    pub prediction_untouched_m_max: Option<f64>,
    /// The furthest a correction's easing moved a drawn avatar in one 60 Hz frame, m.
    pub correction_jump_m_max: f64,
    /// Remote bodies compared with the server's positions at the tick they were drawn at.
    pub interpolation_samples: u64,
    /// Drawn minus the server's position, m: median.
    pub interpolation_error_m_p50: Option<f64>,
    /// 99th percentile.
    pub interpolation_error_m_p99: Option<f64>,
    /// Samples of bodies nothing changed the motion of between the frames they were drawn
    /// between (`DrawnBody::steady`).
    pub interpolation_steady_samples: u64,
    /// Their error's 99th percentile, m (up to the stream's f32).
    pub interpolation_steady_m_p99: Option<f64>,
    /// The others' (a bounce or a push between their frames, drawn on the straight line
    /// between them): 99th percentile, m.
    pub interpolation_changed_m_p99: Option<f64>,
}

/// The `q` quantile of `v` (sorted in place); `None` when empty.
pub fn quantile(v: &mut [f64], q: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[((v.len() as f64 * q).ceil() as usize).clamp(1, v.len()) - 1])
}

impl Prediction {
    /// The prediction figures over the game clients' sessions (interpolation is filled in by
    /// the load, which asks the server).
    pub fn over<'a>(sessions: impl Iterator<Item = &'a impact_client::Session>) -> Prediction {
        let mut p = Prediction::default();
        let (mut all, mut untouched) = (Vec::new(), Vec::new());
        for s in sessions {
            p.predicting_clients += 1;
            p.prediction_stopped += u32::from(s.prediction_problem().is_some());
            let st = s.prediction();
            p.prediction_states += st.compared;
            p.prediction_exact += st.exact;
            p.prediction_teleports += st.teleported;
            for (cause, n) in &st.causes {
                *p.prediction_causes.entry(cause.to_string()).or_insert(0) += n;
            }
            all.extend_from_slice(&st.errors_m);
            untouched.extend_from_slice(&st.errors_untouched_m);
            p.correction_jump_m_max = p.correction_jump_m_max.max(st.max_frame_correction_m);
        }
        p.prediction_mispredicted_share = (p.prediction_states > 0)
            .then(|| (p.prediction_states - p.prediction_exact) as f64 / p.prediction_states as f64);
        p.prediction_error_m_p50 = quantile(&mut all, 0.5);
        p.prediction_error_m_p99 = quantile(&mut all, 0.99);
        p.prediction_error_m_max = all.last().copied();
        p.prediction_untouched_states = untouched.len() as u64;
        p.prediction_untouched_m_p99 = quantile(&mut untouched, 0.99);
        p.prediction_untouched_m_max = untouched.last().copied();
        p
    }
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

impl Report {
    /// Whether the load generator kept up: its inputs at most a tick (15.6 ms at 64 Hz) late at
    /// the 99th percentile, and every message it received had room in its inbox.
    pub fn load_kept_up(&self) -> bool {
        self.load_lag_ms_p99 <= LAG_BOUND_MS && self.load_inbox_dropped == 0
    }

    /// Counts an answer no delivery was owed, and tells the first few: `at` into the load.
    pub fn not_owed(&mut self, at: std::time::Duration, client: impact_protocol::ClientId, seq: u32, what: String) {
        self.answers_unexpected += 1;
        if self.unexpected.len() < UNEXPECTED_KEPT {
            self.unexpected.push(format!("{:.3} s: client {} seq {seq}: {what}", at.as_secs_f64(), client.0));
        }
    }
}

/// The input lag past which the load generator did not keep up (a tick at 64 Hz).
pub const LAG_BOUND_MS: f64 = 1000.0 / 64.0;

impl Report {
    /// The lines about links lost and back, reconnects and owners, where anything happened.
    fn fmt_recovery(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.links_restored > 0 {
            writeln!(
                f,
                "  links    {} lost and back; {} confirmed ticks before a link came back not compared with a view",
                self.links_restored, self.views_unverified
            )?;
        }
        if self.inputs_known_lost + self.answered_by_welcome > 0 {
            writeln!(
                f,
                "  resumed  {} inputs known lost at a reconnect (never reached the server), {} answered by a \
                 welcome; of the unanswered deliveries, {} inputs still awaited",
                self.inputs_known_lost, self.answered_by_welcome, self.inputs_awaited
            )?;
        }
        if self.session_drops > 0 {
            writeln!(
                f,
                "  returns  {} sessions dropped; {} clients back, {} welcomed again, {} within the grace period \
                 ({} kept their avatar), {} resumed their inputs, {} of {} drawing given a full frame",
                self.session_drops,
                self.returns,
                self.returns_welcomed,
                self.returns_in_grace,
                self.returns_kept_avatar,
                self.returns_resumed,
                self.returns_full_frame,
                self.returns_drawing
            )?;
        }
        if self.confirmed_changed + self.confirmed_repeated > 0 {
            writeln!(
                f,
                "  confirmed {} batches of a tick already held said something else, {} said the same",
                self.confirmed_changed, self.confirmed_repeated
            )?;
        }
        if self.stale_owner > 0 {
            writeln!(
                f,
                "  owners   {} messages of an older owner dropped (a primary that resumed after a failover)",
                self.stale_owner
            )?;
        }
        if self.messages_lost > 0 {
            writeln!(
                f,
                "  lost     {} numbered messages never arrived (a skip in a key's numbers)",
                self.messages_lost
            )?;
        }
        Ok(())
    }
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "impact-sim: {} clients over {} sessions for {:.1} s ({} welcomed{})",
            self.clients,
            self.sessions,
            self.duration_s,
            self.clients_welcomed,
            match self.presence_repeats {
                0 => String::new(),
                n => format!(", presence declared again {n} times for a late welcome"),
            }
        )?;
        writeln!(
            f,
            "  inputs   sent {}{} ({} copies again) | lost in the network {} ({} messages) | delivered {} ({} twice) | acked {} ({} acks lost, told by the next) | unanswered {} | answered unexpectedly {}",
            self.inputs_sent,
            match self.keepalives {
                0 => String::new(),
                n => format!(", {n} of them keepalives"),
            },
            self.input_copies_sent, self.inputs_lost_in_network, self.messages_lost_in_network, self.inputs_delivered, self.inputs_duplicated, self.acks, self.acks_recovered, self.inputs_unanswered, self.answers_unexpected
        )?;
        self.fmt_recovery(f)?;
        if self.worlds_followed > 0 {
            writeln!(
                f,
                "  worlds   followed {} closed worlds to the next | inputs void at a close {}",
                self.worlds_followed, self.inputs_void_at_close
            )?;
        }
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
        let pct = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{:.2} %", 100.0 * x));
        writeln!(
            f,
            "           late in the first 2 s of play {} (of {}), after {}",
            pct(self.late_share_first_2s),
            self.acked_first_2s,
            pct(self.late_share_steady)
        )?;
        writeln!(
            f,
            "  views    {} confirmed ticks matched, {} differed ({} of them missed and not recovered in time; {} recovered)",
            self.views_matched, self.views_mismatched, self.views_given_up, self.views_recovered
        )?;
        self.prediction.write(f)?;
        if self.state_frames > 0 {
            writeln!(
                f,
                "  state    {} frames, {:.0} bytes per client per second",
                self.state_frames, self.state_bytes_per_client_s
            )?;
        }
        writeln!(
            f,
            "  bytes    per client per second: {:.0} received, {:.0} sent | load generator: input lag p99 {:.1} ms max {:.1} ms, inbox full {} times{}",
            self.bytes_down_per_client_s,
            self.bytes_up_per_client_s,
            self.load_lag_ms_p99,
            self.load_lag_ms_max,
            self.load_inbox_dropped,
            if self.load_kept_up() { "" } else { " (it fell behind: the figures measure it too)" }
        )?;
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

impl Prediction {
    /// The prediction's lines of the readable report (none without game clients).
    fn write(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = self;
        if p.predicting_clients == 0 {
            return Ok(());
        }
        let pct = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{:.2} %", 100.0 * x));
        let m = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{:.3} m", x));
        let mm = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{:.3} mm", x * 1e3));
        let causes: Vec<String> = p.prediction_causes.iter().map(|(k, v)| format!("{k} {v}")).collect();
        writeln!(
            f,
            "  predict  {} clients ({} stopped) | {} states ({} teleports apart), {} exact, {} mispredicted ({}) | error p50 {} p99 {} max {}",
            p.predicting_clients,
            p.prediction_stopped,
            p.prediction_states,
            p.prediction_teleports,
            p.prediction_exact,
            pct(p.prediction_mispredicted_share),
            if causes.is_empty() { "none".into() } else { causes.join(", ") },
            m(p.prediction_error_m_p50),
            m(p.prediction_error_m_p99),
            m(p.prediction_error_m_max),
        )?;
        writeln!(
            f,
            "           untouched: {} states, p99 {} max {} | largest correction step {:.1} mm per 60 Hz frame",
            p.prediction_untouched_states,
            mm(p.prediction_untouched_m_p99),
            mm(p.prediction_untouched_m_max),
            p.correction_jump_m_max * 1e3
        )?;
        writeln!(
            f,
            "  interp   {} bodies drawn vs the server: p50 {} p99 {} | steady {}: p99 {} | the others p99 {}",
            p.interpolation_samples,
            mm(p.interpolation_error_m_p50),
            mm(p.interpolation_error_m_p99),
            p.interpolation_steady_samples,
            mm(p.interpolation_steady_m_p99),
            mm(p.interpolation_changed_m_p99)
        )?;
        Ok(())
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
