//! The network runtime: the authoritative server on Zenoh.
//!
//! ```text
//!  zenoh callbacks (decode, validate)  ──try_send──▶ ingress queue (bounded)
//!  liveliness, queries                 ──try_send──▶ control / query queues (bounded)
//!                                                        │
//!                       tick thread (owns the rollback Session, fixed schedule)
//!                                                        │ try_send
//!                                                        ▼
//!                         egress queue (bounded) ──▶ egress thread ──▶ zenoh put / reply
//! ```
//!
//! One thread owns the world and steps it on a deadline schedule. Zenoh's callbacks never touch
//! the world: they decode, validate and enqueue, and a full queue drops the input with a
//! `queue_full` reject rather than wait. Nothing the tick thread sends can block it: it hands
//! messages to the egress thread through a bounded queue (full: dropped and counted), and the
//! egress thread publishes with congestion control `Drop`, so a subscriber that stops reading
//! costs only its own messages.

pub mod auth;
mod egress;
mod error;
pub mod gate;
pub mod http;
pub mod metrics;
pub mod owner;
mod server;
pub mod state;
mod thread_clock;
mod timing;
mod zenoh_config;

pub use error::RuntimeError;
pub use metrics::Metrics;
pub use server::{
    start, start_worlds, Host, HostOptions, SceneLoader, ServerHandle, ServerOptions, Summary, TickThread,
    WorldOptions, DEFAULT_TICK_NICE,
};
pub use state::StateOptions;
pub use thread_clock::pin_to_cpu;
pub use zenoh_config::zenoh_config;
