//! Running a scene with no network: the core, a tick at a time, as fast as it goes. This is how
//! a game team checks a scene in its own CI and how a bug is reproduced: the same scene and the
//! same input file give the same events and the same final state hash, bit for bit.

use impact_core::scene::Scene;
use impact_core::sim::ray_index::RayIndex;
use impact_core::sim::{Plan, Pool, Stepper, TickInput, TickOutput, World};
use impact_protocol::limits::MAX_CLIENT_MESSAGE_BYTES;
use impact_protocol::{ClientMessage, CollisionEvent, Encoding, Phase, Response};
use std::collections::BTreeMap;
use std::io::{BufRead, Write};
use std::path::Path;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Why an offline run failed.
#[derive(Debug, thiserror::Error)]
pub enum OfflineError {
    /// The inputs file could not be read or has a bad line.
    #[error("{file}:{line}: {detail}")]
    Inputs {
        /// The file.
        file: String,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        detail: String,
    },
    /// Writing events failed.
    #[error("writing events: {0}")]
    Io(#[from] std::io::Error),
}

/// Inputs by tick, as an offline run applies them.
pub type InputScript = BTreeMap<u32, Vec<TickInput>>;

/// Reads an inputs file: one JSON `input` message per line (the wire format of PROTOCOL.md),
/// applied at its `tick`. Blank lines and lines starting with `#` are skipped.
pub fn read_inputs(path: &Path) -> Result<InputScript, OfflineError> {
    let file = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|e| OfflineError::Inputs {
        file: file.clone(),
        line: 0,
        detail: e.to_string(),
    })?;
    let mut script = InputScript::new();
    let mut seen = std::collections::BTreeSet::new();
    for (k, line) in std::io::BufReader::new(f).lines().enumerate() {
        let line = line.map_err(|e| OfflineError::Inputs { file: file.clone(), line: k + 1, detail: e.to_string() })?;
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let msg: ClientMessage = impact_protocol::decode(trimmed.as_bytes(), Encoding::Json, MAX_CLIENT_MESSAGE_BYTES)
            .map_err(|e| OfflineError::Inputs { file: file.clone(), line: k + 1, detail: e.to_string() })?;
        let inputs = match msg {
            ClientMessage::Input(input) => vec![input],
            ClientMessage::Inputs(batch) => batch.inputs,
            ClientMessage::Ping(_) | ClientMessage::FullFrame(_) | ClientMessage::World(_) => {
                let detail = "not an input: only `input` and `inputs` lines apply".to_string();
                return Err(OfflineError::Inputs { file: file.clone(), line: k + 1, detail });
            }
        };
        for input in inputs {
            // Each (client, seq) applies once, as on a server: a batch repeats earlier inputs.
            if seen.insert((input.client, input.seq)) {
                script.entry(input.tick.0).or_default().push(TickInput {
                    view_tick: input.rewind_tick(),
                    ..TickInput::new(input.client, input.seq, input.actions)
                });
            }
        }
    }
    Ok(script)
}

/// What an offline run produced.
#[derive(Debug, Clone)]
pub struct OfflineReport {
    /// Ticks simulated.
    pub ticks: u32,
    /// Dynamic bodies at the start and the end.
    pub bodies: (usize, usize),
    /// Events by `(phase, response)`.
    pub events: BTreeMap<(Phase, Response), u64>,
    /// All events, if kept.
    pub kept: Vec<CollisionEvent>,
    /// Final state hash.
    pub state_hash: u64,
    /// Time per stage and counters.
    pub stages: impact_core::sim::StageStats,
    /// The plan used.
    pub plan: Plan,
    /// Wall time of the stepping loop.
    pub wall: Duration,
    /// Inputs that could not apply.
    pub skipped: usize,
}

impl OfflineReport {
    /// Total events.
    pub fn total_events(&self) -> u64 {
        self.events.values().sum()
    }
}

