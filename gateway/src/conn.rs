//! One browser connection, from its hello to its close: authenticate, join the world's relay,
//! then pass the player's messages both ways until either side ends it. Every way it can end
//! has a [`Close`] reason the browser receives.
//!
//! The loop reads from the socket and writes what the mailbox holds, one at a time: a browser
//! that does not read stalls only its own connection, for at most the write timeout, while its
//! bounded mailbox drops state frames and then closes it (`crate::outbox`).

use crate::auth::Player;
use crate::gateway::Gateway;
use crate::outbox::{Kind, Mailbox, Queued};
use crate::relay::{Link, RelayError};
use crate::token::unix_now;
use crate::wire::{close_reason, encode_notice, Close, Hello, Notice, Request};
use axum::extract::ws::{CloseFrame, Message, WebSocket};
use futures_util::stream::{SplitSink, SplitStream};
use futures_util::{SinkExt, StreamExt};
use impact_client::transport::{WELCOME_WAIT, WELCOME_WAIT_MAX};
use impact_protocol::limits::MAX_CLIENT_MESSAGE_BYTES;
use impact_protocol::{ClientMessage, Encoding};
use std::sync::atomic::Ordering::Relaxed;
use std::sync::{Arc, Weak};
use std::time::Instant;

type Tx = SplitSink<WebSocket, Message>;
type Rx = SplitStream<WebSocket>;

/// Serves one upgraded connection to its end.
pub async fn serve(socket: WebSocket, gw: Arc<Gateway>) {
    let (mut tx, mut rx) = socket.split();
    let (why, detail) = match hello(&mut rx, &gw).await {
        Ok((player, state)) => play(&mut tx, &mut rx, &gw, player, state).await,
        Err(e) => e,
    };
    gw.counters.closed(why);
    if why != Close::Gone {
        let frame = CloseFrame { code: why.code(), reason: close_reason(why, &detail).into() };
        let _ = tokio::time::timeout(gw.config.write_timeout, tx.send(Message::Close(Some(frame)))).await;
    }
}

/// The first message: a hello that proves a player.
async fn hello(rx: &mut Rx, gw: &Gateway) -> Result<(Player, bool), (Close, String)> {
    let first = match tokio::time::timeout(gw.config.hello_timeout, rx.next()).await {
        Err(_) => return Err((Close::HelloTimeout, format!("send a hello within {:?}", gw.config.hello_timeout))),
        Ok(None | Some(Ok(Message::Close(_)))) => return Err((Close::Gone, String::new())),
        Ok(Some(Err(e))) => return Err(read_error(&e)),
        Ok(Some(Ok(m))) => m,
    };
    let Message::Binary(bytes) = first else {
        return Err((Close::BadHello, "the hello is one binary frame of MessagePack".into()));
    };
    let hello: Hello = match rmp_serde::from_slice::<Request>(&bytes) {
        Ok(Request::Hello(h)) => h,
        Ok(_) => return Err((Close::BadHello, "the first message is a hello".into())),
        Err(e) => return Err((Close::BadHello, e.to_string())),
    };
    let player = gw.config.auth.check(&hello, unix_now()).map_err(|e| (Close::Unauthorized, e.to_string()))?;
    Ok((player, hello.state.unwrap_or(true)))
}

/// Why reading failed, as a close.
fn read_error(e: &axum::Error) -> (Close, String) {
    let text = e.to_string();
    if text.contains("too long") || text.contains("too big") || text.contains("Space limit") {
        (Close::TooBig, format!("at most {MAX_CLIENT_MESSAGE_BYTES} bytes a message"))
    } else {
        (Close::Gone, String::new())
    }
}

