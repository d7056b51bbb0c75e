//! The tick's thread pool, and the one way the stages use it: a loop over `0..n` is cut into
//! consecutive pieces, each piece is worked by one thread exactly as the sequential loop works
//! it, and the pieces' outputs are joined in order. Every parallel loop in the core is a map or
//! a filter over its items (each item's output depends on the world as the stage found it, never
//! on another item's output), so joining in order gives the sequential loop's output bit for bit,
//! however many threads there are and wherever the cuts fall. That is why a result cannot depend
//! on the thread count: no stage adds floating-point numbers across pieces, no stage lets the
//! first thread to finish decide an order, and what depends on order (resolution in time of
//! impact, the resting-contact and settle passes) stays on one thread. The determinism test
//! (`server/tests/threads.rs`) checks it over every bundled scene and a rollback stress run.
//!
//! The threads are a feature (`threads`, on by default): without it there is no rayon, every
//! loop runs inline on the caller's thread, and [`Pool::new`] refuses more than one thread. A
//! client stepping its own avatar builds the core that way.

#[cfg(feature = "threads")]
use rayon::prelude::*;
use std::ops::Range;
#[cfg(feature = "threads")]
use std::sync::atomic::{AtomicBool, Ordering};
#[cfg(feature = "threads")]
use std::sync::Arc;

/// Threads the tick may use, shared by every stepper of a process (clones share the threads).
/// The default is one thread: no pool at all, the loops run inline.
#[derive(Clone, Debug, Default)]
pub struct Pool {
    #[cfg(feature = "threads")]
    pool: Option<Arc<rayon::ThreadPool>>,
    /// Cut every loop as finely as the threads allow, whatever its length (tests: small
    /// scenes then take the parallel paths too).
    fine: bool,
}

/// Items per piece for cheap per-item work (a box, a position, a key: a few nanoseconds each).
/// A piece holds about ten microseconds of work, enough to pay for handing it to a thread that
/// [`Pool::run`] keeps awake (16,384 when the threads slept between loops: two threads at
/// 10,000 bodies went from 1.16x to 1.24x over one when this came down to 2,048; 1,024 did no
/// better).
pub const MIN_PIECE: usize = 2 * 1024;

/// Items per piece for expensive per-item work (a grid cell sweep, a narrowphase pair, a
/// contact record: tens of nanoseconds each).
pub const MIN_PIECE_HEAVY: usize = 1024;

/// Looks for work (about a microsecond apart) a thread kept awake by [`Pool::run`] makes in a
/// row, finding none, before it stops keeping awake for the tick (it then sleeps as rayon's idle
/// threads do): longer than the sequential stretches of a tick of 10,000 bodies.
#[cfg(feature = "threads")]
const IDLE_LOOKS: u32 = 512;

