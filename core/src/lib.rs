//! impact's deterministic core: everything one tick needs and nothing of the runtime. No network,
//! no clock, no async; threads only behind the `threads` feature, and the thread count never
//! reaches a result. The server steps its worlds with it; a client steps its own avatar with the
//! same code, so prediction is exact where nothing else touched the avatar.
//!
//! - [`geometry`]: shapes and bounds, the ground every other part stands on.
//! - [`par`]: the thread pool, and the one way stages use it so that results never depend on the
//!   thread count.
//! - [`sim`]: the world state and the tick, one stage per file; islands and sleeping, the plan,
//!   ray casts against a world.
//! - [`broadphase`], [`narrow`], [`toi`], [`terrain`]: the collision machinery the tick is built
//!   from, one concept per module.
//! - [`scene`]: the scene file format and loader (SCENES.md).

#![warn(missing_docs)]

pub mod broadphase;
pub mod geometry;
pub mod narrow;
pub mod par;
pub mod scene;
pub mod sim;
pub mod terrain;
pub mod toi;