/// Relays `player` until the connection ends: its reason.
async fn play(tx: &mut Tx, rx: &mut Rx, gw: &Arc<Gateway>, player: Player, state: bool) -> (Close, String) {
    let c = &gw.config;
    let mailbox = Arc::new(Mailbox::new(c.outbox_messages, c.outbox_bytes, gw.counters.clone()));
    // Ready first, so it reaches the browser before the welcome the join brings.
    mailbox.deliver(
        Kind::Kept,
        encode_notice(&Notice::Ready {
            client: player.client.0,
            world: player.world.as_str().to_string(),
            max_message_bytes: c.max_message_bytes as u32,
            max_messages_per_s: c.max_messages_per_s,
        }),
    );
    let link = match gw.join(&player, state, &mailbox).await {
        Ok(link) => link,
        Err(e @ (RelayError::NoServer(_) | RelayError::Version { .. })) => return (Close::NoServer, e.to_string()),
        Err(e) => return (Close::Unavailable, e.to_string()),
    };
    let ended = relay(tx, rx, gw, &player, &mailbox, &link).await;
    gw.leave(&player, &mailbox);
    ended
}

/// The relay loop.
async fn relay(
    tx: &mut Tx,
    rx: &mut Rx,
    gw: &Arc<Gateway>,
    player: &Player,
    mailbox: &Arc<Mailbox>,
    link: &Weak<Link>,
) -> (Close, String) {
    let mut bucket = Bucket::new(gw.config.max_messages_per_s);
    let mut batch = Vec::new();
    // While no welcome comes, the presence is declared again (after 1 s, doubling up to 8 s).
    let mut welcome_wait = WELCOME_WAIT;
    let mut announce_at = tokio::time::Instant::now() + welcome_wait;
    loop {
        // Whatever is queued goes out before the connection waits again.
        mailbox.drain_into(&mut batch);
        if !batch.is_empty() && batch.iter().all(|q| q.kind == Kind::State) {
            // State frames come in bursts, every player's at once 20 times a second, and wake
            // every connection in turn: one woken by state frames alone lets those woken since
            // (by an ack behind the burst) write first, then sends what it has by then.
            tokio::task::yield_now().await;
            mailbox.drain_into(&mut batch);
        }
        if !batch.is_empty() {
            if let Err(why) = write(tx, gw, &mut batch).await {
                return why;
            }
        }
        if let Some(why) = mailbox.closing() {
            return why;
        }
        let joining = link.upgrade().is_some_and(|l| !l.welcomed());
        tokio::select! {
            _ = mailbox.wake.notified() => {}
            _ = tokio::time::sleep_until(announce_at), if joining => {
                if let Some(l) = link.upgrade() {
                    if l.announce_again().await.is_ok() {
                        gw.counters.presence_repeats.fetch_add(1, Relaxed);
                    }
                }
                welcome_wait = (welcome_wait * 2).min(WELCOME_WAIT_MAX);
                announce_at = tokio::time::Instant::now() + welcome_wait;
            }
            msg = rx.next() => {
                let msg = match msg {
                    None | Some(Ok(Message::Close(_))) => return (Close::Gone, String::new()),
                    Some(Err(e)) => return read_error(&e),
                    Some(Ok(m)) => m,
                };
                if !bucket.take(Instant::now()) {
                    return (Close::Flood, format!("at most {} messages a second", gw.config.max_messages_per_s));
                }
                if let Err(why) = inbound(msg, gw, player, mailbox, link).await {
                    return why;
                }
            }
        }
    }
}

/// Sends `batch` to the browser within the write timeout, and times the kept messages' stay in
/// the gateway (queued to written).
async fn write(tx: &mut Tx, gw: &Gateway, batch: &mut Vec<Queued>) -> Result<(), (Close, String)> {
    let (n, bytes) = (batch.len() as u64, batch.iter().map(|q| q.bytes.len() as u64).sum::<u64>());
    let kept: Vec<Instant> = batch.iter().filter(|q| q.kind == Kind::Kept).map(|q| q.at).collect();
    let sending = async {
        for q in batch.drain(..) {
            tx.feed(Message::Binary(q.bytes.into())).await?;
        }
        tx.flush().await
    };
    match tokio::time::timeout(gw.config.write_timeout, sending).await {
        Err(_) => Err((Close::TooSlow, format!("the browser took no message for {:?}", gw.config.write_timeout))),
        Ok(Err(_)) => Err((Close::Gone, String::new())),
        Ok(Ok(())) => {
            gw.counters.messages_out.fetch_add(n, Relaxed);
            gw.counters.bytes_out.fetch_add(bytes, Relaxed);
            gw.counters.relayed(&kept);
            Ok(())
        }
    }
}

