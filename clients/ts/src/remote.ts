// The remote world (a port of the Rust client library's `remote`): the bodies a state stream
// shows, kept as samples of where each was and how it moved, and drawn at a render tick: the
// clock's estimate of the server's present less the interpolation delay (100 ms by default).
//
// Between a sample at or before the render tick and the next: the two carried paths (the first
// forward at its velocity, the next back at its) are the same when nothing changed the body,
// meet where it collided (drawn on each side of the meeting), or are blended when it was pushed.
// After the last sample: carried forward, extrapolated at most `maxExtrapolationS` past the
// stream's newest tick, then held. Before the first: carried back, unless game logic teleported
// it into view. Across a teleport: each side on its own path, never between.
//
// The stream's rules (PROTOCOL.md, "State streams"): a full frame replaces what is held, a delta
// applies to the frame before it, and after a gap deltas are ignored until a full frame
// (`needsFullFrame`). Bounded: `maxBodies` bodies, `history` samples each.

import type { BodyInfo, BodyMotion, StateFrame, Vec3 } from "./messages.js";

export interface RemoteConfig {
  tickHz: number;
  delayS: number;
  maxExtrapolationS: number;
  maxBodies: number;
  history: number;
}

export const remoteConfig = (tickHz: number): RemoteConfig => ({
  tickHz,
  delayS: 0.1,
  maxExtrapolationS: 0.25,
  maxBodies: 65_536,
  history: 32,
});

interface Sample {
  tick: number;
  position: Vec3;
  velocity: Vec3;
  asleep: boolean;
  teleported: number | undefined;
  /** Up to this tick the body was on the previous sample's path: the tick of the frame just
   * before the one that carried this sample, when that frame held nothing back. */
  vouched: number | undefined;
}

const at = (s: Sample, t: number, dt: number): Vec3 => {
  const k = (t - s.tick) * dt;
  return [s.position[0] + s.velocity[0] * k, s.position[1] + s.velocity[1] * k, s.position[2] + s.velocity[2] * k];
};

const mix = (a: Vec3, b: Vec3, f: number): Vec3 => [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f];

/** Carried paths closer than this where they pass are taken to meet (a collision), metres. */
export const CROSSING_M = 0.01;

/** The tick after which the motion changed between samples `a` and `n`. */
const changedAfter = (a: Sample, n: Sample): number =>
  n.vouched === undefined ? a.tick : Math.min(Math.max(n.vouched, a.tick), n.tick);

/** The tick between `from` and sample `n` at which the carried paths of `a` and `n` come within
 * CROSSING_M. */
function crossing(a: Sample, n: Sample, from: number, dt: number): number | null {
  const pa = at(a, from, dt);
  const pn = at(n, from, dt);
  const d0 = [pa[0] - pn[0], pa[1] - pn[1], pa[2] - pn[2]];
  const dv = [0, 1, 2].map((k) => (a.velocity[k]! - n.velocity[k]!) * dt);
  const vv = dv.reduce((s, x) => s + x * x, 0);
  if (vv === 0) return null;
  const t = Math.min(Math.max(from - (d0[0]! * dv[0]! + d0[1]! * dv[1]! + d0[2]! * dv[2]!) / vv, from), n.tick);
  const gap = Math.hypot(...[0, 1, 2].map((k) => d0[k]! + dv[k]! * (t - from)));
  return gap <= CROSSING_M ? t : null;
}

/** A body as drawn. */
export interface DrawnBody {
  entity: number;
  position: Vec3;
  velocity: Vec3;
  /** Drawn past the stream's newest tick. */
  extrapolated: boolean;
  /** Between two samples that agree (the server's own motion). */
  steady: boolean;
  asleep: boolean;
  info: BodyInfo;
}

export type Applied = "applied" | "gap" | "stale";

export class RemoteWorld {
  private readonly bodies = new Map<number, { info: BodyInfo; samples: Sample[] }>();
  private expected: number | null = null;
  private newest: number | null = null;
  /** The tick of the last frame applied, when it held nothing back. */
  private clean: number | undefined = undefined;
  readonly stats = { frames: 0, fullFrames: 0, gaps: 0, ignored: 0, overCapacity: 0, unknownBodies: 0 };

  constructor(readonly config: RemoteConfig) {}

  get newestTick(): number | null {
    return this.newest;
  }

  /** After a gap, until a full frame. */
  get needsFullFrame(): boolean {
    return this.expected === null;
  }

  get size(): number {
    return this.bodies.size;
  }

  info(entity: number): BodyInfo | undefined {
    return this.bodies.get(entity)?.info;
  }

