// The client's clock (PROTOCOL.md, "Timing"): its estimate of the server's tick, and the tick to
// stamp an input with. A port of the Rust client library's `clock` module; times are
// milliseconds on a monotonic clock the caller passes in (`performance.now()`): nothing here
// reads a clock.
//
// Anchored by the welcome, it counts ticks from there. Every message naming the server's tick is
// an observation: more than RESYNC_TICKS ahead re-anchors at once (no message arrives before it
// was sent); that far behind is a late message (the page or the path stalled) or a server that
// fell behind wall time, and only the second goes on naming old ticks, so the clock follows them
// back once they have for SLIP_CONFIRM_TICKS of its own time, to the least late of them; a
// smaller drift is followed once per DRIFT_WINDOW_MS when every observation in the window
// agrees. Inputs are stamped behind (the tick seen) or ahead by the lead the acks recommend,
// reached by time dilation (at most DILATION of the ticks elapsed), lowered at once by a `future`
// reject (`backOff`).

/** The most the stamped ticks run fast or slow to reach a new lead: 10 %. */
export const DILATION = 0.1;
/** How far the clock may be from a tick the server names before it re-anchors. */
export const RESYNC_TICKS = 4;
/** How long (ticks of the client's own time) observations past RESYNC_TICKS behind must go on
 * coming before the clock follows them back: what queued while a page was stalled arrives at
 * once, then a timely message; a server that fell behind names old ticks in every message. */
export const SLIP_CONFIRM_TICKS = 2;
/** The window over which a small drift must agree before the clock follows it. */
export const DRIFT_WINDOW_MS = 1000;

export class Clock {
  private anchorAt: { tick: number; atMs: number; hz: number } | null = null;
  private drift: { startMs: number; hi: number; lo: number } | null = null;
  private behind: { sinceMs: number; tick: number; atMs: number; off: number } | null = null;
  private leadNow: number | null = null;
  private leadTarget = 0;
  private leadAtMs: number | null = null;

  /** The server was at `tick`, ticking at `tickHz`, at `nowMs`. The lead is kept. */
  anchor(tick: number, tickHz: number, nowMs: number): void {
    this.anchorAt = { tick, atMs: nowMs, hz: Math.max(tickHz, 1) };
    this.drift = null;
    this.behind = null;
  }

  get anchored(): boolean {
    return this.anchorAt !== null;
  }

  get tickHz(): number | null {
    return this.anchorAt?.hz ?? null;
  }

  /** The server's tick at `nowMs`, fractional; null before the welcome. */
  serverTicks(nowMs: number): number | null {
    const a = this.anchorAt;
    if (!a) return null;
    return a.tick + (Math.max(0, nowMs - a.atMs) / 1000) * a.hz;
  }

  /** The server's tick at `nowMs`. */
  serverTick(nowMs: number): number | null {
    const t = this.serverTicks(nowMs);
    return t === null ? null : Math.floor(t);
  }

  /** The server named `tick` at `nowMs`: true when that re-anchored the clock. */
  observe(tick: number, nowMs: number): boolean {
    const est = this.serverTick(nowMs);
    const a = this.anchorAt;
    if (est === null || !a) return false;
    const off = tick - est;
    if (off > RESYNC_TICKS) {
      this.anchor(tick, a.hz, nowMs);
      return true;
    }
    if (off < -RESYNC_TICKS) {
      const b = (this.behind ??= { sinceMs: nowMs, tick, atMs: nowMs, off });
      if (off > b.off) Object.assign(b, { tick, atMs: nowMs, off });
      if (((nowMs - b.sinceMs) / 1000) * a.hz < SLIP_CONFIRM_TICKS) return false;
      this.anchor(b.tick, a.hz, b.atMs);
      return true;
    }
    this.behind = null;
    const w = (this.drift ??= { startMs: nowMs, hi: off, lo: off });
    w.hi = Math.max(w.hi, off);
    w.lo = Math.min(w.lo, off);
    if (nowMs - w.startMs >= DRIFT_WINDOW_MS) {
      this.drift = null;
      const shift = w.hi < 0 ? w.hi : Math.max(w.lo, 0);
      if (shift !== 0) this.anchorAt = { tick: Math.max(a.tick + shift, 0), atMs: a.atMs, hz: a.hz };
    }
    return false;
  }

  /** The server recommends a lead (ticks): the first is taken at once, later ones by dilation. */
  recommend(lead: number): void {
    this.leadTarget = lead;
    if (this.leadNow === null) this.leadNow = lead;
  }

  get lead(): number | null {
    return this.leadNow;
  }

  /** How fast stamped ticks run against the server's: 1 ± DILATION while the lead moves. */
  stampRate(ahead: boolean): number {
    if (!ahead || this.leadNow === null) return 1;
    return 1 + Math.min(Math.max(this.leadTarget - this.leadNow, -DILATION), DILATION);
  }

  /** A `future` reject of an input stamped `tick` at view `view`, the server's newest allowed
   * tick `newest`, `acceptedAhead` past its present (the welcome's `input_lead_ticks`): the lead
   * drops at once to what would have fitted, however far past it was. A view past the server's
   * present by more than the resync bound is the server's tick jumping back, not the lead. */
  backOff(tick: number, view: number, newest: number, acceptedAhead: number): void {
    if (tick <= newest || view > newest - acceptedAhead + RESYNC_TICKS || this.leadNow === null) return;
    const most = newest - view - 1;
    this.leadNow = Math.min(this.leadNow, Math.max(most, 0));
    this.leadTarget = Math.min(this.leadTarget, this.leadNow);
  }

  /** The tick to stamp an input made at `nowMs` with, and the tick seen; null before the welcome. */
  stamp(ahead: boolean, nowMs: number): { tick: number; view: number } | null {
    const view = this.serverTick(nowMs);
    if (view === null) return null;
    if (!ahead || this.leadNow === null) return { tick: view, view };
    const hz = this.tickHz ?? 64;
    const elapsed = this.leadAtMs === null ? 0 : (Math.max(0, nowMs - this.leadAtMs) / 1000) * hz;
    const step = DILATION * elapsed;
    const lead = this.leadNow + Math.min(Math.max(this.leadTarget - this.leadNow, -step), step);
    this.leadNow = lead;
    this.leadAtMs = nowMs;
    return { tick: view + Math.max(0, Math.round(lead)), view };
  }
}
