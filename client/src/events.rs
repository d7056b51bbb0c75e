//! The event view: a client's collision events as they stand. Provisional `events` batches are
//! applied as they come, then `corrections` by event identity (PROTOCOL.md, "Collision event"), and
//! when a tick is confirmed its view is compared with the confirmed batch and the tick leaves the
//! view, with every earlier tick still held: confirmations come in tick order, and a client's own
//! stream carries a tick's batch only when one of its confirmed events involves the client, so an
//! earlier tick with no batch of its own is final with no events for it. A game reads a tick's events as they stand with [`EventView::at`]; what it already showed
//! and is corrected, it redraws.
//!
//! A tick made final that way while its view still held events is in doubt: its own batch may
//! have been lost on the way (a router dropped it, the primary died as it went out). It is held
//! apart ([`EventView::doubtful`]) until the batch the server kept comes
//! ([`EventView::recovered`], from `query/confirmed`) or the session gives up on it
//! ([`EventView::give_up`]: compared with no events, as before).
//!
//! Bounded: at most [`MAX_TICKS`] ticks are held, and [`MAX_DOUBTFUL`] in doubt. The server confirms each tick once it leaves its
//! rollback window, so a view holds about a window's worth; a view whose confirmations stop
//! coming (a lost session) forgets its oldest ticks past the bound, and counts them.

use impact_protocol::{CollisionEvent, CorrectionBatch, EventBatch, EventKey, Tick};
use std::collections::BTreeMap;

/// The most ticks an event view holds (about 16 seconds at 64 Hz; a window is a quarter second).
pub const MAX_TICKS: usize = 1024;

/// The most ticks in doubt at once; past it a tick is compared at once, with no events.
pub const MAX_DOUBTFUL: usize = 64;

/// Mismatched ticks an [`EventView`] describes.
pub const MISMATCHES_KEPT: usize = 8;

/// Per-tick events as the client holds them.
#[derive(Debug, Default)]
pub struct EventView {
    ticks: BTreeMap<Tick, BTreeMap<EventKey, CollisionEvent>>,
    /// Ticks whose view equalled the confirmed batch.
    pub matched: u64,
    /// Ticks whose view differed from the confirmed batch.
    pub mismatched: u64,
    /// The first [`MISMATCHES_KEPT`] of those: the tick, the events the view held and the
    /// events confirmed (to tell a missed event from a wrong one when debugging).
    pub mismatches: Vec<(Tick, usize, usize)>,
    /// Corrections applied.
    pub corrections: u64,
    /// Ticks forgotten unconfirmed because [`MAX_TICKS`] were held.
    pub forgotten: u64,
    /// Confirmed ticks not compared, because the link was lost before them (see
    /// [`EventView::lost_before`]): taken from the confirmed batch as they are.
    pub unverified: u64,
    /// Ticks made final by a later tick's confirmation, with no batch of their own (also counted
    /// in `matched`, `mismatched` or `unverified`): a view that held events for such a tick
    /// missed their retraction or their confirmation.
    pub implied: u64,
    /// Ticks in doubt that the batch the server kept made final.
    pub recovered: u64,
    /// Ticks in doubt given up on (no batch came back in time): compared with no events, so
    /// each is also in `mismatched`, a view the client could not check rather than one it held
    /// wrong.
    pub given_up: u64,
    /// Ticks before this one may have lost provisional events or corrections to a lost link.
    lost_before: Option<Tick>,
    /// Ticks made final by a later confirmation while they held events, with those events.
    doubtful: BTreeMap<Tick, BTreeMap<EventKey, CollisionEvent>>,
}

fn same(a: &CollisionEvent, b: &CollisionEvent) -> bool {
    let close = |x: &[f64; 3], y: &[f64; 3]| x.iter().zip(y).all(|(p, q)| (p - q).abs() <= 1e-6);
    (a.toi - b.toi).abs() <= 1e-9
        && close(&a.point, &b.point)
        && close(&a.normal, &b.normal)
        && a.response == b.response
}

impl EventView {
    /// The tick's entry, making room under [`MAX_TICKS`] by forgetting the oldest.
    fn tick(&mut self, tick: Tick) -> &mut BTreeMap<EventKey, CollisionEvent> {
        if !self.ticks.contains_key(&tick) && self.ticks.len() >= MAX_TICKS {
            self.ticks.pop_first();
            self.forgotten += 1;
        }
        self.ticks.entry(tick).or_default()
    }

