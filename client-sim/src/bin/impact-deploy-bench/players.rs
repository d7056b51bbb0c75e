//! `players`: what a watching player costs the server, measured on the server alone.
//!
//! The server runs on one CPU (`taskset`), the load generator on another (this process pins
//! itself), so the server's figures are its own: its user + system CPU time read from the OS over
//! a steady window (after the players joined), split by thread name, the tick's percentiles and
//! overruns from its stats, and the tick thread's own CPU from its summary. Each run is a fresh
//! server; a run whose load generator fell behind (`Report::load_kept_up`) is marked invalid and
//! left out of the medians (a setting with no valid run shows the medians of all its runs, marked).

use super::{endpoint, median, progress, router_proc, server_on, stat_cpu_s};
use anyhow::{bail, Result};
use impact_client::netsim::Link;
use impact_client_sim::load::{self, Behaviour, LoadConfig};
use impact_client_sim::net::Mode;
use impact_client_sim::process::zenohd;
use impact_client_sim::report::Report;
use impact_client_sim::timing::Timing;
use impact_protocol::{Encoding, WorldId};
use serde_json::json;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// The arena's tick rate.
const TICK_HZ: f64 = 64.0;

/// What the suite runs.
#[derive(clap::Args, Debug)]
pub struct Players {
    /// Player counts, one series of runs each.
    #[arg(long, value_delimiter = ',', default_value = "100,300,1000,2000")]
    players: Vec<u32>,
    /// State streams: on, off, or both (each count runs with and without).
    #[arg(long, value_delimiter = ',', default_value = "on,off")]
    streams: Vec<Streams>,
    /// Runs per count and stream setting.
    #[arg(long, default_value_t = 3)]
    rounds: u32,
    /// Seconds of load per run.
    #[arg(long, default_value_t = 20)]
    seconds: u64,
    /// Seconds after the load starts before the server's CPU is counted (the players join).
    #[arg(long, default_value_t = 6)]
    warmup: u64,
    /// Players per Zenoh session in the load generator (1: a session per player, as games).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..))]
    per_session: u32,
    /// Through a zenohd router (on the load's CPU), as deployed.
    #[arg(long)]
    router: bool,
    /// One-way latency of the simulated network, ms.
    #[arg(long, default_value_t = 80.0)]
    latency_ms: f64,
    /// Its jitter, ms.
    #[arg(long, default_value_t = 20.0)]
    jitter_ms: f64,
    /// Probability an input is lost on the way.
    #[arg(long, default_value_t = 0.01)]
    loss: f64,
    /// The server's CPU.
    #[arg(long, default_value_t = 0)]
    server_cpu: usize,
    /// The load generator's CPU.
    #[arg(long, default_value_t = 1)]
    load_cpu: usize,
    /// Write the plot (server CPU per player and tick p99 against players) here.
    #[arg(long)]
    svg: Option<std::path::PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum)]
enum Streams {
    On,
    Off,
}

/// One run's figures.
#[derive(Clone, Debug)]
struct Run {
    players: u32,
    streams: bool,
    report: Report,
    /// The server's CPU over the steady window, cores.
    cores: f64,
    /// The same by thread name, cores.
    threads: BTreeMap<String, f64>,
    /// The tick thread's own CPU per tick, ms (from the server's summary).
    tick_cpu: Option<(f64, f64)>,
}

impl Run {
    fn us_per_player_tick(&self) -> f64 {
        self.cores * 1e6 / (TICK_HZ * f64::from(self.players.max(1)))
    }

    fn valid(&self) -> bool {
        self.report.load_kept_up() && self.report.clients_welcomed == self.players
    }
}

