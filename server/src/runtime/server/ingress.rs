//! The primary's declarations: the input subscriber (decode and validate in Zenoh's callback,
//! enqueue, never block), the queryables, and the liveliness token a standby watches.

use super::{reason_index, reject, send, Ingress, Primary, RuntimeError, Wiring};
use impact_protocol::limits::MAX_CLIENT_MESSAGE_BYTES;
use impact_protocol::{
    decode_unchecked, keys, ClientId, ClientMessage, Encoding, RejectReason, Tick, Validate, WorldId,
};
use std::sync::atomic::Ordering;
use std::sync::mpsc::TrySendError;
use zenoh::Wait;

/// Declares what makes this process the world's server: the input subscriber (decode and
/// validate in the callback, enqueue, never block), the queryables, and its liveliness token.
pub(super) fn declare_primary(
    zs: &zenoh::Session,
    world_id: &WorldId,
    wiring: &Wiring,
) -> Result<Primary, RuntimeError> {
    let input_sub = {
        let tx = wiring.ingress.clone();
        let etx = wiring.egress.clone();
        let shared = wiring.shared.clone();
        let default_enc = wiring.encoding;
        zs.declare_subscriber(keys::INPUT.any_client(world_id))
            .callback(move |sample| {
                // A world closed for good answers nothing more: its clients were told, and what
                // they sent after is void (PROTOCOL.md, "Worlds at run time").
                if shared.closed.load(Ordering::Relaxed) {
                    return;
                }
                let key = sample.key_expr().as_str().to_string();
                let from_key = keys::INPUT.parse(&key).ok().and_then(|(_, c)| c);
                let tag = sample.encoding().to_string();
                let encoding = Encoding::from_zenoh_tag(&tag).unwrap_or(default_enc);
                let bytes = sample.payload().to_bytes();
                let refuse = |client: ClientId, header: Option<(u32, Tick)>, reason: RejectReason, detail: String| {
                    shared.rejected_in_callbacks[reason_index(reason)].fetch_add(1, Ordering::Relaxed);
                    let key = keys::CLIENT_ACK.key(&world_of(&key), Some(client));
                    send(&etx, &shared, key.into(), reject(client, header, reason, detail), encoding);
                };
                let Some(client) = from_key else {
                    return; // not a key of ours: nobody to answer
                };
                // Whatever fails from here on is answered with the input's own seq and tick when
                // the payload can be read that far, so the client can tell which input it was.
                let header = || {
                    impact_protocol::input_header(&bytes, encoding, MAX_CLIENT_MESSAGE_BYTES).map(|(_, s, t)| (s, t))
                };
                if Encoding::from_zenoh_tag(&tag).is_none() && !tag.is_empty() && tag != "zenoh/bytes" {
                    return refuse(
                        client,
                        None,
                        RejectReason::Malformed,
                        format!("unknown encoding {tag:?}: use application/msgpack or application/json"),
                    );
                }
                let inputs = match decode_unchecked::<ClientMessage>(&bytes, encoding, MAX_CLIENT_MESSAGE_BYTES) {
                    Err(e) => return refuse(client, header(), e.reject_reason(), e.to_string()),
                    Ok(ClientMessage::Input(input)) => vec![input],
                    Ok(ClientMessage::Inputs(batch)) => {
                        if batch.client != client {
                            let detail =
                                format!("inputs name client {} but were sent on client {client}'s key", batch.client);
                            return refuse(client, None, RejectReason::NotOwner, detail);
                        }
                        if let Err(e) = batch.validate_envelope() {
                            return refuse(client, None, e.reject_reason(), e.to_string());
                        }
                        batch.inputs
                    }
                    Ok(ClientMessage::FullFrame(r)) => {
                        if r.client == client {
                            let _ = tx.try_send(Ingress::FullFrame(client));
                        }
                        return;
                    }
                    Ok(ClientMessage::World(_)) => {
                        let detail = format!("a world command is a query on {}", keys::WORLD_COMMAND.pattern);
                        return refuse(client, None, RejectReason::Malformed, detail);
                    }
                    Ok(ClientMessage::Ping(ping)) => {
                        // A probe lost to a full queue is one the client sends again.
                        if ping.client == client {
                            let _ = tx.try_send(Ingress::Ping { ping, encoding });
                        }
                        return;
                    }
                };
                let newest = inputs.len().saturating_sub(1);
                for (k, input) in inputs.into_iter().enumerate() {
                    let here = Some((input.seq, input.tick));
                    if input.client != client {
                        refuse(
                            client,
                            here,
                            RejectReason::NotOwner,
                            format!("input names client {} but was sent on client {client}'s key", input.client),
                        );
                        continue;
                    }
                    if let Err(e) = input.validate() {
                        refuse(client, here, e.reject_reason(), e.to_string());
                        continue;
                    }
                    if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) =
                        tx.try_send(Ingress::Input { input, encoding, copy: k < newest })
                    {
                        refuse(
                            client,
                            here,
                            RejectReason::QueueFull,
                            "the server's ingress queue is full; resend later".into(),
                        );
                    }
                }
            })
            .wait()
            .map_err(|e| RuntimeError::Zenoh(format!("declaring the input subscriber: {e}")))?
    };
    fn world_of(key: &str) -> WorldId {
        keys::INPUT.parse(key).map(|(w, _)| w).unwrap_or_else(|_| WorldId::new("unknown").expect("valid name"))
    }

    // Queries: answered by the tick thread (it owns the history), replied by the egress thread.
    let mut queryables = Vec::new();
    for pattern in
        [keys::QUERY_STATE, keys::QUERY_HISTORY, keys::QUERY_CONFIRMED, keys::QUERY_SCENE, keys::QUERY_CHECKPOINT]
    {
        let tx = wiring.queries.clone();
        let q = zs
            .declare_queryable(pattern.key(world_id, None))
            .callback(move |query| {
                let _ = tx.try_send(query);
            })
            .wait()
            .map_err(|e| RuntimeError::Zenoh(format!("declaring a queryable: {e}")))?;
        queryables.push(q);
    }
    let token = zs
        .liveliness()
        .declare_token(keys::SERVER.key(world_id, None))
        .wait()
        .map_err(|e| RuntimeError::Zenoh(format!("declaring the server's liveliness token: {e}")))?;
    Ok(Primary { _inputs: input_sub, _queryables: queryables, _token: token })
}
