//! Worlds at run time: a server process as the host of its worlds, which game logic opens from
//! a scene and closes (a match starting and ending; PROTOCOL.md, "Worlds at run time").
//!
//! The process declares one queryable, `impact/v1/*/client/*/world`. Its callback only hands
//! the query to the host thread (a bounded queue: full, the command is refused `queue_full`);
//! the host thread checks the sender (game logic only), loads the scene and starts or stops the
//! world. Opening is bounded (`open_worlds` at once); a world that is not here is not answered
//! (a host that runs another process's world says nothing, so only the owner answers a close).

use super::{open_session, start_on, start_world, Closer, ServerHandle, ServerOptions, Summary};
use crate::runtime::error::RuntimeError;
use impact_core::scene::Scene;
use impact_protocol::limits::MAX_CLIENT_MESSAGE_BYTES;
use impact_protocol::{
    decode_unchecked, encode, keys, ClientId, ClientMessage, Encoding, RejectReason, ServerMessage, Validate,
    WorldAnswer, WorldCommand, WorldId, WorldOutcome,
};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use zenoh::Wait;

/// Loads a scene file as the process runs its scenes (the command line's overrides).
pub type SceneLoader = dyn Fn(&Path) -> Result<Scene, String> + Send + Sync;
/// The options a world opened at run time runs with.
pub type WorldOptions = dyn Fn(&Scene) -> ServerOptions + Send + Sync;

/// What game logic may open in this process.
#[derive(Clone)]
pub struct HostOptions {
    /// Most worlds opened at run time running at once (`--open-worlds`; 0: none are opened,
    /// though game logic may still close a world).
    pub open_worlds: usize,
    /// Scenes it may open, by name (the started scenes' file names without `.toml`).
    pub scenes: BTreeMap<String, PathBuf>,
    /// A directory of more scenes, `{name}.toml` (`--scene-dir`).
    pub scene_dir: Option<PathBuf>,
    /// Loads a scene.
    pub load: Arc<SceneLoader>,
    /// The options of a world opened from a scene.
    pub options: Arc<WorldOptions>,
}

impl std::fmt::Debug for HostOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HostOptions")
            .field("open_worlds", &self.open_worlds)
            .field("scenes", &self.scenes)
            .field("scene_dir", &self.scene_dir)
            .finish_non_exhaustive()
    }
}

impl HostOptions {
    /// Opens no world, loads nothing.
    pub fn none() -> HostOptions {
        HostOptions {
            open_worlds: 0,
            scenes: BTreeMap::new(),
            scene_dir: None,
            load: Arc::new(|p: &Path| Scene::load(p).map_err(|e| e.to_string())),
            options: Arc::new(|_: &Scene| ServerOptions::default()),
        }
    }
}

/// A world this process runs.
struct Hosted {
    handle: ServerHandle,
    /// Opened by game logic (counts against `open_worlds`).
    opened: bool,
}

/// The worlds of one process, and the thread that opens and closes them.
pub struct Host {
    worlds: Arc<Mutex<BTreeMap<WorldId, Hosted>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    _queryable: Option<zenoh::query::Queryable<()>>,
    _session: Arc<Closer>,
}

impl std::fmt::Debug for Host {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Host").field("worlds", &self.worlds()).finish_non_exhaustive()
    }
}

