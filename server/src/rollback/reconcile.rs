//! Reconciling a re-simulated tick with what was already published for it.
//!
//! Events are matched by their identity `(tick, a, b, phase)`. An event published before and
//! missing now is *retracted*; one present now and not before is *added*; one present in both
//! whose fields differ is *amended*. Because re-simulation is bit-for-bit deterministic, an
//! unchanged past reproduces its events exactly, so the tolerances below only have to separate a
//! real change from nothing, not absorb noise: a time of impact that moved by more than 1e-9 of a
//! tick, a point, depth or closing speed by more than a micrometre (per second), a normal by more
//! than 1e-6 (about 0.2 arc-seconds), or a different response, is an amendment.

use impact_protocol::{CollisionEvent, EventKey};

/// What changed in one tick's events.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Diff {
    /// Published, no longer happens (as published).
    pub retracted: Vec<CollisionEvent>,
    /// Still happens with different fields (new values).
    pub amended: Vec<CollisionEvent>,
    /// Happens now, was not published.
    pub added: Vec<CollisionEvent>,
}

impl Diff {
    /// Whether nothing changed.
    pub fn is_empty(&self) -> bool {
        self.retracted.is_empty() && self.amended.is_empty() && self.added.is_empty()
    }
}

/// Whether two events with the same identity differ enough to publish an amendment.
pub fn differs(a: &CollisionEvent, b: &CollisionEvent) -> bool {
    let far = |x: &[f64; 3], y: &[f64; 3], tol: f64| x.iter().zip(y).any(|(p, q)| (p - q).abs() > tol);
    (a.toi - b.toi).abs() > 1e-9
        || far(&a.point, &b.point, 1e-6)
        || far(&a.normal, &b.normal, 1e-6)
        || (a.depth_m - b.depth_m).abs() > 1e-6
        || (a.closing_speed_mps - b.closing_speed_mps).abs() > 1e-6
        || a.response != b.response
}

/// The difference between the events published for a tick and the events a re-simulation
/// produced for it.
pub fn diff(published: &[CollisionEvent], now: &[CollisionEvent]) -> Diff {
    let mut old: Vec<(EventKey, &CollisionEvent)> = published.iter().map(|e| (e.key(), e)).collect();
    let mut new: Vec<(EventKey, &CollisionEvent)> = now.iter().map(|e| (e.key(), e)).collect();
    old.sort_by_key(|x| x.0);
    new.sort_by_key(|x| x.0);
    let mut d = Diff::default();
    let (mut i, mut j) = (0, 0);
    while i < old.len() || j < new.len() {
        match (old.get(i), new.get(j)) {
            (Some(o), Some(n)) if o.0 == n.0 => {
                if differs(o.1, n.1) {
                    d.amended.push(n.1.clone());
                }
                i += 1;
                j += 1;
            }
            (Some(o), Some(n)) if o.0 < n.0 => {
                d.retracted.push(o.1.clone());
                i += 1;
            }
            (Some(_), Some(n)) => {
                d.added.push(n.1.clone());
                j += 1;
            }
            (Some(o), None) => {
                d.retracted.push(o.1.clone());
                i += 1;
            }
            (None, Some(n)) => {
                d.added.push(n.1.clone());
                j += 1;
            }
            (None, None) => break,
        }
    }
    d
}