pub fn players(a: &Players) -> Result<()> {
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    if a.server_cpu == a.load_cpu || a.server_cpu.max(a.load_cpu) >= cpus {
        bail!("the server and the load need a CPU each (this machine has {cpus}): --server-cpu, --load-cpu");
    }
    // Every thread this process starts from now on (Zenoh's, the router's client) stays here.
    impact_server::runtime::pin_to_cpu(a.load_cpu).map_err(anyhow::Error::msg)?;
    let zenohd = if a.router { Some(zenohd()) } else { None };
    println!(
        "players: the arena at 64 Hz, timing ahead, {} +- {} ms, {} % input loss; server on CPU {}, load on CPU {}; \
         {} players per session{}; {} s a run, CPU counted from {} s",
        a.latency_ms,
        a.jitter_ms,
        a.loss * 100.0,
        a.server_cpu,
        a.load_cpu,
        a.per_session,
        if a.router { ", through a zenohd router" } else { "" },
        a.seconds,
        a.warmup
    );
    if let Some(z) = &zenohd {
        progress(&format!("zenohd: {}", z.display()));
    }
    println!(
        "{:>7} {:>7} {:>5} {:>7} {:>9} {:>11} {:>10} {:>9} {:>8} {:>9} {:>10} {:>8} {:>8} {:>7}  threads (cores)",
        "players",
        "streams",
        "round",
        "cores",
        "us/pl/tk",
        "tick p50/99",
        "tick max",
        "overruns",
        "ack p99",
        "down B/s",
        "up B/s",
        "lag p99",
        "tick cpu",
        "valid"
    );
    let mut runs = Vec::new();
    for &n in &a.players {
        for round in 1..=a.rounds {
            for s in a.streams.iter().copied() {
                progress(&format!("{n} players, streams {s:?}, round {round}"));
                let run = one(a, n, s == Streams::On, round)?;
                print_run(&run, round);
                runs.push(run);
            }
        }
    }
    summary(a, &runs)
}

/// One run: a fresh server (and router) on the server's CPU, the load here.
fn one(a: &Players, players: u32, streams: bool, round: u32) -> Result<Run> {
    let listen = endpoint();
    let router = a.router.then(|| {
        let r = endpoint();
        (router_proc("players-router", &r, &[]), r)
    });
    let connect = router.as_ref().map_or(listen.clone(), |(_, r)| r.clone());
    let hz = if streams { "20" } else { "0" };
    let mut srv = server_on(
        "players-server",
        &listen,
        router.as_ref().map(|(_, r)| r.as_str()),
        &["--quiet", "--state-hz", hz],
        Some(a.server_cpu),
    )?;
    let pid = srv.pid();
    // The server's CPU over the steady window, sampled beside the load.
    let window = Duration::from_secs(a.seconds.saturating_sub(a.warmup + 1).max(1));
    let warmup = Duration::from_secs(a.warmup);
    let sampler = std::thread::spawn(move || {
        std::thread::sleep(warmup);
        let (t0, c0) = (Instant::now(), thread_cpu(pid));
        std::thread::sleep(window);
        let (secs, c1) = (t0.elapsed().as_secs_f64(), thread_cpu(pid));
        let mut by_name: BTreeMap<String, f64> = BTreeMap::new();
        for (tid, (name, s)) in &c1 {
            let before = c0.get(tid).map_or(0.0, |b| b.1);
            *by_name.entry(name.clone()).or_default() += (s - before) / secs;
        }
        by_name
    });
    let link = |loss: f64| Link {
        latency: Duration::from_secs_f64(a.latency_ms / 1e3),
        jitter: Duration::from_secs_f64(a.jitter_ms / 1e3),
        loss,
    };
    let cfg = LoadConfig {
        connect: vec![connect],
        zenoh_config: None,
        mode: Mode::Client,
        world: WorldId::new("arena")?,
        clients: players,
        first_client: 1000,
        sessions: players.div_ceil(a.per_session),
        users: None,
        duration: Duration::from_secs(a.seconds),
        uplink: link(a.loss),
        downlink: link(0.0),
        behaviour: Behaviour::Mixed,
        timing: Timing::Ahead,
        input_hz: 10.0,
        encoding: Encoding::MsgPack,
        seed: u64::from(round),
        settle: Duration::from_secs(2),
        progress: false,
        faults: Default::default(),
        state: streams,
        predict: 0,
        scene: None,
    };
    let report = load::run(&cfg)?;
    let threads = sampler.join().map_err(|_| anyhow::anyhow!("the CPU sampler panicked"))?;
    srv.stop();
    let tick_cpu = tick_thread_cpu(&srv.output());
    Ok(Run { players, streams, cores: threads.values().sum(), threads, report, tick_cpu })
}

