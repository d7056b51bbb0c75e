//! The client's clock: its estimate of the server's tick, and the tick to stamp an input with
//! (PROTOCOL.md, "Timing").
//!
//! It is anchored by the welcome (the server's tick and tick rate when it sent it) and counts
//! ticks from there on the local clock the caller passes in (nothing here reads a clock). Every
//! message that names the server's tick (acks, event batches, the once-a-second stats) is an
//! observation. One more than [`RESYNC_TICKS`] ahead of the clock re-anchors it at once (no
//! message arrives before it was sent: the clock is behind). One more than that behind is either
//! a late message (the client or the path stalled, and what queued meanwhile arrives at once) or
//! a server whose tick fell behind wall time (it drops a backlog after a stall rather than
//! running fast): only the second goes on naming old ticks, so the clock follows them back once
//! they have for [`SLIP_CONFIRM_TICKS`] of its own time, to the least late of them. A smaller
//! drift is followed once per [`DRIFT_WINDOW`] when every observation in it agrees.
//!
//! Inputs are stamped either behind (the tick the client sees: every input arrives a round trip
//! late and the server rolls back for it) or ahead, by the lead the acks recommend: the first
//! recommendation is taken at once, later ones are reached by time dilation (the lead moves by
//! at most [`DILATION`] of the ticks elapsed, so the stamped ticks never jump), and a `future`
//! reject lowers the lead at once ([`Clock::back_off`]).

use impact_protocol::Tick;
use std::time::{Duration, Instant};

/// The most an ahead client's clock runs fast or slow to reach a new recommended lead: 10 %, so
/// a lead 13 ticks off is reached in about two seconds, with no jump in the ticks stamped.
pub const DILATION: f64 = 0.1;

/// How far (ticks) the clock may drift from the ticks the server names before it re-anchors.
/// Both carry the same downlink delay, so they agree to within the jitter (80 +- 20 ms is +-1.3
/// ticks at 64 Hz); a larger gap means the server's tick fell behind wall time, and a client that
/// kept its old clock would stamp every later input in the future.
pub const RESYNC_TICKS: u32 = 4;

/// How long (ticks of the client's own time) observations past [`RESYNC_TICKS`] behind the clock
/// must go on coming before the clock follows them back. A burst of late messages (what queued
/// while the client's loop, its page or the path stalled) arrives within a fraction of a tick and
/// is followed at once by a timely one, which ends the suspicion; a server that fell behind names
/// old ticks in every message after. Following a burst back made the next inputs late or `stale`
/// and the next timely message pushed the clock forward again, with a lead raised in between.
pub const SLIP_CONFIRM_TICKS: f64 = 2.0;

/// Drift smaller than [`RESYNC_TICKS`] is corrected once per window: if every tick heard in it
/// was behind the clock (or every one ahead), the clock moves by the smallest such offset. The
/// observation that came soonest is the best estimate of the server's tick (NTP keeps its
/// minimum-delay sample for the same reason), so jitter alone never moves the clock, while a
/// server that dropped a few ticks after a stall is followed within a window instead of leaving
/// ahead clients stamping up to 4 ticks further ahead for good (the 30-minute soak found 5 % of
/// inputs refused as `future` that way).
pub const DRIFT_WINDOW: Duration = Duration::from_secs(1);

/// Observations past the resync bound behind the clock (see [`SLIP_CONFIRM_TICKS`]).
#[derive(Clone, Copy, Debug)]
struct Behind {
    since: Instant,
    tick: Tick,
    at: Instant,
    off: i64,
}

/// The client's clock (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct Clock {
    /// The server's tick at a local instant, and its tick rate; `None` until the welcome.
    anchor: Option<(Tick, Instant, u32)>,
    /// This window's start and the largest and smallest (observed - estimated) tick offsets.
    drift: Option<(Instant, i64, i64)>,
    /// Observations past the resync bound behind the clock, since the first of them: when it
    /// came, and the least late of them (its tick, when, and its offset).
    behind: Option<Behind>,
    /// Ahead: the lead in use (ticks; `None` until the first ack recommends one), the lead
    /// recommended last, and when the lead was last moved.
    lead: Option<f64>,
    lead_target: f64,
    lead_at: Option<Instant>,
}

impl Clock {
    /// A clock not yet anchored.
    pub fn new() -> Clock {
        Clock::default()
    }

    /// Anchors the clock: the server was at `tick`, ticking at `tick_hz`, at local instant `now`
    /// (the welcome). The lead is kept.
    pub fn anchor(&mut self, tick: Tick, tick_hz: u32, now: Instant) {
        self.anchor = Some((tick, now, tick_hz.max(1)));
        self.drift = None;
        self.behind = None;
    }

