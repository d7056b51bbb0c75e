// The play page (served by impact-gateway at `/`, bundled into gateway/page/play.js by
// `npm run page`): a person plays a world from above. WASD moves the own avatar along x and z,
// Q and E down and up (its velocity, predicted at once); a click on a body fires a ray at it
// (hitscan, rewound by the server to what this page drew); other players and balls are drawn from
// the state stream, interpolated; a hit flashes both ends.
//
// `#status` reads `playing · client C · tick T · N bodies` once joined and keeps counters in data
// attributes for tests and tools: data-acked, data-rejects, data-events, data-hits (hit events
// this avatar shot or took), data-rays (shots answered), data-players (other players drawn), data-confirmed and data-mismatched
// (confirmed ticks compared with the view, and those it got wrong), data-reject-reasons (the server's
// rejects of this page's inputs by reason, `stale:2 future:1`, also shown beside the ping), data-avatar (the own
// entity), data-hit-last (the last entity it hit), data-hit-by (the last that hit it), and its
// drawn position data-x, data-y, data-z with the view's data-scale (pixels a metre).
//
// Credentials come from the address: `?token=T`, or `?world=W&client=C&user=U&password=P`; with
// neither, a guest token from the gateway (`impact-gateway --guests WORLD`).

import { Connection, Session, sessionConfig, type Action, type Hello, type Vec3 } from "../src/index.js";

const SPEED_MPS = 6;
const RANGE_M = 60;
/** The server streams the bodies within this of the avatar by default (impact-server --aoi-m):
 * the view fits a little more than that. */
const AREA_M = 10;
const FLASH_MS = 300;
/** The velocity goes again this often: an input lost on the way is redone, and an avatar a ball
 * knocked takes the player's velocity again. */
const REPEAT_MS = 250;

const status = document.getElementById("status") as HTMLElement;
const canvas = document.getElementById("view") as HTMLCanvasElement;
const ctx = canvas.getContext("2d") as CanvasRenderingContext2D;
const panel = (id: string, text: string) => {
  const el = document.getElementById(id);
  if (el) el.textContent = text;
};

async function hello(): Promise<Hello> {
  const q = new URLSearchParams(location.search);
  const token = q.get("token");
  if (token) return { token };
  const user = q.get("user");
  if (user) return { world: q.get("world") ?? "arena", client: Number(q.get("client")), user, password: q.get("password") ?? "" };
  const r = await fetch("/guest", { method: "POST" });
  if (!r.ok) throw new Error(`no credentials in the address (?token= or ?user=), and ${(await r.text()).trim()}`);
  const guest = (await r.json()) as { token: string };
  return { token: guest.token };
}

const keys = new Set<string>();
addEventListener("keydown", (e) => keys.add(e.key.toLowerCase()));
addEventListener("keyup", (e) => keys.delete(e.key.toLowerCase()));
addEventListener("blur", () => keys.clear());
let mouse: [number, number] = [0, 0];
const clicks: [number, number][] = [];
canvas.addEventListener("mousemove", (e) => (mouse = [e.offsetX, e.offsetY]));
canvas.addEventListener("mousedown", (e) => {
  if (clicks.length < 4) clicks.push([e.offsetX, e.offsetY]);
});

/** The view from above: x to the right, z down, centred on `centre` (x, z), `scale` pixels a
 * metre so that the area streamed fits. */
class View {
  centre: [number, number] = [0, 0];
  scale = 12;
  fit(): void {
    this.scale = Math.max(4, Math.min(canvas.width, canvas.height) / 2 / (AREA_M * 1.2));
  }
  toScreen(x: number, z: number): [number, number] {
    return [canvas.width / 2 + (x - this.centre[0]) * this.scale, canvas.height / 2 + (z - this.centre[1]) * this.scale];
  }
  toWorld(sx: number, sy: number): [number, number] {
    return [this.centre[0] + (sx - canvas.width / 2) / this.scale, this.centre[1] + (sy - canvas.height / 2) / this.scale];
  }
}

