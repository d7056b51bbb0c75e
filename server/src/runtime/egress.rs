//! The egress thread: encodes and publishes what the tick thread hands it (encoding is off the
//! tick thread, which only moves each message into the queue), each key through a publisher it
//! declared once. Publishing uses congestion control
//! `Drop`, so a slow subscriber loses its own messages and never holds anyone back; the input
//! log alone uses `Block`, because a standby that missed an entry has to start over. Each message
//! carries the world's epoch and its number on its key as its attachment ([`Stamp`]), so a
//! subscriber knows when messages were lost on the way, and nothing goes out while the world is
//! held or fenced ([`Owner`]).

use super::gate::{TickGate, TICK_WAIT_MOST};
use super::owner::Owner;
use impact_protocol::codec::encode;
use impact_protocol::{Encoding, Epoch, ServerMessage, Stamp};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use zenoh::Wait;

/// A message for the network.
pub enum Out {
    /// Publish `msg` on `key`.
    Put {
        /// Key expression (shared: a client's keys are formatted once).
        key: Arc<str>,
        /// The message (boxed: the queue's slots stay small).
        msg: Box<ServerMessage>,
        /// Its encoding (sets the sample's tag).
        encoding: Encoding,
        /// How many messages for keys the queue had dropped when this one was queued.
        dropped_before: u64,
    },
    /// Publish `msg` on `key` of the input log: congestion control `Block`, so a slow
    /// subscriber (a standby) slows this thread rather than lose an entry.
    Log {
        /// Key expression.
        key: Arc<str>,
        /// The message.
        msg: Box<ServerMessage>,
        /// Its encoding.
        encoding: Encoding,
        /// As for `Put`.
        dropped_before: u64,
    },
    /// Answer a query.
    Reply {
        /// The query.
        query: zenoh::query::Query,
        /// The replies, in order (none: the query ends unanswered).
        replies: Vec<Vec<u8>>,
        /// Its encoding.
        encoding: Encoding,
    },
}

/// Most keys the egress keeps a declared publisher for (two per client and the world's own);
/// past it the cache starts again empty (clients that left take their keys with them), and so do
/// the keys' numbers: a receiver takes a number 1 as a count started again, not as a gap.
const PUBLISHERS: usize = 8_192;

/// The numbers of each key's messages ([`Stamp::number`]): one more per message, and one more
/// again after the queue into this thread dropped a message for a key, on every key, since which
/// key lost it is not kept: a subscriber of any of them then sees a gap, which costs it a
/// comparison it could have made; never one it should not have made.
#[derive(Default)]
struct Numbers {
    /// Messages for keys the queue had dropped before the one being published.
    overflows: u64,
}

/// One key's count, and the overflow count it has taken in.
#[derive(Default)]
struct KeyCount {
    sent: u64,
    overflows: u64,
}

impl Numbers {
    /// The number of the next message on the key counted by `key`. (Two threads queue messages,
    /// so one may come with an older drop count than the one before it: the count only rises.)
    fn next(&self, key: &mut KeyCount) -> u64 {
        if self.overflows > key.overflows {
            key.overflows = self.overflows;
            key.sent += u64::from(key.sent > 0);
        }
        key.sent += 1;
        key.sent
    }
}

/// Declared publishers by key, one set per congestion control. Zenoh matches an undeclared key
/// against every subscription on each put; a declared one is matched once and kept up to date.
/// With 500 clients through a router and a standby beside the server, that matching was half the
/// server's CPU and held every ack back by seconds.
struct Publishers<'a> {
    session: &'a zenoh::Session,
    congestion: zenoh::qos::CongestionControl,
    by_key: std::collections::HashMap<Arc<str>, (zenoh::pubsub::Publisher<'static>, KeyCount)>,
}

