//! Building the Zenoh configuration: embedded peer listening on loopback by default, a config
//! file for anything else (joining a router, other transports, TLS).

use super::error::RuntimeError;
use std::path::Path;

/// The lease a server announces, ms (keep-alives go four times per lease).
pub const SERVER_LEASE_MS: &str = "1500";
/// [`SERVER_LEASE_MS`] as a duration.
pub const SERVER_LEASE: std::time::Duration = std::time::Duration::from_millis(1500);

/// How a lost endpoint is tried again (see [`zenoh_config`]).
pub const RETRY: &str = r#"{"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}"#;

/// The Zenoh configuration for a process of impact: from `file` if given (used as is, except
/// that `listen`/`connect` given on the command line are added), otherwise a peer that listens
/// on `listen` (on nothing when it is empty: not on Zenoh's default of every interface), connects
/// to `connect`, and does no multicast scouting (so a test or a demo never talks to anything it
/// did not name). A peer that listens on nothing can reach others but cannot be reached: peers
/// talk to each other directly, and a router between them does not relay.
pub fn zenoh_config(file: Option<&Path>, listen: &[String], connect: &[String]) -> Result<zenoh::Config, RuntimeError> {
    let err = |what: &str, e: zenoh::Error| RuntimeError::Zenoh(format!("{what}: {e}"));
    let mut c = match file {
        Some(p) => zenoh::Config::from_file(p).map_err(|e| RuntimeError::Config(format!("{}: {e}", p.display())))?,
        None => {
            let mut c = zenoh::Config::default();
            c.insert_json5("mode", "\"peer\"").map_err(|e| err("mode", e))?;
            c.insert_json5("scouting/multicast/enabled", "false").map_err(|e| err("scouting", e))?;
            // A server that stops answering (its host hung or cut off) is declared gone by its
            // peers and routers after this lease, and a standby takes over: 1.5 s, not Zenoh's 10 s.
            // (A process that dies closes its sockets and is seen gone at once.)
            c.insert_json5("transport/link/tx/lease", SERVER_LEASE_MS).map_err(|e| err("lease", e))?;
            // A lost router (restarted, say) is tried again every 100 ms doubling to 500 ms, not
            // Zenoh's 1 s doubling to 4 s: its clients are back within a second of it.
            c.insert_json5("connect/retry", RETRY).map_err(|e| err("retry", e))?;
            // Replies come in bursts (a partition heals and a second of inputs is answered in one
            // tick, each refused copy too), and Zenoh drops what its queue of two 64 KB batches
            // cannot take within a millisecond: acks and rejects lost for good. Sixteen batches,
            // allocated only when a burst needs them (lazily: Zenoh's default), bound a link's
            // queue at 1 MiB.
            c.insert_json5("transport/link/tx/queue/size/data", "16").map_err(|e| err("queue size", e))?;
            // A receive window that stays open after a pause (see the constant).
            let rcvbuf = impact_protocol::limits::TCP_RECEIVE_BUFFER_BYTES.to_string();
            c.insert_json5("transport/link/tcp/so_rcvbuf", &rcvbuf).map_err(|e| err("receive buffer", e))?;
            c
        }
    };
    let list = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
    if !listen.is_empty() || file.is_none() {
        c.insert_json5("listen/endpoints", &list(listen)).map_err(|e| err("listen", e))?;
    }
    if !connect.is_empty() {
        c.insert_json5("connect/endpoints", &list(connect)).map_err(|e| err("connect", e))?;
    }
    Ok(c)
}
