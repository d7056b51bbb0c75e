//! One connection's queue toward its browser, bounded in messages and bytes.
//!
//! What the server publishes for a player arrives on Zenoh's threads whatever the browser's
//! pace; the queue holds it until the connection's writer sends it. A browser that reads too
//! slowly (a background tab, a stalled phone) must not grow the gateway's memory, so the queue
//! has a fixed bound, and when it is reached state frames go first: a client that misses one
//! sees the gap in the frame numbers and asks for a full frame (PROTOCOL.md, "State streams"),
//! which brings it back to the world as it is.
//! Acks, rejects and events are not dropped: when they no longer fit after every state frame
//! was dropped, the connection is closed `too_slow` (the player's client reconnects and resumes
//! within the grace period).

use crate::stats::Counters;
use crate::wire::Close;
use std::collections::VecDeque;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// What a queued message is, for the drop policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A state frame: dropped first.
    State,
    /// Anything else (acks, rejects, events, pongs, the welcome, notices): never dropped.
    Kept,
}

/// A queued message, and when it was queued (the gateway's own share of its latency is from
/// then to its write).
#[derive(Debug)]
pub struct Queued {
    /// What it is.
    pub kind: Kind,
    /// The MessagePack message.
    pub bytes: Vec<u8>,
    /// When the gateway had it.
    pub at: Instant,
}

/// What became of a pushed message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pushed {
    /// Queued (state frames may have been dropped to make room).
    Queued,
    /// A state frame that did not fit: dropped.
    Dropped,
    /// A message that must not be dropped did not fit: close the connection `too_slow`.
    Overflow,
}

/// The bounded queue.
#[derive(Debug)]
pub struct Outbox {
    queue: VecDeque<Queued>,
    bytes: usize,
    max_messages: usize,
    max_bytes: usize,
    /// State frames dropped so far.
    pub dropped_state: u64,
    /// Set once a kept message overflowed: nothing more is queued.
    overflowed: bool,
}

impl Outbox {
    /// An empty queue holding at most `max_messages` messages and `max_bytes` bytes.
    pub fn new(max_messages: usize, max_bytes: usize) -> Outbox {
        Outbox {
            queue: VecDeque::new(),
            bytes: 0,
            max_messages: max_messages.max(1),
            max_bytes,
            dropped_state: 0,
            overflowed: false,
        }
    }

    fn fits(&self, len: usize) -> bool {
        self.queue.len() < self.max_messages && self.bytes + len <= self.max_bytes
    }

    /// Queues `bytes`, dropping state frames (oldest first) to make room.
    pub fn push(&mut self, kind: Kind, bytes: Vec<u8>) -> Pushed {
        if self.overflowed {
            return Pushed::Overflow;
        }
        while !self.fits(bytes.len()) {
            let Some(i) = self.queue.iter().position(|q| q.kind == Kind::State) else { break };
            if let Some(old) = self.queue.remove(i) {
                self.bytes -= old.bytes.len();
                self.dropped_state += 1;
            }
        }
        if self.fits(bytes.len()) {
            self.bytes += bytes.len();
            self.queue.push_back(Queued { kind, bytes, at: Instant::now() });
            return Pushed::Queued;
        }
        match kind {
            Kind::State => {
                self.dropped_state += 1;
                Pushed::Dropped
            }
            Kind::Kept => {
                self.overflowed = true;
                Pushed::Overflow
            }
        }
    }

    /// Whether a kept message overflowed (the connection is to be closed).
    pub fn overflowed(&self) -> bool {
        self.overflowed
    }

    /// Takes every queued message, oldest first, into `out`.
    pub fn drain_into(&mut self, out: &mut Vec<Queued>) {
        out.extend(self.queue.drain(..));
        self.bytes = 0;
    }

    /// Messages queued.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// Bytes queued.
    pub fn bytes(&self) -> usize {
        self.bytes
    }
}

/// A connection's outbox shared with Zenoh's callbacks, the writer woken when there is
/// something to send or the connection is to close.
#[derive(Debug)]
pub struct Mailbox {
    outbox: Mutex<Outbox>,
    /// Woken on every delivery and on close.
    pub wake: tokio::sync::Notify,
    closing: Mutex<Option<(Close, String)>>,
    counters: Arc<Counters>,
}

