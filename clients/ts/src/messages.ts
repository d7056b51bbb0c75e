// The protocol's messages as TypeScript types, and the schemas that encode them exactly as the
// server does (PROTOCOL.md, "Client -> server" and "Server -> client"). Positions and velocities
// are metres and metres per second in world axes; ticks, seqs and ids are unsigned 32-bit
// integers; hashes are BigInt.

import { decodeMsgpack, encodeJsonWith, encodeWith, type Field, type Kind } from "./codec.js";

export type Vec3 = [number, number, number];

/** A collision shape (PROTOCOL.md, "Shapes"). */
export type ShapeSpec =
  | { type: "sphere"; radius_m: number }
  | { type: "capsule"; half_height_m: number; radius_m: number }
  | { type: "cuboid"; half_extents_m: Vec3 }
  | { type: "ellipsoid"; radii_m: Vec3 }
  | { type: "convex"; points: Vec3[] }
  | { type: "mesh"; vertices: Vec3[]; triangles: [number, number, number][] };

/** What a client can do to the world. */
export type Action =
  | { type: "set_velocity"; entity: number; velocity: Vec3 }
  | { type: "apply_impulse"; entity: number; impulse: Vec3 }
  | { type: "spawn_projectile"; shape: ShapeSpec; position: Vec3; velocity: Vec3 }
  | { type: "fire_ray"; shooter: number; origin: Vec3; direction: Vec3; max_distance_m: number }
  | { type: "move"; entity: number; direction: Vec3; jump: boolean }
  | { type: "teleport"; entity: number; position: Vec3; velocity: Vec3 | null }
  | { type: "spawn"; class: string; shape: ShapeSpec; position: Vec3; velocity: Vec3; owner: number | null }
  | { type: "set_class"; entity: number; class: string }
  | { type: "set_state"; entity: number; values: Record<string, number> }
  | { type: "despawn"; entity: number };

/** One input: actions stamped with the tick the client acted at. */
export interface ClientInput {
  client: number;
  seq: number;
  tick: number;
  view_tick?: number;
  actions: Action[];
  aim_tick?: number;
}

export type ClientMessage =
  | ({ type: "input" } & ClientInput)
  | { type: "inputs"; client: number; inputs: ClientInput[] }
  | { type: "ping"; client: number; id: number }
  | { type: "full_frame"; client: number };

export type Phase = "begin" | "end" | "hit";
export type Response = "bounce" | "slide" | "stop" | "destroy" | "trigger";
export type EventStatus = "provisional" | "corrected" | "confirmed";

export interface CollisionEvent {
  tick: number;
  toi: number;
  a: number;
  b: number;
  point: Vec3;
  normal: Vec3;
  depth_m: number;
  closing_speed_mps: number;
  phase: Phase;
  response: Response;
  status: EventStatus;
}

export interface EventBatch {
  tick: number;
  revision: number;
  events: CollisionEvent[];
}

export interface CorrectionBatch {
  tick: number;
  revision: number;
  retracted: CollisionEvent[];
  amended: CollisionEvent[];
  added: CollisionEvent[];
}

export type RejectReason =
  | "stale"
  | "future"
  | "not_owner"
  | "unknown_entity"
  | "invalid_number"
  | "out_of_range"
  | "rate_limited"
  | "too_large"
  | "malformed"
  | "queue_full"
  | "duplicate"
  | "not_allowed";

export interface InputAck {
  client: number;
  seq: number;
  tick: number;
  applied_tick: number;
  server_tick: number;
  margin_ticks: number;
  lead_ticks: number;
  accepted_before: bigint;
}

export interface InputReject {
  client: number;
  seq: number | null;
  tick: number | null;
  reason: RejectReason;
  detail: string;
  oldest_tick: number | null;
  newest_tick: number | null;
}

export interface Welcome {
  client: number;
  avatar: number | null;
  tick: number;
  tick_hz: number;
  window_ticks: number;
  input_lead_ticks: number;
  max_rewind_ticks: number;
  next_seq: number;
  scene_hash: bigint;
}

export interface RayHit {
  entity: number;
  point: Vec3;
  normal: Vec3;
  distance_m: number;
}

export interface RayResult {
  client: number;
  seq: number;
  tick: number;
  view_tick: number;
  clamped: boolean;
  shooter: number;
  hit: RayHit | null;
}

export type BodyShape = "sphere" | "capsule" | "cuboid" | "ellipsoid" | "convex" | "trimesh" | "terrain";

