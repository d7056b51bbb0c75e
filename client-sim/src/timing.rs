//! How a simulated client times its inputs (PROTOCOL.md, "Timing"): the two modes (the clock
//! that stamps them is the client library's, `impact_client::clock`), and the histogram of
//! arrival margins its acks report.

/// How a client stamps its inputs (PROTOCOL.md, "Timing").
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Timing {
    /// Stamp the tick the client sees: every input arrives a round trip late and the server
    /// rolls back for it (favours the mover: what it did happens where it saw it).
    Behind,
    /// Run ahead of the server by the lead its acks recommend, adjusted smoothly (the clock runs
    /// up to [`impact_client::clock::DILATION`] fast or slow), so inputs arrive just before their tick: no rollback
    /// but for the late few. Shots are rewound to the view tick the input carries.
    Ahead,
}

/// Margins (ticks) counted per client, from `-MARGIN_SPAN` to `+MARGIN_SPAN` (outliers land in
/// the end buckets).
const MARGIN_SPAN: i32 = 64;

/// A fixed histogram of arrival margins, ticks.
#[derive(Clone, Debug)]
pub struct Margins {
    counts: [u32; (2 * MARGIN_SPAN + 1) as usize],
    total: u64,
}

impl Default for Margins {
    fn default() -> Self {
        Margins { counts: [0; (2 * MARGIN_SPAN + 1) as usize], total: 0 }
    }
}

impl Margins {
    /// Counts one margin.
    pub fn record(&mut self, margin: i32) {
        self.counts[(margin.clamp(-MARGIN_SPAN, MARGIN_SPAN) + MARGIN_SPAN) as usize] += 1;
        self.total += 1;
    }

    /// Adds another histogram's counts.
    pub fn merge(&mut self, other: &Margins) {
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        self.total += other.total;
    }

    /// The margin at quantile `q` (0 when nothing was counted).
    pub fn quantile(&self, q: f64) -> i32 {
        if self.total == 0 {
            return 0;
        }
        let rank = ((q * self.total as f64).ceil() as u64).clamp(1, self.total);
        let mut seen = 0;
        for (k, c) in self.counts.iter().enumerate() {
            seen += u64::from(*c);
            if seen >= rank {
                return k as i32 - MARGIN_SPAN;
            }
        }
        MARGIN_SPAN
    }

    /// Inputs that arrived late (negative margin): each made the server roll back.
    pub fn late(&self) -> u64 {
        self.counts[..MARGIN_SPAN as usize].iter().map(|c| u64::from(*c)).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn margins_give_quantiles_and_count_the_late() {
        let mut m = Margins::default();
        for x in [-3, -1, 0, 1, 1, 2, 2, 2, 3, 100] {
            m.record(x);
        }
        assert_eq!(m.late(), 2);
        assert_eq!(m.quantile(0.01), -3);
        assert_eq!(m.quantile(0.5), 1);
        assert_eq!(m.quantile(0.99), MARGIN_SPAN, "outliers land in the end bucket");
    }
}