    /// Applies a provisional batch.
    pub fn events(&mut self, b: &EventBatch) {
        let t = self.tick(b.tick);
        for e in &b.events {
            t.insert(e.key(), e.clone());
        }
    }

    /// Applies a correction.
    pub fn correct(&mut self, c: &CorrectionBatch) {
        self.corrections += 1;
        let t = self.tick(c.tick);
        for e in &c.retracted {
            t.remove(&e.key());
        }
        for e in c.amended.iter().chain(&c.added) {
            t.insert(e.key(), e.clone());
        }
    }

    /// The link was lost and is back, with the server at about `tick`: what was published
    /// meanwhile never arrived, so the view of every tick before `tick` may lack events or
    /// corrections. Their confirmations are not compared ([`EventView::unverified`]).
    pub fn lost_before(&mut self, tick: Tick) {
        self.lost_before = self.lost_before.max(Some(tick));
    }

    /// Compares the view of a confirmed tick with the batch and forgets the tick, after every
    /// earlier tick still held: those are final with no events for this client (see the module
    /// notes) and compared with an empty batch. `each(tick, matched)` hears every tick made final,
    /// oldest first, `matched` being whether the view equalled the server's record (`false` for a
    /// tick the link was lost before: take the batch).
    /// An earlier tick that still held events is put in doubt instead (see the module notes); the
    /// batch of a tick in doubt (the stream's late copy) makes it final alone.
    pub fn confirm(&mut self, b: &EventBatch, mut each: impl FnMut(Tick, bool)) {
        if self.recovered(b, &mut each) {
            return;
        }
        while let Some(entry) = self.ticks.first_entry().filter(|e| *e.key() < b.tick) {
            let (tick, mine) = entry.remove_entry();
            self.implied += 1;
            let verified = self.lost_before.is_none_or(|t| tick >= t);
            if verified && !mine.is_empty() && self.doubtful.len() < MAX_DOUBTFUL {
                self.doubtful.insert(tick, mine);
                continue;
            }
            let matched = self.compare(tick, &mine, &[]);
            each(tick, matched);
        }
        let mine = self.ticks.remove(&b.tick).unwrap_or_default();
        let matched = self.compare(b.tick, &mine, &b.events);
        each(b.tick, matched);
    }