export interface BodyInfo {
  entity: number;
  class: string;
  owner: number | null;
  shape: BodyShape;
  half_extents_m: Vec3;
  offset_m: Vec3;
  fixed: boolean;
  rotation?: [number, number, number, number];
  local_shape?: ShapeSpec;
  state?: Record<string, number>;
  teleported?: number;
}

/** `[entity, position, velocity, asleep]`, positions and velocities f32. */
export type BodyMotion = [number, Vec3, Vec3, boolean];

export interface AvatarTouch {
  other: number;
  normal: Vec3;
  depth_m: number;
  impulse: number;
  friction_impulse: Vec3;
}

export interface AvatarState {
  entity: number;
  position: Vec3;
  velocity: Vec3;
  asleep: boolean;
  still_ticks: number;
  touching: AvatarTouch[];
  class: number | null;
  teleported?: number;
}

export interface StateFrame {
  tick: number;
  frame: number;
  full: boolean;
  entered: BodyInfo[];
  moved: BodyMotion[];
  left: number[];
  deferred: number;
  centre: Vec3 | null;
  avatar?: AvatarState;
}

export type ServerMessage =
  | ({ type: "events" } & EventBatch)
  | ({ type: "corrections" } & CorrectionBatch)
  | ({ type: "confirmed" } & EventBatch)
  | ({ type: "ack" } & InputAck)
  | ({ type: "reject" } & InputReject)
  | ({ type: "ray_result" } & RayResult)
  | ({ type: "welcome" } & Welcome)
  | ({ type: "state" } & StateFrame)
  | { type: "pong"; client: number; id: number; server_tick: number }
  | { type: "closed"; world: string; tick: number; next: string | null; reason: string }
  | { type: "query_error"; detail: string }
  | { type: "owner"; epoch: bigint; tick: number };
// Other server messages (log, checkpoint, snapshot, history, scene) are for servers, tools and
// predicting clients: decodeServer passes them through with their `type`, and a browser client
// ignores them.

/** The gateway's own messages (PROTOCOL.md, "WebSocket binding"). */
export type GatewayNotice =
  | { type: "ready"; client: number; world: string; max_message_bytes: number; max_messages_per_s: number }
  | { type: "link_restored" };

// ---- schemas: field order and types as the server's encoder writes them ----

const f: (name: string, kind: Kind, skip?: boolean) => Field = (name, kind, skip) => (skip ? { name, kind, skip } : { name, kind });
const vec3: Kind = { vec: "f64" };
const vec3f32: Kind = { vec: "f32" };

export const SHAPE: Kind = {
  tagged: {
    sphere: [f("radius_m", "f64")],
    capsule: [f("half_height_m", "f64"), f("radius_m", "f64")],
    cuboid: [f("half_extents_m", vec3)],
    ellipsoid: [f("radii_m", vec3)],
    convex: [f("points", { vec: vec3 })],
    mesh: [f("vertices", { vec: vec3 }), f("triangles", { vec: { vec: "u" } })],
  },
};

export const ACTION: Kind = {
  tagged: {
    set_velocity: [f("entity", "u"), f("velocity", vec3)],
    apply_impulse: [f("entity", "u"), f("impulse", vec3)],
    spawn_projectile: [f("shape", SHAPE), f("position", vec3), f("velocity", vec3)],
    fire_ray: [f("shooter", "u"), f("origin", vec3), f("direction", vec3), f("max_distance_m", "f64")],
    move: [f("entity", "u"), f("direction", vec3), f("jump", "bool")],
    teleport: [f("entity", "u"), f("position", vec3), f("velocity", { opt: vec3 })],
    spawn: [f("class", "str"), f("shape", SHAPE), f("position", vec3), f("velocity", vec3), f("owner", { opt: "u" })],
    set_class: [f("entity", "u"), f("class", "str")],
    set_state: [f("entity", "u"), f("values", { map: "f64" })],
    despawn: [f("entity", "u")],
  },
};

const INPUT_FIELDS: Field[] = [
  f("client", "u"),
  f("seq", "u"),
  f("tick", "u"),
  f("view_tick", "u", true),
  f("actions", { vec: ACTION }),
  f("aim_tick", "u", true),
];

export const CLIENT_MESSAGE: Kind = {
  tagged: {
    input: INPUT_FIELDS,
    inputs: [f("client", "u"), f("inputs", { vec: { struct: INPUT_FIELDS } })],
    ping: [f("client", "u"), f("id", "u")],
    full_frame: [f("client", "u")],
  },
};