  /**
   * Applies the next frame, in arrival order. Ticks only go forward along a stream, so a frame at
   * a tick no newer than the newest applied is a repeat or late, whatever its number; the numbers
   * tell gaps (a stream taken up anew, back from a drop or after a takeover, numbers from 0 again
   * at newer ticks: its first delta, its full frame lost, is a gap).
   */
  apply(frame: StateFrame): Applied {
    if (this.newest !== null && frame.tick <= this.newest) {
      this.stats.ignored++;
      return "stale";
    }
    // The frame before vouches for the paths up to its tick if it came just before and held
    // nothing back.
    const vouched = this.expected === frame.frame ? this.clean : undefined;
    if (!frame.full) {
      if (this.expected === null) {
        this.stats.ignored++;
        return "gap";
      }
      if (frame.frame !== this.expected) {
        this.stats.ignored++;
        this.stats.gaps++;
        this.expected = null;
        return "gap";
      }
    } else {
      const listed = new Set([...frame.moved.map((m) => m[0]), ...frame.entered.map((i) => i.entity)]);
      for (const e of [...this.bodies.keys()]) if (!listed.has(e)) this.bodies.delete(e);
      this.stats.fullFrames++;
    }
    for (const info of frame.entered) {
      const b = this.bodies.get(info.entity);
      if (b) b.info = info;
      else if (this.bodies.size < this.config.maxBodies) this.bodies.set(info.entity, { info, samples: [] });
      else this.stats.overCapacity++;
    }
    for (const m of frame.moved) this.record(frame.tick, m, vouched);
    for (const e of frame.left) if (!this.bodies.delete(e)) this.stats.unknownBodies++;
    this.expected = (frame.frame + 1) % 2 ** 32;
    this.newest = Math.max(this.newest ?? frame.tick, frame.tick);
    this.clean = frame.deferred === 0 ? frame.tick : undefined;
    this.stats.frames++;
    return "applied";
  }

  private record(tick: number, [entity, p, v, asleep]: BodyMotion, vouched: number | undefined): void {
    const b = this.bodies.get(entity);
    if (!b || ![...p, ...v].every(Number.isFinite)) {
      this.stats.unknownBodies++;
      return;
    }
    while (b.samples.length > 0 && b.samples[b.samples.length - 1]!.tick >= tick) b.samples.pop();
    b.samples.push({ tick, position: [...p], velocity: [...v], asleep, teleported: b.info.teleported, vouched });
    while (b.samples.length > Math.max(this.config.history, 1)) b.samples.shift();
  }

  /** Every body at `renderTick`. */
  draw(renderTick: number): DrawnBody[] {
    const out: DrawnBody[] = [];
    for (const [e, b] of this.bodies) {
      const d = this.drawn(e, b, renderTick);
      if (d) out.push(d);
    }
    return out;
  }

  private drawn(entity: number, b: { info: BodyInfo; samples: Sample[] }, renderTick: number): DrawnBody | null {
    const first = b.samples[0];
    if (this.newest === null || !first) return null;
    const newest = this.newest;
    const dt = 1 / Math.max(this.config.tickHz, 1);
    const r = Math.min(renderTick, newest + this.config.maxExtrapolationS * Math.max(this.config.tickHz, 1));
    let after = b.samples.findIndex((s) => s.tick > r);
    if (after < 0) after = b.samples.length;
    const a = after > 0 ? b.samples[after - 1] : undefined;
    const n = b.samples[after];
    let position: Vec3;
    let velocity: Vec3;
    let steady = false;
    if (!a) {
      if (first.teleported !== undefined && r <= first.teleported) return null;
      [position, velocity] = [at(first, r, dt), first.velocity];
    } else if (n && a.teleported !== n.teleported) {
      const before = n.teleported !== undefined && r <= n.teleported;
      [position, velocity] = before ? [at(a, r, dt), a.velocity] : [at(n, r, dt), n.velocity];
    } else if (!n) {
      [position, velocity, steady] = [at(a, r, dt), a.velocity, r <= newest];
    } else {
      const pa = at(a, r, dt);
      const pn = at(n, r, dt);
      const lo = changedAfter(a, n);
      if (a.velocity.every((x, k) => x === n.velocity[k])) {
        [position, velocity, steady] = [mix(pa, pn, (r - a.tick) / (n.tick - a.tick)), a.velocity, true];
      } else if (r <= lo) {
        // Up to the frame before n's the stream vouched for a's path.
        [position, velocity, steady] = [pa, a.velocity, true];
      } else {
        const tc = crossing(a, n, lo, dt);
        if (tc === null) [position, velocity] = [mix(pa, pn, (r - lo) / (n.tick - lo)), a.velocity];
        else [position, velocity] = r <= tc ? [pa, a.velocity] : [pn, n.velocity];
      }
    }
    const asleep = a ? a.asleep : first.asleep;
    return { entity, position, velocity, extrapolated: renderTick > newest, steady, asleep, info: b.info };
  }
}
