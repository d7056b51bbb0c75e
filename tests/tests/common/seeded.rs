//! What the seeded runs share ([`faults.rs`](../faults.rs), [`deploy_faults.rs`](../deploy_faults.rs)):
//! the seeds to run, running them, and the invariants every run's report keeps.

/// Resident memory a server may reach on the arena with 30 clients (it sits near 60 MiB).
pub const RSS_BOUND_MIB: f64 = 512.0;

/// Runs `run` for each seed, each one's summary printed (only a line for each that passed, on
/// a long run), and fails naming the seeds that failed, why (each one's reasons again, so a log
/// cut in the middle still shows them at its end) and how to run them again.
pub fn run_seeds(kind: &str, var: &str, seeds: Vec<u64>, run: fn(u64) -> Result<String, String>, test: &str) {
    let (mut failed, mut reasons, long, started) =
        (Vec::new(), String::new(), seeds.len() > 20, std::time::Instant::now());
    for (k, &seed) in seeds.iter().enumerate() {
        match run(seed) {
            Ok(_) if long => eprintln!(
                "{kind} seed {seed}: ok ({} of {}, {:.0} s)",
                k + 1,
                seeds.len(),
                started.elapsed().as_secs_f64()
            ),
            Ok(summary) => eprintln!("{kind} seed {seed}: ok\n{summary}\n"),
            Err(why) => {
                eprintln!("{kind} seed {seed}: FAILED\n{why}\n");
                reasons.push_str(&format!("seed {seed}: {}\n", reasons_of(&why)));
                failed.push(seed);
            }
        }
    }
    assert!(
        failed.is_empty(),
        "failing {kind} seeds: {failed:?} of {}\n{reasons}reproduce with {var}={} cargo test -p impact-tests --test {test}",
        seeds.len(),
        failed.iter().map(u64::to_string).collect::<Vec<_>>().join(",")
    );
}

/// The reasons a failed run gave (what follows its last "FAILED:", else its last lines), at most
/// 2,000 characters.
fn reasons_of(why: &str) -> String {
    let tail = match why.rsplit_once("FAILED:") {
        Some((_, reasons)) => reasons.trim().to_string(),
        None => why.lines().rev().take(6).collect::<Vec<_>>().into_iter().rev().collect::<Vec<_>>().join("\n"),
    };
    match tail.char_indices().nth(2_000) {
        Some((cut, _)) => format!("{} [...]", &tail[..cut]),
        None => tail,
    }
}

/// What any seeded run's report shows wrong: an input answered twice, a view of a confirmed
/// tick that differed (or none compared), a confirmed batch that changed, nothing played, no
/// stall.
pub fn violations(r: &impact_client_sim::report::Report, wrong: &mut Vec<String>) {
    if r.answers_unexpected > 0 {
        wrong.push(format!("{} answers were not owed (an input answered twice?)", r.answers_unexpected));
        wrong.extend(r.unexpected.iter().map(|u| format!("    {u}")));
    }
    if r.views_mismatched > 0 || r.views_matched == 0 {
        wrong.push(format!("views: {} matched, {} differed", r.views_matched, r.views_mismatched));
        wrong.extend(r.views_differed.iter().map(|v| format!("    {v}")));
    }
    if r.confirmed_changed > 0 {
        wrong.push(format!("{} confirmed batches changed what a client held confirmed", r.confirmed_changed));
    }
    if r.inputs_delivered == 0 || r.acks == 0 {
        wrong.push("no input was delivered and acked: the run tested nothing".into());
    }
    if r.server_stalls == 0 {
        wrong.push("the server was never stalled".into());
    }
}

/// Seeds from `var` ("3", "1,5,9" or "1-1000"), or `default`.
pub fn seeds(var: &str, default: impl Iterator<Item = u64>) -> Vec<u64> {
    let Ok(v) = std::env::var(var) else { return default.collect() };
    let mut out = Vec::new();
    for part in v.split(',').map(str::trim) {
        let n = |x: &str| x.parse::<u64>().unwrap_or_else(|_| panic!("{var}: {part} is not a seed or a range of them"));
        match part.split_once('-') {
            Some((a, b)) => out.extend(n(a)..=n(b)),
            None => out.push(n(part)),
        }
    }
    out
}
