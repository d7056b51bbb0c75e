// The event view (a port of the Rust client library's `events`): a client's collision events as
// they stand. Provisional `events` batches apply as they come, then `corrections` by event
// identity (tick, a, b, phase); when a tick is confirmed its view is compared with the confirmed
// batch and the tick leaves the view, with every earlier tick still held: confirmations come in
// tick order, and a client's own stream carries a tick's batch only when one of its confirmed
// events involves the client, so an earlier tick with no batch of its own is final with no events
// for it. A tick made final that way while its view still held events is in doubt (its own batch
// may have been lost on the way): held apart until the batch the server kept comes (asked for
// through the gateway, or the stream's late copy) or the session gives up on it. Bounded: at most
// MAX_TICKS ticks held, MAX_DOUBTFUL in doubt.

import type { CollisionEvent, CorrectionBatch, EventBatch } from "./messages.js";

/** The most ticks held (about 16 s at 64 Hz). */
export const MAX_TICKS = 1024;

/** The most ticks in doubt at once; past it a tick is compared at once, with no events. */
export const MAX_DOUBTFUL = 64;

type Final = { tick: number; matched: boolean };

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
  /** Ticks made final by a later tick's confirmation, with no batch of their own (also counted in
   * matched, mismatched or unverified). */
  implied = 0;
  /** Ticks in doubt that the batch the server kept made final. */
  recovered = 0;
  private lostBeforeTick: number | null = null;
  private readonly doubt = new Map<number, Map<string, CollisionEvent>>();

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

  /** Makes a confirmed tick final, after every earlier tick still held (compared with no events,
   * or put in doubt if it held events): each tick made final, oldest first, with whether the view
   * equalled the server's record. The batch of a tick in doubt makes it final alone. */
  confirm(b: EventBatch): Final[] {
    const doubted = this.doubt.get(b.tick);
    if (doubted) {
      this.doubt.delete(b.tick);
      this.recovered++;
      return [{ tick: b.tick, matched: this.compare(b.tick, doubted, b.events) }];
    }
    const finals: Final[] = [];
    for (const tick of [...this.ticks.keys()].filter((t) => t < b.tick).sort((x, y) => x - y)) {
      this.implied++;
      const mine = this.take(tick);
      const verified = this.lostBeforeTick === null || tick >= this.lostBeforeTick;
      if (verified && mine.size > 0 && this.doubt.size < MAX_DOUBTFUL) this.doubt.set(tick, mine);
      else finals.push({ tick, matched: this.compare(tick, mine, []) });
    }
    finals.push({ tick: b.tick, matched: this.compare(b.tick, this.take(b.tick), b.events) });
    return finals;
  }

  /** The ticks in doubt, oldest first. */
  doubtful(): number[] {
    return [...this.doubt.keys()].sort((x, y) => x - y);
  }

  /** Gives up on a tick in doubt: final with no events for this client. */
  giveUp(tick: number): Final[] {
    const mine = this.doubt.get(tick);
    if (!mine) return [];
    this.doubt.delete(tick);
    return [{ tick, matched: this.compare(tick, mine, []) }];
  }

  private take(tick: number): Map<string, CollisionEvent> {
    const mine = this.ticks.get(tick) ?? new Map<string, CollisionEvent>();
    this.ticks.delete(tick);
    return mine;
  }

  private compare(tick: number, mine: Map<string, CollisionEvent>, confirmed: CollisionEvent[]): boolean {
    if (this.lostBeforeTick !== null && tick < this.lostBeforeTick) {
      this.unverified++;
      return false;
    }
    const ok = mine.size === confirmed.length && confirmed.every((e) => {
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