/// Each thread of `pid`: its name and seconds of CPU (user + system), by thread id.
fn thread_cpu(pid: u32) -> BTreeMap<u32, (String, f64)> {
    let mut out = BTreeMap::new();
    let Ok(dir) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return out };
    for t in dir.flatten() {
        let Some(tid) = t.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else { continue };
        let stat = std::fs::read_to_string(t.path().join("stat")).unwrap_or_default();
        // The name is between the first '(' and the last ')'.
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else { continue };
        out.insert(tid, (thread_kind(&stat[open + 1..close]), stat_cpu_s(&stat)));
    }
    out
}

/// What a thread is, from its name: the server's own threads without their world's name (cut
/// short by the kernel's 15 characters), Zenoh's runtime threads without their number.
fn thread_kind(name: &str) -> String {
    match name.strip_prefix("impact-") {
        Some(rest) => format!("impact-{}", rest.split('-').next().unwrap_or(rest)),
        None => name.trim_end_matches(|c: char| c.is_ascii_digit() || c == '-').to_string(),
    }
}

/// The tick thread's CPU per tick, p50 and p99 ms, from the server's summary line.
fn tick_thread_cpu(log: &str) -> Option<(f64, f64)> {
    let line = log.lines().find_map(|l| l.split_once("tick thread: cpu ms p50 "))?.1;
    let mut w = line.split_whitespace();
    let p50 = w.next()?.parse().ok()?;
    let p99 = w.nth(1)?.trim_end_matches(';').parse().ok()?;
    Some((p50, p99))
}

fn print_run(r: &Run, round: u32) {
    let p = &r.report;
    let mut threads: Vec<(&String, &f64)> = r.threads.iter().filter(|(_, c)| **c >= 0.01).collect();
    threads.sort_by(|a, b| b.1.total_cmp(a.1));
    let threads: Vec<String> = threads.iter().map(|(n, c)| format!("{n} {c:.2}")).collect();
    println!(
        "{:>7} {:>7} {:>5} {:>7.3} {:>9.2} {:>5.2}/{:<5.2} {:>10.2} {:>9} {:>8.0} {:>9.0} {:>10.0} {:>8.1} {:>8} {:>7}  {}",
        r.players,
        if r.streams { "on" } else { "off" },
        round,
        r.cores,
        r.us_per_player_tick(),
        p.server_tick_ms_p50,
        p.server_tick_ms_p99,
        p.server_tick_ms_max,
        p.server_overruns,
        p.latency_ms_p99,
        p.bytes_down_per_client_s,
        p.bytes_up_per_client_s,
        p.load_lag_ms_p99,
        r.tick_cpu.map_or("-".into(), |(_, p99)| format!("{p99:.2}")),
        if r.valid() { "yes" } else { "NO" },
        threads.join(", ")
    );
    println!(
        "{}",
        json!({
            "suite": "players", "players": r.players, "streams": r.streams, "round": round,
            "sessions": p.sessions, "valid": r.valid(), "welcomed": p.clients_welcomed,
            "server_cores": r.cores, "server_us_per_player_tick": r.us_per_player_tick(),
            "server_threads_cores": r.threads,
            "tick_ms_p50": p.server_tick_ms_p50, "tick_ms_p99": p.server_tick_ms_p99,
            "tick_ms_max": p.server_tick_ms_max, "overruns": p.server_overruns,
            "tick_cpu_ms_p50": r.tick_cpu.map(|t| t.0), "tick_cpu_ms_p99": r.tick_cpu.map(|t| t.1),
            "ack_ms_p50": p.latency_ms_p50, "ack_ms_p99": p.latency_ms_p99,
            "bytes_down_per_client_s": p.bytes_down_per_client_s, "bytes_up_per_client_s": p.bytes_up_per_client_s,
            "state_bytes_per_client_s": p.state_bytes_per_client_s,
            "load_lag_ms_p99": p.load_lag_ms_p99, "load_lag_ms_max": p.load_lag_ms_max,
            "load_inbox_dropped": p.load_inbox_dropped,
            "inputs_unanswered": p.inputs_unanswered, "answers_unexpected": p.answers_unexpected,
        })
    );
}

