//! Simulated clients for load-testing an impact server, and the event-stream inspector. The
//! clients' event view and network model are the client library's (`impact-client`).
//!
//! - [`net`]: opening a client's Zenoh session.
//! - [`load`]: the load generator behind `impact-sim`.
//! - [`ledger`]: the answers the server owes each simulated client, as the invariants count them.
//! - [`timing`]: how a client times its inputs (behind or ahead) and the margins it is told.
//! - [`report`]: its report (human summary, JSON, SVG histogram).
//! - [`web`]: the live web viewer (`impact-inspect web`).
//! - [`process`]: real processes (servers, zenohd routers) for deployment tests and benchmarks.

pub mod ledger;
pub mod load;
pub mod net;
pub mod process;
pub mod report;
pub mod timing;
pub mod web;
