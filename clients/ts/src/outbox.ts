// Sequence numbers and the inputs awaiting an answer (PROTOCOL.md: every input gets one `ack` or
// one `reject` carrying its `seq`). A port of the Rust client library's `inputs` module.
//
// Seqs start at 1 and go on at 1 after 4,294,967,295 (0 is never a seq); they compare as serial
// numbers (RFC 1982). Held inputs are keyed by their number unwrapped (a double holds it exactly),
// so the oldest stays the oldest across the wrap. Bounded: past `capacity` inputs awaiting an
// answer, the oldest are forgotten and counted.

const U32 = 2 ** 32;

/** Whether seq `a` comes before `b` (serial number order across the wrap). */
export function precedes(a: number, b: number): boolean {
  return a !== b && (b - a + U32) % U32 < 2 ** 31;
}

/** The seqs an ack's `accepted_before` bits name: bit k is seq - k - 1. */
export function acceptedBefore(seq: number, bits: bigint): number[] {
  const out: number[] = [];
  for (let k = 0; k < 64; k++) {
    if ((bits >> BigInt(k)) & 1n) {
      const s = (seq - k - 1 + U32) % U32;
      if (s !== 0) out.push(s);
    }
  }
  return out;
}

/** What the outbox remembers of a sent input. */
export interface Sent {
  /** When it was made (ms). */
  atMs: number;
  /** Its tick. */
  tick: number;
  /** Its view tick (ahead only). */
  view: number | null;
  /** When a message last carried it (ms). */
  carriedMs: number;
  /** The session's own input of no actions (KEEPALIVE_AFTER_MS): its answer is not the game's. */
  keepalive?: boolean;
}

const FIRST = U32 + 1;

export class Outbox {
  static readonly DEFAULT_CAPACITY = 1024;
  private next = FIRST;
  private readonly pending = new Map<number, Sent>();
  private numbered = false;
  /** Inputs forgotten unanswered past the bound. */
  forgotten = 0;

  constructor(readonly capacity = Outbox.DEFAULT_CAPACITY) {}

  /** The next seq. */
  nextSeq(): number {
    const seq = this.next % U32;
    this.next += seq === U32 - 1 ? 2 : 1;
    this.numbered = true;
    return seq;
  }

  private key(seq: number): number {
    const nextSeq = this.next % U32;
    let back = (nextSeq - seq + U32) % U32;
    if (back >= 2 ** 31) back -= U32;
    return this.next - back;
  }

  /**
   * The welcome's `next_seq`: ours go on from the further one. Inputs below it still awaiting an
   * answer stay awaited: the server answered each or never heard it, and the next ack tells.
   */
  resumeFrom(next: number): void {
    const at = this.numbered ? this.key(next) : FIRST - 1 + next;
    if (at > this.next) this.next = at + (at % U32 === 0 ? 1 : 0);
  }

  sent(seq: number, sent: Sent): void {
    this.pending.set(this.key(seq), sent);
    while (this.pending.size > this.capacity) {
      const oldest = Math.min(...this.pending.keys());
      this.pending.delete(oldest);
      this.forgotten++;
    }
  }

  /** The answer to `seq`: what was sent, once; undefined when not held. */
  answered(seq: number): Sent | undefined {
    const k = this.key(seq);
    const s = this.pending.get(k);
    this.pending.delete(k);
    return s;
  }

  carried(seq: number, atMs: number): void {
    const s = this.pending.get(this.key(seq));
    if (s) s.carriedMs = Math.max(s.carriedMs, atMs);
  }

  /** Takes the held inputs `lost` says never reached the server, oldest first. */
  takePending(lost: (seq: number, s: Sent) => boolean): [number, Sent][] {
    const out: [number, Sent][] = [];
    for (const k of [...this.pending.keys()].sort((a, b) => a - b)) {
      const s = this.pending.get(k)!;
      if (lost(k % U32, s)) {
        this.pending.delete(k);
        out.push([k % U32, s]);
      }
    }
    return out;
  }

  /** Whether any of the last `reach` seqs numbered is the game's input (not a keepalive)
   * awaiting an answer. */
  awaitsTheGames(reach: number): boolean {
    for (const [k, s] of this.pending) if (!s.keepalive && k >= this.next - reach) return true;
    return false;
  }

  /** Whether the game's input `seq` awaits an answer (a keepalive is the session's own). */
  awaits(seq: number): boolean {
    const s = this.pending.get(this.key(seq));
    return s !== undefined && !s.keepalive;
  }

  /** The game's inputs awaiting an answer (not keepalives). */
  get games(): number {
    let n = 0;
    for (const s of this.pending.values()) if (!s.keepalive) n++;
    return n;
  }

  get size(): number {
    return this.pending.size;
  }
}
