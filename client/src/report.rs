//! How a game played, as it saw it: what it drew checked against the server's record, its shots,
//! and the one-line summary the examples print (`impact-client`'s `play`, `impact-bevy`'s
//! `arena`). Needs the Zenoh transport: the check asks the server where every body was.
//!
//! Twice a second [`PlayReport::frame`] draws the remote world at the last whole tick it renders
//! and asks the server for its state at that tick (`query/state?tick=T`); when the answer comes,
//! each body's distance between where it was drawn and where the server had it is the
//! interpolation error ([`DrawCheck`]; `impact-sim` checks its players the same way).

use crate::remote::DrawnBody;
use crate::session::Session;
use crate::transport::{decode_server, Connection, TransportError};
use ::zenoh::Wait;
use impact_protocol::{keys, EntityId, RayResult, ServerMessage, Tick, WorldId};
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// How often a game's drawing is checked against the server's.
pub const CHECK_EVERY: Duration = Duration::from_millis(500);

/// Checks awaiting an answer at most (an answer takes a round trip; the query times out in 2 s).
pub const MAX_CHECKS: usize = 16;

/// Shots awaiting their result at most, for the hits on target.
pub const MAX_AIMED: usize = 1024;

/// Bodies drawn at one tick, awaiting the server's positions at that tick.
#[derive(Debug)]
pub struct DrawCheck {
    tick: Tick,
    drawn: Vec<DrawnBody>,
    replies: ::zenoh::handlers::FifoChannelHandler<::zenoh::query::Reply>,
}

impl DrawCheck {
    /// Asks the server of `world` where every body was at `tick`, for `drawn` (drawn at that
    /// tick; several clients' drawings may be given together).
    pub fn ask(
        zs: &::zenoh::Session,
        world: &WorldId,
        tick: Tick,
        drawn: Vec<DrawnBody>,
    ) -> Result<DrawCheck, TransportError> {
        let key = format!("{}?tick={}", keys::QUERY_STATE.key(world, None), tick.0);
        let replies = zs
            .get(key)
            .timeout(Duration::from_secs(2))
            .wait()
            .map_err(|e| TransportError::Zenoh(format!("state query: {e}")))?;
        Ok(DrawCheck { tick, drawn, replies })
    }

    /// Once the answer came: each drawn body's error, metres, and whether it was steady (nothing
    /// changed its motion between the frames it was drawn between), into `errors`. True when the
    /// check is over (answered, refused or timed out); false while it waits.
    pub fn compare(&self, errors: &mut Vec<(f64, bool)>) -> bool {
        let reply = match self.replies.try_recv() {
            Ok(Some(reply)) => reply,
            Ok(None) => return false,
            Err(_) => return true,
        };
        let Ok(ServerMessage::Snapshot(s)) =
            reply.result().map_err(|_| ()).and_then(|s| decode_server(s).map_err(|_| ()))
        else {
            return true;
        };
        if s.tick != self.tick {
            return true;
        }
        let truth: BTreeMap<_, _> = s.bodies.iter().map(|b| (b.entity, b.position)).collect();
        for d in &self.drawn {
            if let Some(p) = truth.get(&d.entity) {
                errors.push((distance(d.position, *p), d.steady));
            }
        }
        true
    }
}

