//! A network model for testing a game locally (and the one `impact-sim` runs its clients
//! behind): a delay line whose items come out when their time is due, in the order they went in.
//! It models one direction of a stream (Zenoh over TCP) with latency, jitter and loss: jitter
//! moves delivery times but never reorders, because a stream does not (a message waits behind a
//! slower one before it, head-of-line), and stalls ([`DelayLine::stall_until`]: nothing comes out
//! until it ends, then what was due comes out in order, as a stream does once a stalled link
//! recovers). The caller passes the time in; nothing here reads a clock. Bounded: past `capacity` items, new ones are dropped and counted.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::time::{Duration, Instant};

/// Latency model: uniform jitter around the latency, and a loss probability.
#[derive(Clone, Copy, Debug)]
pub struct Link {
    /// One-way latency.
    pub latency: Duration,
    /// Jitter: the delay is `latency +- jitter`, uniformly.
    pub jitter: Duration,
    /// Probability an item is lost.
    pub loss: f64,
}

/// A small deterministic generator (xorshift64*), seeded per run.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// From a seed (0 is replaced by a constant).
    pub fn new(seed: u64) -> Rng {
        Rng(if seed == 0 { 0x9E37_79B9_7F4A_7C15 } else { seed })
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The delay line.
#[derive(Debug)]
pub struct DelayLine<T> {
    heap: BinaryHeap<Reverse<(Instant, u64, usize)>>,
    items: Vec<Option<T>>,
    free: Vec<usize>,
    seq: u64,
    last_due: Option<Instant>,
    stalled_until: Option<Instant>,
    capacity: usize,
    /// Items dropped by the loss model.
    pub lost: u64,
    /// Items dropped because the line was full.
    pub overflow: u64,
}

impl<T> DelayLine<T> {
    /// An empty line holding at most `capacity` items.
    pub fn new(capacity: usize) -> DelayLine<T> {
        DelayLine {
            heap: BinaryHeap::new(),
            items: Vec::new(),
            free: Vec::new(),
            seq: 0,
            last_due: None,
            stalled_until: None,
            capacity,
            lost: 0,
            overflow: 0,
        }
    }

    /// Sends `item` through `link` at `now`. Returns false if it was lost or dropped.
    pub fn send(&mut self, now: Instant, link: &Link, rng: &mut Rng, item: T) -> bool {
        if rng.unit() < link.loss {
            self.lost += 1;
            return false;
        }
        if self.heap.len() >= self.capacity {
            self.overflow += 1;
            return false;
        }
        let j = link.jitter.as_secs_f64() * (2.0 * rng.unit() - 1.0);
        let delay = (link.latency.as_secs_f64() + j).max(0.0);
        let slot = match self.free.pop() {
            Some(s) => {
                self.items[s] = Some(item);
                s
            }
            None => {
                self.items.push(Some(item));
                self.items.len() - 1
            }
        };
        self.seq += 1;
        let due = (now + Duration::from_secs_f64(delay)).max(self.last_due.unwrap_or(now));
        self.last_due = Some(due);
        self.heap.push(Reverse((due, self.seq, slot)));
        true
    }

    /// Stalls the line until `until`: nothing comes out before it (a stall already longer
    /// stays); what was due meanwhile comes out then, in order.
    pub fn stall_until(&mut self, until: Instant) {
        self.stalled_until = Some(self.stalled_until.map_or(until, |t| t.max(until)));
    }

    /// The next item due at or before `now` (none while stalled).
    pub fn pop_due(&mut self, now: Instant) -> Option<T> {
        if self.stalled_until.is_some_and(|t| now < t) {
            return None;
        }
        let Reverse((due, _, slot)) = *self.heap.peek()?;
        if due > now {
            return None;
        }
        self.heap.pop();
        self.free.push(slot);
        self.items[slot].take()
    }

    /// Items in flight.
    pub fn len(&self) -> usize {
        self.heap.len()
    }

    /// Whether nothing is in flight.
    pub fn is_empty(&self) -> bool {
        self.heap.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn items_come_out_in_due_order_after_their_delay() {
        let mut d = DelayLine::new(16);
        let mut rng = Rng::new(1);
        let t0 = Instant::now();
        let link = Link { latency: Duration::from_millis(50), jitter: Duration::ZERO, loss: 0.0 };
        d.send(t0, &link, &mut rng, 1);
        d.send(t0 + Duration::from_millis(10), &link, &mut rng, 2);
        assert_eq!(d.pop_due(t0 + Duration::from_millis(49)), None);
        assert_eq!(d.pop_due(t0 + Duration::from_millis(50)), Some(1));
        assert_eq!(d.pop_due(t0 + Duration::from_millis(59)), None);
        assert_eq!(d.pop_due(t0 + Duration::from_millis(60)), Some(2));
    }

    #[test]
    fn jitter_never_reorders() {
        let mut d = DelayLine::new(1024);
        let mut rng = Rng::new(3);
        let t0 = Instant::now();
        let link = Link { latency: Duration::from_millis(80), jitter: Duration::from_millis(20), loss: 0.0 };
        for k in 0..500u32 {
            d.send(t0 + Duration::from_millis(u64::from(k)), &link, &mut rng, k);
        }
        let mut out = Vec::new();
        while let Some(x) = d.pop_due(t0 + Duration::from_secs(10)) {
            out.push(x);
        }
        assert_eq!(out, (0..500).collect::<Vec<_>>());
    }

    #[test]
    fn a_stall_holds_everything_then_delivers_it_in_order() {
        let mut d = DelayLine::new(16);
        let mut rng = Rng::new(1);
        let t0 = Instant::now();
        let ms = |m: u64| t0 + Duration::from_millis(m);
        let link = Link { latency: Duration::from_millis(10), jitter: Duration::ZERO, loss: 0.0 };
        d.send(t0, &link, &mut rng, 1);
        d.stall_until(ms(500));
        d.stall_until(ms(200));
        d.send(ms(100), &link, &mut rng, 2);
        assert_eq!(d.pop_due(ms(499)), None, "stalled (the shorter stall does not shorten it)");
        assert_eq!((d.pop_due(ms(500)), d.pop_due(ms(500)), d.pop_due(ms(500))), (Some(1), Some(2), None));
    }

    #[test]
    fn loss_and_capacity_drop_and_count() {
        let mut d = DelayLine::new(2);
        let mut rng = Rng::new(7);
        let t0 = Instant::now();
        let lossy = Link { latency: Duration::ZERO, jitter: Duration::ZERO, loss: 0.5 };
        let sent = (0..1000).filter(|k| d.send(t0, &lossy, &mut rng, *k)).count();
        assert!(d.lost > 400 && d.lost < 600, "lost {}", d.lost);
        assert_eq!(sent, 2, "capacity 2");
        assert_eq!(d.overflow as usize + d.lost as usize + sent, 1000);
    }
}
