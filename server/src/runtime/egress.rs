//! The egress thread: encodes and publishes what the tick thread hands it (encoding is off the
//! tick thread, which only moves each message into the queue), each key through a publisher it
//! declared once. Publishing uses congestion control
//! `Drop`, so a slow subscriber loses its own messages and never holds anyone back; the input
//! log alone uses `Block`, because a standby that missed an entry has to start over. Each message
//! carries the world's epoch as its attachment, and nothing goes out while the world is held or
//! fenced ([`Owner`]).

use super::owner::Owner;
use impact_protocol::codec::encode;
use impact_protocol::{Encoding, ServerMessage};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use zenoh::Wait;

/// A message for the network.
pub enum Out {
    /// Publish `msg` on `key`.
    Put {
        /// Key expression.
        key: String,
        /// The message (boxed: the queue's slots stay small).
        msg: Box<ServerMessage>,
        /// Its encoding (sets the sample's tag).
        encoding: Encoding,
    },
    /// Publish `msg` on `key` of the input log: congestion control `Block`, so a slow
    /// subscriber (a standby) slows this thread rather than lose an entry.
    Log {
        /// Key expression.
        key: String,
        /// The message.
        msg: Box<ServerMessage>,
        /// Its encoding.
        encoding: Encoding,
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
/// past it the cache starts again empty (clients that left take their keys with them).
const PUBLISHERS: usize = 8_192;

/// Declared publishers by key, one set per congestion control. Zenoh matches an undeclared key
/// against every subscription on each put; a declared one is matched once and kept up to date.
/// With 500 clients through a router and a standby beside the server, that matching was half the
/// server's CPU and held every ack back by seconds.
struct Publishers<'a> {
    session: &'a zenoh::Session,
    congestion: zenoh::qos::CongestionControl,
    by_key: std::collections::HashMap<String, zenoh::pubsub::Publisher<'static>>,
}

impl<'a> Publishers<'a> {
    fn new(session: &'a zenoh::Session, congestion: zenoh::qos::CongestionControl) -> Publishers<'a> {
        Publishers { session, congestion, by_key: std::collections::HashMap::new() }
    }

    /// Publishes `bytes` on `key` with the world's epoch as the attachment (if it has one).
    fn put(&mut self, key: String, bytes: Vec<u8>, encoding: Encoding, stamp: Option<[u8; 8]>) -> bool {
        if !self.by_key.contains_key(&key) {
            if self.by_key.len() >= PUBLISHERS {
                self.by_key.clear();
            }
            let declared = self.session.declare_publisher(key.clone()).congestion_control(self.congestion).wait();
            match declared {
                Ok(p) => {
                    self.by_key.insert(key.clone(), p);
                }
                Err(_) => return false,
            }
        }
        let Some(p) = self.by_key.get(&key) else { return false };
        let put = p.put(bytes).encoding(encoding.zenoh_tag());
        match stamp {
            Some(a) => put.attachment(a.to_vec()).wait().is_ok(),
            None => put.wait().is_ok(),
        }
    }
}

/// Runs until the sending side is dropped. `failures` counts the messages that could not be
/// encoded (never: the server validates what it builds) or published.
pub fn run(session: zenoh::Session, rx: Receiver<Out>, failures: Arc<AtomicU64>, owner: Arc<Owner>) {
    let mut dropping = Publishers::new(&session, zenoh::qos::CongestionControl::Drop);
    let mut blocking = Publishers::new(&session, zenoh::qos::CongestionControl::Block);
    for out in rx {
        let Ok(stamp) = owner.stamp() else { continue };
        let ok = match out {
            Out::Put { key, msg, encoding } => {
                encode(&*msg, encoding).is_ok_and(|bytes| dropping.put(key, bytes, encoding, stamp))
            }
            Out::Log { key, msg, encoding } => {
                encode(&*msg, encoding).is_ok_and(|bytes| blocking.put(key, bytes, encoding, stamp))
            }
            Out::Reply { query, replies, encoding } => replies.into_iter().all(|bytes| {
                let reply = query.reply(query.key_expr().clone(), bytes).encoding(encoding.zenoh_tag());
                match stamp {
                    Some(a) => reply.attachment(a.to_vec()).wait().is_ok(),
                    None => reply.wait().is_ok(),
                }
            }),
        };
        if !ok {
            failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}
