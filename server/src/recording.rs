//! Recordings: the input log on disk, and replaying it.
//!
//! `impact-server --record FILE` writes a header line ([`RecordingHeader`]) and then one JSON
//! [`LogTick`] per confirmed tick, oldest first. `impact-server --offline --replay FILE` steps the
//! scene through the same inputs and server actions and checks the state hash after every tick:
//! a recorded match is a bug report anyone with the scene file can reproduce, bit for bit.

use crate::rollback::log::ConfirmedTick;
use crate::rollback::{RollbackConfig, Session};
use impact_core::scene::Scene;
use impact_core::sim::world::window_ticks;
use impact_core::sim::Plan;
use impact_protocol::{LogTick, Tick};
use serde::{Deserialize, Serialize};
use std::io::{BufRead, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The first line of a recording.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RecordingHeader {
    /// Always `"impact-recording"`.
    pub format: String,
    /// Format version (1).
    pub version: u32,
    /// The world's name.
    pub world: String,
    /// Ticks per second the server ran at (the step depends on it).
    pub tick_hz: u32,
    /// Its rollback window, ticks (rewound rays depend on it).
    pub window_ticks: u32,
    /// State hash of the scene's world at tick 0: a replay against another scene file is refused
    /// before it starts.
    pub initial_hash: u64,
}

const FORMAT: &str = "impact-recording";

/// Writes a recording as the server confirms ticks.
#[derive(Debug)]
pub struct Recorder {
    out: BufWriter<std::fs::File>,
    path: PathBuf,
    /// The first error, reported at the end (the server keeps running without the file).
    error: Option<String>,
}

impl Recorder {
    /// Creates `path` and writes the header for `scene`.
    pub fn create(path: &Path, scene: &Scene) -> Result<Recorder, String> {
        let f = std::fs::File::create(path).map_err(|e| format!("--record {}: {e}", path.display()))?;
        let mut r = Recorder { out: BufWriter::new(f), path: path.to_path_buf(), error: None };
        let cfg = &scene.world.config;
        let header = RecordingHeader {
            format: FORMAT.into(),
            version: 1,
            world: scene.name.to_string(),
            tick_hz: cfg.tick_hz,
            window_ticks: cfg.window_ticks,
            initial_hash: scene.world.state_hash(),
        };
        r.line(&header);
        r.error.take().map_or(Ok(r), Err)
    }

    /// Appends a confirmed tick, flushed at once: a server killed a moment later leaves every
    /// tick it confirmed on disk (at most the last line cut short).
    pub fn write(&mut self, entry: &LogTick) {
        self.line(entry);
        if self.error.is_none() {
            if let Err(e) = self.out.flush() {
                self.error = Some(format!("writing {}: {e}", self.path.display()));
            }
        }
    }

    fn line<T: Serialize>(&mut self, v: &T) {
        if self.error.is_some() {
            return;
        }
        let r = serde_json::to_writer(&mut self.out, v)
            .map_err(std::io::Error::from)
            .and_then(|_| self.out.write_all(b"\n"));
        if let Err(e) = r {
            self.error = Some(format!("writing {}: {e}", self.path.display()));
        }
    }

    /// Flushes to disk; the first write error if there was one.
    pub fn flush(&mut self) -> Result<(), String> {
        if let Err(e) = self.out.flush() {
            self.error.get_or_insert(format!("writing {}: {e}", self.path.display()));
        }
        self.error.clone().map_or(Ok(()), Err)
    }
}

/// What a replay found.
#[derive(Clone, Debug, Default)]
pub struct ReplayReport {
    /// The recording's header.
    pub world: String,
    /// Confirmed ticks replayed.
    pub ticks: u64,
    /// Ticks whose state hash matched the recording.
    pub matched: u64,
    /// The first tick whose hash differed: `(tick, recorded, replayed)`.
    pub first_mismatch: Option<(Tick, u64, u64)>,
    /// Inputs and server actions applied.
    pub inputs: u64,
    /// Server actions applied.
    pub system: u64,
    /// Wall time, seconds.
    pub seconds: f64,
    /// The last line was cut short (the server was killed while writing it): ignored.
    pub truncated: bool,
}

impl std::fmt::Display for ReplayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "replayed world {}: {} ticks, {} inputs, {} server actions in {:.2} s",
            self.world, self.ticks, self.inputs, self.system, self.seconds
        )?;
        if self.truncated {
            writeln!(f, "the last line is cut short (the server died while writing it): ignored")?;
        }
        match self.first_mismatch {
            None => write!(f, "every recorded state hash reproduced ({} of {})", self.matched, self.ticks),
            Some((t, want, got)) => write!(
                f,
                "state hashes reproduced {} of {}; first difference at tick {}: recorded {want:#018x}, replayed {got:#018x}",
                self.matched, self.ticks, t.0
            ),
        }
    }
}

