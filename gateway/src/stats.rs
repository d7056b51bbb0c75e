//! What the gateway counts: connections by how they ended, messages and bytes each way, what
//! its bounds dropped, and how long what it relays stays in it. Served as JSON on `GET /stats` and printed by `impact-gateway` every
//! few seconds.

use crate::wire::Close;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Mutex;
use std::time::Instant;

/// The counters, shared by every connection.
#[derive(Debug, Default)]
pub struct Counters {
    /// Connections upgraded to WebSocket.
    pub accepted: AtomicU64,
    /// Connections refused before the upgrade (the connection limit, the origin check).
    pub refused: AtomicU64,
    /// Players authenticated and relayed.
    pub joined: AtomicU64,
    /// Connections open now.
    pub open: AtomicU64,
    /// Connections ended, by reason ([`Close::ALL`]'s order).
    pub closed: [AtomicU64; Close::ALL.len()],
    /// Messages and bytes from the browsers, relayed to the servers.
    pub messages_in: AtomicU64,
    /// See `messages_in`.
    pub bytes_in: AtomicU64,
    /// Messages and bytes sent to the browsers.
    pub messages_out: AtomicU64,
    /// See `messages_out`.
    pub bytes_out: AtomicU64,
    /// State frames dropped because a browser's queue was full.
    pub state_dropped: AtomicU64,
    /// Samples of an older owner epoch, dropped.
    pub stale_owner: AtomicU64,
    /// Messages on players' events keys that never reached the gateway (skips in the keys'
    /// numbers; each skip tells its player `link_restored`).
    pub messages_lost: AtomicU64,
    /// Samples from the servers that did not decode, dropped.
    pub malformed_from_server: AtomicU64,
    /// Presences declared again because a player's welcome had not come.
    pub presence_repeats: AtomicU64,
    /// How long answers, events and the rest of what is never dropped stayed in the gateway:
    /// from their sample's arrival to their write to the browser, microseconds, since start.
    relay_us: Mutex<Option<hdrhistogram::Histogram<u64>>>,
}

/// The counters at one moment.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Snapshot {
    /// See [`Counters`].
    pub accepted: u64,
    /// See [`Counters`].
    pub refused: u64,
    /// See [`Counters`].
    pub joined: u64,
    /// See [`Counters`].
    pub open: u64,
    /// Connections ended, by reason name (only reasons that happened).
    pub closed: BTreeMap<&'static str, u64>,
    /// See [`Counters`].
    pub messages_in: u64,
    /// See [`Counters`].
    pub bytes_in: u64,
    /// See [`Counters`].
    pub messages_out: u64,
    /// See [`Counters`].
    pub bytes_out: u64,
    /// See [`Counters`].
    pub state_dropped: u64,
    /// See [`Counters`].
    pub stale_owner: u64,
    /// See [`Counters`].
    pub messages_lost: u64,
    /// See [`Counters`].
    pub malformed_from_server: u64,
    /// See [`Counters`].
    pub presence_repeats: u64,
    /// Messages never dropped (answers, events, ...) relayed to browsers, and their time in the
    /// gateway from arrival to write, microseconds: median, 99th percentile, most.
    pub relayed_kept: u64,
    /// See `relayed_kept`.
    pub relay_us_p50: u64,
    /// See `relayed_kept`.
    pub relay_us_p99: u64,
    /// See `relayed_kept`.
    pub relay_us_max: u64,
}

impl Counters {
    /// Kept messages written, each queued at one of `at`.
    pub fn relayed(&self, at: &[Instant]) {
        if at.is_empty() {
            return;
        }
        let mut h = self.relay_us.lock().unwrap_or_else(|e| e.into_inner());
        let h = h.get_or_insert_with(|| {
            hdrhistogram::Histogram::new_with_bounds(1, 60_000_000, 2).expect("the bounds are valid")
        });
        for t in at {
            h.saturating_record(t.elapsed().as_micros().max(1) as u64);
        }
    }

    /// Counts a connection ended for `why`.
    pub fn closed(&self, why: Close) {
        if let Some(i) = Close::ALL.iter().position(|c| *c == why) {
            self.closed[i].fetch_add(1, Relaxed);
        }
    }

    /// The counters now.
    pub fn snapshot(&self) -> Snapshot {
        let relay = self.relay_us.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let closed = Close::ALL
            .iter()
            .zip(&self.closed)
            .map(|(c, n)| (c.name(), n.load(Relaxed)))
            .filter(|(_, n)| *n > 0)
            .collect();
        Snapshot {
            accepted: self.accepted.load(Relaxed),
            refused: self.refused.load(Relaxed),
            joined: self.joined.load(Relaxed),
            open: self.open.load(Relaxed),
            closed,
            messages_in: self.messages_in.load(Relaxed),
            bytes_in: self.bytes_in.load(Relaxed),
            messages_out: self.messages_out.load(Relaxed),
            bytes_out: self.bytes_out.load(Relaxed),
            state_dropped: self.state_dropped.load(Relaxed),
            stale_owner: self.stale_owner.load(Relaxed),
            messages_lost: self.messages_lost.load(Relaxed),
            malformed_from_server: self.malformed_from_server.load(Relaxed),
            presence_repeats: self.presence_repeats.load(Relaxed),
            relayed_kept: relay.as_ref().map_or(0, |h| h.len()),
            relay_us_p50: relay.as_ref().map_or(0, |h| h.value_at_quantile(0.5)),
            relay_us_p99: relay.as_ref().map_or(0, |h| h.value_at_quantile(0.99)),
            relay_us_max: relay.as_ref().map_or(0, |h| h.max()),
        }
    }
}
