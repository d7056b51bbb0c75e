//! `impact-gateway`: browsers play over WebSocket, relayed to their worlds over Zenoh.
//!
//! ```text
//! impact-gateway --connect tcp/127.0.0.1:7447 --users users.toml --listen 127.0.0.1:8088
//! impact-gateway token --secret-file secret --client 7 --world arena --ttl-s 3600
//! impact-gateway --connect tcp/127.0.0.1:7447 --guests arena   # the play page, no logins
//! ```

use anyhow::{bail, Context, Result};
use clap::{Args as ClapArgs, Parser, Subcommand};
use impact_client::transport::{open_session, Credentials, Mode};
use impact_gateway::auth::Authenticator;
use impact_gateway::page::GuestPolicy;
use impact_gateway::token::{unix_now, Grant, Secret};
use impact_gateway::{Config, Gateway};
use impact_protocol::users::Users;
use impact_protocol::{ClientId, WorldId};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(version, about = "impact's WebSocket gateway: browsers play, relayed to their worlds over Zenoh")]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    serve: Serve,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Prints a signed token for a player (as a game backend issues one).
    Token {
        /// The shared secret's file (at least 32 bytes).
        #[arg(long)]
        secret_file: PathBuf,
        /// The player's client id.
        #[arg(long)]
        client: u32,
        /// The world.
        #[arg(long)]
        world: String,
        /// Seconds the token is valid for.
        #[arg(long, default_value_t = 3600)]
        ttl_s: u64,
    },
}

#[derive(ClapArgs, Debug)]
struct Serve {
    /// Address to accept browsers on: WebSocket at /ws, counters at /stats.
    #[arg(long, default_value = "127.0.0.1:8088")]
    listen: String,
    /// Zenoh endpoints of the servers or their router (repeat for several).
    #[arg(long, default_value = "tcp/127.0.0.1:7447")]
    connect: Vec<String>,
    /// Zenoh mode: peer (to a server or a router) or client (to a router).
    #[arg(long, value_enum, default_value_t = ZenohMode::Peer)]
    mode: ZenohMode,
    /// A Zenoh configuration file instead of the options above (TLS, say).
    #[arg(long)]
    zenoh_config: Option<PathBuf>,
    /// The users file: players who may log in with user and password, and the gateway's own
    /// credential (`[[gateway]]`, picked by --as) for a deployment under --users.
    #[arg(long)]
    users: Option<PathBuf>,
    /// Which `[[gateway]]` of the users file this gateway authenticates to Zenoh as.
    #[arg(long = "as")]
    as_gateway: Option<String>,
    /// The secret of signed player tokens (at least 32 bytes), shared with the game's backend.
    #[arg(long)]
    token_secret: Option<PathBuf>,
    /// Let pages without credentials play as guests in this world: `POST /guest` gives each a
    /// token for a fresh client id (signed with --token-secret, or a secret made at start).
    #[arg(long)]
    guests: Option<String>,
    /// The first guest's client id (guests count up from it).
    #[arg(long, default_value_t = GuestPolicy::FIRST)]
    guest_ids: u32,
    /// Seconds a guest token is valid for.
    #[arg(long, default_value_t = 3600)]
    guest_ttl_s: u64,
    /// An origin whose pages may connect besides the gateway's own (repeat; `*` for any).
    #[arg(long = "allow-origin")]
    allow_origins: Vec<String>,
    /// Connections open at once.
    #[arg(long, default_value_t = Config::default().max_connections)]
    max_connections: usize,
    /// Messages a second one connection may send.
    #[arg(long, default_value_t = Config::default().max_messages_per_s)]
    max_messages_per_s: u32,
    /// The async runtime's worker threads (0: one a core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Seconds between the counters printed on stderr (0: never).
    #[arg(long, default_value_t = 10)]
    report_s: u64,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum ZenohMode {
    Peer,
    Client,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Token { secret_file, client, world, ttl_s }) => {
            let secret = read_secret(&secret_file)?;
            let world = WorldId::new(world.as_str()).map_err(|e| anyhow::anyhow!("--world: {e}"))?;
            let grant = Grant { client: ClientId(client), world, expires: unix_now().saturating_add(ttl_s) };
            println!("{}", secret.issue(&grant));
            Ok(())
        }
        None => serve(&cli.serve),
    }
}

