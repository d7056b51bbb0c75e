//! Who owns a world: its epoch (a fencing token), the fence, and the owner's announcements.
//!
//! A world's first server owns it at epoch 1; a standby that takes over owns it at one more than
//! the newest epoch it has heard. Everything a server publishes or replies for the world carries
//! its epoch as the Zenoh attachment ([`Epoch::attachment`]), and the owner announces itself on
//! `owner` four times a second. A server that hears a newer epoch than its own is *fenced*: from
//! that moment its egress and state threads publish nothing for the world, and the tick loop
//! ends it. A server whose own process stalled for longer than its lease (a hung host, a long
//! pause: its peers have declared it gone, and a standby may own the world now) *holds* its
//! publications until it has been reachable long enough to hear a newer owner, and is fenced if
//! it does (PROTOCOL.md, "Failover").

use impact_protocol::Epoch;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;
use zenoh::Wait;

/// How often the owner announces itself on `owner`.
pub const ANNOUNCE_EVERY: Duration = Duration::from_millis(250);

/// How long a server that stalled holds its publications once it is reachable again: long
/// enough for its link to be re-established if it was closed under it (Zenoh retries within
/// 500 ms) and for several announcements of a newer owner to arrive.
pub const HOLD_REACHABLE: Duration = Duration::from_millis(2_000);

/// The longest a stalled server holds while it reaches nobody: a server alone on its host (a
/// laptop that slept, with no client connected) has nobody to be fenced by, and publishes again.
pub const HOLD_UNREACHABLE: Duration = Duration::from_millis(4_000);

/// One world's ownership, shared by its tick, egress and state threads and its callbacks.
#[derive(Debug, Default)]
pub struct Owner {
    /// This process's epoch for the world; 0 while it follows as a standby.
    epoch: AtomicU64,
    /// The newest epoch heard from any server of the world (this one's included).
    newest: AtomicU64,
    /// Held after a stall, until the process knows it still owns the world.
    held: AtomicBool,
    /// Messages not published because the world was held or fenced.
    withheld: AtomicU64,
}

impl Owner {
    /// A world's first owner.
    pub fn first() -> Owner {
        let o = Owner::default();
        o.own(Epoch::FIRST);
        o
    }

    /// This process's epoch (`None` while it follows).
    pub fn epoch(&self) -> Option<Epoch> {
        Some(Epoch(self.epoch.load(Ordering::SeqCst))).filter(|e| e.0 > 0)
    }

    /// The newest epoch heard, this process's own included.
    pub fn newest(&self) -> Epoch {
        Epoch(self.newest.load(Ordering::SeqCst))
    }

    /// Takes the world at `epoch` (a takeover).
    pub fn own(&self, epoch: Epoch) {
        self.epoch.store(epoch.0, Ordering::SeqCst);
        self.newest.fetch_max(epoch.0, Ordering::SeqCst);
    }

    /// Another server of the world said `epoch` (an announcement, a log entry, a checkpoint).
    pub fn heard(&self, epoch: Epoch) {
        self.newest.fetch_max(epoch.0, Ordering::SeqCst);
    }

    /// The newer owner's epoch, once one has been heard: this process must not publish again.
    pub fn fenced(&self) -> Option<Epoch> {
        let (own, newest) = (self.epoch.load(Ordering::SeqCst), self.newest.load(Ordering::SeqCst));
        (own > 0 && newest > own).then_some(Epoch(newest))
    }

    /// Holds (`true`) or releases the world's publications.
    pub fn hold(&self, held: bool) {
        self.held.store(held, Ordering::SeqCst);
    }

    /// The epoch to publish a message with, or `Err` when nothing may be published (held, or
    /// fenced; counted). A standby's (no epoch yet) go out without one.
    pub(crate) fn stamp(&self) -> Result<Option<Epoch>, ()> {
        if self.held.load(Ordering::Relaxed) || self.fenced().is_some() {
            self.withheld.fetch_add(1, Ordering::Relaxed);
            return Err(());
        }
        Ok(self.epoch())
    }

    /// Messages withheld so far.
    pub fn withheld(&self) -> u64 {
        self.withheld.load(Ordering::Relaxed)
    }
}

/// The epoch a sample carries, if any.
pub fn epoch_of(sample: &zenoh::sample::Sample) -> Option<Epoch> {
    sample.attachment().and_then(|a| Epoch::from_attachment(&a.to_bytes()))
}

/// Whether the session has a live link to a router or a peer: a process that has none cannot
/// tell a primary that died from a network that left it alone.
pub fn reachable(zs: &zenoh::Session) -> bool {
    let info = zs.info();
    info.routers_zid().wait().next().is_some() || info.peers_zid().wait().next().is_some()
}

/// Whether the session has a live link to a router (the way clients reach a server deployed
/// behind routers; its direct peers, a standby or a tap, carry no client's presence).
pub fn routed(zs: &zenoh::Session) -> bool {
    zs.info().routers_zid().wait().next().is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first owner stamps epoch 1; a newer epoch heard fences it (nothing goes out, counted);
    /// a hold withholds too and is released; a standby stamps nothing until it owns the world.
    #[test]
    fn the_fence_and_the_hold_withhold_everything() {
        let o = Owner::first();
        assert_eq!(o.stamp(), Ok(Some(Epoch(1))));
        o.heard(Epoch(1));
        assert_eq!(o.fenced(), None, "its own epoch does not fence it");
        o.hold(true);
        assert_eq!(o.stamp(), Err(()));
        o.hold(false);
        assert!(o.stamp().is_ok());
        o.heard(Epoch(2));
        assert_eq!(o.fenced(), Some(Epoch(2)));
        assert_eq!((o.stamp(), o.stamp(), o.withheld()), (Err(()), Err(()), 3));

        let standby = Owner::default();
        standby.heard(Epoch(4));
        assert_eq!((standby.stamp(), standby.fenced()), (Ok(None), None), "a follower is never fenced");
        standby.own(standby.newest().next());
        assert_eq!((standby.epoch(), standby.stamp()), (Some(Epoch(5)), Ok(Some(Epoch(5)))));
        assert_eq!(Epoch::from_attachment(&Epoch(5).attachment()), Some(Epoch(5)));
        assert_eq!(Epoch::from_attachment(&[1, 2, 3]), None);
    }
}
