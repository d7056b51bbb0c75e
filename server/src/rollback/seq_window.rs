//! Replay protection: a sliding window over each client's input seqs, as DTLS (RFC 6347
//! §4.1.2.6) and IPsec (RFC 4303 §3.4.3) keep over record numbers.
//!
//! A window remembers the highest seq accepted and which of the [`WINDOW`] seqs at and below it
//! were accepted. A seq above the highest is new; one inside the window is new unless its bit is
//! set; one at or below the floor (`highest - WINDOW`) is refused as a duplicate, because the
//! window can no longer tell. So a seq is a nonce for as long as the window lives (the client's
//! presence and its grace period), not just for the rollback window, and the memory is a fixed
//! 136 bytes per client however long it stays. Seqs compare as serial numbers
//! ([`impact_protocol::serial`]): a client's seqs go on past `u32::MAX` at 1.
//!
//! [`Window`] is the same over any multiple of 64 seqs: the load generator keeps a wider one per
//! client over the seqs the server acked, so a second ack (an input applied twice) is seen in
//! fixed memory from the first input on.

use impact_protocol::serial::{distance, next_seq, precedes};

/// Seqs remembered below the highest accepted one (including it).
pub const WINDOW: u32 = 1024;

const WORDS: usize = (WINDOW / 64) as usize;

/// One client's window on the server: [`WINDOW`] seqs.
pub type SeqWindow = Window<WORDS>;

/// Why a seq was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Replay {
    /// This seq was accepted before.
    Seen,
    /// The seq is at or below the floor: older than the window remembers.
    BelowFloor {
        /// The newest seq not accepted for that reason (`highest - WINDOW`, wrapping).
        floor: u32,
    },
}

/// A window over `64 * N` seqs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Window<const N: usize> {
    /// The highest seq accepted, if any.
    highest: Option<u32>,
    /// Bit `s % Self::SEQS` is set when seq `s` (within the window) was accepted.
    bits: [u64; N],
}

impl<const N: usize> Default for Window<N> {
    fn default() -> Self {
        Window { highest: None, bits: [0; N] }
    }
}

impl<const N: usize> Window<N> {
    /// Seqs remembered below the highest accepted one (including it).
    pub const SEQS: u32 = 64 * N as u32;

    /// `Ok` when `seq` has not been accepted (and can still be told apart).
    pub fn check(&self, seq: u32) -> Result<(), Replay> {
        let Some(h) = self.highest else { return Ok(()) };
        if precedes(h, seq) {
            return Ok(());
        }
        if distance(seq, h) >= Self::SEQS {
            return Err(Replay::BelowFloor { floor: h.wrapping_sub(Self::SEQS) });
        }
        if self.bit(seq) {
            Err(Replay::Seen)
        } else {
            Ok(())
        }
    }

    /// Records `seq` as accepted (call after [`check`](Self::check) passed).
    pub fn accept(&mut self, seq: u32) {
        match self.highest {
            Some(h) if !precedes(h, seq) => {}
            Some(h) => {
                // The seqs between the old highest and the new one enter the window unseen.
                if distance(h, seq) >= Self::SEQS {
                    self.bits = [0; N];
                } else {
                    for k in 1..distance(h, seq) {
                        self.set(h.wrapping_add(k), false);
                    }
                }
                self.highest = Some(seq);
            }
            None => self.highest = Some(seq),
        }
        self.set(seq, true);
    }

    /// Which of the 64 seqs below `seq` were accepted: bit `k` is seq `seq - 1 - k` (what an
    /// ack carries, so a lost one is recovered from the next).
    pub fn accepted_before(&self, seq: u32) -> u64 {
        let Some(h) = self.highest else { return 0 };
        (0..64u32)
            .map(|k| (k, seq.wrapping_sub(k + 1)))
            .filter(|&(_, s)| distance(s, h) < Self::SEQS && self.bit(s))
            .fold(0, |bits, (k, _)| bits | 1 << k)
    }

    /// The seq after every accepted one: where a reconnecting client resumes (0 before any).
    pub fn next_seq(&self) -> u32 {
        self.highest.map_or(0, next_seq)
    }

    /// The highest seq accepted and the window's bits (a checkpoint carries them).
    pub fn parts(&self) -> (Option<u32>, Vec<u64>) {
        (self.highest, self.bits.to_vec())
    }

    /// The window [`parts`](Self::parts) describe; `None` when `bits` has the wrong length.
    pub fn from_parts(highest: Option<u32>, bits: &[u64]) -> Option<Window<N>> {
        Some(Window { highest, bits: bits.try_into().ok()? })
    }

    /// Remembers `seq` as accepted and says whether it was new: `false` when it was accepted
    /// before, `true` also when it is below the floor (too old to tell; not recorded).
    pub fn insert(&mut self, seq: u32) -> bool {
        match self.check(seq) {
            Ok(()) => {
                self.accept(seq);
                true
            }
            Err(Replay::Seen) => false,
            Err(Replay::BelowFloor { .. }) => true,
        }
    }

    /// Whether `seq` was accepted (and is still in the window).
    pub fn contains(&self, seq: u32) -> bool {
        self.check(seq) == Err(Replay::Seen)
    }

    fn bit(&self, seq: u32) -> bool {
        let i = seq % Self::SEQS;
        self.bits[(i / 64) as usize] & (1 << (i % 64)) != 0
    }

