//! Output helpers: a fixed-width table on stdout, JSON lines when asked.

use std::time::Duration;

/// Median of durations in milliseconds.
pub fn median_ms(samples: &mut [Duration]) -> f64 {
    if samples.is_empty() {
        return f64::NAN;
    }
    samples.sort_unstable();
    let mid = samples.len() / 2;
    let m = if samples.len() % 2 == 1 { samples[mid] } else { (samples[mid - 1] + samples[mid]) / 2 };
    m.as_secs_f64() * 1e3
}

/// Mean of durations in milliseconds.
pub fn mean_ms(samples: &[Duration]) -> f64 {
    if samples.is_empty() {
        return f64::NAN;
    }
    samples.iter().map(Duration::as_secs_f64).sum::<f64>() * 1e3 / samples.len() as f64
}

/// The core's pools for `--threads` counts (default: one thread and the machine's cores, for
/// the speed-up), each with its count.
pub fn pools(threads: &[u16]) -> anyhow::Result<Vec<(usize, impact_core::par::Pool)>> {
    let mut counts: Vec<usize> = threads.iter().map(|&t| usize::from(t)).collect();
    if counts.is_empty() {
        counts = vec![1, impact_core::par::Pool::available()];
    }
    counts.dedup();
    counts
        .into_iter()
        .map(|t| {
            anyhow::ensure!(t >= 1, "--threads must be at least 1");
            Ok((t, impact_core::par::Pool::new(t).map_err(anyhow::Error::msg)?))
        })
        .collect()
}

/// Prints a JSON line (always to stdout, so `--json | grep '^{'` works with the table too).
pub fn json_line(v: &serde_json::Value) {
    println!("{v}");
}

/// Progress to stderr, so stdout stays clean for tables and JSON.
pub fn progress(msg: &str) {
    eprintln!("  .. {msg}");
}
