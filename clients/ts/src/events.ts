// The event view (a port of the Rust client library's `events`): a client's collision events as
// they stand. Provisional `events` batches apply as they come, then `corrections` by event
// identity (tick, a, b, phase); when a tick is confirmed its view is compared with the confirmed
// batch and the tick leaves the view. Bounded: at most MAX_TICKS ticks held.

import type { CollisionEvent, CorrectionBatch, EventBatch } from "./messages.js";

/** The most ticks held (about 16 s at 64 Hz). */
export const MAX_TICKS = 1024;

const key = (e: CollisionEvent): string => `${e.tick}/${e.a}/${e.b}/${e.phase}`;

function same(a: CollisionEvent, b: CollisionEvent): boolean {
  const close = (x: number[], y: number[]) => x.every((p, i) => Math.abs(p - (y[i] ?? NaN)) <= 1e-6);
  return Math.abs(a.toi - b.toi) <= 1e-9 && close(a.point, b.point) && close(a.normal, b.normal) && a.response === b.response;
}

export class EventView {
  private readonly ticks = new Map<number, Map<string, CollisionEvent>>();
  /** Ticks whose view equalled the confirmed batch. */
  matched = 0;
  /** Ticks whose view differed. */
  mismatched = 0;
  corrections = 0;
  /** Ticks forgotten unconfirmed past MAX_TICKS. */
  forgotten = 0;
  /** Confirmed ticks not compared because the link was lost before them. */
  unverified = 0;
  private lostBeforeTick: number | null = null;

  private tick(tick: number): Map<string, CollisionEvent> {
    let t = this.ticks.get(tick);
    if (!t) {
      if (this.ticks.size >= MAX_TICKS) {
        this.ticks.delete(Math.min(...this.ticks.keys()));
        this.forgotten++;
      }
      t = new Map();
      this.ticks.set(tick, t);
    }
    return t;
  }

  events(b: EventBatch): void {
    const t = this.tick(b.tick);
    for (const e of b.events) t.set(key(e), e);
  }

  correct(c: CorrectionBatch): void {
    this.corrections++;
    const t = this.tick(c.tick);
    for (const e of c.retracted) t.delete(key(e));
    for (const e of [...c.amended, ...c.added]) t.set(key(e), e);
  }

  /** The link came back with the server at about `tick`: earlier ticks are not compared. */
  lostBefore(tick: number): void {
    this.lostBeforeTick = Math.max(this.lostBeforeTick ?? tick, tick);
  }

  /** Compares a confirmed tick with the view and forgets it: whether they were equal. */
  confirm(b: EventBatch): boolean {
    const mine = this.ticks.get(b.tick) ?? new Map<string, CollisionEvent>();
    this.ticks.delete(b.tick);
    if (this.lostBeforeTick !== null && b.tick < this.lostBeforeTick) {
      this.unverified++;
      return false;
    }
    const ok = mine.size === b.events.length && b.events.every((e) => {
      const m = mine.get(key(e));
      return m !== undefined && same(m, e);
    });
    if (ok) this.matched++;
    else this.mismatched++;
    return ok;
  }

  newest(): number | null {
    return this.ticks.size === 0 ? null : Math.max(...this.ticks.keys());
  }

  get held(): number {
    return this.ticks.size;
  }

  /** The events of an unconfirmed tick as they stand. */
  at(tick: number): CollisionEvent[] {
    return [...(this.ticks.get(tick)?.values() ?? [])];
  }
}
