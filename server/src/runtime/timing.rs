//! The lead the server recommends to each client, from the delays its inputs arrive with.
//!
//! A client that runs ahead stamps its inputs `view_tick + lead`, where its view tick lags the
//! server by the downlink delay and the input takes the uplink delay to arrive: it is on time
//! when `lead` covers the whole round trip in ticks. The server sees each input's round trip
//! directly: `server_tick - view_tick` when it arrives (`view_tick` is the input's `tick` for a
//! client that stamps what it sees). The recommendation is the largest of the client's last
//! [`DELAYS_KEPT`] delays plus one tick of margin: an input then arrives early by one to a few
//! ticks (the jitter), waits in the server's per-tick buffer, and needs no rollback.
//!
//! It is also no more than every one of those inputs would have been accepted with: the smallest
//! delay plus the ticks the server accepts ahead (`input_lead_ticks`), less [`JITTER_TICKS`]. The
//! two bounds disagree only when the delays spread wider than the ticks accepted ahead (a spike: a
//! stalled path, a page that stopped for a moment), and then the lead errs late, not early: an
//! input that arrives late is still applied (rolled back), one stamped too far ahead is refused
//! as `future` and lost. Capped at the delay of the input just heard instead, a recommendation
//! raised by a spike sat at the very edge of what is accepted, and the next input to arrive one
//! tick quicker was refused.

use impact_protocol::Tick;

/// Delays remembered per client (about half a second of inputs at 60 Hz).
pub const DELAYS_KEPT: usize = 32;

/// Ticks of margin over the largest recent delay.
pub const MARGIN_TICKS: u32 = 1;

/// Ticks of margin under the most ahead every recent input would have been accepted.
pub const JITTER_TICKS: u32 = 1;

/// One client's recent delays, in ticks.
#[derive(Clone, Debug, Default)]
pub struct LeadEstimator {
    delays: [u32; DELAYS_KEPT],
    len: usize,
    next: usize,
}

impl LeadEstimator {
    /// Records an input that arrived when the server was at `server_tick`, from a client that was
    /// looking at `view_tick`, and returns the lead to recommend ([`LeadEstimator::lead`]) to a
    /// client whose inputs are accepted up to `accepted_ahead` ticks past the server's present.
    pub fn observe(&mut self, server_tick: Tick, view_tick: Tick, accepted_ahead: u32) -> u32 {
        // A view tick from the future (a confused clock) counts as no delay at all.
        self.delays[self.next] = server_tick.0.saturating_sub(view_tick.0);
        self.next = (self.next + 1) % DELAYS_KEPT;
        self.len = (self.len + 1).min(DELAYS_KEPT);
        self.lead(accepted_ahead)
    }

    /// The recommended lead: the largest remembered delay plus [`MARGIN_TICKS`], at most the
    /// smallest plus `accepted_ahead` less [`JITTER_TICKS`] (see the module docs); the margin alone
    /// before any input arrived.
    pub fn lead(&self, accepted_ahead: u32) -> u32 {
        let recent = &self.delays[..self.len];
        let (Some(&most), Some(&least)) = (recent.iter().max(), recent.iter().min()) else { return MARGIN_TICKS };
        let fits = least.saturating_add(accepted_ahead).saturating_sub(JITTER_TICKS);
        most.saturating_add(MARGIN_TICKS).min(fits)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lead_covers_the_largest_recent_delay_and_forgets_old_ones() {
        let mut e = LeadEstimator::default();
        assert_eq!(e.lead(8), MARGIN_TICKS);
        // Round trips of 10 to 12 ticks: lead 13.
        for (k, d) in [10, 12, 11, 10].iter().enumerate() {
            let lead = e.observe(Tick(100 + k as u32), Tick(100 + k as u32 - d), 64);
            assert_eq!(lead, [11, 13, 13, 13][k]);
        }
        // A spike lifts it at once; once the spike leaves the window it falls back.
        assert_eq!(e.observe(Tick(200), Tick(180), 64), 21);
        for k in 0..DELAYS_KEPT as u32 {
            e.observe(Tick(300 + k), Tick(300 + k - 9), 64);
        }
        assert_eq!(e.lead(64), 10);
        // A view from the future is no delay.
        let mut f = LeadEstimator::default();
        assert_eq!(f.observe(Tick(5), Tick(9), 64), MARGIN_TICKS);
    }

    /// Delays of 1 and 2 ticks with a spike of 12 among them, 8 ticks accepted ahead: the spike
    /// alone would recommend 13, which every input arriving in 1 or 2 ticks would carry past the
    /// 9 or 10 accepted. Each recommendation is accepted for the next input (it arrives no quicker
    /// than a tick under the quickest remembered), so none is refused as `future`; while the spike
    /// is remembered the lead stays below it (its inputs are late, rolled back, not lost).
    #[test]
    fn a_spike_never_lifts_the_lead_past_what_the_quicker_inputs_are_accepted_with() {
        let accepted_ahead = 8;
        let delays: Vec<u32> = (0..40).map(|k| if k == 5 { 12 } else { 1 + k % 2 }).collect();
        let mut e = LeadEstimator::default();
        let mut lead = MARGIN_TICKS;
        for (k, &d) in delays.iter().enumerate() {
            let now = 1000 + k as u32;
            assert!(lead <= d + accepted_ahead, "input {k}: lead {lead} is refused at delay {d}");
            lead = e.observe(Tick(now), Tick(now - d), accepted_ahead);
            if (5..5 + DELAYS_KEPT).contains(&k) {
                assert_eq!(lead, 1 + accepted_ahead - JITTER_TICKS, "input {k}: capped by the quickest");
            }
        }
        assert_eq!(lead, 2 + MARGIN_TICKS, "the spike forgotten, the largest delay left is 2");
        // Delays spread wider than the ticks accepted ahead cap the lead at the quickest; none
        // spread that wide leave it at the slowest plus the margin.
        let mut g = LeadEstimator::default();
        g.observe(Tick(50), Tick(50), accepted_ahead);
        assert_eq!(g.observe(Tick(60), Tick(30), accepted_ahead), accepted_ahead - JITTER_TICKS);
        assert_eq!(g.lead(64), 30 + MARGIN_TICKS);
    }
}