impl Mailbox {
    /// An empty mailbox with the given bounds, counting into `counters`.
    pub fn new(max_messages: usize, max_bytes: usize, counters: Arc<Counters>) -> Mailbox {
        Mailbox {
            outbox: Mutex::new(Outbox::new(max_messages, max_bytes)),
            wake: tokio::sync::Notify::new(),
            closing: Mutex::new(None),
            counters,
        }
    }

    /// Queues a message for the browser (or, when it does not fit, drops it or closes the
    /// connection, as [`Outbox::push`] says).
    pub fn deliver(&self, kind: Kind, bytes: Vec<u8>) {
        let (pushed, dropped) = {
            let mut o = self.lock();
            let before = o.dropped_state;
            let pushed = o.push(kind, bytes);
            (pushed, o.dropped_state - before)
        };
        self.counters.state_dropped.fetch_add(dropped, Relaxed);
        match pushed {
            Pushed::Queued => self.wake.notify_one(),
            Pushed::Dropped => {}
            Pushed::Overflow => self.close(Close::TooSlow, "the browser read too slowly"),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Outbox> {
        self.outbox.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Asks the connection to close with `why` (the first reason given stands).
    pub fn close(&self, why: Close, detail: &str) {
        let mut c = self.closing.lock().unwrap_or_else(|e| e.into_inner());
        if c.is_none() {
            *c = Some((why, detail.to_string()));
        }
        drop(c);
        self.wake.notify_one();
    }

    /// The reason to close, once asked.
    pub fn closing(&self) -> Option<(Close, String)> {
        self.closing.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Takes what is queued into `out`, oldest first.
    pub fn drain_into(&self, out: &mut Vec<Queued>) {
        self.lock().drain_into(out);
    }

    /// A sample of an older owner, dropped.
    pub fn count_stale_owner(&self) {
        self.counters.stale_owner.fetch_add(1, Relaxed);
    }

    /// Messages on the player's events key that never reached the gateway (a skip in the key's
    /// numbers).
    pub fn count_messages_lost(&self, lost: u64) {
        self.counters.messages_lost.fetch_add(lost, Relaxed);
    }

    /// A sample that did not decode, dropped.
    pub fn count_malformed(&self) {
        self.counters.malformed_from_server.fetch_add(1, Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_frames_go_first_then_the_connection() {
        let mut o = Outbox::new(4, 1000);
        assert_eq!(o.push(Kind::State, vec![1; 10]), Pushed::Queued);
        assert_eq!(o.push(Kind::Kept, vec![2; 10]), Pushed::Queued);
        assert_eq!(o.push(Kind::State, vec![3; 10]), Pushed::Queued);
        assert_eq!(o.push(Kind::Kept, vec![4; 10]), Pushed::Queued);
        // Full: a kept message makes room by dropping the oldest state frame.
        assert_eq!(o.push(Kind::Kept, vec![5; 10]), Pushed::Queued);
        assert_eq!(o.dropped_state, 1);
        // A state frame replaces the other one.
        assert_eq!(o.push(Kind::State, vec![6; 10]), Pushed::Queued);
        assert_eq!(o.dropped_state, 2);
        // Only kept messages and the newest state frame: a state frame fits by dropping that one.
        assert_eq!(o.push(Kind::Kept, vec![7; 10]), Pushed::Queued);
        assert_eq!(o.dropped_state, 3);
        assert_eq!(o.push(Kind::State, vec![8; 10]), Pushed::Dropped);
        assert_eq!(o.push(Kind::Kept, vec![9; 10]), Pushed::Overflow);
        assert!(o.overflowed());
        assert_eq!(o.push(Kind::State, vec![10; 1]), Pushed::Overflow, "nothing after an overflow");
        let mut out = Vec::new();
        o.drain_into(&mut out);
        let firsts: Vec<u8> = out.iter().map(|q| q.bytes[0]).collect();
        assert_eq!(firsts, vec![2, 4, 5, 7], "kept messages in order");
        assert_eq!((o.len(), o.bytes()), (0, 0));
    }

    /// The byte bound holds as the message bound does, whatever is pushed.
    #[test]
    fn the_bounds_always_hold() {
        let mut o = Outbox::new(64, 4096);
        let mut x: u32 = 12345;
        for _ in 0..10_000 {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let kind = if x % 3 == 0 { Kind::Kept } else { Kind::State };
            let len = (x >> 8) as usize % 700;
            o.push(kind, vec![0; len]);
            assert!(o.len() <= 64 && o.bytes() <= 4096);
            if o.overflowed() || x % 17 == 0 {
                o = Outbox::new(64, 4096);
            }
        }
    }
}
