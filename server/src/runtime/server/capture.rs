//! The copy of the world the state streams are built from: taken by the tick thread when a
//! frame is due and handed to the state thread (`runtime/state.rs`), never waited for.

use super::{Capture, Summary, TickLoop, Watcher};
use std::sync::atomic::Ordering;
use std::sync::mpsc::TrySendError;
use std::time::Instant;

impl TickLoop {
    /// Hands a copy of the world to the state thread when a state frame is due (`--state-hz`
    /// frames per second, on the first tick of each frame's span).
    pub(super) fn capture_state(&mut self) {
        let Some(tx) = &self.state_tx else { return };
        let hz = u64::from(self.opts.state.hz);
        let tick_hz = u64::from(self.session.world().config.tick_hz.max(1));
        let frame = u64::from(self.session.now().0) * hz / tick_hz;
        if self.state_frame == Some(frame) {
            return;
        }
        self.state_frame = Some(frame);
        let t0 = Instant::now();
        let watchers: Vec<Watcher> = self
            .clients
            .iter()
            .filter(|(_, s)| s.present)
            .filter_map(|(c, s)| {
                s.avatar.map(|avatar| Watcher { client: *c, avatar, encoding: s.encoding, full: s.want_full })
            })
            .collect();
        let cap = Capture::of(self.session.world(), watchers);
        if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(cap) {
            self.state_counters.skipped.fetch_add(1, Ordering::Relaxed);
        } else {
            // The asks went with this capture.
            self.clients.values_mut().for_each(|s| s.want_full = false);
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
        summary.state_waited_s = c.waited_ns.load(Ordering::Relaxed) as f64 / 1e9;
        summary.state_capture_s = c.capture_ns.load(Ordering::Relaxed) as f64 / 1e9;
        summary.state_skipped = c.skipped.load(Ordering::Relaxed);
    }
}
