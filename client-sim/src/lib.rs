//! Simulated clients for load-testing an impact server, and the event-stream inspector.
//!
//! - [`net`]: opening a client's Zenoh session.
//! - [`view`]: a client's view of the event stream (events, then corrections by identity), and
//!   the check that it ends equal to the confirmed stream.
//! - [`delay`]: a delay line that models network latency, jitter and loss.
//! - [`load`]: the load generator behind `impact-sim`.
//! - [`timing`]: how a client times its inputs (behind or ahead) and the margins it is told.
//! - [`report`]: its report (human summary, JSON, SVG histogram).
//! - [`web`]: the live web viewer (`impact-inspect web`).
//! - [`process`]: real processes (servers, zenohd routers) for deployment tests and benchmarks.

pub mod delay;
pub mod load;
pub mod net;
pub mod process;
pub mod report;
pub mod timing;
pub mod view;
pub mod web;
