//! Opening a Zenoh session for clients: the client library's transport
//! ([`impact_client::transport`]), with the mode as a command-line choice.

use std::path::Path;

pub use impact_client::transport::{decode_server, Credentials};

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

impl From<Mode> for impact_client::transport::Mode {
    fn from(m: Mode) -> Self {
        match m {
            Mode::Peer => impact_client::transport::Mode::Peer,
            Mode::Client => impact_client::transport::Mode::Client,
        }
    }
}

/// Opens a session connected to `connect` (or configured by `file`), authenticated as `creds`
/// if given ([`impact_client::transport::open_session`]).
pub fn open(
    connect: &[String],
    file: Option<&Path>,
    creds: Option<&Credentials>,
    mode: Mode,
) -> anyhow::Result<zenoh::Session> {
    Ok(impact_client::transport::open_session(connect, file, creds, mode.into())?)
}