async function main(): Promise<void> {
  const h = await hello();
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`;
  const conn = await Connection.open({ url, hello: h });
  const me = conn.ready?.client ?? 0;
  const game = new Session(sessionConfig(me));
  const view = new View();
  const flashes = new Map<number, number>(); // entity -> until (ms)
  const counts = { acked: 0, rejects: 0, events: 0, hits: 0, rays: 0, confirmed: 0, mismatched: 0 };
  let sent = { velocity: "", atMs: -Infinity };
  let second = { atMs: performance.now(), corrections: 0, bytes: 0 };
  const rtts: number[] = [];
  let drawn: { entity: number; position: Vec3; sx: number; sy: number; r: number }[] = [];

  /** The body drawn under a click (not the own avatar, not fixed), if any. */
  const picked = (sx: number, sy: number, avatar: number | null) => {
    let best: { position: Vec3; d: number } | null = null;
    for (const b of drawn) {
      if (b.entity === avatar) continue;
      const d = Math.hypot(b.sx - sx, b.sy - sy);
      if (d <= Math.max(b.r, 8) && (best === null || d < best.d)) best = { position: b.position, d };
    }
    return best?.position ?? null;
  };

  function play(now: number, avatar: number, at: Vec3): void {
    const v: Vec3 = [0, 0, 0];
    if (keys.has("a")) v[0] -= SPEED_MPS;
    if (keys.has("d")) v[0] += SPEED_MPS;
    if (keys.has("w")) v[2] -= SPEED_MPS;
    if (keys.has("s")) v[2] += SPEED_MPS;
    if (keys.has("q")) v[1] -= SPEED_MPS;
    if (keys.has("e")) v[1] += SPEED_MPS;
    const actions: Action[] = [];
    const key = v.join(",");
    // Held, standing still too: a ball that knocks the avatar does not send it drifting.
    if (key !== sent.velocity || now - sent.atMs > REPEAT_MS) {
      actions.push({ type: "set_velocity", entity: avatar, velocity: v });
    }
    for (const [sx, sy] of clicks.splice(0)) {
      // At the body clicked, wherever it is in height; else level, toward the point.
      const [wx, wz] = view.toWorld(sx, sy);
      const target = picked(sx, sy, avatar) ?? [wx, at[1], wz];
      const d: Vec3 = [target[0] - at[0], target[1] - at[1], target[2] - at[2]];
      const n = Math.hypot(...d);
      if (n < 1e-6) continue;
      actions.push({ type: "fire_ray", shooter: avatar, origin: at, direction: [d[0] / n, d[1] / n, d[2] / n], max_distance_m: RANGE_M });
    }
    if (actions.length > 0) {
      game.input(actions, now);
      sent = { velocity: key, atMs: now };
    }
  }

  function frame(now: number): void {
    canvas.width = canvas.clientWidth;
    canvas.height = canvas.clientHeight;
    view.fit();
    conn.pump(game);
    const avatar = game.avatar;
    const at = game.drawAvatar(now);
    if (at) view.centre = [at[0], at[2]];
    if (game.status === "playing" && avatar !== null && at) play(now, avatar, at);
    for (const a of game.takeAnswers()) {
      if (a.outcome.kind === "accepted" || a.outcome.kind === "ack_lost") counts.acked++;
      if (a.outcome.kind === "rejected") counts.rejects++;
      if (a.outcome.kind === "accepted") rtts.push(a.roundTripMs);
    }
    if (rtts.length > 64) rtts.splice(0, rtts.length - 64);
    for (const n of game.takeEventNews()) {
      if (n.kind !== "event") continue;
      counts.events++;
      const e = n.event;
      if (e.phase === "hit" && avatar !== null && (e.a === avatar || e.b === avatar)) {
        counts.hits++;
        status.dataset[e.a === avatar ? "hitLast" : "hitBy"] = String(e.a === avatar ? e.b : e.a);
        flashes.set(e.a, now + FLASH_MS);
        flashes.set(e.b, now + FLASH_MS);
      }
    }
    counts.rays += game.takeRayResults().length;
    counts.confirmed = game.events.matched + game.events.mismatched;
    counts.mismatched = game.events.mismatched;
    if (avatar !== null) status.dataset.avatar = String(avatar);
    draw(now, avatar, at);
    const closed = conn.closed ?? (game.closed ? { reason: `the world closed ${game.closed.reason}` } : null);
    const bodies = game.remote?.size ?? 0;
    const tick = game.clock.serverTick(now) ?? 0;
    status.textContent = closed
      ? `closed: ${closed.reason}`
      : game.status === "playing"
        ? `playing · client ${me} · tick ${tick} · ${bodies} bodies`
        : `${game.status} · client ${me}`;
    for (const [k, v] of Object.entries(counts)) status.dataset[k] = String(v);
    // Why the server turned inputs away (a `stale` input came too late for its tick, a `future` one
    // too early): the first thing to read when data-rejects is not 0.
    const reasons = Object.entries(game.stats.rejects)
      .map(([r, n]) => `${r}:${n}`)
      .join(" ");
    status.dataset.rejectReasons = reasons;
    if (at) [status.dataset.x, status.dataset.y, status.dataset.z] = at.map((c) => c.toFixed(2));
    status.dataset.scale = view.scale.toFixed(3);
    if (now - second.atMs >= 1000) {
      const sorted = [...rtts].sort((x, y) => x - y);
      const median = sorted[Math.floor(sorted.length / 2)];
      panel("ping", `ping ${median === undefined ? "-" : median.toFixed(0)} ms`);
      panel("lead", `lead ${(game.clock.lead ?? 0).toFixed(1)} ticks`);
      panel("corr", `${game.stats.corrections - second.corrections} corrections/s`);
      panel("bytes", `${((conn.bytesIn - second.bytes) / 1024).toFixed(1)} KiB/s in`);
      panel("rejects", reasons === "" ? "" : `rejected: ${reasons}`);
      second = { atMs: now, corrections: game.stats.corrections, bytes: conn.bytesIn };
    }
    requestAnimationFrame(frame);
  }

  function draw(now: number, avatar: number | null, at: Vec3 | null): void {
    ctx.font = "12px system-ui, sans-serif";
    ctx.fillStyle = "#151515";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    // Lowest first, so what is higher is drawn over it; brighter the higher.
    const bodies = game.drawRemote(now).sort((p, q) => p.position[1] - q.position[1]);
    drawn = [];
    let players = 0;
    for (const b of bodies) {
      if (b.entity === avatar) continue;
      const [sx, sy] = view.toScreen(b.position[0], b.position[2]);
      const [hx, , hz] = b.info.half_extents_m;
      if (b.info.fixed) {
        ctx.strokeStyle = "#444";
        ctx.strokeRect(sx - hx * view.scale, sy - hz * view.scale, hx * 2 * view.scale, hz * 2 * view.scale);
        continue;
      }
      const r = Math.max(hx * view.scale, 1.5);
      drawn.push({ entity: b.entity, position: b.position, sx, sy, r });
      const light = 35 + Math.min(Math.max(b.position[1], 0), 20) * 2;
      const flash = (flashes.get(b.entity) ?? 0) > now;
      ctx.fillStyle = flash ? "#fff" : b.info.class === "player" ? `hsl(35 80% ${light}%)` : b.info.class === "bolt" ? "#f55" : `hsl(210 45% ${light}%)`;
      ctx.beginPath();
      ctx.arc(sx, sy, r, 0, Math.PI * 2);
      ctx.fill();
      if (b.info.class === "player" && b.info.owner !== null) {
        players++;
        ctx.fillStyle = "#bbb";
        ctx.fillText(`player ${b.info.owner}`, sx + r + 3, sy + 4);
      }
    }
    status.dataset.players = String(players);
    if (at && avatar !== null) {
      const [sx, sy] = view.toScreen(at[0], at[2]);
      const r = (game.remote?.info(avatar)?.half_extents_m[0] ?? 0.5) * view.scale;
      // The area the server streams: nothing is drawn past it.
      ctx.strokeStyle = "#2a2a2a";
      ctx.beginPath();
      ctx.arc(sx, sy, AREA_M * view.scale, 0, Math.PI * 2);
      ctx.stroke();
      ctx.strokeStyle = "#7c5a";
      ctx.beginPath();
      ctx.moveTo(sx, sy);
      ctx.lineTo(mouse[0], mouse[1]);
      ctx.stroke();
      ctx.fillStyle = (flashes.get(avatar) ?? 0) > now ? "#fff" : "#7c5";
      ctx.beginPath();
      ctx.arc(sx, sy, r, 0, Math.PI * 2);
      ctx.fill();
      ctx.fillText("you", sx + r + 3, sy + 4);
    }
  }

  requestAnimationFrame(frame);
}

main().catch((e: unknown) => {
  status.textContent = `error: ${e instanceof Error ? e.message : String(e)}`;
  status.className = "error";
});
