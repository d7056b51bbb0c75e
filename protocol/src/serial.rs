//! Counters that wrap: input seqs and state frame numbers are `u32`s that go on past
//! `u32::MAX`, compared as serial numbers (RFC 1982) rather than as integers: `b` comes after
//! `a` when it is less than half the space (2^31) ahead of it. Two numbers a client or server
//! compares are never that far apart (a seq window is 1,024, a frame stream is contiguous), so
//! a session that outlives the space (years of inputs) carries on across the wrap.
//!
//! Input seqs skip 0 ([`next_seq`]): a reject without a seq is never mistaken for one.

/// Whether `a` comes before `b` (in serial order; never when they are equal).
pub fn precedes(a: u32, b: u32) -> bool {
    a != b && b.wrapping_sub(a) < 1 << 31
}

/// How far `b` is after `a` (0 when equal; the numbers that wrapped counted, 0 included).
pub fn distance(a: u32, b: u32) -> u32 {
    b.wrapping_sub(a)
}

/// The input seq after `seq`: one more, and 1 after `u32::MAX` (seq 0 is never used).
pub fn next_seq(seq: u32) -> u32 {
    match seq.wrapping_add(1) {
        0 => 1,
        n => n,
    }
}

/// Serial order as an [`Ordering`](std::cmp::Ordering), for sorting numbers that span less than
/// half the space (the inputs of one client in one tick).
pub fn cmp(a: u32, b: u32) -> std::cmp::Ordering {
    if a == b {
        std::cmp::Ordering::Equal
    } else if precedes(a, b) {
        std::cmp::Ordering::Less
    } else {
        std::cmp::Ordering::Greater
    }
}

/// The later of two serial numbers.
pub fn later(a: u32, b: u32) -> u32 {
    if precedes(a, b) {
        b
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_holds_across_the_wrap() {
        assert!(precedes(1, 2) && !precedes(2, 1) && !precedes(7, 7));
        assert!(precedes(u32::MAX - 1, u32::MAX));
        assert!(precedes(u32::MAX, 0) && precedes(u32::MAX, 1) && precedes(u32::MAX - 500, 500));
        assert!(!precedes(1, u32::MAX) && !precedes(500, u32::MAX - 500));
        assert_eq!(distance(u32::MAX - 1, 2), 4);
        assert_eq!((next_seq(5), next_seq(u32::MAX - 1), next_seq(u32::MAX)), (6, u32::MAX, 1));
        assert_eq!((later(u32::MAX, 3), later(3, u32::MAX), later(4, 9)), (3, 3, 9));
        let mut seqs = vec![2, u32::MAX, 1, u32::MAX - 1];
        seqs.sort_by(|&a, &b| cmp(a, b));
        assert_eq!(seqs, [u32::MAX - 1, u32::MAX, 1, 2]);
    }
}
