//! The tick thread's own CPU time and its wait for a core, per tick.
//!
//! A tick's wall time mixes the server's work with the machine's: on a shared machine (a load
//! generator beside the server, another world's tick, the state thread) a tick can take twice its
//! CPU time because it waited for a core. Linux counts both per thread: the time run on a CPU
//! (`CLOCK_THREAD_CPUTIME_ID`, exact to the nanosecond when read) and the time spent runnable on
//! a run queue (`/proc/thread-self/schedstat`, brought up to date each time the thread is put
//! back on a CPU, so exact whenever the thread reads it itself). Read before and after each tick,
//! the two split the wall time into the server's own cost and the machine's share. The run time
//! is not taken from `schedstat` too: there it advances only at scheduler events (a timer tick
//! every 4 ms at `HZ=250`), which would round a 2 ms tick's CPU to 0 or 4 ms. The file is opened
//! once on the measured thread and re-read from the start (a few microseconds); elsewhere than
//! Linux, or where the file is missing, the clock reads nothing and the figures are left out.
//!
//! [`set_nice`] puts the calling thread ahead of others when a core is contended: the tick thread
//! asks for it (`ServerOptions::tick_nice`), so its wait shrinks where the system allows.
//! [`pin_to_cpu`] keeps a thread on one CPU.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};

/// Nanoseconds a thread has run on a CPU and waited runnable for one, since it started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct ThreadTimes {
    /// Run on a CPU.
    pub(crate) run_ns: u64,
    /// Runnable, waiting on a run queue (preempted or woken without a free core).
    pub(crate) wait_ns: u64,
}

impl ThreadTimes {
    /// What passed from `earlier` to `self`.
    pub(crate) fn since(self, earlier: ThreadTimes) -> ThreadTimes {
        ThreadTimes {
            run_ns: self.run_ns.saturating_sub(earlier.run_ns),
            wait_ns: self.wait_ns.saturating_sub(earlier.wait_ns),
        }
    }
}

/// The calling thread's scheduler clock (see the module).
#[derive(Debug)]
pub(crate) struct ThreadClock {
    file: Option<File>,
}

impl ThreadClock {
    /// The clock of the thread that calls this (read it from the same thread).
    pub(crate) fn of_this_thread() -> ThreadClock {
        ThreadClock { file: File::open("/proc/thread-self/schedstat").ok() }
    }

    /// The thread's times now, or `None` where the system does not count them.
    pub(crate) fn read(&mut self) -> Option<ThreadTimes> {
        let file = self.file.as_mut()?;
        let mut buf = [0u8; 96];
        let n = file.seek(SeekFrom::Start(0)).and_then(|_| file.read(&mut buf)).ok()?;
        let scheduled = parse(&buf[..n])?;
        Some(ThreadTimes { run_ns: run_ns(), ..scheduled })
    }
}

/// The calling thread's CPU time, exact (the schedstat file is read only on Linux).
fn run_ns() -> u64 {
    #[cfg(target_os = "linux")]
    {
        let t = rustix::time::clock_gettime(rustix::time::ClockId::ThreadCPUTime);
        (t.tv_sec as u64).saturating_mul(1_000_000_000).saturating_add(t.tv_nsec as u64)
    }
    #[cfg(not(target_os = "linux"))]
    {
        0
    }
}

/// Sets the calling thread's nice value (`setpriority` on its thread id): below 0 needs
/// `CAP_SYS_NICE` or root. The error says why not; elsewhere than Linux it is refused.
pub(crate) fn set_nice(nice: i32) -> Result<(), String> {
    #[cfg(target_os = "linux")]
    {
        rustix::process::setpriority_process(Some(rustix::thread::gettid()), nice).map_err(|e| e.to_string())
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = nice;
        Err("thread priorities are set on Linux only".into())
    }
}

