//! The state thread: builds and publishes each capture's frames on Zenoh.

use super::{Capture, StateCounters, StateOptions, Streams};
use crate::runtime::gate::{TickGate, TICK_WAIT_MOST};
use crate::runtime::owner::Owner;
use impact_protocol::{keys, ClientId, Encoding, WorldId};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A publisher, and whether anyone subscribes to it, as Zenoh tells it: a matching listener sets
/// the flag whenever subscribers come or go. (Asking `matching_status` instead walks every
/// subscription in the routing tables: once a second for each of 1,000 clients, that was a seventh
/// of this thread.) Where there is no publisher or no listener, it counts as listened to.
struct Listener {
    publisher: Option<zenoh::pubsub::Publisher<'static>>,
    listening: Arc<AtomicBool>,
}

impl Listener {
    fn new(publisher: Option<zenoh::pubsub::Publisher<'static>>) -> Listener {
        use zenoh::Wait;
        let listening = Arc::new(AtomicBool::new(true));
        if let Some(p) = &publisher {
            // Declaring the listener reports the status at once (true if anyone matches), then
            // each change; it is undeclared with the publisher.
            listening.store(false, Ordering::Relaxed);
            let flag = listening.clone();
            let declared = p
                .matching_listener()
                .callback(move |m| flag.store(m.matching(), Ordering::Relaxed))
                .background()
                .wait();
            if declared.is_err() {
                listening.store(true, Ordering::Relaxed);
            }
        }
        Listener { publisher, listening }
    }

    fn listening(&self) -> bool {
        self.listening.load(Ordering::Relaxed)
    }
}

/// The state thread: builds and publishes frames for every capture until the queue closes.
///
/// Streams nobody subscribes to are not built (a matching listener per publisher: a client that
/// subscribes is seen as soon as Zenoh knows, and starts with a full frame), so players that never
/// look at the state cost nothing here. It builds and publishes between the world's ticks
/// (`gate`), the tick first.
#[allow(clippy::too_many_arguments)]
pub fn run(
    session: zenoh::Session,
    world: WorldId,
    opts: StateOptions,
    encoding: Encoding,
    rx: Receiver<Capture>,
    counters: Arc<StateCounters>,
    owner: Arc<Owner>,
    gate: Arc<TickGate>,
) {
    use zenoh::Wait;
    let drop = zenoh::qos::CongestionControl::Drop;
    let publisher = |key: String| session.declare_publisher(key).congestion_control(drop).wait().ok();
    let world_listener = Listener::new(publisher(keys::STATE.key(&world, None)));
    let mut listeners: BTreeMap<ClientId, Listener> = BTreeMap::new();
    let frame_span = Duration::from_secs(1) / opts.hz.max(1);
    let mut streams = Streams::new(world.clone(), opts, encoding);
    for mut cap in rx {
        let t0 = Instant::now();
        // Forget the clients gone (a search each, not a pass over the watchers each).
        let mut watching: Vec<ClientId> = cap.watchers.iter().map(|v| v.client).collect();
        watching.sort_unstable();
        listeners.retain(|c, _| watching.binary_search(c).is_ok());
        cap.watchers.retain(|v| {
            listeners
                .entry(v.client)
                .or_insert_with(|| Listener::new(publisher(keys::CLIENT_STATE.key(&world, Some(v.client)))))
                .listening()
        });
        // Waits for ticks to end, at most a frame's span a capture: frames come at their rate.
        let mut waited = Duration::ZERO;
        let mut pause = || {
            let left = frame_span.saturating_sub(waited).min(TICK_WAIT_MOST);
            if !left.is_zero() {
                waited += gate.after_tick(left);
            }
        };
        let listening = world_listener.listening();
        let frames = streams.frames_between(&cap, listening, false, &mut pause);
        // The burst of puts, whole between two ticks: Zenoh's transmit threads write it then too.
        pause();
        let mut deferred = 0;
        for p in frames {
            let len = p.bytes.len() as u64;
            let target = match p.client {
                None => {
                    counters.world_frames.fetch_add(1, Ordering::Relaxed);
                    counters.world_bytes.fetch_add(len, Ordering::Relaxed);
                    world_listener.publisher.as_ref()
                }
                Some(c) => {
                    counters.client_frames.fetch_add(1, Ordering::Relaxed);
                    counters.client_bytes.fetch_add(len, Ordering::Relaxed);
                    listeners.get(&c).and_then(|l| l.publisher.as_ref())
                }
            };
            deferred += u64::from(p.deferred);
            // Held or fenced: nothing goes out. (A standby builds no frames: it has no epoch.)
            let Ok(Some(epoch)) = owner.stamp() else { continue };
            let stamp = epoch.attachment();
            match target {
                Some(publisher) => {
                    let _ = publisher.put(p.bytes).encoding(p.encoding.zenoh_tag()).attachment(stamp.to_vec()).wait();
                }
                None => {
                    let put = session.put(p.key, p.bytes).encoding(p.encoding.zenoh_tag());
                    let _ = put.congestion_control(drop).attachment(stamp.to_vec()).wait();
                }
            }
        }
        counters.deferred.fetch_add(deferred, Ordering::Relaxed);
        counters.busy_ns.fetch_add(t0.elapsed().saturating_sub(waited).as_nanos() as u64, Ordering::Relaxed);
        counters.waited_ns.fetch_add(waited.as_nanos() as u64, Ordering::Relaxed);
    }
}