/// Runs `ticks` ticks of `scene` with `inputs`, the core's parallel stages on `pool`. Each event goes to `sink` as it is produced;
/// `progress` is called after every tick with the tick count done.
pub fn run(
    scene: &Scene,
    plan: Plan,
    pool: &Pool,
    ticks: u32,
    inputs: &InputScript,
    mut sink: impl FnMut(&CollisionEvent) -> std::io::Result<()>,
    mut progress: impl FnMut(u32),
) -> Result<OfflineReport, OfflineError> {
    let mut world = scene.world.clone();
    let mut stepper = Stepper::new(plan.clone(), true);
    stepper.set_pool(pool.clone());
    let mut out = TickOutput::default();
    let mut events = BTreeMap::new();
    let start_bodies = world.bodies.len();
    let empty = Vec::new();
    let mut skipped = 0;
    // Rays rewound to a view tick need the worlds a network session's history would hold: kept
    // only when some input asks for it.
    let rewinds = inputs.values().flatten().any(|i| i.view_tick.is_some());
    let window = world.config.window_ticks as usize;
    // Each past world beside its ray index, built when a shot first looks at it.
    let mut past: std::collections::VecDeque<(World, OnceLock<RayIndex>)> = std::collections::VecDeque::new();
    let started = Instant::now();
    for k in 0..ticks {
        let tick = world.tick;
        let mut rewound;
        let tick_inputs = match inputs.get(&tick.0) {
            Some(list) if rewinds => {
                rewound = list.clone();
                let oldest = past.front().map_or(tick, |(w, _)| w.tick);
                let max_rewind = world.config.max_rewind_ticks;
                crate::rollback::hitscan::rewind_rays(tick, &mut rewound, max_rewind, oldest, None, &world, |t| {
                    let (w, index) = past.get(t.0.checked_sub(oldest.0)? as usize)?;
                    Some((w, index.get_or_init(|| RayIndex::build(w))))
                });
                &rewound
            }
            Some(list) => list,
            None => &empty,
        };
        if rewinds && window > 0 {
            if past.len() == window {
                past.pop_front();
            }
            past.push_back((world.clone(), OnceLock::new()));
        }
        stepper.step(&mut world, tick_inputs, &mut out);
        skipped += out.skipped.len();
        for e in &out.events {
            *events.entry((e.phase, e.response)).or_insert(0) += 1;
            sink(e)?;
        }
        progress(k + 1);
    }
    Ok(OfflineReport {
        ticks,
        bodies: (start_bodies, world.bodies.len()),
        events,
        kept: Vec::new(),
        state_hash: world.state_hash(),
        stages: stepper.stats.clone(),
        plan,
        wall: started.elapsed(),
        skipped,
    })
}

/// Writes the human summary of a run.
pub fn print_summary(r: &OfflineReport, out: &mut impl Write) -> std::io::Result<()> {
    let ticks = r.ticks.max(1) as f64;
    writeln!(
        out,
        "ran {} ticks in {:.3} s ({:.3} ms/tick)",
        r.ticks,
        r.wall.as_secs_f64(),
        r.wall.as_secs_f64() * 1e3 / ticks
    )?;
    writeln!(out, "bodies: {} at start, {} at end", r.bodies.0, r.bodies.1)?;
    writeln!(out, "events: {}", r.total_events())?;
    for ((phase, response), n) in &r.events {
        writeln!(
            out,
            "  {:<6} {:<8} {n:>10}",
            format!("{phase:?}").to_lowercase(),
            format!("{response:?}").to_lowercase()
        )?;
    }
    if r.skipped > 0 {
        writeln!(out, "inputs skipped: {}", r.skipped)?;
    }
    writeln!(
        out,
        "last tick: {} pairs tested, {} impacts resolved, {} overlap tests in TOI searches; bodies frozen by the per-body cap: {}",
        r.stages.pairs_tested, r.stages.resolutions, r.stages.toi_tests, r.stages.frozen
    )?;
    writeln!(
        out,
        "bodies at the end: {} awake, {} asleep; ticks skipped whole (everything asleep): {}",
        r.stages.awake, r.stages.asleep, r.stages.idle_ticks
    )?;
    writeln!(out, "time per stage (mean per tick):")?;
    let total: Duration = r.stages.stages().iter().map(|(_, d)| *d).sum();
    for (name, d) in r.stages.stages() {
        let share = if total.is_zero() { 0.0 } else { d.as_secs_f64() / total.as_secs_f64() * 100.0 };
        writeln!(out, "  {name:<12} {:>9.4} ms  {share:>5.1} %", d.as_secs_f64() * 1e3 / ticks)?;
    }
    writeln!(out, "state hash: {:016x}", r.state_hash)
}
