//! Hard bounds on everything that crosses the wire. A payload is checked against its size limit
//! before a single byte is decoded, and every decoded message against the value bounds here.

/// Largest client -> server payload, in bytes. An input with [`MAX_ACTIONS_PER_INPUT`] actions
/// encodes to well under 2 KiB in either encoding.
pub const MAX_CLIENT_MESSAGE_BYTES: usize = 4 * 1024;

/// Largest server -> client payload, in bytes (a full world snapshot of 100k bodies fits).
pub const MAX_SERVER_MESSAGE_BYTES: usize = 32 * 1024 * 1024;

/// Most inputs one [`InputBatch`](crate::message::InputBatch) may carry: the newest and up to
/// three unanswered ones before it.
pub const MAX_INPUTS_PER_MESSAGE: usize = 4;

/// Most actions one input may carry.
pub const MAX_ACTIONS_PER_INPUT: usize = 16;

/// Longest name (world, class) in bytes.
pub const MAX_NAME_LEN: usize = 64;

/// Largest absolute coordinate accepted anywhere, in metres.
pub const MAX_ABS_COORD_M: f64 = 1.0e8;

/// Largest speed or impulse-per-mass magnitude accepted from a client, in m/s. The server's
/// per-class speed limit (scene file) is usually far lower and is checked after this.
pub const MAX_SPEED_MPS: f64 = 1.0e5;

/// Largest impulse magnitude, in N*s.
pub const MAX_IMPULSE_NS: f64 = 1.0e7;

/// Largest shape dimension (radius, half height, half extent) a client may spawn, in metres.
pub const MAX_SHAPE_DIM_M: f64 = 1.0e3;

/// Longest hitscan ray, in metres.
pub const MAX_RAY_DISTANCE_M: f64 = 1.0e5;

/// Deepest nesting the MessagePack decoder follows before it gives up (a depth bomb guard).
pub const MAX_DECODE_DEPTH: usize = 16;

/// Most named numbers in one body's game state ([`GameState`](crate::GameState)).
pub const MAX_GAME_STATE_VALUES: usize = 8;

/// Longest name in a game state, in bytes.
pub const MAX_GAME_STATE_NAME_LEN: usize = 16;

/// Longest reason a world's closing gives, in bytes.
pub const MAX_REASON_LEN: usize = 256;

/// The receive buffer every impact process asks of its TCP links (Zenoh's
/// `transport/link/tcp/so_rcvbuf`; `deploy/zenohd.json5` sets it on the router): 1 MiB, which
/// Linux doubles. On loopback (a server beside its router) a segment is 64 KB, and Linux's
/// default buffer of 128 KB advertises about one segment of window: once a paused process (a
/// hung host, a stop under its lease) has let that buffer fill, its window can stay below one
/// segment, the sender holds everything back, and the link carries nothing until a lease ends
/// it. With this buffer the window stays many segments wide.
pub const TCP_RECEIVE_BUFFER_BYTES: u32 = 1 << 20;
