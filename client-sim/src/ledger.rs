//! What the server owes a simulated client: the answers the load test's invariants count. Every
//! input delivered to the server is owed an answer (PROTOCOL.md, "inputs": an ack, or a reject
//! per copy, since a rejected input does not use up its seq), none is answered twice, and no
//! input is acked twice (applied twice).

use impact_protocol::serial::{later, precedes};
use impact_protocol::RejectReason;
use std::collections::{BTreeMap, BTreeSet};

/// Acked seqs a client remembers: four times the server's window of seqs (1,024), past which a
/// second ack could not be told from a first.
type AckedSeqs = impact_server::rollback::seq_window::Window<64>;

/// Seqs a welcome answered that a client remembers (the server's window of seqs).
const EXCUSED_KEPT: usize = 1024;

/// One client's account of the answers it is owed.
#[derive(Debug, Default)]
pub struct Ledger {
    /// The highest seq delivered to the server: seqs past it are delivered for the first time
    /// (messages are delivered in order, and each carries its newest input last).
    delivered: u32,
    /// Answers owed by the server, per seq: one per delivery of an input not yet accepted (a
    /// copy of an accepted input is skipped without an answer; a rejected one is answered again).
    owed: BTreeMap<u32, u32>,
    /// Seqs acked, the last [`AckedSeqs::SEQS`] (4,096): a second ack is an input applied twice.
    /// A fixed 520 bytes a client from the first input on (a set of the seqs grew for 14 minutes
    /// of a soak).
    acked: AckedSeqs,
    /// Seqs a welcome answered (below its `next_seq`, their answers lost with the old link): the
    /// server accepted some, and refused or never heard others, so one later answer of each may
    /// still come (a copy carried before the welcome, refused now), and no copy is owed one. At
    /// most [`EXCUSED_KEPT`], the oldest forgotten first.
    excused: BTreeSet<u32>,
}

impl Ledger {
    /// A message carrying `seqs` reached the server: each owes an answer, unless acked or
    /// answered by a welcome. Returns how many seqs were delivered for the first time.
    pub fn delivered(&mut self, seqs: &[u32]) -> u64 {
        let mut new = 0;
        for &seq in seqs {
            if !self.acked.contains(seq) && !self.excused.contains(&seq) {
                *self.owed.entry(seq).or_insert(0) += 1;
            }
            if precedes(self.delivered, seq) {
                new += 1;
            }
        }
        self.delivered = seqs.iter().fold(self.delivered, |d, &s| later(d, s));
        new
    }

    /// An ack of `seq`: nothing more is owed for it, however many copies were delivered; false
    /// when it was acked before (applied twice).
    pub fn accepted(&mut self, seq: u32) -> bool {
        self.owed.remove(&seq);
        self.excused.remove(&seq);
        self.acked.insert(seq)
    }

    /// A reject of `seq`: whether it was due (a delivered copy owed it, a welcome left it open,
    /// or the protocol's second answer of an accepted input whose entity went away); else
    /// whether the seq was acked before, to tell.
    pub fn rejected(&mut self, seq: u32, reason: RejectReason) -> Result<(), &'static str> {
        let second = matches!(reason, RejectReason::UnknownEntity | RejectReason::NotOwner | RejectReason::Duplicate);
        if self.answered(seq) || self.excused.remove(&seq) || (self.acked.contains(seq) && second) {
            return Ok(());
        }
        Err(if self.acked.contains(seq) { "acked before" } else { "never acked" })
    }

    /// Counts a reject of `seq` against what its deliveries owe: false when none was owed.
    fn answered(&mut self, seq: u32) -> bool {
        match self.owed.get_mut(&seq) {
            Some(n) if *n > 1 => {
                *n -= 1;
                true
            }
            Some(_) => {
                self.owed.remove(&seq);
                true
            }
            None => false,
        }
    }

    /// A welcome said the server answered every seq below `next_seq` (it accepted the one just
    /// below; the others accepted, refused or never heard): those still owed an answer are owed
    /// none now, and may still get one. Returns how many.
    pub fn welcomed(&mut self, next_seq: u32) -> u64 {
        let told: Vec<u32> = self.owed.keys().copied().filter(|&seq| precedes(seq, next_seq)).collect();
        for &seq in &told {
            self.owed.remove(&seq);
            self.excused.insert(seq);
        }
        while self.excused.len() > EXCUSED_KEPT {
            self.excused.pop_first();
        }
        told.len() as u64
    }

    /// Seqs an ack's `accepted_before` named accepted (their own acks may have been lost).
    pub fn acked_before(&mut self, seqs: impl Iterator<Item = u32>) {
        for seq in seqs {
            self.accepted(seq);
        }
    }

    /// The client knows `seq` never reached the server: owed nothing.
    pub fn lost(&mut self, seq: u32) {
        self.owed.remove(&seq);
    }

    /// Answers owed, one per delivery of each seq still owed one.
    pub fn unanswered(&self) -> u64 {
        self.owed.values().map(|&n| u64::from(n)).sum()
    }

    /// The seqs still owed an answer.
    pub fn owed(&self) -> impl Iterator<Item = u32> + '_ {
        self.owed.keys().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A copy of a seq a welcome answered, carried before the welcome and refused after it (the
    /// server never accepted it: seed 18 of the deployment's faults), is an answer due, once; a
    /// copy delivered after the welcome is owed none; a later ack marks it acked, and a second
    /// ack of it is an input applied twice.
    #[test]
    fn a_welcome_leaves_one_answer_open_below_its_next_seq() {
        let mut l = Ledger::default();
        assert_eq!(l.delivered(&[5, 6, 7]), 3);
        assert!(l.accepted(5));
        // Welcomed again: next_seq 8 (7 accepted, the acks lost); 6 was refused with its answer
        // lost, or never heard.
        assert_eq!(l.welcomed(8), 2);
        assert_eq!(l.unanswered(), 0);
        assert_eq!(l.rejected(6, RejectReason::Stale), Ok(()), "6 may still be refused");
        assert_eq!(l.rejected(6, RejectReason::Stale), Err("never acked"), "but once");
        l.delivered(&[7]);
        assert_eq!(l.unanswered(), 0, "a copy of 7 after the welcome is owed nothing");
        l.acked_before([7].into_iter());
        assert!(!l.accepted(7), "acked twice");
        assert_eq!(l.rejected(7, RejectReason::Stale), Err("acked before"));
        assert_eq!(l.rejected(7, RejectReason::Duplicate), Ok(()), "a duplicate of an acked seq is told");
    }

    /// A rejected input owes an answer per delivered copy, and no more.
    #[test]
    fn each_delivered_copy_of_a_refused_input_is_answered() {
        let mut l = Ledger::default();
        l.delivered(&[1]);
        l.delivered(&[1, 2]);
        assert_eq!(l.unanswered(), 3);
        assert_eq!(l.rejected(1, RejectReason::Future), Ok(()));
        assert_eq!(l.rejected(1, RejectReason::Future), Ok(()));
        assert_eq!(l.rejected(1, RejectReason::Future), Err("never acked"));
        l.lost(2);
        assert_eq!(l.owed().count(), 0);
    }
}