    /// Whether the clock has been anchored.
    pub fn is_anchored(&self) -> bool {
        self.anchor.is_some()
    }

    /// The server's tick rate, from the welcome.
    pub fn tick_hz(&self) -> Option<u32> {
        self.anchor.map(|a| a.2)
    }

    /// The server's tick as the client sees it at `now`, fractional: the anchor plus what the
    /// local clock counted since.
    pub fn server_ticks(&self, now: Instant) -> Option<f64> {
        let (tick, at, hz) = self.anchor?;
        Some(f64::from(tick.0) + now.saturating_duration_since(at).as_secs_f64() * f64::from(hz))
    }

    /// The server's tick as the client sees it at `now` (its view tick).
    pub fn server_tick(&self, now: Instant) -> Option<Tick> {
        self.server_ticks(now).map(|t| Tick(t as u32))
    }

    /// The server named `tick` in a message that arrived `now`: re-anchors the clock on a tick
    /// past [`RESYNC_TICKS`] ahead of it, or on ticks that many behind once they have gone on for
    /// [`SLIP_CONFIRM_TICKS`] (returns `true`), or follows a smaller drift once the window agrees.
    pub fn observe(&mut self, tick: Tick, now: Instant) -> bool {
        let (Some(est), Some((anchor, at, hz))) = (self.server_tick(now), self.anchor) else { return false };
        let off = i64::from(tick.0) - i64::from(est.0);
        let bound = i64::from(RESYNC_TICKS);
        if off > bound {
            self.anchor(tick, hz, now);
            return true;
        }
        if off < -bound {
            let b = self.behind.get_or_insert(Behind { since: now, tick, at: now, off });
            if off > b.off {
                (b.tick, b.at, b.off) = (tick, now, off);
            }
            if now.saturating_duration_since(b.since).as_secs_f64() * f64::from(hz) < SLIP_CONFIRM_TICKS {
                return false;
            }
            let (tick, at) = (b.tick, b.at);
            self.anchor(tick, hz, at);
            return true;
        }
        self.behind = None;
        let w = self.drift.get_or_insert((now, off, off));
        w.1 = w.1.max(off);
        w.2 = w.2.min(off);
        if now.saturating_duration_since(w.0) >= DRIFT_WINDOW {
            let (hi, lo) = (w.1, w.2);
            self.drift = None;
            let shift = if hi < 0 { hi } else { lo.max(0) };
            if shift != 0 {
                self.anchor = Some((Tick((i64::from(anchor.0) + shift).max(0) as u32), at, hz));
            }
        }
        false
    }

    /// An ack recommended `lead` ticks: the first sets the lead outright, later ones are reached
    /// by time dilation in [`Clock::stamp`].
    pub fn recommend(&mut self, lead: u32) {
        self.lead_target = f64::from(lead);
        if self.lead.is_none() {
            self.lead = Some(self.lead_target);
        }
    }

    /// The lead in use, ticks (`None` before the first recommendation).
    pub fn lead(&self) -> Option<f64> {
        self.lead
    }

    /// How fast the ticks an input is stamped with advance against the server's ticks: `1 +
    /// DILATION` while an ahead clock's lead grows towards the recommendation, `1 - DILATION`
    /// while it shrinks, 1 once reached (and always behind). A game that steps its input loop on a
    /// fixed timestep of `1 / (tick_hz * rate)` sends one input per stamped tick.
    pub fn stamp_rate(&self, ahead: bool) -> f64 {
        match (ahead, self.lead) {
            (true, Some(lead)) => 1.0 + (self.lead_target - lead).clamp(-DILATION, DILATION),
            _ => 1.0,
        }
    }

    /// A `future` reject of an input stamped `tick` at view tick `view`: at its arrival the
    /// server accepted ticks up to `newest`, `accepted_ahead` past its present (the welcome's
    /// `input_lead_ticks`), so the lead it carried (`tick - view`) was too much by the excess.
    /// The lead drops at once to one tick under what would have fitted (a burst of such rejects
    /// lowers it once, not once each). Without this a client whose lead was raised by a delay
    /// spike or a view that lagged (the server caps what it recommends at what its quickest
    /// recent input would have been accepted with, but the delay can fall lower still) overshoots
    /// once the delay falls back, every input is refused, and no ack
    /// ever comes to lower it (a soak refused 31 % of inputs that way). A view past the server's
    /// present at the input's arrival by more than [`RESYNC_TICKS`] is not the lead's fault but
    /// the server's tick jumping back: the clock's resync corrects that, and lowering the lead
    /// too would make the next inputs late.
    pub fn back_off(&mut self, tick: Tick, view: Tick, newest: Tick, accepted_ahead: u32) {
        let present = newest.0.saturating_sub(accepted_ahead);
        if view.0 > present.saturating_add(RESYNC_TICKS) || tick <= newest {
            return;
        }
        let most = f64::from(newest.0.saturating_sub(view.0)) - 1.0;
        if let Some(lead) = self.lead.as_mut() {
            *lead = lead.min(most.max(0.0));
            self.lead_target = self.lead_target.min(*lead);
        }
    }

