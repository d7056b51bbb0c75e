//! The input outbox: sequence numbers for a client's inputs, and what it remembers of each sent
//! input until the server answers it (PROTOCOL.md: every input gets one `ack` or one `reject`
//! carrying its `seq`).
//!
//! Numbers start at 1 and increase by one per input (0 is never used, so a reject without a
//! sequence is never mistaken for one). An answer is matched by its `seq` and forgets the input;
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
}

/// Sequence numbers and inputs awaiting an answer (see the module docs).
#[derive(Clone, Debug)]
pub struct Outbox {
    next: u32,
    pending: BTreeMap<u32, Sent>,
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
        Outbox { next: 1, pending: BTreeMap::new(), capacity: capacity.max(1), forgotten: 0 }
    }

    /// The most inputs held awaiting an answer.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The sequence number for the next input.
    pub fn next_seq(&mut self) -> u32 {
        let seq = self.next;
        self.next = self.next.checked_add(1).unwrap_or(1);
        seq
    }

    /// Numbers go on from `next` if that is further than this outbox's own next number: the
    /// server's `next_seq` after a reconnect (seqs are never reused while it remembers the
    /// client). Inputs below it awaiting an answer were accepted, their acks lost: forgotten.
    pub fn resume_from(&mut self, next: u32) {
        self.next = self.next.max(next);
        self.pending.retain(|&seq, _| seq >= next);
    }

    /// Remembers input `seq` as sent; forgets the oldest past the capacity.
    pub fn sent(&mut self, seq: u32, sent: Sent) {
        self.pending.insert(seq, sent);
        while self.pending.len() > self.capacity {
            self.pending.pop_first();
            self.forgotten += 1;
        }
    }

    /// The server answered `seq` (an ack or a reject): what was sent, and the input is forgotten;
    /// `None` when no such input awaits an answer.
    pub fn answered(&mut self, seq: u32) -> Option<Sent> {
        self.pending.remove(&seq)
    }

    /// A message carried input `seq` again at `at` (a copy).
    pub fn carried(&mut self, seq: u32, at: Instant) {
        if let Some(s) = self.pending.get_mut(&seq) {
            s.carried = s.carried.max(at);
        }
    }

    /// Takes the inputs awaiting an answer that `lost` says are lost, oldest first.
    pub fn take_pending(&mut self, mut lost: impl FnMut(u32, &Sent) -> bool) -> Vec<(u32, Sent)> {
        let seqs: Vec<u32> = self.pending.iter().filter(|(&seq, s)| lost(seq, s)).map(|(&seq, _)| seq).collect();
        seqs.into_iter().filter_map(|seq| self.pending.remove(&seq).map(|s| (seq, s))).collect()
    }

    /// The ticks of the inputs awaiting an answer.
    pub fn pending_ticks(&self) -> impl Iterator<Item = Tick> + '_ {
        self.pending.values().map(|s| s.tick)
    }

    /// Whether input `seq` awaits an answer.
    pub fn awaits(&self, seq: u32) -> bool {
        self.pending.contains_key(&seq)
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
        let sent = |t: u32| Sent { at: now, tick: Tick(t), view: None, carried: now };
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
}