/// Euclidean distance, metres.
pub fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// The 99th percentile (nearest rank) of `v`, `None` when empty.
pub fn p99(v: &[f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    Some(v[((v.len() as f64 * 0.99).ceil() as usize).clamp(1, v.len()) - 1])
}

/// A game's account of its play (see the module).
#[derive(Debug, Default)]
pub struct PlayReport {
    frames: u64,
    remote_bodies: usize,
    shots: u64,
    on_target: u64,
    aimed: BTreeMap<u32, EntityId>,
    checks: Vec<DrawCheck>,
    next_check: Option<Instant>,
    /// Interpolation errors, metres, and whether the body was steady.
    errors: Vec<(f64, bool)>,
}

impl PlayReport {
    /// An empty report.
    pub fn new() -> PlayReport {
        PlayReport::default()
    }

    /// One frame drawn at `now` with `drawn` (the remote world as [`Session::draw_remote`] gave
    /// it): counted, and twice a second the world at the last whole render tick is checked
    /// against the server's record.
    pub fn frame(&mut self, conn: &Connection, game: &Session, now: Instant, drawn: &[DrawnBody]) {
        self.frames += 1;
        self.remote_bodies = drawn.len();
        let mut errors = std::mem::take(&mut self.errors);
        self.checks.retain(|c| !c.compare(&mut errors));
        self.errors = errors;
        let due = *self.next_check.get_or_insert(now + CHECK_EVERY);
        let (Some(r), Some(remote)) = (game.render_tick(now), game.remote()) else {
            return;
        };
        if now < due || self.checks.len() >= MAX_CHECKS {
            return;
        }
        self.next_check = Some(due.max(now - CHECK_EVERY) + CHECK_EVERY);
        let tick = Tick(r.floor().max(0.0) as u32);
        let mut at_tick = Vec::new();
        remote.draw(f64::from(tick.0), &mut at_tick);
        // A failed query is one check fewer, not the game's problem.
        if let Ok(c) = DrawCheck::ask(conn.zenoh(), conn.world(), tick, at_tick) {
            self.checks.push(c);
        }
    }

    /// Input `seq` fired a ray aimed at `target` (as drawn).
    pub fn aimed(&mut self, seq: u32, target: EntityId) {
        self.shots += 1;
        if self.aimed.len() < MAX_AIMED {
            self.aimed.insert(seq, target);
        }
    }

    /// A ray result came: a hit on the body it was aimed at counts as on target (the shot was
    /// judged against what the player saw).
    pub fn ray_result(&mut self, r: &RayResult) {
        if let Some(target) = self.aimed.remove(&r.seq) {
            self.on_target += u64::from(r.hit.as_ref().is_some_and(|h| h.entity == target));
        }
    }

    /// The summary at the end of play.
    pub fn summary(&self, game: &Session, conn: &Connection, seconds: f64) -> PlaySummary {
        let s = game.stats();
        let pr = game.prediction();
        let all: Vec<f64> = self.errors.iter().map(|e| e.0).collect();
        let steady: Vec<f64> = self.errors.iter().filter(|e| e.1).map(|e| e.0).collect();
        PlaySummary {
            client: game.config().client.0,
            seconds,
            frames: self.frames,
            inputs_sent: s.inputs_sent,
            inputs_acked: s.inputs_acked,
            rejects: s.rejects.values().sum(),
            events: s.events,
            corrections: s.corrections,
            hits: s.hits,
            shots: self.shots,
            hits_on_target: self.on_target,
            remote_bodies: self.remote_bodies,
            prediction_error_m_p99: p99(&pr.errors_m),
            prediction_error_untouched_m_p99: p99(&pr.errors_untouched_m),
            prediction_states: pr.compared,
            prediction_exact: pr.exact,
            prediction_causes: pr.causes.clone(),
            prediction_max_frame_correction_m: pr.max_frame_correction_m,
            interpolation_error_m_p99: p99(&all),
            interpolation_samples: all.len(),
            interpolation_error_steady_m_p99: p99(&steady),
            interpolation_steady_samples: steady.len(),
            view_mismatches: game.events().mismatched,
            view_matches: game.events().matched,
            rtt_ms_min: s.sync_rtt_min_s * 1e3,
            rtt_ms_max: s.sync_rtt_max_s * 1e3,
            welcomes: s.welcomes,
            malformed: s.malformed,
            inbox_dropped: conn.dropped(),
        }
    }
}

/// The one-line summary a game example prints at the end (JSON, by serde).
#[derive(Clone, Debug, Serialize)]
pub struct PlaySummary {
    /// The client id.
    pub client: u32,
    /// How long it played, seconds.
    pub seconds: f64,
    /// Frames drawn.
    pub frames: u64,
    /// Inputs sent and acked.
    pub inputs_sent: u64,
    /// Inputs acked.
    pub inputs_acked: u64,
    /// Inputs refused, all reasons.
    pub rejects: u64,
    /// Provisional events and correction batches received.
    pub events: u64,
    /// Correction batches received.
    pub corrections: u64,
    /// Ray results that hit something.
    pub hits: u64,
    /// Rays fired at a drawn body, and those that hit the body aimed at.
    pub shots: u64,
    /// Hits on the body aimed at.
    pub hits_on_target: u64,
    /// Remote bodies drawn in the last frame.
    pub remote_bodies: usize,
    /// The own avatar's prediction error at p99, metres, over all states and over those no other
    /// body touched (0 unless the core is not deterministic).
    pub prediction_error_m_p99: Option<f64>,
    /// Over the states no other body touched.
    pub prediction_error_untouched_m_p99: Option<f64>,
    /// Authoritative states compared with the prediction, and those equal to the bit.
    pub prediction_states: u64,
    /// States predicted exactly.
    pub prediction_exact: u64,
    /// Mispredictions by cause.
    pub prediction_causes: BTreeMap<&'static str, u64>,
    /// The most one frame's correction moved the drawn avatar, metres.
    pub prediction_max_frame_correction_m: f64,
    /// Remote bodies as drawn against the server's record at p99, metres: all of them, and those
    /// nothing hit between the two frames they were drawn between.
    pub interpolation_error_m_p99: Option<f64>,
    /// Bodies compared.
    pub interpolation_samples: usize,
    /// Over the steady bodies.
    pub interpolation_error_steady_m_p99: Option<f64>,
    /// Steady bodies compared.
    pub interpolation_steady_samples: usize,
    /// Confirmed ticks whose event view differed from the server's record, and those equal.
    pub view_mismatches: u64,
    /// Confirmed ticks equal to the view.
    pub view_matches: u64,
    /// The sync's fastest and slowest round trips, ms.
    pub rtt_ms_min: f64,
    /// The slowest.
    pub rtt_ms_max: f64,
    /// Welcomes received (more than one: the session reconnected).
    pub welcomes: u64,
    /// Messages that did not decode.
    pub malformed: u64,
    /// Messages dropped because the game did not pump.
    pub inbox_dropped: u64,
}