    /// The ticks in doubt, oldest first.
    pub fn doubtful(&self) -> impl Iterator<Item = Tick> + '_ {
        self.doubtful.keys().copied()
    }

    /// The batch the server kept of a tick in doubt (its `query/confirmed` answer for this
    /// client): the tick is compared with it and made final, heard by `each`. Returns whether
    /// the tick was in doubt (a batch of any other tick is ignored).
    pub fn recovered(&mut self, b: &EventBatch, mut each: impl FnMut(Tick, bool)) -> bool {
        let Some(mine) = self.doubtful.remove(&b.tick) else { return false };
        self.recovered += 1;
        let matched = self.compare(b.tick, &mine, &b.events);
        each(b.tick, matched);
        true
    }

    /// Gives up on a tick in doubt (the server no longer keeps it, or did not answer): it is
    /// final with no events for this client, as the later confirmation implied.
    pub fn give_up(&mut self, tick: Tick, mut each: impl FnMut(Tick, bool)) {
        if let Some(mine) = self.doubtful.remove(&tick) {
            self.given_up += 1;
            let matched = self.compare(tick, &mine, &[]);
            each(tick, matched);
        }
    }

    /// Counts and returns whether a final tick's view equals its confirmed events.
    fn compare(&mut self, tick: Tick, mine: &BTreeMap<EventKey, CollisionEvent>, confirmed: &[CollisionEvent]) -> bool {
        if self.lost_before.is_some_and(|t| tick < t) {
            self.unverified += 1;
            return false;
        }
        let ok =
            mine.len() == confirmed.len() && confirmed.iter().all(|e| mine.get(&e.key()).is_some_and(|m| same(m, e)));
        if ok {
            self.matched += 1;
        } else {
            self.mismatched += 1;
            if self.mismatches.len() < MISMATCHES_KEPT {
                self.mismatches.push((tick, mine.len(), confirmed.len()));
            }
        }
        ok
    }

    /// The newest tick held.
    pub fn newest(&self) -> Option<Tick> {
        self.ticks.last_key_value().map(|(t, _)| *t)
    }

    /// Ticks held (bounded by the server's window while confirmations arrive, and by
    /// [`MAX_TICKS`]).
    pub fn held(&self) -> usize {
        self.ticks.len()
    }

    /// The events of an unconfirmed tick as they stand, by identity.
    pub fn at(&self, tick: Tick) -> impl Iterator<Item = &CollisionEvent> {
        self.ticks.get(&tick).into_iter().flat_map(|t| t.values())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use impact_protocol::{EntityId, EventStatus, Phase, Response};

    /// The ticks a confirmation made final, with whether each matched.
    fn finals(v: &mut EventView, tick: u32, events: Vec<CollisionEvent>) -> Vec<(u32, bool)> {
        let mut out = Vec::new();
        v.confirm(&EventBatch { tick: Tick(tick), revision: 0, events }, |t, m| out.push((t.0, m)));
        out
    }

    pub(crate) fn event(a: u32, b: u32, toi: f64) -> CollisionEvent {
        CollisionEvent {
            tick: Tick(5),
            toi,
            a: EntityId(a),
            b: EntityId(b),
            point: [0.0; 3],
            normal: [1.0, 0.0, 0.0],
            depth_m: 0.0,
            closing_speed_mps: 1.0,
            phase: Phase::Begin,
            response: Response::Bounce,
            status: EventStatus::Provisional,
        }
    }

    /// Events, then a correction that amends one and retracts another, then the confirmed batch:
    /// the view as it stands matches it, and the tick leaves the view.
    #[test]
    fn corrections_apply_by_identity_and_confirmation_compares() {
        let mut v = EventView::default();
        v.events(&EventBatch { tick: Tick(5), revision: 0, events: vec![event(1, 2, 0.5), event(3, 4, 0.25)] });
        let amended = event(1, 2, 0.75);
        v.correct(&CorrectionBatch {
            tick: Tick(5),
            revision: 1,
            retracted: vec![event(3, 4, 0.25)],
            amended: vec![amended.clone()],
            added: vec![],
        });
        assert_eq!(v.at(Tick(5)).collect::<Vec<_>>(), vec![&amended]);
        assert_eq!(finals(&mut v, 5, vec![amended]), [(5, true)]);
        assert_eq!((v.held(), v.matched, v.corrections), (0, 1, 1));
        v.events(&EventBatch { tick: Tick(6), revision: 0, events: vec![event(1, 2, 0.5)] });
        assert_eq!(finals(&mut v, 6, vec![]), [(6, false)]);
        assert_eq!(v.mismatched, 1);
    }

    /// A link lost and back before tick 10: a tick before it that lost its events to the outage
    /// is taken from the confirmed batch without counting a mismatch; tick 10 and later are
    /// compared as before.
    #[test]
    fn ticks_before_a_lost_link_came_back_are_not_compared() {
        let mut v = EventView::default();
        v.lost_before(Tick(10));
        assert_eq!(finals(&mut v, 9, vec![event(1, 2, 0.5)]), [(9, false)]);
        assert_eq!((v.matched, v.mismatched, v.unverified), (0, 0, 1));
        v.events(&EventBatch { tick: Tick(10), revision: 0, events: vec![event(1, 2, 0.5)] });
        assert_eq!(finals(&mut v, 10, vec![]), [(10, false)]);
        assert_eq!((v.matched, v.mismatched, v.unverified), (0, 1, 1));
        v.lost_before(Tick(4));
        assert_eq!(finals(&mut v, 9, vec![]), [(9, false)], "an earlier loss moves nothing");
        assert_eq!(v.unverified, 2);
    }

    /// Confirmations that never come: the oldest ticks go past the bound, counted.
    #[test]
    fn the_view_is_bounded() {
        let mut v = EventView::default();
        for t in 0..(MAX_TICKS as u32 + 10) {
            v.events(&EventBatch { tick: Tick(t), revision: 0, events: vec![] });
        }
        assert_eq!((v.held(), v.forgotten), (MAX_TICKS, 10));
    }

    /// A tick whose events were all retracted gets no confirmation of its own on the client's
    /// stream: the next confirmation makes it final (matched: the view is empty, as the record),
    /// and a tick whose view still held an event nobody confirmed is a mismatch. Nothing is held
    /// after, so a long match's views stay small.
    #[test]
    fn a_confirmation_makes_every_earlier_tick_final() {
        let mut v = EventView::default();
        v.events(&EventBatch { tick: Tick(3), revision: 0, events: vec![event(1, 2, 0.5)] });
        v.correct(&CorrectionBatch {
            tick: Tick(3),
            revision: 1,
            retracted: vec![event(1, 2, 0.5)],
            amended: vec![],
            added: vec![],
        });
        v.events(&EventBatch { tick: Tick(4), revision: 0, events: vec![event(3, 4, 0.5)] });
        v.events(&EventBatch { tick: Tick(5), revision: 0, events: vec![event(1, 2, 0.25)] });
        v.events(&EventBatch { tick: Tick(7), revision: 0, events: vec![event(1, 2, 0.75)] });
        // Tick 4 still held an event with no batch of its own: in doubt, until given up on.
        assert_eq!(finals(&mut v, 5, vec![event(1, 2, 0.25)]), [(3, true), (5, true)]);
        assert_eq!(v.doubtful().collect::<Vec<_>>(), [Tick(4)]);
        let mut gave_up = Vec::new();
        v.give_up(Tick(4), |t, m| gave_up.push((t.0, m)));
        assert_eq!(gave_up, [(4, false)]);
        assert_eq!((v.held(), v.matched, v.mismatched, v.implied), (1, 2, 1, 2));
        assert_eq!(v.newest(), Some(Tick(7)), "later ticks stay");
        for t in 8..(8 + 3 * MAX_TICKS as u32) {
            v.events(&EventBatch { tick: Tick(t), revision: 0, events: vec![event(1, 2, 0.5)] });
            v.correct(&CorrectionBatch {
                tick: Tick(t),
                revision: 1,
                retracted: vec![event(1, 2, 0.5)],
                amended: vec![],
                added: vec![],
            });
            if t % 16 == 0 {
                finals(&mut v, t, vec![]);
                assert_eq!(v.held(), 0);
            }
        }
        let doubtful: Vec<Tick> = v.doubtful().collect();
        assert_eq!(doubtful, [Tick(7)], "tick 7's event was never confirmed");
        v.give_up(Tick(7), |_, _| {});
        assert_eq!(
            (v.forgotten, v.mismatched, v.given_up, v.doubtful().count()),
            (0, 2, 2, 0),
            "both differed as given up"
        );
    }

    /// A tick in doubt (its batch lost, a later one came) is made final by the batch the server
    /// kept: matched when the view held what it says; a batch of a tick not in doubt changes
    /// nothing; past [`MAX_DOUBTFUL`] ticks are compared at once.
    #[test]
    fn a_lost_batch_recovered_makes_its_tick_final() {
        let mut v = EventView::default();
        v.events(&EventBatch { tick: Tick(4), revision: 0, events: vec![event(3, 4, 0.5)] });
        assert_eq!(finals(&mut v, 6, vec![]), [(6, true)]);
        let kept = EventBatch { tick: Tick(4), revision: 0, events: vec![event(3, 4, 0.5)] };
        let mut heard = Vec::new();
        assert!(!v.recovered(&EventBatch { tick: Tick(6), ..kept.clone() }, |t, m| heard.push((t.0, m))));
        assert!(v.recovered(&kept, |t, m| heard.push((t.0, m))));
        assert!(!v.recovered(&kept, |t, m| heard.push((t.0, m))), "once");
        assert_eq!(heard, [(4, true)]);
        assert_eq!((v.matched, v.mismatched, v.recovered, v.implied), (2, 0, 1, 1));
        for t in 10..(10 + MAX_DOUBTFUL as u32 + 2) {
            v.events(&EventBatch { tick: Tick(t), revision: 0, events: vec![event(3, 4, 0.5)] });
        }
        let finals = finals(&mut v, 100, vec![]);
        assert_eq!(v.doubtful().count(), MAX_DOUBTFUL);
        assert_eq!(finals.len(), 3, "two past the bound, and tick 100");
    }
}
