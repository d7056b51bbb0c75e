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
    /// [`Frame::state_mut`] (which drops the ray index built from it) or [`Frame::state_moved`]
    /// only.
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
    /// The frame of `tick` starting from `state`, with nothing applied, published or kept yet.
    pub fn at(tick: Tick, state: World) -> Frame {
        Frame {
            tick,
            state,
            inputs: Vec::new(),
            system: Vec::new(),
            events: Vec::new(),
            revision: 0,
            paths: Vec::new(),
            paths_index: OnceLock::new(),
            paths_moved: Vec::new(),
            capped: false,
            resolutions: 0,
            ray_index: OnceLock::new(),
        }
    }

    /// `state` to change: its ray index is dropped (built again if a shot looks here).
    pub fn state_mut(&mut self) -> &mut World {
        self.ray_index = OnceLock::new();
        &mut self.state
    }

    /// `state` to change in the motion of the bodies in `slots` only (a selective
    /// re-simulation's write-back): a ray index built keeps the rest as filed and tests those
    /// directly ([`RayIndex::moved`]), until too many have moved and it is dropped.
    pub fn state_moved(&mut self, slots: impl IntoIterator<Item = usize>) -> &mut World {
        if let Some(index) = self.ray_index.get_mut() {
            if !index.moved(slots) {
                self.ray_index = OnceLock::new();
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use impact_core::sim::ray::{cast_many, Ray};
    use impact_core::sim::ray_index::cast_many_indexed;

    /// A row of 64 small balls along x, and a frame of it whose ray index is built.
    fn frame() -> Frame {
        let mut text = String::from("[world]\nname = \"h\"\n[[class]]\nname = \"ball\"\n");
        for k in 0..64 {
            text += &format!(
                "[[body]]\nclass = \"ball\"\nshape = {{ type = \"sphere\", radius_m = 0.25 }}\nposition = [{}.0, 0.0, 0.0]\n",
                2 * k
            );
        }
        let state = impact_core::scene::Scene::parse(&text, "<history>").unwrap().world;
        let f = Frame::at(Tick(0), state);
        f.ray_index();
        f
    }

    /// What a ray down the z axis at `x` hits in `f`, through its index and by the scan.
    fn down_z(f: &Frame, x: f64) -> (Option<impact_protocol::RayHit>, Option<impact_protocol::RayHit>) {
        let ray = Ray { origin: DVec3::new(x, 0.0, -50.0), dir: DVec3::Z, max_m: 100.0, exclude: None };
        let (mut indexed, mut scan) = (Vec::new(), Vec::new());
        cast_many_indexed(&f.state, f.ray_index(), &[ray], &mut indexed);
        cast_many(&f.state, &[ray], &mut scan);
        (indexed.pop().flatten(), scan.pop().flatten())
    }

    /// A rollback that writes back a few bodies keeps the frame's ray index, and a shot at the
    /// frame then hits a body where it is now, not where the index filed it.
    #[test]
    fn a_body_moved_in_a_kept_index_is_hit_where_it_is() {
        let mut f = frame();
        let kept = f.ray_index() as *const RayIndex;
        // The first ball jumps from x = 0 to the far end's gap at x = 125.
        f.state_moved([0]).bodies.pos[0] = DVec3::new(125.0, 0.0, 0.0);
        assert!(std::ptr::eq(f.ray_index(), kept), "a few bodies moved: the index is kept");
        let (indexed, scan) = down_z(&f, 125.0);
        assert_eq!(scan.as_ref().map(|h| h.entity), Some(f.state.bodies.id[0]));
        assert_eq!(indexed, scan);
        let (indexed, scan) = down_z(&f, 0.0);
        assert_eq!(scan, None);
        assert_eq!(indexed, scan);
    }

    /// More than a sixteenth of the bodies moved: the index is dropped and built again.
    #[test]
    fn an_index_with_many_bodies_moved_is_built_again() {
        let mut f = frame();
        let kept = f.ray_index() as *const RayIndex;
        f.state_moved(0..4);
        assert!(std::ptr::eq(f.ray_index(), kept));
        let w = f.state_moved(4..5);
        w.bodies.pos[4] = DVec3::new(125.0, 0.0, 0.0);
        assert!(f.ray_index.get().is_none(), "5 of 64 moved: dropped");
        let (indexed, scan) = down_z(&f, 125.0);
        assert_eq!(indexed, scan);
        assert!(scan.is_some());
    }
}
