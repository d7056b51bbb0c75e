//! impact: an authoritative collision server for multiplayer games.
//!
//! - [`geometry`]: shapes and bounds, the ground every other part stands on; [`par`]: the
//!   thread pool, and the one way stages use it so that results never depend on the thread count.
//! - [`sim`]: the deterministic core (world state, the tick one stage per file, islands and
//!   sleeping, the plan, ray casts against a world).
//! - [`broadphase`], [`narrow`], [`toi`], [`terrain`]: the collision machinery the
//!   tick is built from, one concept per module.
//! - [`scene`]: the scene file format and loader.
//! - [`offline`]: running a scene with no network (`impact-server --offline`).
//! - [`recording`]: the input log on disk (`--record`) and its replay (`--offline --replay`).
//! - [`rollback`]: the session with history: late inputs, re-simulation, corrections.
//! - [`runtime`]: the Zenoh runtime (session, tick thread, ingress and egress).
//! - [`stability`], [`trials`]: numerical stress cases and known-answer trials, shared by the
//!   tests and `impact-bench`.

pub mod broadphase;
pub mod geometry;
pub mod narrow;
pub mod offline;
pub mod par;
pub mod recording;
pub mod rollback;
#[cfg(feature = "runtime")]
pub mod runtime;
pub mod scene;
pub mod sim;
pub mod stability;
pub mod terrain;
pub mod toi;
pub mod trials;