/// Keeps the calling thread, and the threads it starts from now on, on one CPU (a benchmark's
/// load generator kept off the server's core). Elsewhere than Linux it is refused.
pub fn pin_to_cpu(cpu: usize) -> Result<(), String> {
    #[cfg(target_os = "linux")]
    {
        let mut set = rustix::thread::CpuSet::new();
        set.set(cpu);
        rustix::thread::sched_setaffinity(None, &set).map_err(|e| format!("CPU {cpu}: {e}"))
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = cpu;
        Err("CPU affinity is set on Linux only".into())
    }
}

/// `"<run ns> <wait ns> <timeslices>\n"`.
fn parse(text: &[u8]) -> Option<ThreadTimes> {
    let mut fields = std::str::from_utf8(text).ok()?.split_ascii_whitespace().map(str::parse::<u64>);
    Some(ThreadTimes { run_ns: fields.next()?.ok()?, wait_ns: fields.next()?.ok()? })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_kernels_line_and_refuses_anything_else() {
        assert_eq!(parse(b"1234 56 7\n"), Some(ThreadTimes { run_ns: 1234, wait_ns: 56 }));
        assert_eq!(parse(b""), None);
        assert_eq!(parse(b"12 x 3"), None);
    }

    /// A nice value the calling thread is allowed (raising it is), read back from the kernel's
    /// own record of the thread; the process's other threads keep theirs.
    #[cfg(target_os = "linux")]
    #[test]
    fn set_nice_moves_the_calling_thread_only() {
        fn nice_of(path: &str) -> i64 {
            let stat = std::fs::read_to_string(path).expect("stat");
            // Field 19 (nice), counted after the parenthesised name.
            stat.rsplit(')').next().unwrap().split_whitespace().nth(16).unwrap().parse().unwrap()
        }
        let main_before = nice_of("/proc/self/stat");
        let moved = std::thread::spawn(|| {
            set_nice(7).expect("raising the nice value needs no privilege");
            nice_of("/proc/thread-self/stat")
        })
        .join()
        .unwrap();
        assert_eq!(moved, 7);
        assert_eq!(nice_of("/proc/self/stat"), main_before, "the process's main thread is untouched");
    }

    #[test]
    fn a_busy_thread_runs_and_the_clock_counts_it() {
        let mut clock = ThreadClock::of_this_thread();
        let Some(before) = clock.read() else {
            return; // not Linux: nothing to count
        };
        let t = std::time::Instant::now();
        let mut x = 0u64;
        while t.elapsed() < std::time::Duration::from_millis(20) {
            x = std::hint::black_box(x.wrapping_add(1));
        }
        let spent = clock.read().expect("read once, read again").since(before);
        // 20 ms of wall time spinning: run + wait covers it (the scheduler's ticks are coarse,
        // so allow a little under), and a sleeping thread's clock would not move at all.
        assert!(spent.run_ns + spent.wait_ns >= 15_000_000, "{spent:?}");
        // Short spans are counted to the microsecond, not to the scheduler's 4 ms tick: a
        // thread that spins for 2 ms ran or waited for all of it, every time.
        for _ in 0..5 {
            let before = clock.read().expect("read");
            let t = std::time::Instant::now();
            while t.elapsed() < std::time::Duration::from_millis(2) {
                x = std::hint::black_box(x.wrapping_add(1));
            }
            let wall = t.elapsed().as_nanos() as u64;
            let spent = clock.read().expect("read").since(before);
            assert!(spent.run_ns + spent.wait_ns >= wall * 9 / 10, "{spent:?} in {wall} ns");
            assert!(spent.run_ns + spent.wait_ns <= wall + 1_000_000, "{spent:?} in {wall} ns");
        }
        let idle = clock.read().expect("read");
        std::thread::sleep(std::time::Duration::from_millis(20));
        let slept = clock.read().expect("read").since(idle);
        assert!(slept.run_ns < 5_000_000, "a sleeping thread ran {slept:?}");
    }
}