/// Medians over the valid runs of each count and setting, and the plot.
fn summary(a: &Players, runs: &[Run]) -> Result<()> {
    println!("\nmedians of the valid runs:");
    println!(
        "{:>7} {:>7} {:>6} {:>7} {:>9} {:>9} {:>9} {:>8} {:>9} {:>10}",
        "players", "streams", "valid", "cores", "us/pl/tk", "tick p99", "overruns", "ack p99", "down B/s", "tick cpu99"
    );
    let mut cpu_series: BTreeMap<bool, Vec<(f64, f64)>> = BTreeMap::new();
    let mut p99_series: BTreeMap<bool, Vec<(f64, f64)>> = BTreeMap::new();
    for &n in &a.players {
        for s in [true, false] {
            let all: Vec<&Run> = runs.iter().filter(|r| r.players == n && r.streams == s).collect();
            if all.is_empty() {
                continue;
            }
            let ok: Vec<&Run> = all.iter().copied().filter(|r| r.valid()).collect();
            // With no valid run, the medians of all of them, marked: what the machine did, not
            // the server's cost alone.
            let of = if ok.is_empty() { &all } else { &ok };
            let m = |f: &dyn Fn(&Run) -> f64| median(of.iter().map(|r| f(r)).collect());
            let (cores, per, p99) =
                (m(&|r| r.cores), m(&|r| r.us_per_player_tick()), m(&|r| r.report.server_tick_ms_p99));
            let overruns = m(&|r| r.report.server_overruns as f64);
            let (ack, down) = (m(&|r| r.report.latency_ms_p99), m(&|r| r.report.bytes_down_per_client_s));
            let tick_cpu = m(&|r| r.tick_cpu.map_or(f64::NAN, |t| t.1));
            println!(
                "{n:>7} {:>7} {:>3}/{:<2} {cores:>7.3} {per:>9.2} {p99:>9.2} {overruns:>9.0} {ack:>8.1} {down:>9.0} {tick_cpu:>10.2}{}",
                if s { "on" } else { "off" },
                ok.len(),
                all.len(),
                if ok.is_empty() { "  (no valid run: medians of all, the load generator's lag in them)" } else { "" }
            );
            println!(
                "{}",
                json!({ "suite": "players", "summary": true, "players": n, "streams": s,
                    "valid_runs": ok.len(), "runs": all.len(), "server_cores": cores,
                    "server_us_per_player_tick": per, "tick_ms_p99": p99, "overruns": overruns,
                    "ack_ms_p99": ack, "bytes_down_per_client_s": down, "tick_cpu_ms_p99": tick_cpu })
            );
            if !ok.is_empty() {
                cpu_series.entry(s).or_default().push((f64::from(n), per));
                p99_series.entry(s).or_default().push((f64::from(n), p99));
            }
        }
    }
    if let Some(path) = &a.svg {
        use impact_server::plot::{svg_loglog, Series};
        // Short names (the legend has 135 pixels): "on" and "off" are the state streams.
        let name = |s: bool, what: &str| format!("{what} {}", if s { "on" } else { "off" });
        let mut series: Vec<Series> = Vec::new();
        for (s, points) in cpu_series.into_iter().rev() {
            series.push(Series { name: name(s, "us/player/tick"), points });
        }
        for (s, points) in p99_series.into_iter().rev() {
            series.push(Series { name: name(s, "tick p99"), points });
        }
        std::fs::write(
            path,
            svg_loglog(
                "players: the server on one core, streams on/off (medians)",
                "players",
                "us per player per tick | tick p99 ms",
                &series,
            ),
        )?;
        println!("plot: {}", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_are_grouped_by_what_they_are() {
        assert_eq!(thread_kind("impact-tick-are"), "impact-tick");
        assert_eq!(thread_kind("impact-state-ar"), "impact-state");
        assert_eq!(thread_kind("rx-12"), "rx");
        assert_eq!(thread_kind("acc-0"), "acc");
        assert_eq!(thread_kind("tx"), "tx");
    }

    #[test]
    fn the_tick_threads_cpu_is_read_from_the_summary() {
        let log = "ticks: 1200\ntick thread: cpu ms p50 0.585 p99 2.929 max 7.100; waited for a core p99 0.3 max 1.2 ms (3 ticks 1 ms or more)\n";
        assert_eq!(tick_thread_cpu(log), Some((0.585, 2.929)));
        assert_eq!(tick_thread_cpu("no such line"), None);
    }
}
