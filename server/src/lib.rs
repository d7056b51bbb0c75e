//! impact's authoritative server: rollback, recordings and the Zenoh runtime on the
//! deterministic core ([`impact_core`]).
//!
//! - [`rollback`]: the session with history: late inputs, re-simulation, corrections.
//! - [`offline`]: running a scene with no network (`impact-server --offline`).
//! - [`recording`]: the input log on disk (`--record`) and its replay (`--offline --replay`).
//! - [`runtime`]: the Zenoh runtime (session, tick thread, ingress and egress).
//! - [`stability`], [`trials`]: numerical stress cases and known-answer trials, shared by the
//!   tests and `impact-bench`.
//! - [`plot`]: the SVG plots the benchmark programs draw.

pub mod offline;
pub mod plot;
pub mod recording;
pub mod rollback;
#[cfg(feature = "runtime")]
pub mod runtime;
pub mod stability;
pub mod trials;