    /// The tick to stamp an input with at `now` (`ahead`: by the lead, moved towards the
    /// recommendation by dilation; otherwise the view tick), and the view tick it was chosen
    /// from. `None` before the welcome.
    pub fn stamp(&mut self, ahead: bool, now: Instant) -> Option<(Tick, Tick)> {
        let view = self.server_tick(now)?;
        match (ahead, self.lead) {
            (true, Some(lead)) => {
                let hz = self.tick_hz().unwrap_or(64);
                let elapsed =
                    self.lead_at.map_or(0.0, |at| now.saturating_duration_since(at).as_secs_f64() * f64::from(hz));
                let step = DILATION * elapsed;
                let lead = lead + (self.lead_target - lead).clamp(-step, step);
                self.lead = Some(lead);
                self.lead_at = Some(now);
                Some((Tick(view.0 + lead.round().max(0.0) as u32), view))
            }
            // Behind, or ahead before the first recommendation: stamp what it sees.
            _ => Some((view, view)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clock(anchor: Tick, at: Instant) -> Clock {
        let mut c = Clock::new();
        c.anchor(anchor, 64, at);
        c
    }

    /// Ahead: the first recommendation is taken at once, a later one is approached at no more
    /// than DILATION of the elapsed ticks, so the stamped ticks never jump; behind stamps the
    /// view tick whatever the acks say.
    #[test]
    fn the_lead_follows_recommendations_by_time_dilation() {
        let t0 = Instant::now();
        let mut c = clock(Tick(100), t0);
        assert_eq!(c.stamp(true, t0), Some((Tick(100), Tick(100))), "no lead before an ack");
        c.recommend(12);
        assert_eq!(c.stamp(true, t0), Some((Tick(112), Tick(100))));
        // The round trip shrinks: a lead of 2 is recommended. One second later (64 ticks) the
        // lead has moved 6.4 ticks, not 10.
        c.recommend(2);
        assert_eq!(c.stamp_rate(true), 1.0 - DILATION, "stamped ticks slow down while the lead shrinks");
        assert_eq!(c.stamp_rate(false), 1.0);
        let t1 = t0 + Duration::from_secs(1);
        let (tick, view) = c.stamp(true, t1).unwrap();
        assert_eq!(view, Tick(164));
        assert_eq!(tick, Tick(164 + 6), "12 - 6.4 rounds to 6");
        // Another second reaches the target and stays there.
        let t2 = t1 + Duration::from_secs(1);
        assert_eq!(c.stamp(true, t2), Some((Tick(230), Tick(228))));
        assert_eq!(c.stamp(false, t2), Some((Tick(228), Tick(228))));
        assert_eq!(Clock::new().stamp(true, t2), None, "not before the welcome");
        assert_eq!(c.stamp_rate(true), 1.0, "the lead reached: no dilation");
    }

    /// A server that stalled and dropped its backlog names ticks behind the client's clock in
    /// every message after: once they have gone on for SLIP_CONFIRM_TICKS the clock follows them
    /// back (to the least late), so its inputs stop landing in the future. A burst of late
    /// messages (the client stalled, and what queued arrives at once) followed by a timely one
    /// leaves the clock alone, as does jitter within the bound; a tick ahead of the clock
    /// re-anchors it at once.
    #[test]
    fn a_stalled_server_re_anchors_the_clock_and_late_messages_do_not() {
        let ms = Duration::from_millis;
        let t0 = Instant::now();
        let mut c = clock(Tick(100), t0);
        let now = t0 + Duration::from_secs(1); // the clock says tick 164
        assert_eq!(c.server_tick(now), Some(Tick(164)));
        assert!(!c.observe(Tick(164 - RESYNC_TICKS), now), "jitter within the bound");
        // The client stalled for 0.4 s: what queued arrives at once, then a timely message.
        for t in [138, 145, 152] {
            assert!(!c.observe(Tick(t), now), "a late message alone is no slip");
        }
        assert!(!c.observe(Tick(163), now + ms(1)));
        assert_eq!(c.server_tick(now + ms(1)), Some(Tick(164)), "the burst left the clock where it was");
        // The server lost 0.4 s to a stall: its batches name ticks 26 behind, and go on doing so.
        let t1 = now + ms(100); // the clock says 170
        assert!(!c.observe(Tick(144), t1));
        assert!(!c.observe(Tick(145), t1 + ms(16)), "a tick's time is not yet a slip");
        assert!(c.observe(Tick(146), t1 + ms(32)), "two ticks' time: followed");
        assert_eq!(c.server_tick(t1 + ms(32)), Some(Tick(146)));
        assert_eq!(c.server_tick(t1 + ms(532)), Some(Tick(178)));
        // A tick ahead of the clock re-anchors at once.
        assert!(c.observe(Tick(200), t1 + ms(532)));
        assert_eq!(c.server_tick(t1 + ms(532)), Some(Tick(200)));
    }

    /// A lead raised by a delay spike overshoots once the delay is back: the `future` reject
    /// lowers it at once, so the next input is accepted without waiting for an ack.
    #[test]
    fn a_future_reject_lowers_the_lead_at_once() {
        let t0 = Instant::now();
        let mut c = clock(Tick(100), t0);
        c.recommend(21); // a stall made the round trip look like 20 ticks
        let (tick, view) = c.stamp(true, t0).unwrap();
        assert_eq!((tick, view), (Tick(121), Tick(100)));
        // The server is at 110 when it arrives and accepts up to 118: a lead of 18 was the most.
        c.back_off(tick, view, Tick(118), 8);
        let (tick, _) = c.stamp(true, t0).unwrap();
        assert_eq!(tick, Tick(117), "lead 18 - 1");
        // The rest of the burst (inputs sent before the first reject came back) lowers it no more.
        c.back_off(Tick(122), Tick(101), Tick(119), 8);
        assert_eq!(c.stamp(true, t0).unwrap().0, Tick(117));
        // A view past the server's present (117) beyond the resync bound is the server's tick
        // jumping back, not the lead.
        c.back_off(Tick(150), Tick(130), Tick(125), 8);
        assert_eq!(c.stamp(true, t0).unwrap().0, Tick(117));
        // An ack recommending the old lead again is followed only by dilation, not a jump.
        c.recommend(21);
        let (tick, _) = c.stamp(true, t0 + Duration::from_millis(100)).unwrap();
        assert!(tick.0 <= 106 + 17 + 1, "{tick:?}");
    }

    /// A lead far past what the server accepts, with a view that agrees with the server (the
    /// lead was recommended while the view lagged, after a takeover): lowered however large the
    /// excess, or every input stays refused and no ack comes to lower it.
    #[test]
    fn a_future_reject_far_past_lowers_the_lead_when_the_view_agrees() {
        let t0 = Instant::now();
        let mut c = clock(Tick(806), t0);
        c.recommend(18);
        let (tick, view) = c.stamp(true, t0).unwrap();
        // At its arrival the server is at 810 and accepts up to 818: 6 ticks too far.
        c.back_off(tick, view, Tick(818), 8);
        assert_eq!(c.stamp(true, t0).unwrap().0, Tick(806 + 11));
    }

    /// Drift under the resync bound is followed within a window when every observation agrees,
    /// and jitter (observations on both sides) leaves the clock alone.
    #[test]
    fn small_drift_is_followed_and_jitter_is_not() {
        let t0 = Instant::now();
        let mut c = clock(Tick(100), t0);
        // Jitter: a second of observations 1 tick either side.
        for k in 0..=64u32 {
            let now = t0 + Duration::from_secs_f64(f64::from(k) / 64.0);
            let est = c.server_tick(now).unwrap();
            let seen = if k % 2 == 0 { est.0 + 1 } else { est.0 - 1 };
            assert!(!c.observe(Tick(seen), now));
        }
        let t1 = t0 + Duration::from_secs(1);
        assert_eq!(c.server_tick(t1), Some(Tick(164)), "jitter moved the clock");
        // The server fell 3 ticks behind (a dropped backlog): every observation says so.
        // (The window that opens with the first of them closes a second later, at k = 65.)
        for k in 1..=65u32 {
            let now = t1 + Duration::from_secs_f64(f64::from(k) / 64.0);
            let est = c.server_tick(now).unwrap();
            let lag = if k % 2 == 0 { 3 } else { 2 };
            assert!(!c.observe(Tick(est.0 - lag), now), "3 ticks is under the resync bound");
        }
        let t2 = t1 + Duration::from_secs_f64(65.0 / 64.0);
        assert_eq!(c.server_tick(t2), Some(Tick(164 + 65 - 2)), "moved back by the smallest lag");
    }
}
