//! The state thread: builds and publishes each capture's frames on Zenoh.

use super::{Capture, StateCounters, StateOptions, Streams};
use crate::runtime::gate::{TickGate, TICK_WAIT_MOST};
use crate::runtime::owner::Owner;
use impact_protocol::{keys, ClientId, Encoding, WorldId};
use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::mpsc::Receiver;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Whether anyone subscribes to what `p` publishes (`true` when it cannot tell).
fn matching(p: Option<&zenoh::pubsub::Publisher<'static>>) -> bool {
    use zenoh::Wait;
    p.is_none_or(|p| p.matching_status().wait().map(|m| m.matching()).unwrap_or(true))
}

/// A client's publisher, and whether it was listening when last asked.
struct Listener {
    publisher: Option<zenoh::pubsub::Publisher<'static>>,
    listening: bool,
    next_check: u64,
}

/// The state thread: builds and publishes frames for every capture until the queue closes.
///
/// Streams nobody subscribes to are not built: the world stream's publisher is asked every frame,
/// each client's once a second (a client that subscribes is seen within a second and starts with
/// a full frame), so players that never look at the state cost only the question. It builds and
/// publishes between the world's ticks (`gate`), the tick first.
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
    let world_publisher = publisher(keys::STATE.key(&world, None));
    let mut listeners: BTreeMap<ClientId, Listener> = BTreeMap::new();
    let check_every = u64::from(opts.hz.max(1));
    let frame_span = Duration::from_secs(1) / opts.hz.max(1);
    let mut streams = Streams::new(world.clone(), opts, encoding);
    for (n, mut cap) in rx.into_iter().enumerate() {
        let t0 = Instant::now();
        let n = n as u64;
        // Forget the clients gone (a search each, not a pass over the watchers each).
        let mut watching: Vec<ClientId> = cap.watchers.iter().map(|v| v.client).collect();
        watching.sort_unstable();
        listeners.retain(|c, _| watching.binary_search(c).is_ok());
        cap.watchers.retain(|v| {
            let l = listeners.entry(v.client).or_insert_with(|| Listener {
                publisher: publisher(keys::CLIENT_STATE.key(&world, Some(v.client))),
                listening: false,
                next_check: n,
            });
            if n >= l.next_check {
                l.listening = matching(l.publisher.as_ref());
                l.next_check = n + check_every;
            }
            l.listening
        });
        // Waits for ticks to end, at most a frame's span a capture: frames come at their rate.
        let mut waited = Duration::ZERO;
        let mut pause = || {
            let left = frame_span.saturating_sub(waited).min(TICK_WAIT_MOST);
            if !left.is_zero() {
                waited += gate.after_tick(left);
            }
        };
        let listening = matching(world_publisher.as_ref());
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
                    world_publisher.as_ref()
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