impl Host {
    /// Starts `worlds` in one process (as [`super::start_worlds`]) and answers game logic's
    /// world commands with `host` (a standby process answers none).
    pub fn start(worlds: Vec<(Scene, ServerOptions)>, host: HostOptions) -> Result<Host, RuntimeError> {
        let Some((_, first)) = worlds.first() else {
            return Err(RuntimeError::Config("a host starts with at least one world".into()));
        };
        let first = first.clone();
        let zs = open_session(&first)?;
        let running =
            start_on(&zs, worlds)?.into_iter().map(|h| (h.world.clone(), Hosted { handle: h, opened: false }));
        let worlds = Arc::new(Mutex::new(running.collect::<BTreeMap<_, _>>()));
        let stop = Arc::new(AtomicBool::new(false));
        let (queryable, thread) = if first.standby {
            (None, None)
        } else {
            let mut logic: BTreeSet<ClientId> = first.logic_clients.iter().copied().collect();
            logic.extend(first.users.iter().flat_map(|u| u.logic_clients()));
            let (tx, rx) = sync_channel::<zenoh::query::Query>(16);
            let q =
                zs.0.declare_queryable(keys::WORLD_COMMAND.any_world())
                    .callback(move |q| {
                        if let Err(TrySendError::Full(q) | TrySendError::Disconnected(q)) = tx.try_send(q) {
                            let detail = "the server is busy with other world commands: send it again".to_string();
                            reply(&q, world_of(&q), WorldOutcome::Refused { reason: RejectReason::QueueFull, detail });
                        }
                    })
                    .wait()
                    .map_err(|e| RuntimeError::Zenoh(format!("declaring the world-command queryable: {e}")))?;
            let run = Running { zs: zs.clone(), worlds: worlds.clone(), logic, host };
            let stop2 = stop.clone();
            let t = std::thread::Builder::new()
                .name("impact-host".into())
                .spawn(move || run.serve(&rx, &stop2))
                .map_err(|e| RuntimeError::Thread(e.to_string()))?;
            (Some(q), Some(t))
        };
        Ok(Host { worlds, stop, thread, _queryable: queryable, _session: zs })
    }

    /// The worlds running now.
    pub fn worlds(&self) -> Vec<WorldId> {
        lock(&self.worlds).keys().cloned().collect()
    }

