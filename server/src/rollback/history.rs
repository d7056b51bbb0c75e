//! The bounded ring of past ticks: for each, the world at its start, the inputs applied at it
//! and the events published for it. Its length never exceeds the window, so memory is fixed once
//! it is full, however long the server runs.

use impact_core::broadphase::grid::Grid;
use impact_core::sim::ray_index::RayIndex;
use impact_core::sim::{TickInput, World};
use impact_protocol::{CollisionEvent, Tick};
use std::collections::VecDeque;
use std::sync::OnceLock;

/// One past tick.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The tick.
    pub tick: Tick,
    /// The world at the start of the tick, before its inputs. Changed through
    /// [`Frame::state_mut`] only, which drops the ray index built from it.
    pub state: World,
    /// The inputs applied at the tick.
    pub inputs: Vec<TickInput>,
    /// The server's own actions at the tick (avatars joining and leaving).
    pub system: Vec<impact_core::sim::SystemAction>,
    /// The tick's events as last published.
    pub events: Vec<CollisionEvent>,
    /// 0 when first published; +1 per correction.
    pub revision: u32,
    /// The box each body's path stayed within during the tick (by slot of `state`), for
    /// selective re-simulation; empty when not kept. Changed through [`Frame::paths_mut`] only,
    /// which drops the index built from it.
    pub paths: Vec<impact_core::geometry::Aabb>,
    /// `paths` filed in a grid for overlap queries, built when a selective re-simulation first
    /// asks.
    pub paths_index: OnceLock<Grid>,
    /// Slots (ascending) whose path box changed since `paths_index` was built: the grid's
    /// answers for them are stale, so they are tested directly.
    pub paths_moved: Vec<u32>,
    /// The tick hit the per-tick resolution cap (its outcome depends on every body: selective
    /// re-simulation is not allowed through it).
    pub capped: bool,
    /// Contact resolutions the tick took (a bound for selective re-simulation's cap check).
    pub resolutions: u32,
    /// `state`'s bodies filed for ray casts, built when a rewound shot first looks at this tick.
    pub ray_index: OnceLock<RayIndex>,
}

impl Frame {
    /// `state` to change: its ray index is dropped (built again if a shot looks here).
    pub fn state_mut(&mut self) -> &mut World {
        self.ray_index = OnceLock::new();
        &mut self.state
    }

    /// The index rewound shots at this tick are cast through.
    pub fn ray_index(&self) -> &RayIndex {
        self.ray_index.get_or_init(|| RayIndex::build(&self.state))
    }

    /// `paths` to change: the index built from them is dropped.
    pub fn paths_mut(&mut self) -> &mut Vec<impact_core::geometry::Aabb> {
        self.paths_index = OnceLock::new();
        self.paths_moved.clear();
        &mut self.paths
    }

    /// Sets one slot's path box. The grid is kept (the slot is tested directly from now on)
    /// until a sixteenth of the slots have moved; then it is dropped, to be built again.
    pub fn set_path(&mut self, slot: usize, b: impact_core::geometry::Aabb) {
        if self.paths_index.get().is_some() {
            if let Err(at) = self.paths_moved.binary_search(&(slot as u32)) {
                self.paths_moved.insert(at, slot as u32);
            }
            if self.paths_moved.len() * 16 > self.paths.len() {
                self.paths_mut();
            }
        }
        self.paths[slot] = b;
    }

    /// Appends the slot of every body whose path box overlaps `q` (through a grid of `paths`,
    /// built once per change).
    pub fn paths_overlapping(&self, q: &impact_core::geometry::Aabb, out: &mut Vec<u32>) {
        let grid = self.paths_index.get_or_init(|| {
            let mut g = Grid::default();
            g.index(&self.paths);
            g
        });
        let first = out.len();
        grid.query(&self.paths, q, out);
        if !self.paths_moved.is_empty() {
            let mut k = first;
            for j in first..out.len() {
                if self.paths_moved.binary_search(&out[j]).is_err() {
                    out[k] = out[j];
                    k += 1;
                }
            }
            out.truncate(k);
            out.extend(self.paths_moved.iter().copied().filter(|&m| self.paths[m as usize].overlaps(q)));
        }
    }
}

/// Frames for consecutive ticks, oldest first, at most `capacity` of them.
#[derive(Debug)]
pub struct History {
    frames: VecDeque<Frame>,
    capacity: usize,
}

impl History {
    /// An empty ring holding at most `capacity` frames.
    pub fn new(capacity: usize) -> History {
        History { frames: VecDeque::with_capacity(capacity + 1), capacity: capacity.max(1) }
    }

    /// Appends the newest frame; returns the oldest one if the ring was full.
    pub fn push(&mut self, frame: Frame) -> Option<Frame> {
        debug_assert!(self.frames.back().is_none_or(|f| f.tick.next() == frame.tick), "frames must be consecutive");
        self.frames.push_back(frame);
        (self.frames.len() > self.capacity).then(|| self.frames.pop_front()).flatten()
    }

    /// The frame of `tick`, if it is in the ring.
    pub fn get(&self, tick: Tick) -> Option<&Frame> {
        let first = self.frames.front()?.tick.0;
        self.frames.get(tick.0.checked_sub(first)? as usize)
    }

    /// The frame of `tick`, mutably.
    pub fn get_mut(&mut self, tick: Tick) -> Option<&mut Frame> {
        let first = self.frames.front()?.tick.0;
        self.frames.get_mut(tick.0.checked_sub(first)? as usize)
    }

    /// The oldest tick held.
    pub fn oldest(&self) -> Option<Tick> {
        self.frames.front().map(|f| f.tick)
    }

    /// Number of frames held.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether the ring is empty.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// The most frames it holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Frames oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &Frame> {
        self.frames.iter()
    }
}
