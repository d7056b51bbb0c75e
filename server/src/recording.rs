//! Recordings: the input log on disk, and replaying it.
//!
//! `impact-server --record FILE` writes a header line ([`RecordingHeader`]) and then one JSON
//! [`LogTick`] per confirmed tick, oldest first. `impact-server --offline --replay FILE` steps the
//! scene through the same inputs and server actions and checks the state hash after every tick:
//! a recorded match is a bug report anyone with the scene file can reproduce, bit for bit.
//!
//! The header carries every `[world]` value the world ran with (format 2), so a build whose
//! defaults differ replays what was run. A recording of format 1 (before the defaults followed
//! the scene) replays with the fixed defaults of its time, unless its world has friction: those
//! builds' impacts had none, so it cannot be reproduced, and the replay refuses it saying so.

use crate::rollback::log::ConfirmedTick;
use crate::rollback::{RollbackConfig, Session};
use impact_core::scene::settings::fixed_defaults;
use impact_core::scene::settings::WorldKeys;
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
    /// Format version: 2 (1 before the header carried `keys`).
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
    /// Every `[world]` value the world ran with (format 2 on).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keys: Option<WorldKeys>,
}

const FORMAT: &str = "impact-recording";

/// The newest format this build writes and reads.
const VERSION: u32 = 2;

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
            version: VERSION,
            world: scene.name.to_string(),
            tick_hz: cfg.tick_hz,
            window_ticks: cfg.window_ticks,
            initial_hash: scene.world.state_hash(),
            keys: Some(scene.keys.clone()),
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

/// Reads a recording's header line.
pub fn header(path: &Path) -> Result<RecordingHeader, String> {
    let file = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|e| format!("{file}: {e}"))?;
    let first = std::io::BufReader::new(f).lines().next().ok_or_else(|| format!("{file}: empty, not a recording"))?;
    let first = first.map_err(|e| format!("{file}:1: {e}"))?;
    let header: RecordingHeader = serde_json::from_str(&first).map_err(|e| format!("{file}:1: {e}"))?;
    if header.format != FORMAT || !(1..=VERSION).contains(&header.version) {
        return Err(format!(
            "{file}: not an impact recording of version 1 to {VERSION} ({} {})",
            header.format, header.version
        ));
    }
    Ok(header)
}

/// The scene file at `scene_path` as the recording at `path` ran it: with the `[world]` values
/// its header carries, or for a format-1 recording the fixed defaults of its time (refused with
/// the reason when that world cannot be reproduced by this build).
pub fn scene_for(scene_path: &Path, path: &Path) -> Result<Scene, String> {
    let header = header(path)?;
    let scene = match &header.keys {
        Some(keys) => Scene::load_with(scene_path, |w| keys.write_into(w)),
        None => Scene::load_with(scene_path, fixed_defaults),
    }
    .map_err(|e| e.to_string())?;
    if header.keys.is_none() && scene.keys.friction > 0.0 {
        return Err(format!(
            "{} was recorded by a build before friction acted at impacts (recording format 1) and its world has \
             friction {}: this build cannot reproduce it; replay it with the build that made it (CHANGELOG.md)",
            path.display(),
            scene.keys.friction
        ));
    }
    Ok(scene)
}

/// Replays the recording at `path` on `scene` (the core's parallel stages on `pool`), calling
/// `progress(ticks_done)` after each tick. `scene` must run with the recording's `[world]`
/// values: load it with [`scene_for`].
pub fn replay(
    scene: &Scene,
    path: &Path,
    pool: &impact_core::par::Pool,
    mut progress: impl FnMut(u64),
) -> Result<ReplayReport, String> {
    let file = path.display().to_string();
    let header = header(path)?;
    if let Some(keys) = &header.keys {
        let differ = keys.differences(&scene.keys);
        if !differ.is_empty() {
            return Err(format!(
                "{file} ran with other [world] values than this scene resolves to (recorded vs here: {}): load the scene with the recording's values",
                differ.join(", ")
            ));
        }
    }
    let f = std::fs::File::open(path).map_err(|e| format!("{file}: {e}"))?;
    let mut lines = std::io::BufReader::new(f).lines().enumerate();
    let bad = |line: usize, e: &dyn std::fmt::Display| format!("{file}:{}: {e}", line + 1);
    lines.next();
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
