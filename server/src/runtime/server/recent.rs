//! The confirmed batches of recent ticks, as they went out, for `query/confirmed`: a subscriber
//! that missed one (a router dropped it, the primary died as it left) asks for it again. A primary
//! keeps what it confirms; a standby keeps what it hears its primary confirm, so after a takeover
//! it answers for the ticks before it too.
//!
//! Each event is kept with the clients that owned its bodies when it was confirmed: a client's
//! stream carries the events of the bodies it owns, and the answer for one client must be that
//! stream's batch even once the bodies are gone. A standby takes the owners from its replica
//! once it has stepped the tick, a window earlier than its primary looked: for a body removed in
//! between, its answer for the owner may hold an event the stream did not carry.

use impact_protocol::{ClientId, CollisionEvent, EventBatch, Tick};
use std::collections::BTreeMap;

/// Ticks kept: half a minute at 64 Hz. A subscriber notices a gap at the next batch, a tick later.
pub(super) const KEPT_TICKS: usize = 2048;

/// The most ticks one query may ask for.
pub(super) const MAX_QUERY_TICKS: u32 = KEPT_TICKS as u32;

/// A confirmed batch and, for each of its events, the owners of its two bodies.
struct Kept {
    batch: EventBatch,
    owners: Vec<[Option<ClientId>; 2]>,
}

/// The last [`KEPT_TICKS`] confirmed batches, by tick.
#[derive(Default)]
pub(super) struct Recent {
    ticks: BTreeMap<u32, Kept>,
}

impl Recent {
    /// Keeps `batch` (`owners` has one entry per event). A tick already kept stays as it was:
    /// what went out first is what subscribers hold.
    pub(super) fn keep(&mut self, batch: EventBatch, owners: Vec<[Option<ClientId>; 2]>) {
        debug_assert_eq!(batch.events.len(), owners.len());
        self.ticks.entry(batch.tick.0).or_insert(Kept { batch, owners });
        while self.ticks.len() > KEPT_TICKS {
            self.ticks.pop_first();
        }
    }

    /// Whether `t` is kept.
    pub(super) fn has(&self, t: Tick) -> bool {
        self.ticks.contains_key(&t.0)
    }

    /// The kept batches of ticks `from..=to`, oldest first: the world's, or (with `client`) the
    /// one its own stream carries, the events of bodies it owned (empty batches included, so the
    /// client knows the tick had none for it). Ticks not kept are left out.
    pub(super) fn batches(&self, from: Tick, to: Tick, client: Option<ClientId>) -> Vec<EventBatch> {
        self.ticks
            .range(from.0..=to.0)
            .map(|(_, k)| match client {
                None => k.batch.clone(),
                Some(c) => EventBatch {
                    tick: k.batch.tick,
                    revision: k.batch.revision,
                    events: mine(&k.batch.events, &k.owners, c),
                },
            })
            .collect()
    }
}

/// The events of `events` whose bodies `client` owned (`owners` per event), each once.
pub(super) fn mine(
    events: &[CollisionEvent],
    owners: &[[Option<ClientId>; 2]],
    client: ClientId,
) -> Vec<CollisionEvent> {
    let mut out = Vec::new();
    for (e, o) in events.iter().zip(owners) {
        if o.contains(&Some(client)) {
            push_once(&mut out, e);
        }
    }
    out
}

/// [`mine`] for every client owning a body of `events`, in one pass, by client.
pub(super) fn by_owner(
    events: &[CollisionEvent],
    owners: &[[Option<ClientId>; 2]],
) -> BTreeMap<ClientId, Vec<CollisionEvent>> {
    let mut out: BTreeMap<ClientId, Vec<CollisionEvent>> = BTreeMap::new();
    for (e, o) in events.iter().zip(owners) {
        for c in o.iter().flatten() {
            push_once(out.entry(*c).or_default(), e);
        }
    }
    out
}

/// Appends `e` unless it is the event just appended (both bodies owned by the one client).
fn push_once(out: &mut Vec<CollisionEvent>, e: &CollisionEvent) {
    if out.last().is_none_or(|l| l.key() != e.key()) {
        out.push(e.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use impact_protocol::{EntityId, EventStatus, Phase, Response};

    fn event(a: u32, b: u32) -> CollisionEvent {
        CollisionEvent {
            tick: Tick(0),
            toi: 0.5,
            a: EntityId(a),
            b: EntityId(b),
            point: [0.0; 3],
            normal: [0.0, 1.0, 0.0],
            depth_m: 0.0,
            closing_speed_mps: 1.0,
            phase: Phase::Begin,
            response: Response::Bounce,
            status: EventStatus::Confirmed,
        }
    }

    fn batch(t: u32, events: Vec<CollisionEvent>) -> EventBatch {
        EventBatch { tick: Tick(t), revision: 0, events }
    }

    /// Bounded, first copy kept, and a client's answer is its stream's batch: the events of the
    /// bodies it owned then, an empty batch for a tick with none.
    #[test]
    fn keeps_a_bounded_window_and_answers_per_client() {
        let mut r = Recent::default();
        for t in 0..(KEPT_TICKS as u32 + 10) {
            r.keep(batch(t, Vec::new()), Vec::new());
        }
        assert!(!r.has(Tick(9)) && r.has(Tick(10)) && r.has(Tick(KEPT_TICKS as u32 + 9)));
        let t = KEPT_TICKS as u32 + 10;
        let (c1, c2) = (ClientId(1), ClientId(2));
        r.keep(batch(t, vec![event(1, 2), event(3, 4)]), vec![[Some(c1), None], [None, Some(c2)]]);
        r.keep(batch(t, Vec::new()), Vec::new());
        assert_eq!(r.batches(Tick(t), Tick(t), None)[0].events.len(), 2, "the first copy stays");
        let for1 = r.batches(Tick(t - 1), Tick(t + 5), Some(c1));
        assert_eq!(for1.len(), 2, "the ticks kept in the range, no more");
        assert_eq!((for1[0].events.len(), for1[1].events.clone()), (0, vec![event(1, 2)]));
        assert_eq!(r.batches(Tick(t), Tick(t), Some(ClientId(3)))[0].events, Vec::new());
        assert!(r.has(Tick(t)) && !r.has(Tick(9)));
    }

    /// The one pass gives each client what [`mine`] gives it: an event of two bodies of one
    /// client once, an event of two clients' bodies to both, an unowned one to none.
    #[test]
    fn by_owner_is_mine_for_every_client() {
        let (c1, c2) = (ClientId(1), ClientId(2));
        let events = vec![event(1, 2), event(3, 4), event(5, 6), event(7, 8)];
        let owners = vec![[Some(c1), Some(c1)], [Some(c1), Some(c2)], [None, None], [None, Some(c2)]];
        let all = by_owner(&events, &owners);
        assert_eq!(all.keys().copied().collect::<Vec<_>>(), vec![c1, c2]);
        for c in [c1, c2] {
            assert_eq!(all[&c], mine(&events, &owners, c));
        }
        assert_eq!(all[&c1], vec![event(1, 2), event(3, 4)]);
        assert_eq!(all[&c2], vec![event(3, 4), event(7, 8)]);
    }
}