    /// Runs until `stop` is set or every world has ended by itself (`max_ticks`), then stops
    /// what still runs; returns the summaries of the worlds stopped here, by name.
    pub fn run_until(mut self, stop: &AtomicBool) -> Vec<(WorldId, Summary)> {
        loop {
            let all_ended = lock(&self.worlds).values().all(|h| h.handle.finished());
            if stop.load(Ordering::SeqCst) || all_ended {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        self.stop_all()
    }

    /// Stops every world (and the host thread); their summaries, by name.
    pub fn stop_all(&mut self) -> Vec<(WorldId, Summary)> {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let worlds = std::mem::take(&mut *lock(&self.worlds));
        worlds.into_iter().map(|(name, h)| (name, h.handle.stop())).collect()
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        self.stop_all();
    }
}

/// The host thread's part.
struct Running {
    zs: Arc<Closer>,
    worlds: Arc<Mutex<BTreeMap<WorldId, Hosted>>>,
    logic: BTreeSet<ClientId>,
    host: HostOptions,
}

/// The world a command's key names (or `invalid` for a key whose world is no world name: the
/// queryable only matches `impact/v1/*/client/*/world`).
fn world_of(q: &zenoh::query::Query) -> WorldId {
    keys::WORLD_COMMAND
        .parse(q.key_expr().as_str())
        .map(|(w, _)| w)
        .or_else(|_| WorldId::new("invalid"))
        .expect("a valid name")
}

fn reply(q: &zenoh::query::Query, world: WorldId, outcome: WorldOutcome) {
    let enc =
        Encoding::from_zenoh_tag(&q.encoding().map(|e| e.to_string()).unwrap_or_default()).unwrap_or(Encoding::MsgPack);
    if let Ok(bytes) = encode(&ServerMessage::World(WorldAnswer { world, outcome }), enc) {
        let _ = q.reply(q.key_expr().clone(), bytes).encoding(enc.zenoh_tag()).wait();
    }
}

/// The worlds, even if a thread panicked holding them (the map is whole between statements).
fn lock(w: &Mutex<BTreeMap<WorldId, Hosted>>) -> std::sync::MutexGuard<'_, BTreeMap<WorldId, Hosted>> {
    w.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn refused(reason: RejectReason, detail: impl Into<String>) -> Option<WorldOutcome> {
    Some(WorldOutcome::Refused { reason, detail: detail.into() })
}

impl Running {
    fn serve(&self, rx: &Receiver<zenoh::query::Query>, stop: &AtomicBool) {
        while !stop.load(Ordering::SeqCst) {
            let Ok(q) = rx.recv_timeout(Duration::from_millis(50)) else { continue };
            let world = world_of(&q);
            if let Some(outcome) = self.command(&q) {
                reply(&q, world, outcome);
            }
        }
    }

    /// What to answer `q` (`None`: not this process's to answer).
    fn command(&self, q: &zenoh::query::Query) -> Option<WorldOutcome> {
        let Ok((world, Some(client))) = keys::WORLD_COMMAND.parse(q.key_expr().as_str()) else {
            return refused(RejectReason::Malformed, format!("not a world-command key: {}", q.key_expr()));
        };
        let bytes = q.payload().map(|p| p.to_bytes().to_vec()).unwrap_or_default();
        let enc = Encoding::from_zenoh_tag(&q.encoding().map(|e| e.to_string()).unwrap_or_default())
            .unwrap_or(Encoding::MsgPack);
        let message = decode_unchecked::<ClientMessage>(&bytes, enc, MAX_CLIENT_MESSAGE_BYTES)
            .and_then(|m| m.validate().map(|()| m));
        let command = match message {
            Ok(ClientMessage::World(c)) => c,
            Ok(_) => return refused(RejectReason::Malformed, "not a world command"),
            Err(e) => return refused(e.reject_reason(), e.to_string()),
        };
        if !self.logic.contains(&client) {
            let detail = format!("opening and closing worlds is game logic's: client {client} has no game-logic role");
            return refused(RejectReason::NotAllowed, detail);
        }
        match command {
            WorldCommand::Open { scene } => Some(self.open(world, &scene)),
            WorldCommand::Close { next, reason } => {
                let hosted = lock(&self.worlds).remove(&world)?;
                let t0 = std::time::Instant::now();
                let summary = hosted.handle.close(next, reason);
                let ms = t0.elapsed().as_secs_f64() * 1e3;
                eprintln!(
                    "impact-server: world {world} closed by game logic (client {client}) in {ms:.0} ms\n{summary}"
                );
                Some(WorldOutcome::Closed { ticks: summary.ticks })
            }
        }
    }

    fn open(&self, world: WorldId, scene: &str) -> WorldOutcome {
        let h = &self.host;
        let worlds = lock(&self.worlds);
        let opened = worlds.values().filter(|w| w.opened && !w.handle.finished()).count();
        let why = if h.open_worlds == 0 {
            Some((RejectReason::NotAllowed, "this server opens no worlds (start it with --open-worlds N)".to_string()))
        } else if worlds.contains_key(&world) {
            Some((RejectReason::OutOfRange, format!("world {world} is open already")))
        } else if opened >= h.open_worlds {
            Some((RejectReason::OutOfRange, format!("{opened} worlds opened already, at most {}", h.open_worlds)))
        } else {
            None
        };
        drop(worlds);
        if let Some((reason, detail)) = why {
            return WorldOutcome::Refused { reason, detail };
        }
        let Some(path) = self.scene_path(scene) else {
            let mut known: Vec<&str> = h.scenes.keys().map(String::as_str).collect();
            known.dedup();
            let dir = h.scene_dir.as_ref().map_or(String::new(), |d| format!(" or {}/{scene}.toml", d.display()));
            let detail = format!("no scene {scene:?} here (this server opens {}{dir})", known.join(", "));
            return WorldOutcome::Refused { reason: RejectReason::OutOfRange, detail };
        };
        let mut loaded = match (h.load)(&path) {
            Ok(s) => s,
            Err(e) => return WorldOutcome::Refused { reason: RejectReason::OutOfRange, detail: e },
        };
        loaded.name = world.clone();
        let (scene_hash, tick_hz) = (loaded.world.scene_hash(), loaded.world.config.tick_hz);
        let opts = (h.options)(&loaded);
        match start_world(&self.zs, loaded, opts) {
            Ok(handle) => {
                lock(&self.worlds).insert(world.clone(), Hosted { handle, opened: true });
                eprintln!("impact-server: world {world} opened from scene {scene} ({})", path.display());
                WorldOutcome::Opened { scene_hash, tick_hz }
            }
            Err(e) => WorldOutcome::Refused { reason: RejectReason::OutOfRange, detail: e.to_string() },
        }
    }

    /// The file of the scene named `name`: a started scene's, or `{name}.toml` in the scene
    /// directory (a plain name only: letters, digits, `-` and `_`).
    fn scene_path(&self, name: &str) -> Option<PathBuf> {
        if let Some(p) = self.host.scenes.get(name) {
            return Some(p.clone());
        }
        let plain = !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
        let p = self.host.scene_dir.as_ref()?.join(format!("{name}.toml"));
        (plain && p.is_file()).then_some(p)
    }
}
