//! Seeded fault simulation, in the spirit of TigerBeetle's VOPR: a real `impact-server` process
//! and 30 clients over real Zenoh, through links that lose inputs, delay and jitter both ways,
//! deliver some inputs twice, and partition for a while, with the server stopped (SIGSTOP) and
//! resumed (SIGCONT) mid-run. Everything is drawn from one seed, printed on failure.
//!
//! Invariants checked at the end of every seed:
//! - every delivered input was answered exactly once per delivery (ack or reject), and nothing
//!   was answered that was not owed;
//! - every client's view of every confirmed tick equals the confirmed stream;
//! - the server did not panic and exits cleanly when asked;
//! - its memory and ingress queue stayed within their bounds.
//!
//! CI runs the fixed seeds below. Reproduce one: `IMPACT_FAULT_SEEDS=7 cargo test -p impact-tests
//! --test faults` (the server binary comes from `cargo build -p impact-server`).
//!
//! Each seeded test is a test binary of its own (this one, `deploy_faults.rs`): a run starts
//! its own servers and clients, and one run's Zenoh sessions never share a process with another's.

mod common;

use common::process::{rss_mib, server_binary, Proc};
use common::seeded::{run_seeds, seeds, violations, RSS_BOUND_MIB};
use impact_client::netsim::Link;
use impact_client_sim::load::{self, Behaviour, Faults, LoadConfig};
use impact_client_sim::timing::Timing;
use impact_protocol::{Encoding, WorldId};

use std::process::Command;
use std::time::Duration;

const SEEDS: [u64; 4] = [1, 2, 3, 4];

/// One seed: returns what went wrong, if anything.
fn run(seed: u64) -> Result<String, String> {
    let port = common::free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut cmd = Command::new(server_binary());
    cmd.args(["--scene", &impact_core::scene::Scene::bundled_path("arena").to_string_lossy()])
        .args(["--listen", &endpoint, "--quiet"]);
    let mut server = Proc::spawn(&format!("fault-{seed}-{port}"), cmd);
    let pid = server.pid();
    std::thread::sleep(Duration::from_millis(800));
    let duration = Duration::from_secs(6);
    let mut rng = impact_client::netsim::Rng::new(seed);
    let latency = Duration::from_millis(20 + (rng.unit() * 80.0) as u64);
    let jitter = Duration::from_millis((rng.unit() * 30.0) as u64);
    let uplink = Link { latency, jitter, loss: rng.unit() * 0.05 };
    let faults = Faults::from_seed(seed, duration, Some(pid));
    let plan = format!("seed {seed}: uplink {uplink:?}, faults {faults:?}");
    let cfg = LoadConfig {
        mode: Default::default(),
        connect: vec![endpoint],
        zenoh_config: None,
        world: WorldId::new("arena").unwrap(),
        clients: 30,
        first_client: 5000,
        sessions: 2,
        users: None,
        duration,
        uplink,
        downlink: Link { loss: 0.0, ..uplink },
        behaviour: Behaviour::Mixed,
        timing: if seed % 2 == 0 { Timing::Ahead } else { Timing::Behind },
        input_hz: 10.0,
        encoding: if seed % 3 == 0 { Encoding::Json } else { Encoding::MsgPack },
        seed,
        // Long enough for the last inputs (held by a partition at the very end, or by a stall)
        // to be answered and their ticks confirmed.
        settle: Duration::from_secs(4),
        progress: false,
        faults,
        state: false,
        predict: 0,
        scene: None,
    };
    let report = load::run(&cfg).map_err(|e| format!("{plan}\nload: {e}"))?;
    let rss = rss_mib(pid);
    let status = server.stop();
    let stderr = server.output();
    let mut wrong = Vec::new();
    if !status.is_some_and(|s| s.success()) || stderr.contains("panicked") {
        wrong.push(format!("the server exited with {status:?}"));
    }
    if report.inputs_unanswered > 0 {
        wrong.push(format!("{} delivered inputs were never answered", report.inputs_unanswered));
    }
    violations(&report, &mut wrong);
    let capacity = impact_server::runtime::ServerOptions::default().ingress_capacity as u32;
    if report.server_queue_depth_max > capacity {
        wrong.push(format!("ingress queue depth {} over its capacity {capacity}", report.server_queue_depth_max));
    }
    if rss > RSS_BOUND_MIB {
        wrong.push(format!("server resident memory {rss:.0} MiB > {RSS_BOUND_MIB} MiB"));
    }
    let summary = format!(
        "{plan}\n{report}\nserver rss {rss:.0} MiB, ingress queue depth max {}, stalls {}",
        report.server_queue_depth_max, report.server_stalls
    );
    if wrong.is_empty() {
        Ok(summary)
    } else {
        // The server's own account (held, egress dropped) tells a server that did not answer from
        // answers lost on the way.
        Err(format!("{summary}\nthe server said:\n{stderr}\nFAILED:\n  {}", wrong.join("\n  ")))
    }
}

#[test]
fn every_seed_keeps_the_invariants() {
    run_seeds("fault", "IMPACT_FAULT_SEEDS", seeds("IMPACT_FAULT_SEEDS", SEEDS.into_iter()), run, "faults");
}
