// impact's client for browsers: the protocol over the WebSocket gateway, typed. A port of the
// Rust client library's model (README, "impact-gateway"; PROTOCOL.md, "WebSocket binding").
//
// - codec: MessagePack exactly as the server writes it (schemas: floats stay floats), u64 as BigInt.
// - messages: the protocol's messages as types, and their schemas.
// - clock: the server's tick, and the tick to stamp an input with (ahead, by time dilation).
// - outbox: seqs and the inputs awaiting an answer, across the wrap.
// - events: the event view (provisional, corrected, confirmed and compared).
// - remote: the remote world from the state stream, interpolated at a render tick.
// - session: all of it as one state machine, no I/O.
// - gateway: the session over a WebSocket to impact-gateway, reconnecting.

export * from "./clock.js";
export * from "./codec.js";
export * from "./events.js";
export * from "./gateway.js";
export * from "./messages.js";
export * from "./outbox.js";
export * from "./remote.js";
export * from "./session.js";
