//! The input outbox: sequence numbers for a client's inputs, and what it remembers of each sent
//! input until the server answers it (PROTOCOL.md: every input gets one `ack` or one `reject`
//! carrying its `seq`).
//!
//! Numbers start at 1 and increase by one per input, going on at 1 after `u32::MAX` (0 is never
//! used, so a reject without a sequence is never mistaken for one: [`impact_protocol::serial`]).
//! Held inputs are ordered by their number unwrapped, so the oldest stays the oldest across the
//! wrap. An answer is matched by its `seq` and forgets the input;
//! an answer for a `seq` not held (answered already, or never sent) is `None`, for the caller to
//! count. Bounded: past [`Outbox::capacity`] inputs awaiting an answer (answers lost on the way
//! back are never coming), the oldest are forgotten and counted.

use impact_protocol::Tick;
use std::collections::BTreeMap;
use std::time::Instant;

/// What the outbox remembers of a sent input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sent {
    /// When it was sent (the caller's clock).
    pub at: Instant,
    /// The tick it was stamped for.
    pub tick: Tick,
    /// The view tick it carried (ahead timing), if any.
    pub view: Option<Tick>,
    /// When a message last carried it (its first sending, or a copy in a later message).
    pub carried: Instant,
    /// The session's own input of no actions, sent to learn what became of the game's
    /// (`impact_client::session::KEEPALIVE_AFTER`): its answer is not the game's.
    pub keepalive: bool,
}

/// The first input's number, unwrapped: seq 1, with a wrap's room below it for [`Outbox::key`]
/// to place the seqs before it.
const FIRST: u64 = (1 << 32) + 1;

/// Sequence numbers and inputs awaiting an answer (see the module docs).
#[derive(Clone, Debug)]
pub struct Outbox {
    /// The next input's number, unwrapped (its seq is the low 32 bits; never 0 there).
    next: u64,
    /// By unwrapped number.
    pending: BTreeMap<u64, Sent>,
    /// Whether any input was numbered.
    numbered: bool,
    capacity: usize,
    forgotten: u64,
}

impl Default for Outbox {
    fn default() -> Outbox {
        Outbox::new(Outbox::DEFAULT_CAPACITY)
    }
}

impl Outbox {
    /// Inputs held awaiting an answer by default: 1,024, over 100 s of inputs at 10 a second
    /// with every answer lost.
    pub const DEFAULT_CAPACITY: usize = 1024;

    /// An outbox holding at most `capacity` inputs awaiting an answer (at least one).
    pub fn new(capacity: usize) -> Outbox {
        Outbox { next: FIRST, pending: BTreeMap::new(), numbered: false, capacity: capacity.max(1), forgotten: 0 }
    }

    /// The most inputs held awaiting an answer.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The sequence number for the next input.
    pub fn next_seq(&mut self) -> u32 {
        let seq = self.next as u32;
        // After u32::MAX comes 1 (0 is skipped).
        self.next += if seq == u32::MAX { 2 } else { 1 };
        self.numbered = true;
        seq
    }

    /// `seq` unwrapped: the number nearest this outbox's next one with those low 32 bits.
    fn key(&self, seq: u32) -> u64 {
        let back = (self.next as u32).wrapping_sub(seq) as i32;
        self.next.wrapping_add_signed(-i64::from(back))
    }

    /// Numbers go on from `next` if that is further than this outbox's own next number: the
    /// server's `next_seq` after a reconnect (seqs are never reused while it remembers the
    /// client). Inputs before it still awaiting an answer stay awaited: the server answered
    /// each or never heard it, and the next ack says which it accepted. An outbox that numbered
    /// nothing yet takes `next` as it is (a client that restarted, resuming where the server left
    /// it).
    pub fn resume_from(&mut self, next: u32) {
        let at = if self.numbered { self.key(next) } else { FIRST - 1 + u64::from(next) };
        if at > self.next {
            self.next = at + u64::from(at as u32 == 0);
        }
    }

    /// Remembers input `seq` as sent; forgets the oldest past the capacity.
    pub fn sent(&mut self, seq: u32, sent: Sent) {
        self.pending.insert(self.key(seq), sent);
        while self.pending.len() > self.capacity {
            self.pending.pop_first();
            self.forgotten += 1;
        }
    }

    /// The server answered `seq` (an ack or a reject): what was sent, and the input is forgotten;
    /// `None` when no such input awaits an answer.
    pub fn answered(&mut self, seq: u32) -> Option<Sent> {
        self.pending.remove(&self.key(seq))
    }

