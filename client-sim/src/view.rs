//! A client's view of the event stream. It applies `events` batches as they come, then
//! `corrections` by event identity, and when a tick is confirmed compares its view of that tick
//! with the confirmed batch.

use impact_protocol::{CollisionEvent, CorrectionBatch, EventBatch, EventKey, Tick};
use std::collections::BTreeMap;

/// Per-tick events as the client holds them.
#[derive(Debug, Default)]
pub struct View {
    ticks: BTreeMap<Tick, BTreeMap<EventKey, CollisionEvent>>,
    /// Ticks whose view equalled the confirmed batch.
    pub matched: u64,
    /// Ticks whose view differed from the confirmed batch.
    pub mismatched: u64,
    /// Corrections applied.
    pub corrections: u64,
}

fn same(a: &CollisionEvent, b: &CollisionEvent) -> bool {
    let close = |x: &[f64; 3], y: &[f64; 3]| x.iter().zip(y).all(|(p, q)| (p - q).abs() <= 1e-6);
    (a.toi - b.toi).abs() <= 1e-9
        && close(&a.point, &b.point)
        && close(&a.normal, &b.normal)
        && a.response == b.response
}

impl View {
    /// Applies a provisional batch.
    pub fn events(&mut self, b: &EventBatch) {
        let t = self.ticks.entry(b.tick).or_default();
        for e in &b.events {
            t.insert(e.key(), e.clone());
        }
    }

    /// Applies a correction.
    pub fn correct(&mut self, c: &CorrectionBatch) {
        self.corrections += 1;
        let t = self.ticks.entry(c.tick).or_default();
        for e in &c.retracted {
            t.remove(&e.key());
        }
        for e in c.amended.iter().chain(&c.added) {
            t.insert(e.key(), e.clone());
        }
    }

    /// Compares the view of a confirmed tick with the batch and forgets the tick. Returns
    /// whether they were equal.
    pub fn confirm(&mut self, b: &EventBatch) -> bool {
        let mine = self.ticks.remove(&b.tick).unwrap_or_default();
        let ok =
            mine.len() == b.events.len() && b.events.iter().all(|e| mine.get(&e.key()).is_some_and(|m| same(m, e)));
        if ok {
            self.matched += 1;
        } else {
            self.mismatched += 1;
        }
        ok
    }

    /// Ticks held (bounded by the server's window while confirmations arrive).
    pub fn held(&self) -> usize {
        self.ticks.len()
    }
}
