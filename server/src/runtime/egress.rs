//! The egress thread: publishes what the tick thread hands it. Publishing uses congestion control
//! `Drop`, so a slow subscriber loses its own messages and never holds anyone back; the input
//! log alone uses `Block`, because a standby that missed an entry has to start over.

use impact_protocol::Encoding;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use zenoh::Wait;

/// A message for the network.
pub enum Out {
    /// Publish `bytes` on `key`.
    Put {
        /// Key expression.
        key: String,
        /// Payload.
        bytes: Vec<u8>,
        /// Its encoding (sets the sample's tag).
        encoding: Encoding,
    },
    /// Publish `bytes` on `key` of the input log: congestion control `Block`, so a slow
    /// subscriber (a standby) slows this thread rather than lose an entry.
    Log {
        /// Key expression.
        key: String,
        /// Payload.
        bytes: Vec<u8>,
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

/// Runs until the sending side is dropped.
pub fn run(session: zenoh::Session, rx: Receiver<Out>, failures: Arc<AtomicU64>) {
    for out in rx {
        let ok = match out {
            Out::Put { key, bytes, encoding } => session
                .put(key, bytes)
                .encoding(encoding.zenoh_tag())
                .congestion_control(zenoh::qos::CongestionControl::Drop)
                .wait()
                .is_ok(),
            Out::Log { key, bytes, encoding } => session
                .put(key, bytes)
                .encoding(encoding.zenoh_tag())
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .wait()
                .is_ok(),
            Out::Reply { query, bytes, encoding } => {
                query.reply(query.key_expr().clone(), bytes).encoding(encoding.zenoh_tag()).wait().is_ok()
            }
        };
        if !ok {
            failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}
