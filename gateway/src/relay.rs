//! The gateway's Zenoh side: one session for every player it relays, and for each player the
//! subscriptions, input publisher and presence token a Rust client's transport would declare,
//! on that player's keys and no other's.
//!
//! Fencing (PROTOCOL.md, "Failover"): every sample the server publishes carries its owner
//! epoch. The gateway keeps the newest epoch heard per world and drops a sample of an older one
//! (a primary that stalled past its lease and resumed), as the Rust client does, so a browser
//! never sees two owners. A player that hears a newer owner than it heard before (a takeover)
//! is told `link_restored` first, as the Rust client takes it: what the old owner published as
//! it died may not have arrived. So is a player whose events key skips a message number (events
//! or corrections dropped on the way to the gateway): the ticks before are not its to compare.

use crate::auth::Player;
use crate::outbox::{Kind, Mailbox};
use impact_client::session::KeyNumbers;
use impact_client::transport::stamp_of;
use impact_protocol::limits::MAX_SERVER_MESSAGE_BYTES;
use impact_protocol::{keys, ClientId, Encoding, ServerMessage, WorldId};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// How long the gateway looks for a world's server before refusing a player.
pub const FIND_SERVER: Duration = Duration::from_secs(2);
/// How long a scene query waits.
pub const QUERY_TIMEOUT: Duration = Duration::from_secs(3);

/// Why a player could not be relayed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RelayError {
    /// No server token for the world.
    #[error("no server runs world {0}")]
    NoServer(String),
    /// Servers for the world speak other protocol versions.
    #[error("world {world} is served at protocol {found:?}, this gateway speaks {ours}")]
    Version {
        /// The world.
        world: String,
        /// The versions found.
        found: Vec<String>,
        /// The gateway's.
        ours: &'static str,
    },
    /// Zenoh refused a declaration or a query.
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// The session and the newest owner epoch per world.
#[derive(Debug)]
pub struct Relay {
    session: zenoh::Session,
    epochs: Mutex<BTreeMap<WorldId, Arc<AtomicU64>>>,
}

/// One player's declarations: dropped, they are undeclared (the presence token last).
#[derive(Debug)]
pub struct Link {
    input: zenoh::pubsub::Publisher<'static>,
    _subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    /// Set by the first message on the player's answers key: its welcome.
    answered: Arc<AtomicBool>,
    /// The presence token, and what re-declaring it needs.
    token: tokio::sync::Mutex<Option<zenoh::liveliness::LivelinessToken>>,
    session: zenoh::Session,
    presence: String,
}

impl Link {
    /// Publishes one client message (MessagePack, checked by the caller) on the player's input
    /// key.
    pub async fn send(&self, bytes: Vec<u8>) -> Result<(), RelayError> {
        self.input.put(bytes).await.map_err(|e| RelayError::Zenoh(e.to_string()))
    }

    /// Whether anything came on the player's answers key yet (the welcome comes first).
    pub fn welcomed(&self) -> bool {
        self.answered.load(Relaxed)
    }

    /// Withdraws the player's presence and declares it again, as the Rust client's transport does
    /// while no welcome comes (`impact_client::transport::WELCOME_WAIT`): the server welcomes
    /// each declaration.
    pub async fn announce_again(&self) -> Result<(), RelayError> {
        let mut token = self.token.lock().await;
        drop(token.take());
        *token = Some(
            self.session.liveliness().declare_token(&self.presence).await.map_err(zerr("declaring the presence"))?,
        );
        Ok(())
    }
}

fn zerr(what: &str) -> impl Fn(zenoh::Error) -> RelayError + '_ {
    move |e| RelayError::Zenoh(format!("{what}: {e}"))
}

/// A sample's payload as MessagePack (the server publishes a player's messages in the encoding
/// of its inputs, MessagePack here; a JSON one is re-encoded), or `None` if it does not decode.
fn as_msgpack(sample: &zenoh::sample::Sample) -> Option<Vec<u8>> {
    let bytes = sample.payload().to_bytes();
    match Encoding::from_zenoh_tag(&sample.encoding().to_string()).unwrap_or_default() {
        Encoding::MsgPack => Some(bytes.into_owned()),
        Encoding::Json => {
            let msg: ServerMessage = impact_protocol::decode(&bytes, Encoding::Json, MAX_SERVER_MESSAGE_BYTES).ok()?;
            impact_protocol::encode(&msg, Encoding::MsgPack).ok()
        }
    }
}

impl Relay {
    /// Relays over `session`.
    pub fn new(session: zenoh::Session) -> Relay {
        Relay { session, epochs: Mutex::new(BTreeMap::new()) }
    }

    /// The Zenoh session.
    pub fn session(&self) -> &zenoh::Session {
        &self.session
    }

    /// Whether the session has a router or a peer (blocking: call it off the async runtime).
    pub fn reachable(&self) -> bool {
        impact_client::transport::reachable(&self.session)
    }

    fn epoch_floor(&self, world: &WorldId) -> Arc<AtomicU64> {
        let mut epochs = self.epochs.lock().unwrap_or_else(|e| e.into_inner());
        epochs.entry(world.clone()).or_default().clone()
    }

    /// Looks for the world's server (its liveliness token, at any protocol version).
    pub async fn find_server(&self, world: &WorldId) -> Result<(), RelayError> {
        let replies = self
            .session
            .liveliness()
            .get(format!("impact/*/{}/server", world.as_str()))
            .timeout(FIND_SERVER)
            .await
            .map_err(zerr("looking for the server"))?;
        let mut found = Vec::new();
        while let Ok(reply) = replies.recv_async().await {
            if let Ok(sample) = reply.result() {
                let v = sample.key_expr().as_str().split('/').nth(1).unwrap_or("").to_string();
                if v == keys::VERSION {
                    return Ok(());
                }
                if !found.contains(&v) {
                    found.push(v);
                }
            }
        }
        if found.is_empty() {
            Err(RelayError::NoServer(world.as_str().to_string()))
        } else {
            Err(RelayError::Version { world: world.as_str().to_string(), found, ours: keys::VERSION })
        }
    }