    /// A message carried input `seq` again at `at` (a copy).
    pub fn carried(&mut self, seq: u32, at: Instant) {
        let k = self.key(seq);
        if let Some(s) = self.pending.get_mut(&k) {
            s.carried = s.carried.max(at);
        }
    }

    /// Takes the inputs awaiting an answer that `lost` says are lost, oldest first.
    pub fn take_pending(&mut self, mut lost: impl FnMut(u32, &Sent) -> bool) -> Vec<(u32, Sent)> {
        let keys: Vec<u64> = self.pending.iter().filter(|(&k, s)| lost(k as u32, s)).map(|(&k, _)| k).collect();
        keys.into_iter().filter_map(|k| self.pending.remove(&k).map(|s| (k as u32, s))).collect()
    }

    /// The ticks of the inputs awaiting an answer.
    pub fn pending_ticks(&self) -> impl Iterator<Item = Tick> + '_ {
        self.pending.values().map(|s| s.tick)
    }

    /// Whether input `seq` awaits an answer.
    pub fn awaits(&self, seq: u32) -> bool {
        self.pending.contains_key(&self.key(seq))
    }

    /// Whether any of the last `reach` seqs numbered is the game's input (not a keepalive)
    /// awaiting an answer.
    pub fn awaits_the_games(&self, reach: u32) -> bool {
        let from = self.next.saturating_sub(u64::from(reach));
        self.pending.range(from..).any(|(_, s)| !s.keepalive)
    }

    /// What is remembered of input `seq`, while it awaits an answer.
    pub fn get(&self, seq: u32) -> Option<&Sent> {
        self.pending.get(&self.key(seq))
    }

    /// The game's inputs awaiting an answer (not keepalives).
    pub fn pending_games(&self) -> usize {
        self.pending.values().filter(|s| !s.keepalive).count()
    }

    /// Inputs awaiting an answer.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// Inputs forgotten unanswered because the outbox was full.
    pub fn forgotten(&self) -> u64 {
        self.forgotten
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Numbers start at 1 and follow on; an answer matches once; a full outbox forgets the
    /// oldest and counts it.
    #[test]
    fn inputs_are_numbered_matched_once_and_bounded() {
        let now = Instant::now();
        let mut o = Outbox::new(3);
        let sent = |t: u32| Sent { at: now, tick: Tick(t), view: None, carried: now, keepalive: false };
        let seqs: Vec<u32> = (0..5).map(|_| o.next_seq()).collect();
        assert_eq!(seqs, [1, 2, 3, 4, 5]);
        for &s in &seqs {
            o.sent(s, sent(s + 100));
        }
        assert_eq!((o.pending(), o.forgotten()), (3, 2));
        assert_eq!(o.answered(1), None, "forgotten");
        assert_eq!(o.answered(4).map(|s| s.tick), Some(Tick(104)));
        assert_eq!(o.answered(4), None, "answered once");
        assert_eq!(o.pending(), 2);
    }

    /// Resumed just before `u32::MAX` (a server's welcome can say so): numbers go on at 1 after
    /// it, the oldest held is still the first forgotten and the first lost, and a resume from a
    /// seq past the wrap forgets those before it.
    #[test]
    fn numbers_go_on_across_the_wrap() {
        let now = Instant::now();
        let mut o = Outbox::new(4);
        let sent = Sent { at: now, tick: Tick(1), view: None, carried: now, keepalive: false };
        o.resume_from(u32::MAX - 2);
        let seqs: Vec<u32> = (0..6).map(|_| o.next_seq()).collect();
        assert_eq!(seqs, [u32::MAX - 2, u32::MAX - 1, u32::MAX, 1, 2, 3]);
        for &s in &seqs {
            o.sent(s, sent);
        }
        assert_eq!((o.pending(), o.forgotten()), (4, 2), "the two oldest forgotten");
        assert!(!o.awaits(u32::MAX - 1) && o.awaits(u32::MAX) && o.awaits(1));
        let lost: Vec<u32> = o.take_pending(|_, _| true).into_iter().map(|(seq, _)| seq).collect();
        assert_eq!(lost, [u32::MAX, 1, 2, 3], "oldest first");
        for &s in &seqs[3..] {
            o.sent(s, sent);
        }
        o.resume_from(2);
        assert!(o.awaits(1) && o.awaits(2) && o.awaits(3), "still awaited: the next ack tells");
        assert_eq!(o.next_seq(), 4, "a resume from behind does not go back");
        o.resume_from(u32::MAX);
        assert_eq!(o.next_seq(), 5, "nor from before the wrap");
    }
}