#[cfg(feature = "threads")]
thread_local! {
    /// Set while this thread runs a tick ([`Pool::run`]'s closure) or keeps awake for one.
    static BUSY: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Marks this thread busy until dropped (restoring what was there: ticks may nest, a rollback's
/// re-simulation inside a tick, say).
#[cfg(feature = "threads")]
struct Busy(bool);

#[cfg(feature = "threads")]
impl Busy {
    fn enter() -> Busy {
        Busy(BUSY.replace(true))
    }
}

#[cfg(feature = "threads")]
impl Drop for Busy {
    fn drop(&mut self) {
        BUSY.set(self.0);
    }
}

impl Pool {
    /// One thread: every loop runs inline on the caller's thread.
    pub fn sequential() -> Pool {
        Pool::default()
    }

    /// A pool of `threads` threads (1 or 0: [`Pool::sequential`]; more than one is refused
    /// without the `threads` feature).
    pub fn new(threads: usize) -> Result<Pool, String> {
        if threads <= 1 {
            return Ok(Pool::sequential());
        }
        #[cfg(not(feature = "threads"))]
        return Err(format!("{threads} core threads asked, but impact-core was built without its `threads` feature"));
        #[cfg(feature = "threads")]
        Pool::spawn(threads)
    }

    #[cfg(feature = "threads")]
    fn spawn(threads: usize) -> Result<Pool, String> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("impact-core-{i}"))
            .build()
            .map_err(|e| format!("starting {threads} core threads: {e}"))?;
        Ok(Pool { pool: Some(Arc::new(pool)), fine: false })
    }

    /// The same threads, with every loop cut into pieces however short it is (for tests: the
    /// bundled scenes are small, and the joins must be exercised on them).
    pub fn cut_finely(mut self) -> Pool {
        self.fine = true;
        self
    }

    /// The machine's available cores (the default of `--threads`).
    pub fn available() -> usize {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }

    /// Threads in the pool.
    pub fn threads(&self) -> usize {
        #[cfg(feature = "threads")]
        if let Some(pool) = &self.pool {
            return pool.current_num_threads();
        }
        1
    }

    /// Runs `f` on one of the pool's threads (inline without a pool). A whole tick runs this
    /// way, so its sequential parts run on a pool thread too and the loops it cuts are worked
    /// by that thread and the others: the pool's threads are all the threads the tick uses.
    ///
    /// While `f` runs, the pool's other threads stay awake, taking the pieces of each loop as
    /// it is cut and yielding the core to the operating system in between. Asleep, a thread
    /// takes 30-60 us to wake on a virtual machine (measured here), and a tick cuts a dozen
    /// loops separated by sequential stages: on 10,000 bodies that cost more than the second
    /// thread saved.
    ///
    /// `items` is the size of the work (a world's bodies): below [`MIN_PIECE`] its per-body
    /// loops would not be cut, so `f` runs inline and no thread is woken (a selective rollback
    /// re-simulates a few bodies sixteen times; waking the pool for each tick took longer than
    /// the ticks).
    pub fn run<R: Send>(&self, items: usize, f: impl FnOnce() -> R + Send) -> R {
        #[cfg(feature = "threads")]
        if let Some(pool) = &self.pool {
            if items >= MIN_PIECE || self.fine {
                return Pool::keep_awake_while(pool, f);
            }
        }
        #[cfg(not(feature = "threads"))]
        let _ = items;
        f()
    }

    /// Runs `f` on one of `pool`'s threads while its other threads stay awake ([`Pool::run`]).
    #[cfg(feature = "threads")]
    fn keep_awake_while<R: Send>(pool: &rayon::ThreadPool, f: impl FnOnce() -> R + Send) -> R {
        pool.install(|| {
            let done = Arc::new(AtomicBool::new(false));
            let awake = done.clone();
            rayon::spawn_broadcast(move |_| {
                // Not on a thread that is running a tick or keeping awake already: this job
                // would then sit on top of that work in the thread's stack and spin until its
                // own tick ends, and that tick may be waiting for the work beneath it (a thread
                // keeping awake for one tick can take a piece of the next before it sees its
                // tick end, and run the next tick's job while waiting inside that piece).
                if BUSY.get() {
                    return;
                }
                let _busy = Busy::enter();
                // Look for work a microsecond or so apart (looking touches the other threads'
                // queues, and looking constantly slowed the tick's own thread down by half),
                // and let the operating system run another thread now and then.
                //
                // And give up after a stretch with nothing to do. This job may still sit on top
                // of a piece of the tick: a thread looking for work can take a piece the moment
                // the tick starts, before it sees this job, and run this job while waiting inside
                // that piece. The tick then waits for the piece, nothing else is left to do, and
                // after IDLE_LOOKS this job returns and the piece finishes: a stall, not a
                // deadlock (`back_to_back_ticks_never_deadlock`).
                let mut idle = 0u32;
                while !awake.load(Ordering::Acquire) && idle < IDLE_LOOKS {
                    if rayon::yield_now() == Some(rayon::Yield::Executed) {
                        idle = 0;
                        continue;
                    }
                    idle += 1;
                    if idle % 64 == 0 {
                        std::thread::yield_now();
                    } else {
                        for _ in 0..64 {
                            std::hint::spin_loop();
                        }
                    }
                }
            });
            let r = {
                let _busy = Busy::enter();
                f()
            };
            done.store(true, Ordering::Release);
            r
        })
    }

    /// The pool and the number of pieces for `n` items, or `None` to run inline.
    #[cfg(feature = "threads")]
    fn cut(&self, n: usize, min_piece: usize) -> Option<(&rayon::ThreadPool, usize)> {
        let pool = self.pool.as_deref()?;
        // A few pieces per thread, so one slow piece (a crowded region) does not hold the rest.
        let min_piece = if self.fine { 1 } else { min_piece.max(1) };
        let pieces = (n / min_piece).min(pool.current_num_threads() * 4);
        (pieces > 1).then_some((pool, pieces))
    }

    /// Appends to `out` what `f(0..n, out)` appends, with `0..n` cut into pieces worked in
    /// parallel and joined in order. `f` must append for a range exactly what it appends for
    /// the range's pieces one after another (a map or a filter over the items does).
    pub fn extend<T: Send>(
        &self,
        n: usize,
        #[cfg_attr(not(feature = "threads"), allow(unused_variables))] min_piece: usize,
        out: &mut Vec<T>,
        f: impl Fn(Range<usize>, &mut Vec<T>) + Sync,
    ) {
        #[cfg(feature = "threads")]
        if let Some((pool, pieces)) = self.cut(n, min_piece) {
            return Pool::extend_in_pieces(pool, pieces, n, out, f);
        }
        f(0..n, out)
    }

    /// [`Pool::extend`] on `pool`, in `pieces` pieces.
    #[cfg(feature = "threads")]
    fn extend_in_pieces<T: Send>(
        pool: &rayon::ThreadPool,
        pieces: usize,
        n: usize,
        out: &mut Vec<T>,
        f: impl Fn(Range<usize>, &mut Vec<T>) + Sync,
    ) {
        let parts: Vec<Vec<T>> = pool.install(|| {
            (0..pieces)
                .into_par_iter()
                .map(|k| {
                    let mut part = Vec::new();
                    f(n * k / pieces..n * (k + 1) / pieces, &mut part);
                    part
                })
                .collect()
        });
        out.reserve(parts.iter().map(Vec::len).sum());
        for part in parts {
            out.extend(part);
        }
    }

    /// Appends `f(i)` for every `i` in `0..n`, in order, computed in parallel and written in
    /// place (no piece is copied into `out` afterwards).
    pub fn map_into<T: Send>(
        &self,
        n: usize,
        #[cfg_attr(not(feature = "threads"), allow(unused_variables))] min_piece: usize,
        out: &mut Vec<T>,
        f: impl Fn(usize) -> T + Sync + Send,
    ) {
        #[cfg(feature = "threads")]
        if let Some((pool, _)) = self.cut(n, min_piece) {
            let min = if self.fine { 1 } else { min_piece };
            return pool.install(|| out.par_extend((0..n).into_par_iter().with_min_len(min).map(f)));
        }
        out.extend((0..n).map(f));
    }

    /// Calls `f(first, piece)` on consecutive pieces of `items` in parallel (`first`: the index
    /// of the piece's first item). For element-wise maps: each item's new value must depend on
    /// nothing another item's call writes.
    pub fn for_each_mut<T: Send>(
        &self,
        items: &mut [T],
        #[cfg_attr(not(feature = "threads"), allow(unused_variables))] min_piece: usize,
        f: impl Fn(usize, &mut [T]) + Sync,
    ) {
        #[cfg(feature = "threads")]
        if let Some((pool, pieces)) = self.cut(items.len(), min_piece) {
            let size = items.len().div_ceil(pieces);
            return pool.install(|| items.par_chunks_mut(size).enumerate().for_each(|(k, piece)| f(k * size, piece)));
        }
        f(0, items);
    }

    /// Sorts `v`. The order is total and no two items are equal unless identical (callers sort
    /// tuples that end in a unique index or are unique themselves), so the sorted slice is the
    /// same whichever algorithm and however many threads sorted it.
    pub fn sort_unstable<T: Ord + Send>(&self, v: &mut [T]) {
        #[cfg(feature = "threads")]
        if let Some((pool, _)) = self.cut(v.len(), MIN_PIECE) {
            return pool.install(|| v.par_sort_unstable());
        }
        v.sort_unstable();
    }
}