    fn set(&mut self, seq: u32, on: bool) {
        let i = seq % Self::SEQS;
        let (w, b) = ((i / 64) as usize, 1u64 << (i % 64));
        if on {
            self.bits[w] |= b;
        } else {
            self.bits[w] &= !b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::BTreeSet;

    /// The model: every accepted seq in a set; below the floor is refused whether seen or not.
    fn model(accepted: &BTreeSet<u32>, seq: u32) -> Result<(), Replay> {
        model_of(WINDOW, accepted, seq)
    }

    /// The model of a window over `seqs`.
    fn model_of(seqs: u32, accepted: &BTreeSet<u32>, seq: u32) -> Result<(), Replay> {
        let Some(&h) = accepted.last() else { return Ok(()) };
        if seq <= h && h - seq >= seqs {
            Err(Replay::BelowFloor { floor: h - seqs })
        } else if accepted.contains(&seq) {
            Err(Replay::Seen)
        } else {
            Ok(())
        }
    }

    proptest! {
        #[test]
        /// The window over seqs `base + 0..3000` (wrapping: a third of the cases cross
        /// `u32::MAX`) says what the model says over `0..3000`.
        fn window_equals_the_set_of_accepted_seqs(
            steps in prop::collection::vec((0u32..3000, any::<bool>()), 1..400),
            base in prop_oneof![Just(0u32), u32::MAX - 3000..=u32::MAX, any::<u32>()],
        ) {
            let mut w = SeqWindow::default();
            let mut accepted = BTreeSet::new();
            let shift = |r: Result<(), Replay>| match r {
                Err(Replay::BelowFloor { floor }) => Err(Replay::BelowFloor { floor: base.wrapping_add(floor) }),
                r => r,
            };
            for (seq, take) in steps {
                let got = w.check(base.wrapping_add(seq));
                prop_assert_eq!(got, shift(model(&accepted, seq)), "seq {}", seq);
                if take && got.is_ok() {
                    w.accept(base.wrapping_add(seq));
                    accepted.insert(seq);
                }
                prop_assert_eq!(w.next_seq(), accepted.last().map_or(0, |h| next_seq(base.wrapping_add(*h))));
                // What an ack of `seq` says of the 64 seqs before it: those the model holds
                // accepted and the window still tells apart.
                let told: u64 = (0..64u32)
                    .filter_map(|k| seq.checked_sub(k + 1).map(|s| (k, s)))
                    .filter(|&(_, s)| model(&accepted, s) == Err(Replay::Seen))
                    .fold(0, |bits, (k, _)| bits | 1 << k);
                prop_assert_eq!(w.accepted_before(base.wrapping_add(seq)), told, "seq {}", seq);
            }
        }

        #[test]
        /// A narrow window (128 seqs) as a set, through `insert` and `contains`: a seq is new
        /// unless the model holds it accepted; below the floor it is new and not recorded.
        fn a_window_of_any_width_is_a_set_of_its_latest_seqs(
            steps in prop::collection::vec(0u32..1000, 1..400),
            base in prop_oneof![Just(0u32), u32::MAX - 1000..=u32::MAX, any::<u32>()],
        ) {
            let mut w = Window::<2>::default();
            let mut accepted = BTreeSet::new();
            for seq in steps {
                let before = model_of(Window::<2>::SEQS, &accepted, seq);
                prop_assert_eq!(w.contains(base.wrapping_add(seq)), before == Err(Replay::Seen), "seq {}", seq);
                prop_assert_eq!(w.insert(base.wrapping_add(seq)), before != Err(Replay::Seen), "seq {}", seq);
                if before.is_ok() {
                    accepted.insert(seq);
                }
                let recorded = !matches!(before, Err(Replay::BelowFloor { .. }));
                prop_assert_eq!(w.contains(base.wrapping_add(seq)), recorded, "seq {} after its insert", seq);
            }
        }
    }

    #[test]
    fn a_seq_is_refused_long_after_the_rollback_window() {
        let mut w = SeqWindow::default();
        for s in 0..5000 {
            w.accept(s);
        }
        assert_eq!(w.check(4999), Err(Replay::Seen));
        assert_eq!(w.check(4000), Err(Replay::Seen));
        assert_eq!(w.check(3976), Err(Replay::Seen), "the lowest seq the window still holds");
        assert_eq!(w.check(3975), Err(Replay::BelowFloor { floor: 3975 }), "the floor itself");
        assert_eq!(w.check(0), Err(Replay::BelowFloor { floor: 3975 }));
        assert_eq!(w.check(5000), Ok(()));
        // A jump past the whole window forgets the bits it skipped.
        w.accept(10_000);
        assert_eq!(w.check(9_999), Ok(()));
        assert_eq!(w.check(10_000 + (1 << 30)), Ok(()), "a quarter of the space ahead: newer");
    }

    /// A client whose seqs pass `u32::MAX` goes on at 1: accepted, told apart from the seqs
    /// before the wrap, acked with them in `accepted_before`, and resumed after them.
    #[test]
    fn seqs_go_on_across_the_wrap() {
        let mut w = SeqWindow::default();
        for s in u32::MAX - 2..=u32::MAX {
            w.accept(s);
        }
        assert_eq!(w.next_seq(), 1, "seq 0 is never used");
        assert_eq!(w.check(1), Ok(()));
        w.accept(1);
        w.accept(3);
        assert_eq!((w.check(u32::MAX), w.check(1), w.check(2)), (Err(Replay::Seen), Err(Replay::Seen), Ok(())));
        assert_eq!(w.next_seq(), 4);
        // Bit k of an ack of 4 is seq 3 - k: 3, (2 not), 1, (0 never), MAX, MAX - 1, MAX - 2.
        assert_eq!(w.accepted_before(4), 0b111_0101);
        for s in 4..1100 {
            w.accept(s);
        }
        assert_eq!(w.check(u32::MAX), Err(Replay::BelowFloor { floor: 1099 - WINDOW }));
    }
}