    /// Declares `player`'s subscriptions (its answers, events and, with `state`, its state
    /// stream, into `mailbox`), its input publisher, then its presence: the server's welcome
    /// follows.
    pub async fn join(&self, player: &Player, state: bool, mailbox: Arc<Mailbox>) -> Result<Link, RelayError> {
        let (w, c) = (&player.world, Some(player.client));
        let floor = self.epoch_floor(w);
        let mut wanted = vec![(keys::CLIENT_ACK.key(w, c), Kind::Kept), (keys::CLIENT_EVENTS.key(w, c), Kind::Kept)];
        if state {
            wanted.push((keys::CLIENT_STATE.key(w, c), Kind::State));
        }
        let mut subscribers = Vec::new();
        let answered = Arc::new(AtomicBool::new(false));
        // The newest owner this player heard.
        let heard = Arc::new(AtomicU64::new(0));
        for (key, kind) in wanted {
            let (mailbox, floor, heard) = (mailbox.clone(), floor.clone(), heard.clone());
            let answers = (key == keys::CLIENT_ACK.key(w, c)).then(|| answered.clone());
            // The events key's numbers, from the owner heard on it.
            let numbers = (key == keys::CLIENT_EVENTS.key(w, c)).then(|| Mutex::new((0, KeyNumbers::default())));
            let sub = self
                .session
                .declare_subscriber(key)
                .callback(move |sample| {
                    if let Some(stamp) = stamp_of(&sample) {
                        let e = stamp.epoch;
                        // An older owner's sample is dropped; a newer owner raises the floor.
                        if floor.fetch_max(e.0, Relaxed) > e.0 {
                            mailbox.count_stale_owner();
                            return;
                        }
                        let before = heard.fetch_max(e.0, Relaxed);
                        let mut restored = before != 0 && before < e.0;
                        if let (Some(numbers), Some(n)) = (&numbers, stamp.number) {
                            let mut numbers = numbers.lock().unwrap_or_else(|p| p.into_inner());
                            if numbers.0 != e.0 {
                                *numbers = (e.0, KeyNumbers::default());
                            }
                            let lost = numbers.1.heard(n);
                            if lost > 0 {
                                mailbox.count_messages_lost(lost);
                                restored = true;
                            }
                        }
                        if restored {
                            mailbox.deliver(Kind::Kept, crate::wire::encode_notice(&crate::wire::Notice::LinkRestored));
                        }
                    }
                    if let Some(a) = &answers {
                        a.store(true, Relaxed);
                    }
                    match as_msgpack(&sample) {
                        Some(bytes) => mailbox.deliver(kind, bytes),
                        None => mailbox.count_malformed(),
                    }
                })
                .await
                .map_err(zerr("subscribing"))?;
            subscribers.push(sub);
        }
        let input = self
            .session
            .declare_publisher(keys::INPUT.key(w, c))
            .encoding(Encoding::MsgPack.zenoh_tag())
            .await
            .map_err(zerr("declaring the input publisher"))?;
        let presence = keys::PRESENCE.key(w, c);
        let token = self.session.liveliness().declare_token(&presence).await.map_err(zerr("declaring the presence"))?;
        Ok(Link {
            input,
            _subscribers: subscribers,
            answered,
            token: tokio::sync::Mutex::new(Some(token)),
            session: self.session.clone(),
            presence,
        })
    }

    /// The confirmed batch of `tick` for `client` (`query/confirmed`), MessagePack, if the
    /// world's server still keeps it.
    pub async fn confirmed(&self, world: &WorldId, client: ClientId, tick: u32) -> Vec<Vec<u8>> {
        let selector = format!("{}?from={tick};to={tick};client={}", keys::QUERY_CONFIRMED.key(world, None), client.0);
        let asked = self
            .session
            .get(selector)
            .consolidation(zenoh::query::ConsolidationMode::None)
            .timeout(impact_client::transport::RECOVERY_QUERY_TIMEOUT)
            .await;
        let Ok(replies) = asked else { return Vec::new() };
        let mut out = Vec::new();
        while let Ok(reply) = replies.recv_async().await {
            if let Some(bytes) = reply.result().ok().and_then(as_msgpack) {
                out.push(bytes);
            }
        }
        out
    }

    /// The world's scene (`query/scene`) as the server answered it, MessagePack; a
    /// `query_error` message when nobody answered.
    pub async fn scene(&self, world: &WorldId) -> Vec<u8> {
        let failed = |detail: String| {
            let msg = ServerMessage::QueryError(impact_protocol::QueryError { detail });
            impact_protocol::encode(&msg, Encoding::MsgPack).unwrap_or_default()
        };
        let replies = match self.session.get(keys::QUERY_SCENE.key(world, None)).timeout(QUERY_TIMEOUT).await {
            Ok(r) => r,
            Err(e) => return failed(format!("querying the scene: {e}")),
        };
        while let Ok(reply) = replies.recv_async().await {
            if let Ok(sample) = reply.result() {
                if let Some(bytes) = as_msgpack(sample) {
                    return bytes;
                }
            }
        }
        failed(format!("no scene from world {} within {} s", world.as_str(), QUERY_TIMEOUT.as_secs()))
    }
}
