//! The copy of the world the state streams are built from: taken by the tick thread when a
//! frame is due and handed to the state thread (`runtime/state.rs`), never waited for.

use super::{stream_frame, Capture, Summary, TickLoop, Watcher};
use impact_protocol::ClientId;
use std::sync::atomic::Ordering;
use std::sync::mpsc::TrySendError;
use std::time::Instant;

impl TickLoop {
    /// Hands a copy of the world to the state thread when a state frame is due: the world
    /// stream's, or a client's (each stream `--state-hz` frames a second, the clients' spread over
    /// the ticks: [`stream_frame`]). A copy the state thread had no room for is counted and the
    /// same streams are due on the next tick.
    pub(super) fn capture_state(&mut self) {
        let Some(tx) = &self.state_tx else { return };
        let (hz, tick_hz, now) = (self.opts.state.hz, self.session.world().config.tick_hz, self.session.now());
        let frame_of = |c: Option<ClientId>| stream_frame(c, now, hz, tick_hz);
        let world = self.state_frame != Some(frame_of(None));
        let watchers: Vec<Watcher> = self
            .clients
            .iter()
            .filter(|(_, s)| s.present)
            .filter_map(|(c, s)| {
                let due = s.state_frame != Some(frame_of(Some(*c)));
                s.avatar.map(|avatar| Watcher { client: *c, avatar, encoding: s.encoding, full: s.want_full, due })
            })
            .collect();
        if !world && !watchers.iter().any(|v| v.due) {
            return;
        }
        let t0 = Instant::now();
        let mut cap = Capture::of(self.session.world(), watchers);
        cap.world = world;
        if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(cap) {
            self.state_counters.skipped.fetch_add(1, Ordering::Relaxed);
        } else {
            self.state_frame = Some(frame_of(None));
            // The due streams' frames went with this capture, and their clients' asks.
            for (c, s) in self.clients.iter_mut().filter(|(_, s)| s.present && s.avatar.is_some()) {
                let frame = Some(frame_of(Some(*c)));
                if s.state_frame != frame {
                    (s.state_frame, s.want_full) = (frame, false);
                }
            }
        }
        self.state_counters.capture_ns.fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }

    /// The state streams' figures, into the run's summary.
    pub(super) fn state_summary(&self, summary: &mut Summary) {
        let c = &self.state_counters;
        summary.state_client_frames = c.client_frames.load(Ordering::Relaxed);
        summary.state_client_bytes = c.client_bytes.load(Ordering::Relaxed);
        summary.state_world_bytes = c.world_bytes.load(Ordering::Relaxed);
        // Each client frame stands for 1/hz of a client's second.
        summary.state_client_s = summary.state_client_frames as f64 / f64::from(self.opts.state.hz.max(1));
        summary.state_busy_s = c.busy_ns.load(Ordering::Relaxed) as f64 / 1e9;
        summary.state_capture_s = c.capture_ns.load(Ordering::Relaxed) as f64 / 1e9;
        summary.state_skipped = c.skipped.load(Ordering::Relaxed);
    }
}
