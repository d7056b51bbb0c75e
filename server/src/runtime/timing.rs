//! The lead the server recommends to each client, from the delays its inputs arrive with.
//!
//! A client that runs ahead stamps its inputs `view_tick + lead`, where its view tick lags the
//! server by the downlink delay and the input takes the uplink delay to arrive: it is on time
//! when `lead` covers the whole round trip in ticks. The server sees each input's round trip
//! directly: `server_tick - view_tick` when it arrives (`view_tick` is the input's `tick` for a
//! client that stamps what it sees). The recommendation is the largest of the client's last
//! [`DELAYS_KEPT`] delays plus one tick of margin: an input then arrives early by one to a few
//! ticks (the jitter), waits in the server's per-tick buffer, and needs no rollback.

use impact_protocol::Tick;

/// Delays remembered per client (about half a second of inputs at 60 Hz).
pub const DELAYS_KEPT: usize = 32;

/// Ticks of margin over the largest recent delay.
pub const MARGIN_TICKS: u32 = 1;

/// One client's recent delays, in ticks.
#[derive(Clone, Debug, Default)]
pub struct LeadEstimator {
    delays: [u32; DELAYS_KEPT],
    len: usize,
    next: usize,
}

impl LeadEstimator {
    /// Records an input that arrived when the server was at `server_tick`, from a client that was
    /// looking at `view_tick`, and returns the lead to recommend, at most `max_lead` (a lead the
    /// server would refuse as `future` helps nobody).
    pub fn observe(&mut self, server_tick: Tick, view_tick: Tick, max_lead: u32) -> u32 {
        // A view tick from the future (a confused clock) counts as no delay at all.
        self.delays[self.next] = server_tick.0.saturating_sub(view_tick.0);
        self.next = (self.next + 1) % DELAYS_KEPT;
        self.len = (self.len + 1).min(DELAYS_KEPT);
        self.lead().min(max_lead)
    }

    /// The recommended lead: the largest remembered delay plus the margin (the margin alone
    /// before any input arrived).
    pub fn lead(&self) -> u32 {
        self.delays[..self.len].iter().copied().max().unwrap_or(0).saturating_add(MARGIN_TICKS)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lead_covers_the_largest_recent_delay_and_forgets_old_ones() {
        let mut e = LeadEstimator::default();
        assert_eq!(e.lead(), MARGIN_TICKS);
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
        assert_eq!(e.lead(), 10);
        // Bounded by what the server accepts, and a view from the future is no delay.
        assert_eq!(e.observe(Tick(400), Tick(300), 16), 16);
        let mut f = LeadEstimator::default();
        assert_eq!(f.observe(Tick(5), Tick(9), 64), MARGIN_TICKS);
    }
}
