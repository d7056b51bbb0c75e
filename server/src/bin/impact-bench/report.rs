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

/// Prints a JSON line (always to stdout, so `--json | grep '^{'` works with the table too).
pub fn json_line(v: &serde_json::Value) {
    println!("{v}");
}

/// Progress to stderr, so stdout stays clean for tables and JSON.
pub fn progress(msg: &str) {
    eprintln!("  .. {msg}");
}