impl<'a> Publishers<'a> {
    fn new(session: &'a zenoh::Session, congestion: zenoh::qos::CongestionControl) -> Publishers<'a> {
        Publishers { session, congestion, by_key: std::collections::HashMap::new() }
    }

    /// A message for `key` that the world held back (a primary that stood still, waiting to know
    /// whether it still owns the world): it counts, so the next message a subscriber hears on the
    /// key tells it something was lost. (A key never published on has no one to tell.)
    fn withheld(&mut self, key: &str, numbers: &Numbers) {
        if let Some((_, count)) = self.by_key.get_mut(key) {
            numbers.next(count);
        }
    }

    /// Publishes `bytes` on `key`, stamped with the world's epoch (if it has one) and the
    /// message's number on the key.
    fn put(
        &mut self,
        key: Arc<str>,
        bytes: Vec<u8>,
        encoding: Encoding,
        epoch: Option<Epoch>,
        numbers: &Numbers,
    ) -> bool {
        if !self.by_key.contains_key(&key) {
            if self.by_key.len() >= PUBLISHERS {
                self.by_key.clear();
            }
            let declared = self.session.declare_publisher(key.to_string()).congestion_control(self.congestion).wait();
            match declared {
                Ok(p) => {
                    self.by_key.insert(key.clone(), (p, KeyCount::default()));
                }
                Err(_) => return false,
            }
        }
        let Some((p, count)) = self.by_key.get_mut(&*key) else { return false };
        let number = numbers.next(count);
        let put = p.put(bytes).encoding(encoding.zenoh_tag());
        match epoch {
            Some(epoch) => put.attachment(Stamp { epoch, number: Some(number) }.attachment()).wait().is_ok(),
            None => put.wait().is_ok(),
        }
    }
}

/// Runs until the sending side is dropped. `failures` counts the messages that could not be
/// encoded (never: the server validates what it builds) or published.
/// It publishes between the world's ticks (`gate`, as the state thread does): what a tick hands
/// it goes out once the tick is over, in one burst, not beside the tick on its core.
pub fn run(
    session: zenoh::Session,
    rx: Receiver<Out>,
    failures: Arc<AtomicU64>,
    owner: Arc<Owner>,
    gate: Arc<TickGate>,
) {
    let mut dropping = Publishers::new(&session, zenoh::qos::CongestionControl::Drop);
    let mut blocking = Publishers::new(&session, zenoh::qos::CongestionControl::Block);
    let mut numbers = Numbers::default();
    for out in rx {
        gate.after_tick(TICK_WAIT_MOST);
        let Ok(epoch) = owner.stamp() else {
            match &out {
                Out::Put { key, .. } => dropping.withheld(key, &numbers),
                Out::Log { key, .. } => blocking.withheld(key, &numbers),
                Out::Reply { .. } => {}
            }
            continue;
        };
        let ok = match out {
            Out::Put { key, msg, encoding, dropped_before } => {
                numbers.overflows = dropped_before;
                encode(&*msg, encoding).is_ok_and(|bytes| dropping.put(key, bytes, encoding, epoch, &numbers))
            }
            Out::Log { key, msg, encoding, dropped_before } => {
                numbers.overflows = dropped_before;
                encode(&*msg, encoding).is_ok_and(|bytes| blocking.put(key, bytes, encoding, epoch, &numbers))
            }
            Out::Reply { query, replies, encoding } => replies.into_iter().all(|bytes| {
                let reply = query.reply(query.key_expr().clone(), bytes).encoding(encoding.zenoh_tag());
                match epoch {
                    Some(e) => reply.attachment(e.attachment().to_vec()).wait().is_ok(),
                    None => reply.wait().is_ok(),
                }
            }),
        };
        if !ok {
            failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{KeyCount, Numbers};

    /// Each key counts its own messages from 1; after the queue overflowed, every key's next
    /// number skips one (once), except a key's very first.
    #[test]
    fn numbers_count_per_key_and_skip_after_an_overflow() {
        let mut numbers = Numbers::default();
        let (mut a, mut b) = (KeyCount::default(), KeyCount::default());
        assert_eq!([numbers.next(&mut a), numbers.next(&mut a), numbers.next(&mut b)], [1, 2, 1]);
        numbers.overflows = 1;
        assert_eq!([numbers.next(&mut a), numbers.next(&mut a), numbers.next(&mut b)], [4, 5, 3]);
        let mut c = KeyCount::default();
        assert_eq!(numbers.next(&mut c), 1, "a key first used now: no one heard it before to see a skip");
        numbers.overflows = 3;
        assert_eq!([numbers.next(&mut c), numbers.next(&mut c)], [3, 4]);
    }
}
