//! The egress thread: encodes and publishes what the tick thread hands it (encoding is off the
//! tick thread, which only moves each message into the queue). Publishing uses congestion control
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
        /// Payload.
        bytes: Vec<u8>,
        /// Its encoding.
        encoding: Encoding,
    },
}

/// Runs until the sending side is dropped. `failures` counts the messages that could not be
/// encoded (never: the server validates what it builds) or published.
pub fn run(session: zenoh::Session, rx: Receiver<Out>, failures: Arc<AtomicU64>, owner: Arc<Owner>) {
    let put = |key: String, msg: &ServerMessage, encoding: Encoding, congestion, stamp: Option<[u8; 8]>| {
        let Ok(bytes) = encode(msg, encoding) else { return false };
        let put = session.put(key, bytes).encoding(encoding.zenoh_tag()).congestion_control(congestion);
        match stamp {
            Some(a) => put.attachment(a.to_vec()).wait().is_ok(),
            None => put.wait().is_ok(),
        }
    };
    for out in rx {
        let Ok(stamp) = owner.stamp() else { continue };
        let ok = match out {
            Out::Put { key, msg, encoding } => put(key, &msg, encoding, zenoh::qos::CongestionControl::Drop, stamp),
            Out::Log { key, msg, encoding } => put(key, &msg, encoding, zenoh::qos::CongestionControl::Block, stamp),
            Out::Reply { query, bytes, encoding } => {
                let reply = query.reply(query.key_expr().clone(), bytes).encoding(encoding.zenoh_tag());
                match stamp {
                    Some(a) => reply.attachment(a.to_vec()).wait().is_ok(),
                    None => reply.wait().is_ok(),
                }
            }
        };
        if !ok {
            failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}