/// One message from the browser: a client message relayed on the player's input key, or a
/// gateway request.
async fn inbound(
    msg: Message,
    gw: &Arc<Gateway>,
    player: &Player,
    mailbox: &Arc<Mailbox>,
    link: &Weak<Link>,
) -> Result<(), (Close, String)> {
    let bytes = match msg {
        Message::Binary(b) => b,
        // Answered by the WebSocket layer.
        Message::Ping(_) | Message::Pong(_) => return Ok(()),
        Message::Text(_) => return Err((Close::Malformed, "binary frames of MessagePack only".into())),
        Message::Close(_) => return Err((Close::Gone, String::new())),
    };
    gw.counters.messages_in.fetch_add(1, Relaxed);
    gw.counters.bytes_in.fetch_add(bytes.len() as u64, Relaxed);
    // Its structure only: the values are the server's to refuse, with a reject the client
    // matches to its input (a refused value here would reach the client as a close instead).
    match impact_protocol::decode_unchecked::<ClientMessage>(&bytes, Encoding::MsgPack, gw.config.max_message_bytes) {
        Ok(ClientMessage::World(_)) => Err((Close::NotAllowed, "world commands are for game logic".into())),
        Ok(_) => {
            // Gone when a newer connection of the same player replaced this one.
            let Some(link) = link.upgrade() else {
                return Err(mailbox.closing().unwrap_or((Close::Replaced, String::new())));
            };
            link.send(bytes.to_vec()).await.map_err(|e| (Close::Unavailable, e.to_string()))
        }
        Err(not_client) => match rmp_serde::from_slice::<Request>(&bytes) {
            Ok(Request::Scene) => {
                let (gw, world, mailbox) = (gw.clone(), player.world.clone(), mailbox.clone());
                tokio::spawn(async move { mailbox.deliver(Kind::Kept, gw.relay.scene(&world).await) });
                Ok(())
            }
            Ok(Request::Confirmed { tick }) => {
                let (gw, p, mailbox) = (gw.clone(), player.clone(), mailbox.clone());
                tokio::spawn(async move {
                    for bytes in gw.relay.confirmed(&p.world, p.client, tick).await {
                        mailbox.deliver(Kind::Kept, bytes);
                    }
                });
                Ok(())
            }
            Ok(Request::Hello(_)) => Err((Close::Malformed, "a second hello".into())),
            Err(_) => Err((Close::Malformed, not_client.to_string())),
        },
    }
}

/// A token bucket: `rate` messages a second, a burst of as many.
#[derive(Debug)]
struct Bucket {
    rate: f64,
    tokens: f64,
    at: Option<Instant>,
}

impl Bucket {
    fn new(rate: u32) -> Bucket {
        Bucket { rate: f64::from(rate.max(1)), tokens: f64::from(rate.max(1)), at: None }
    }

    /// Takes one token at `now`: false when none is left.
    fn take(&mut self, now: Instant) -> bool {
        if let Some(at) = self.at {
            self.tokens = (self.tokens + now.duration_since(at).as_secs_f64() * self.rate).min(self.rate);
        }
        self.at = Some(now);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn the_bucket_allows_its_rate_and_a_burst_of_it() {
        let t0 = Instant::now();
        let mut b = Bucket::new(10);
        assert_eq!((0..15).filter(|_| b.take(t0)).count(), 10, "a burst of the rate");
        assert!(!b.take(t0 + Duration::from_millis(50)), "half a token after 50 ms");
        assert!(b.take(t0 + Duration::from_millis(100)));
        // A second later, the rate again, never more.
        let t1 = t0 + Duration::from_secs(5);
        assert_eq!((0..15).filter(|_| b.take(t1)).count(), 10);
    }
}
