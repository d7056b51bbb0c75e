//! Opening a Zenoh session for clients: a peer that connects to the given endpoints, with
//! multicast scouting off, or a configuration file.

use std::path::Path;
use zenoh::Wait;

/// A Zenoh user name and password (for a server started with `--users`).
#[derive(Clone, Debug)]
pub struct Credentials {
    /// User name.
    pub user: String,
    /// Password.
    pub password: String,
}

/// How a client session joins the Zenoh network.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    /// A peer: connects to the endpoints given and, through gossip, directly to the peers they
    /// know (the servers): the default for a server without a router.
    #[default]
    Peer,
    /// A client: talks only to the router (or peer) it connects to, as game clients behind a
    /// zenohd router do.
    Client,
}

/// Opens a session connected to `connect` (or configured by `file`), authenticated as `creds`
/// if given. Without a configuration file, a session that cannot reach every endpoint within
/// 10 s (no server there, or it refused the credentials) is an error, not a silent wait.
pub fn open(
    connect: &[String],
    file: Option<&Path>,
    creds: Option<&Credentials>,
    mode: Mode,
) -> anyhow::Result<zenoh::Session> {
    let mut c = match file {
        Some(p) => zenoh::Config::from_file(p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?,
        None => {
            let mut c = zenoh::Config::default();
            let mode = if mode == Mode::Client { "\"client\"" } else { "\"peer\"" };
            c.insert_json5("mode", mode).map_err(|e| anyhow::anyhow!("{e}"))?;
            c.insert_json5("scouting/multicast/enabled", "false").map_err(|e| anyhow::anyhow!("{e}"))?;
            c.insert_json5("listen/endpoints", "[]").map_err(|e| anyhow::anyhow!("{e}"))?;
            c.insert_json5("connect/timeout_ms", "10000").map_err(|e| anyhow::anyhow!("{e}"))?;
            c.insert_json5("connect/exit_on_failure", "true").map_err(|e| anyhow::anyhow!("{e}"))?;
            c
        }
    };
    if !connect.is_empty() {
        let list = serde_json::to_string(connect)?;
        c.insert_json5("connect/endpoints", &list).map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    if let Some(k) = creds {
        impact_server::runtime::auth::client_credentials(&mut c, &k.user, &k.password)?;
    }
    let who = creds.map_or(String::new(), |k| format!(" as user {:?}", k.user));
    zenoh::open(c).wait().map_err(|e| anyhow::anyhow!("opening a zenoh session to {}{who}: {e}", connect.join(", ")))
}

/// Decodes a sample's payload by its encoding tag (MessagePack when untagged).
pub fn decode_server(
    sample: &zenoh::sample::Sample,
) -> Result<impact_protocol::ServerMessage, impact_protocol::ProtocolError> {
    let tag = sample.encoding().to_string();
    let enc = impact_protocol::Encoding::from_zenoh_tag(&tag).unwrap_or_default();
    impact_protocol::decode(&sample.payload().to_bytes(), enc, impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES)
}