/// Replays the recording at `path` on `scene` (the core's parallel stages on `pool`), calling
/// `progress(ticks_done)` after each tick.
pub fn replay(
    scene: &Scene,
    path: &Path,
    pool: &impact_core::par::Pool,
    mut progress: impl FnMut(u64),
) -> Result<ReplayReport, String> {
    let file = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|e| format!("{file}: {e}"))?;
    let mut lines = std::io::BufReader::new(f).lines().enumerate();
    let bad = |line: usize, e: &dyn std::fmt::Display| format!("{file}:{}: {e}", line + 1);
    let (k, first) = lines.next().ok_or_else(|| format!("{file}: empty, not a recording"))?;
    let first = first.map_err(|e| bad(k, &e))?;
    let header: RecordingHeader = serde_json::from_str(&first).map_err(|e| bad(k, &e))?;
    if header.format != FORMAT || header.version != 1 {
        return Err(format!("{file}: not an impact recording of version 1 ({} {})", header.format, header.version));
    }
    let mut world = scene.world.clone();
    {
        let cfg = Arc::make_mut(&mut world.config);
        if !(1..=1000).contains(&header.tick_hz) {
            return Err(format!("{file}: tick_hz {} out of range", header.tick_hz));
        }
        cfg.tick_hz = header.tick_hz;
        cfg.dt = 1.0 / f64::from(header.tick_hz);
        cfg.window_ticks = header.window_ticks.clamp(1, window_ticks(10_000, header.tick_hz));
    }
    if world.state_hash() != header.initial_hash {
        return Err(format!(
            "{file} was recorded on another scene: its world starts with hash {:#018x}, this scene's with {:#018x}",
            header.initial_hash,
            world.state_hash()
        ));
    }
    let avatar = scene.avatar.as_ref().map(|a| (a.class, &a.shape));
    let cfg = RollbackConfig::for_world(&world);
    let mut session = Session::new(world, Plan::for_world(&scene.world), cfg);
    session.set_pool(pool.clone());
    let mut report = ReplayReport { world: header.world.clone(), ..ReplayReport::default() };
    let started = std::time::Instant::now();
    let mut lines = lines.peekable();
    while let Some((k, line)) = lines.next() {
        let line = line.map_err(|e| bad(k, &e))?;
        if line.trim().is_empty() {
            continue;
        }
        let entry: LogTick = match serde_json::from_str(&line) {
            Ok(e) => e,
            // A last line without its end: the recording server was killed mid-write.
            Err(e) if lines.peek().is_none() && e.is_eof() => {
                report.truncated = true;
                break;
            }
            Err(e) => return Err(bad(k, &e)),
        };
        let t = ConfirmedTick::from_wire(entry, avatar).map_err(|e| bad(k, &e))?;
        report.inputs += t.inputs.len() as u64;
        report.system += t.system.len() as u64;
        session.follow(t.tick, t.system, t.inputs).map_err(|e| bad(k, &e))?;
        session.advance();
        report.ticks += 1;
        let got = session.world().state_hash();
        if got == t.state_hash {
            report.matched += 1;
        } else if report.first_mismatch.is_none() {
            report.first_mismatch = Some((t.tick, t.state_hash, got));
        }
        progress(report.ticks);
    }
    report.seconds = started.elapsed().as_secs_f64();
    Ok(report)
}