const EVENT: Kind = {
  struct: [
    f("tick", "u"),
    f("toi", "f64"),
    f("a", "u"),
    f("b", "u"),
    f("point", vec3),
    f("normal", vec3),
    f("depth_m", "f64"),
    f("closing_speed_mps", "f64"),
    f("phase", "str"),
    f("response", "str"),
    f("status", "str"),
  ],
};
const EVENT_BATCH: Field[] = [f("tick", "u"), f("revision", "u"), f("events", { vec: EVENT })];
const BODY_INFO: Kind = {
  struct: [
    f("entity", "u"),
    f("class", "str"),
    f("owner", { opt: "u" }),
    f("shape", "str"),
    f("half_extents_m", vec3f32),
    f("offset_m", vec3f32),
    f("fixed", "bool"),
    f("rotation", { vec: "f32" }, true),
    f("local_shape", SHAPE, true),
    f("state", { map: "f64" }, true),
    f("teleported", "u", true),
  ],
};
const AVATAR: Kind = {
  struct: [
    f("entity", "u"),
    f("position", vec3),
    f("velocity", vec3),
    f("asleep", "bool"),
    f("still_ticks", "u"),
    f("touching", {
      vec: {
        struct: [f("other", "u"), f("normal", vec3), f("depth_m", "f64"), f("impulse", "f64"), f("friction_impulse", vec3)],
      },
    }),
    f("class", { opt: "u" }),
    f("teleported", "u", true),
  ],
};

/** The server messages a browser client reads. */
export const SERVER_MESSAGE: Kind = {
  tagged: {
    events: EVENT_BATCH,
    confirmed: EVENT_BATCH,
    corrections: [f("tick", "u"), f("revision", "u"), f("retracted", { vec: EVENT }), f("amended", { vec: EVENT }), f("added", { vec: EVENT })],
    ack: [
      f("client", "u"),
      f("seq", "u"),
      f("tick", "u"),
      f("applied_tick", "u"),
      f("server_tick", "u"),
      f("margin_ticks", "i"),
      f("lead_ticks", "u"),
      f("accepted_before", "u64"),
    ],
    reject: [
      f("client", "u"),
      f("seq", { opt: "u" }),
      f("tick", { opt: "u" }),
      f("reason", "str"),
      f("detail", "str"),
      f("oldest_tick", { opt: "u" }),
      f("newest_tick", { opt: "u" }),
    ],
    ray_result: [
      f("client", "u"),
      f("seq", "u"),
      f("tick", "u"),
      f("view_tick", "u"),
      f("clamped", "bool"),
      f("shooter", "u"),
      f("hit", { opt: { struct: [f("entity", "u"), f("point", vec3), f("normal", vec3), f("distance_m", "f64")] } }),
    ],
    welcome: [
      f("client", "u"),
      f("avatar", { opt: "u" }),
      f("tick", "u"),
      f("tick_hz", "u"),
      f("window_ticks", "u"),
      f("input_lead_ticks", "u"),
      f("max_rewind_ticks", "u"),
      f("next_seq", "u"),
      f("scene_hash", "u64"),
    ],
    state: [
      f("tick", "u"),
      f("frame", "u"),
      f("full", "bool"),
      f("entered", { vec: BODY_INFO }),
      f("moved", { vec: { tuple: ["u", vec3f32, vec3f32, "bool"] } }),
      f("left", { vec: "u" }),
      f("deferred", "u"),
      f("centre", { opt: vec3f32 }),
      f("avatar", AVATAR, true),
    ],
    pong: [f("client", "u"), f("id", "u"), f("server_tick", "u")],
    closed: [f("world", "str"), f("tick", "u"), f("next", { opt: "str" }), f("reason", "str")],
    query_error: [f("detail", "str")],
    owner: [f("epoch", "u64"), f("tick", "u")],
  },
};

/** A client message as MessagePack, byte for byte as the server's encoder writes it. */
export function encodeClient(msg: ClientMessage): Uint8Array {
  return encodeWith(CLIENT_MESSAGE, msg);
}

/** A client message as the server's compact JSON. */
export function encodeClientJson(msg: ClientMessage): string {
  return encodeJsonWith(CLIENT_MESSAGE, msg);
}

/** A server message (or a gateway notice) from MessagePack, u64 fields as BigInt. */
export function decodeServer(bytes: Uint8Array): ServerMessage | GatewayNotice {
  const m = decodeMsgpack(bytes);
  if (typeof m !== "object" || m === null || typeof (m as { type?: unknown }).type !== "string") {
    throw new Error("not a message: no type");
  }
  const o = m as Record<string, unknown>;
  for (const k of ["accepted_before", "scene_hash", "epoch", "state_hash"]) {
    if (typeof o[k] === "number") o[k] = BigInt(o[k] as number);
  }
  return o as ServerMessage | GatewayNotice;
}
