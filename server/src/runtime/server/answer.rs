//! Answers to the queries a server declares: the state at a tick, the events of a range, the
//! confirmed batches of recent ticks, the rules and static world a client predicts with, and the
//! checkpoint a standby starts from.
//! Answered by the tick thread from its history, replied by the egress thread.

use super::recent::MAX_QUERY_TICKS;
use super::{Out, TickLoop};
use impact_protocol::{encode, ClientId, Encoding, EventHistory, QueryError, ServerMessage, Tick};
use std::sync::atomic::Ordering;

impl TickLoop {
    pub(super) fn answer(&self, q: zenoh::query::Query) {
        let params = q.parameters().clone();
        let encoding = params.get("encoding").and_then(|e| e.parse().ok()).unwrap_or(self.opts.encoding);
        let key = q.key_expr().as_str().to_string();
        let parse = |name: &str| {
            params.get(name).map(|v| v.parse::<u32>().map(Tick).map_err(|_| format!("{name}={v} is not a tick")))
        };
        let msg = if key.ends_with("/query/checkpoint") {
            match self.session.checkpoint() {
                Ok(mut c) => {
                    // Every client the server remembers, with its avatar.
                    for (client, s) in &self.clients {
                        match c.clients.iter_mut().find(|x| x.client == *client) {
                            Some(x) => x.avatar = s.avatar,
                            None => c.clients.push(impact_protocol::log::CheckpointClient {
                                client: *client,
                                avatar: s.avatar,
                                highest_seq: None,
                                seq_bits: vec![0; crate::rollback::seq_window::WINDOW as usize / 64],
                            }),
                        }
                    }
                    ServerMessage::Checkpoint(c)
                }
                Err(e) => ServerMessage::QueryError(QueryError { detail: e }),
            }
        } else if key.ends_with("/query/confirmed") {
            let client = params
                .get("client")
                .map(|v| v.parse::<u32>().map(ClientId).map_err(|_| format!("client={v} is not a client id")));
            let replies = match (parse("from").transpose(), parse("to").transpose(), client.transpose()) {
                (Ok(Some(from)), Ok(Some(to)), Ok(client)) if from <= to && to.0 - from.0 < MAX_QUERY_TICKS => {
                    self.recent.batches(from, to, client).into_iter().map(ServerMessage::Confirmed).collect()
                }
                (Err(e), _, _) | (_, Err(e), _) | (_, _, Err(e)) => {
                    vec![ServerMessage::QueryError(QueryError { detail: e })]
                }
                _ => vec![ServerMessage::QueryError(QueryError {
                    detail: format!("confirmed needs from=T1;to=T2 with T1 <= T2, at most {MAX_QUERY_TICKS} ticks"),
                })],
            };
            return self.reply(q, &replies, encoding);
        } else if key.ends_with("/query/scene") {
            ServerMessage::Scene(Box::new(self.described.clone()))
        } else if key.ends_with("/query/state") {
            match parse("tick").transpose() {
                Err(e) => ServerMessage::QueryError(QueryError { detail: e }),
                Ok(t) => {
                    let now = self.session.now();
                    let world = match t {
                        None => Some(self.session.world()),
                        Some(t) if t == now => Some(self.session.world()),
                        Some(t) => self.session.frame(t).map(|f| &f.state),
                    };
                    match world {
                        Some(w) => ServerMessage::Snapshot(snapshot(w)),
                        None => ServerMessage::QueryError(QueryError {
                            detail: format!(
                                "tick {} is outside the history (oldest {}, now {now})",
                                t.map_or(0, |t| t.0),
                                self.session.oldest_accepted()
                            ),
                        }),
                    }
                }
            }
        } else {
            match (parse("from").transpose(), parse("to").transpose()) {
                (Ok(Some(from)), Ok(Some(to))) if from < self.session.oldest_accepted() || to >= self.session.now() => {
                    ServerMessage::QueryError(QueryError {
                        detail: format!(
                            "ticks {}..={} are not all in the history (held: {}..{}; older ticks were confirmed)",
                            from.0,
                            to.0,
                            self.session.oldest_accepted(),
                            self.session.now()
                        ),
                    })
                }
                (Ok(Some(from)), Ok(Some(to))) if from <= to && to.0 - from.0 <= 10_000 => {
                    let events = (from.0..=to.0)
                        .filter_map(|t| self.session.frame(Tick(t)))
                        .flat_map(|f| f.events.iter().cloned())
                        .collect();
                    ServerMessage::History(EventHistory { from, to, events })
                }
                (Err(e), _) | (_, Err(e)) => ServerMessage::QueryError(QueryError { detail: e }),
                _ => ServerMessage::QueryError(QueryError {
                    detail: "history needs from=T1;to=T2 with T1 <= T2, at most 10000 ticks".into(),
                }),
            }
        };
        self.reply(q, std::slice::from_ref(&msg), encoding);
    }

    /// Hands the egress thread the replies to `q` (none: the query ends unanswered).
    fn reply(&self, query: zenoh::query::Query, msgs: &[ServerMessage], encoding: Encoding) {
        let replies = msgs.iter().filter_map(|m| encode(m, encoding).ok()).collect();
        if self.egress.try_send(Out::Reply { query, replies, encoding }).is_err() {
            self.shared.egress_dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The world as a snapshot message.
fn snapshot(w: &impact_core::sim::World) -> impact_protocol::WorldSnapshot {
    let b = &w.bodies;
    impact_protocol::WorldSnapshot {
        tick: w.tick,
        state_hash: w.state_hash(),
        bodies: (0..b.len())
            .map(|i| impact_protocol::BodyState {
                entity: b.id[i],
                class: w.config.classes.props[b.class[i].0 as usize].name.clone(),
                owner: b.owner[i],
                position: b.pos[i].to_array(),
                velocity: b.vel[i].to_array(),
            })
            .collect(),
    }
}