#[cfg(all(test, feature = "threads"))]
mod tests {
    use super::*;

    /// Ticks back to back, each a few cut loops, never wait on each other. A thread kept awake
    /// for one tick used to take a piece of the next tick's first loop before it saw its tick
    /// end; waiting inside that piece it ran the next tick's keep-awake job, which spins until
    /// that tick ends, while the tick waited for the piece beneath it: a deadlock, seen once in
    /// CI. A watchdog turns a hang into a failure.
    #[test]
    fn back_to_back_ticks_never_deadlock() {
        let done = Arc::new(AtomicBool::new(false));
        let watch = done.clone();
        std::thread::spawn(move || {
            for _ in 0..600 {
                std::thread::sleep(std::time::Duration::from_millis(100));
                if watch.load(Ordering::Acquire) {
                    return;
                }
            }
            eprintln!("back_to_back_ticks_never_deadlock: no progress in 60 s, a deadlock");
            std::process::exit(101);
        });
        const TICKS: u64 = 40_000;
        for threads in [2, 3, 4] {
            let pool = Pool::new(threads).unwrap().cut_finely();
            let mut sum = 0u64;
            for tick in 0..TICKS {
                sum += pool.run(0, || {
                    let mut a = Vec::new();
                    pool.extend(64, 1, &mut a, |r, out| out.extend(r.map(|i| i as u64 * tick)));
                    let mut b = Vec::new();
                    pool.map_into(64, 1, &mut b, |i| a[i] + 1);
                    b.iter().sum::<u64>()
                });
            }
            assert_eq!(sum, (0..TICKS).map(|t| (0..64u64).map(|i| i * t + 1).sum::<u64>()).sum::<u64>());
        }
        done.store(true, Ordering::Release);
    }

