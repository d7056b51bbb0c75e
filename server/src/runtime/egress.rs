//! The egress thread: encodes and publishes what the tick thread hands it (encoding is off the
//! tick thread, which only moves each message into the queue). Publishing uses congestion control
//! `Drop`, so a slow subscriber loses its own messages and never holds anyone back; the input
//! log alone uses `Block`, because a standby that missed an entry has to start over.

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
pub fn run(session: zenoh::Session, rx: Receiver<Out>, failures: Arc<AtomicU64>) {
    let put = |key: String, msg: &ServerMessage, encoding: Encoding, congestion| match encode(msg, encoding) {
        Ok(bytes) => {
            session.put(key, bytes).encoding(encoding.zenoh_tag()).congestion_control(congestion).wait().is_ok()
        }
        Err(_) => false,
    };
    for out in rx {
        let ok = match out {
            Out::Put { key, msg, encoding } => put(key, &msg, encoding, zenoh::qos::CongestionControl::Drop),
            Out::Log { key, msg, encoding } => put(key, &msg, encoding, zenoh::qos::CongestionControl::Block),
            Out::Reply { query, bytes, encoding } => {
                query.reply(query.key_expr().clone(), bytes).encoding(encoding.zenoh_tag()).wait().is_ok()
            }
        };
        if !ok {
            failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}
