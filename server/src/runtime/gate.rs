//! The tick first: the state and egress threads work between the world's ticks, not during them.
//!
//! A server sized for its players shares one core between the tick and the state thread (at
//! 1,000 watching players the state thread's building is about 0.4 of it). The tick thread is
//! ahead by priority (`--tick-nice`), yet a tick that wakes while a capture is being built still
//! shares the core with it for the scheduler's slices, and Zenoh's transmit threads write a burst
//! of puts made just before the tick while it runs. So the tick thread raises a flag while it
//! ticks ([`TickGate::enter`]: an atomic add, and at the end a lock held for a few instructions
//! and a wake-up; it waits for no one's work), and the state thread looks at it before each
//! receiver's frame and before publishing, the egress thread before each message
//! ([`TickGate::after_tick`]): a tick under way, they sleep until that tick ends. Their work moves
//! into the idle part of each tick period, whole: a capture's frames still go out in one burst, so
//! Zenoh batches them as before (the state thread at a lower priority instead, tried, had its puts
//! preempted one by one and Zenoh's transmit threads' cost tripled; BENCHMARKS.md, issue 30).
//!
//! Never a starvation: a waiter waits for the tick it saw, not for the next (ticks back to back
//! leave it the moment between them), and for a bounded time; and the tick loop raises the gate
//! only on a tick it slept before, so a world behind its schedule runs its threads side by side as
//! if there were no gate. The gate is one world's: worlds sharing a core do not wait for each
//! other's ticks.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

/// The longest a thread waits for one tick to end: a tick that long is a stall, and the work goes
/// on beside it.
pub const TICK_WAIT_MOST: Duration = Duration::from_millis(50);

/// Whether the world is ticking, and a wake-up for whoever waits for it to stop. One tick thread
/// enters it.
#[derive(Debug, Default)]
pub struct TickGate {
    /// Ticks begun and ended: odd while one is under way.
    ticks: AtomicU64,
    lock: Mutex<()>,
    over: Condvar,
}

/// A tick under way: the gate opens when this drops (a tick that panics opens it too).
#[must_use = "the tick is under way until this drops"]
#[derive(Debug)]
pub struct Ticking<'a>(&'a TickGate);

impl TickGate {
    /// The tick begins (the tick thread).
    pub fn enter(&self) -> Ticking<'_> {
        self.ticks.fetch_add(1, Ordering::AcqRel);
        Ticking(self)
    }

    /// Returns once the tick under way (if one is) has ended, or after `most`; the time it
    /// waited.
    pub fn after_tick(&self, most: Duration) -> Duration {
        let seen = self.ticks.load(Ordering::Acquire);
        if seen % 2 == 0 {
            return Duration::ZERO;
        }
        self.wait_past(seen, most)
    }

    /// Waits until the count is past `seen` (that tick ended), at most `most`.
    fn wait_past(&self, seen: u64, most: Duration) -> Duration {
        let t0 = Instant::now();
        let mut guard = self.lock.lock().unwrap_or_else(|e| e.into_inner());
        // The count moves under the lock at a tick's end, so not between this look and the wait.
        while self.ticks.load(Ordering::Acquire) == seen {
            let Some(left) = most.checked_sub(t0.elapsed()).filter(|l| !l.is_zero()) else { break };
            guard = self.over.wait_timeout(guard, left).unwrap_or_else(|e| e.into_inner()).0;
        }
        drop(guard);
        t0.elapsed()
    }
}

impl Drop for Ticking<'_> {
    fn drop(&mut self) {
        let guard = self.0.lock.lock().unwrap_or_else(|e| e.into_inner());
        self.0.ticks.fetch_add(1, Ordering::AcqRel);
        drop(guard);
        self.0.over.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Barrier};

    #[test]
    fn without_a_tick_nothing_waits() {
        let gate = TickGate::default();
        assert_eq!(gate.after_tick(Duration::from_secs(5)), Duration::ZERO);
        drop(gate.enter());
        assert_eq!(gate.after_tick(Duration::from_secs(5)), Duration::ZERO);
    }

    #[test]
    fn a_waiter_sleeps_until_the_tick_ends() {
        let gate = Arc::new(TickGate::default());
        let ticking = gate.enter();
        let (g, ready) = (gate.clone(), Arc::new(Barrier::new(2)));
        let r = ready.clone();
        let waiter = std::thread::spawn(move || {
            r.wait();
            g.after_tick(Duration::from_secs(30))
        });
        ready.wait();
        std::thread::sleep(Duration::from_millis(50));
        assert!(!waiter.is_finished(), "returned while the tick was under way");
        let t0 = Instant::now();
        drop(ticking);
        let waited = waiter.join().unwrap();
        assert!(waited > Duration::ZERO && t0.elapsed() < Duration::from_secs(10), "the tick's end did not wake it");
    }

    #[test]
    fn a_waiter_waits_for_the_tick_it_saw_not_the_next() {
        let gate = TickGate::default();
        let first = gate.enter();
        let seen = gate.ticks.load(Ordering::Acquire);
        drop(first);
        let _next = gate.enter();
        let waited = gate.wait_past(seen, Duration::from_secs(30));
        assert!(waited < Duration::from_secs(10), "waited {waited:?} for a tick it never saw");
    }

    #[test]
    fn a_tick_that_never_ends_is_waited_for_at_most_the_bound() {
        let gate = TickGate::default();
        let _ticking = gate.enter();
        let waited = gate.after_tick(Duration::from_millis(20));
        assert!(waited >= Duration::from_millis(20) && waited < Duration::from_secs(10), "waited {waited:?}");
    }
}