    /// A filter-map gives the same output inline and cut over 2, 3 and 4 threads, for lengths
    /// around every cut.
    #[test]
    fn pieces_join_to_the_sequential_output() {
        let f = |r: Range<usize>, out: &mut Vec<(usize, u64)>| {
            for i in r {
                if i % 3 != 1 {
                    out.push((i, (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)));
                }
            }
        };
        for threads in [2, 3, 4] {
            let pool = Pool::new(threads).unwrap();
            assert_eq!(pool.threads(), threads);
            for n in [0, 1, 7, 255, 256, 257, 1000, 4099] {
                let (mut inline, mut cut) = (vec![(9, 9)], vec![(9, 9)]);
                Pool::sequential().extend(n, 16, &mut inline, f);
                pool.extend(n, 16, &mut cut, f);
                assert_eq!(inline, cut, "n = {n}, {threads} threads");
                let mut a: Vec<u64> = (0..n as u64).collect();
                let mut b = a.clone();
                Pool::sequential().for_each_mut(&mut a, 16, |first, p| {
                    p.iter_mut().enumerate().for_each(|(k, x)| *x = *x * 7 + (first + k) as u64)
                });
                pool.for_each_mut(&mut b, 16, |first, p| {
                    p.iter_mut().enumerate().for_each(|(k, x)| *x = *x * 7 + (first + k) as u64)
                });
                assert_eq!(a, b);
            }
        }
    }
}