fn read_secret(path: &Path) -> Result<Secret> {
    let bytes = std::fs::read(path).with_context(|| format!("reading the token secret {}", path.display()))?;
    Secret::new(&bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

fn serve(a: &Serve) -> Result<()> {
    let users = a.users.as_deref().map(load_users).transpose()?;
    let mut secret = a.token_secret.as_deref().map(read_secret).transpose()?;
    let guests = match &a.guests {
        Some(world) => {
            let world = WorldId::new(world.as_str()).map_err(|e| anyhow::anyhow!("--guests: {e}"))?;
            if secret.is_none() {
                secret = Some(Secret::random()?);
            }
            Some(GuestPolicy { world, first: a.guest_ids, ttl_s: a.guest_ttl_s })
        }
        None => None,
    };
    if users.as_ref().is_none_or(|u| u.users.is_empty()) && secret.is_none() {
        bail!("nobody could play: give --users (with [[user]] entries), --token-secret or --guests WORLD");
    }
    let creds = match (&a.as_gateway, &users) {
        (Some(name), Some(u)) => {
            let g = u
                .gateway(name)
                .with_context(|| format!("--as {name}: no [[gateway]] of that name in the users file"))?;
            Some(Credentials { user: g.name.clone(), password: g.password.clone() })
        }
        (Some(_), None) => bail!("--as names a [[gateway]] of the users file: give --users too"),
        (None, _) => None,
    };
    let mode = match a.mode {
        ZenohMode::Peer => Mode::Peer,
        ZenohMode::Client => Mode::Client,
    };
    let hint = if creds.is_some() {
        "no server or router there, or it refused the gateway's credential"
    } else {
        "no server or router there; if it runs --users, give --users FILE --as NAME (a [[gateway]] entry)"
    };
    let session = open_session(&a.connect, a.zenoh_config.as_deref(), creds.as_ref(), mode).context(hint)?;
    let config = Config {
        auth: Authenticator { users, secret },
        allow_origins: a.allow_origins.clone(),
        max_connections: a.max_connections,
        max_messages_per_s: a.max_messages_per_s,
        guests,
        ..Config::default()
    };
    let gw = Gateway::new(config, session);
    let running = impact_gateway::gateway::start(gw.clone(), &a.listen, a.threads)
        .with_context(|| format!("listening on {}", a.listen))?;
    let addr = running.addr;
    println!("impact-gateway listening on http://{addr} (WebSocket ws://{addr}/ws, counters /stats)");
    match &gw.config.guests {
        Some(g) => println!("play: http://{addr}/ (guests in {}, from client {})", g.world, g.first),
        None => println!("play: http://{addr}/?token=TOKEN (or ?world=W&client=C&user=U&password=P)"),
    }
    report(gw.clone(), a.report_s);
    let (stop_tx, stop_rx) = std::sync::mpsc::sync_channel::<()>(1);
    ctrlc::set_handler(move || {
        let _ = stop_tx.try_send(());
    })?;
    let _ = stop_rx.recv();
    running.stop()?;
    eprintln!("impact-gateway: stopped; {}", serde_json::to_string(&gw.counters.snapshot())?);
    Ok(())
}

/// The users file, read and checked.
fn load_users(path: &Path) -> Result<Users> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading users file {}", path.display()))?;
    Users::parse(&text).map_err(|e| anyhow::anyhow!("users file {}: {e}", path.display()))
}

/// Prints the counters every `every_s` seconds, when they changed.
fn report(gw: Arc<Gateway>, every_s: u64) {
    if every_s == 0 {
        return;
    }
    std::thread::spawn(move || {
        let mut last = None;
        loop {
            std::thread::sleep(Duration::from_secs(every_s));
            let now = gw.counters.snapshot();
            if last.as_ref() != Some(&now) {
                if let Ok(line) = serde_json::to_string(&now) {
                    eprintln!("impact-gateway: {line}");
                }
                last = Some(now);
            }
        }
    });
}
