// A client's whole side of the protocol as one state machine (a port of the Rust client
// library's `Session`): fed with the messages the transport received and the local clock, giving
// the messages to send and plain data to draw. No I/O, no timers: `src/gateway.ts` drives it over
// a WebSocket, a test drives it with scripted messages.
//
// Joining -> (welcome) Syncing: time-sync pings until SYNC_PROBES pongs or SYNC_TIMEOUT_MS ->
// Playing: inputs stamped ahead by the lead (or behind), each sent with the unanswered ones
// before it (redundancy), answered by seq (accepted, rejected with a reason, or known lost) ->
// Closed when the world closes. The event view takes events, corrections and confirmations; the
// remote world takes state frames and is drawn at the render tick; the own avatar is predicted
// from the last state the server streamed of it and the velocities the player's inputs set since,
// with corrections eased in (full prediction with the core waits for a wasm target).

import { Clock } from "./clock.js";
import { EventView } from "./events.js";
import type {
  Action,
  AvatarState,
  ClientInput,
  ClientMessage,
  CollisionEvent,
  CorrectionBatch,
  RayResult,
  RejectReason,
  ServerMessage,
  Vec3,
  Welcome,
} from "./messages.js";
import { Outbox, acceptedBefore, precedes, type Sent } from "./outbox.js";
import { RemoteWorld, remoteConfig, type DrawnBody } from "./remote.js";

export const SYNC_PROBES = 5;
export const SYNC_TIMEOUT_MS = 2000;
export const PROBE_TIMEOUT_MS = 250;
/** The game's inputs awaiting an answer while it makes none for this long: the session sends an
 * input of no actions (a keepalive, `stats.keepalives`), again each time this passes, until none
 * of the game's awaits one. An input is known lost only by the ack of a later one, so one sent
 * just before the game fell idle, into a server that stood still or a link that dropped it,
 * would otherwise wait forever. Only inputs an ack can tell about bring them: within
 * KEEPALIVE_REACH seqs of the next (an ack's `accepted_before` covers 64), so an idle game sends
 * at most 64 for one input. */
export const KEEPALIVE_AFTER_MS = 1000;
export const KEEPALIVE_REACH = 64;
export const FULL_FRAME_EVERY_MS = 250;
export const MAX_OUTGOING = 256;
export const MAX_ANSWERS = 1024;
export const MAX_NEWS = 4096;
/** How long a tick in doubt waits for the batch the server kept before it is taken as empty. */
export const RECOVERY_WAIT_MS = 2000;
export const MAX_RAY_RESULTS = 256;
/** Inputs per message at most (the protocol's limit), and actions per input. */
export const MAX_INPUTS_PER_MESSAGE = 4;
export const MAX_ACTIONS_PER_INPUT = 16;
/** How fast a correction of the own avatar is eased in: the offset shrinks by e every 1/rate s. */
export const CORRECTION_RATE_PER_S = 12;

export type Status = "joining" | "syncing" | "playing" | "closed";

export type Outcome =
  | { kind: "accepted"; appliedTick: number; marginTicks: number }
  | { kind: "ack_lost" } // accepted: a later ack said so, its own was lost
  | { kind: "rejected"; reason: RejectReason }
  | { kind: "lost" }; // never reached the server: send its actions again if they still matter

export interface Answer {
  seq: number;
  tick: number;
  sentMs: number;
  roundTripMs: number;
  outcome: Outcome;
}

export type EventNews =
  | { kind: "event"; event: CollisionEvent }
  | { kind: "corrected"; batch: CorrectionBatch }
  | { kind: "confirmed"; tick: number; matched: boolean };

export interface SessionConfig {
  client: number;
  /** Stamp inputs ahead (the default) or behind. */
  ahead: boolean;
  /** Unanswered inputs sent again with each new one (at most 3). */
  redundancy: number;
  /** The interpolation delay of the remote world, seconds. */
  interpolationDelayS: number;
}

export const sessionConfig = (client: number): SessionConfig => ({ client, ahead: true, redundancy: 3, interpolationDelayS: 0.1 });

export class InputError extends Error {}

export class Session {
  readonly clock = new Clock();
  readonly events = new EventView();
  remote: RemoteWorld | null = null;
  status: Status = "joining";
  welcome: Welcome | null = null;
  closed: { world: string; next: string | null; reason: string } | null = null;
  readonly stats = {
    welcomes: 0,
    inputsSent: 0,
    /** Inputs of no actions the session sent itself (counted in inputsSent too). */
    keepalives: 0,
    inputsAcked: 0,
    acksRecovered: 0,
    inputsLost: 0,
    rejects: {} as Partial<Record<RejectReason, number>>,
    unmatchedAnswers: 0,
    events: 0,
    corrections: 0,
    stateFrames: 0,
    rayResults: 0,
    hits: 0,
    malformed: 0,
    clockResyncs: 0,
    syncRttMinMs: 0,
    syncRttMaxMs: 0,
    fullFramesAsked: 0,
    outgoingDropped: 0,
    linksRestored: 0,
  };

  private readonly outbox = new Outbox();
  private resend: ClientInput[] = [];
  private outgoing: ClientMessage[] = [];
  private answers: Answer[] = [];
  private news: EventNews[] = [];
  private rays: RayResult[] = [];
  private samples: { rttMs: number; tick: number; atMs: number }[] = [];
  private probe: { id: number; atMs: number } | null = null;
  private nextProbe = 1;
  private syncStartedMs: number | null = null;
  private fullAskedMs: number | null = null;
  /** After a second welcome: the inputs it left unaccepted, answered lost once an input made
   * after it is acked. */
  private lostCheck: { welcomedMs: number; nextSeq: number } | null = null;
  /** When the last input was made (the game's or a keepalive). */
  private lastInputMs: number | null = null;
  /** After a restored link: the server's present then, as estimated; see `publishedAt`. */
  private pathCheck: number | null = null;
  /** The link was restored before the welcome, with no estimate of the server's present to say
   * which ticks it lost: until the welcome gives one, each tick an events message names is taken
   * as lost up to it, and the welcome restores the link again with its present. */
  private lostUnwelcomed = false;
  /** The newest tick the server named, and when: run on at the full rate for `linkRestored`. */
  private newestNamed: { tick: number; atMs: number } | null = null;
  /** The event view's ticks in doubt: since when, and whether the transport was given it. */
  private recovery = new Map<number, { sinceMs: number; asked: boolean }>();
  /** The own avatar: the last state streamed, and the velocities set since, by tick. */
  private avatarState: { tick: number; position: Vec3; velocity: Vec3 } | null = null;
  private velocities: { tick: number; velocity: Vec3 }[] = [];
  private correction: { offset: Vec3; atMs: number } = { offset: [0, 0, 0], atMs: 0 };
  private lastDrawn: { tick: number; position: Vec3 } | null = null;

  constructor(readonly config: SessionConfig) {}

  /** The own avatar's entity, once welcomed with one. */
  get avatar(): number | null {
    return this.welcome?.avatar ?? null;
  }

  /** The game's inputs awaiting an answer (the session's keepalives are not counted). */
  get pendingInputs(): number {
    return this.outbox.games;
  }

  /** A message that did not decode. */
  malformed(): void {
    this.stats.malformed++;
  }

  /** Feeds one message received at `nowMs`. */
  receive(msg: ServerMessage, nowMs: number): void {
    const me = this.config.client;
    switch (msg.type) {
      case "welcome":
        if (msg.client === me) this.welcomed(msg, nowMs);
        return;
      case "pong":
        if (msg.client !== me || this.status !== "syncing" || !this.probe || this.probe.id !== msg.id) return;
        this.samples.push({ rttMs: nowMs - this.probe.atMs, tick: msg.server_tick, atMs: nowMs });
        this.probe = null;
        if (this.samples.length >= SYNC_PROBES) this.startPlaying();
        return;
      case "ack": {
        if (msg.client !== me) return;
        this.observe(msg.server_tick, nowMs);
        this.clock.recommend(msg.lead_ticks);
        this.resend = this.resend.filter((i) => i.seq !== msg.seq);
        const sent = this.outbox.answered(msg.seq);
        if (sent) {
          this.stats.inputsAcked++;
          this.answered(msg.seq, sent, { kind: "accepted", appliedTick: msg.applied_tick, marginTicks: msg.margin_ticks }, nowMs);
        } else this.stats.unmatchedAnswers++;
        for (const seq of acceptedBefore(msg.seq, msg.accepted_before)) {
          const s = this.outbox.answered(seq);
          if (!s) continue;
          this.resend = this.resend.filter((i) => i.seq !== seq);
          this.stats.inputsAcked++;
          this.stats.acksRecovered++;
          this.answered(seq, s, { kind: "ack_lost" }, nowMs);
        }
        if (sent) {
          this.lostBefore(msg.seq, msg.accepted_before, sent.atMs, nowMs);
          this.ackedAfter(sent.atMs, nowMs);
        }
        return;
      }
      case "reject": {
        if (msg.client !== me) return;
        this.stats.rejects[msg.reason] = (this.stats.rejects[msg.reason] ?? 0) + 1;
        if (msg.seq === null) return;
        const seq = msg.seq;
        this.resend = this.resend.filter((i) => i.seq !== seq);
        const sent = this.outbox.answered(seq);
        if (sent) {
          if (msg.reason === "future" && msg.tick !== null && msg.newest_tick !== null && sent.view !== null) {
            this.clock.backOff(msg.tick, sent.view, msg.newest_tick, this.welcome?.input_lead_ticks ?? 0);
          }
          this.answered(seq, sent, { kind: "rejected", reason: msg.reason }, nowMs);
        } else if (msg.reason !== "unknown_entity" && msg.reason !== "not_owner") this.stats.unmatchedAnswers++;
        return;
      }
      case "events":
        if (this.lostUnwelcomed) this.events.lostBefore(msg.tick + 1);
        this.observe(msg.tick, nowMs);
        this.stats.events += msg.events.length;
        this.events.events(msg);
        for (const event of msg.events) this.pushNews({ kind: "event", event });
        return;
      case "corrections":
        if (this.lostUnwelcomed) this.events.lostBefore(msg.tick + 1);
        this.stats.corrections++;
        this.events.correct(msg);
        this.pushNews({ kind: "corrected", batch: msg });
        return;
      case "confirmed": {
        // Published as the tick left the server's rollback window.
        if (this.welcome) this.publishedAt(msg.tick + this.welcome.window_ticks);
        if (this.lostUnwelcomed) this.events.lostBefore(msg.tick + 1);
        for (const f of this.events.confirm(msg)) this.pushNews({ kind: "confirmed", ...f });
        const doubtful = this.events.doubtful();
        for (const t of this.recovery.keys()) if (!doubtful.includes(t)) this.recovery.delete(t);
        for (const t of doubtful) if (!this.recovery.has(t)) this.recovery.set(t, { sinceMs: nowMs, asked: false });
        return;
      }
      case "ray_result":
        if (msg.client !== me) return;
        this.stats.rayResults++;
        if (msg.hit) this.stats.hits++;
        if (this.rays.length >= MAX_RAY_RESULTS) this.rays.shift();
        this.rays.push(msg);
        return;
      case "state":
        this.stats.stateFrames++;
        this.observe(msg.tick, nowMs);
        this.remote?.apply(msg);
        if (msg.avatar) this.reconcile(msg.tick, msg.avatar, nowMs);
        return;
      case "closed":
        this.status = "closed";
        this.outgoing = [];
        this.resend = [];
        this.closed = { world: msg.world, next: msg.next, reason: msg.reason };
        return;
      default:
        return;
    }
  }

  /** The link to the server was lost and is back (the gateway's `link_restored`, or a
   * reconnect): ticks before the server's present are not compared with the view. The client's
   * link being back does not mean the server's is (each side of a restarted router reconnects in
   * its own time): the ticks before the server's present when it published the first message
   * heard since are not compared either. */
  linkRestored(nowMs: number): void {
    this.stats.linksRestored++;
    this.restoredAt(nowMs);
  }

  /** Ticks before the server's present at `nowMs`, as estimated, are not compared; before the
   * welcome, with no estimate, until it comes (`lostUnwelcomed`). */
  private restoredAt(nowMs: number): void {
    const MARGIN_TICKS = 8;
    const hz = this.clock.tickHz ?? 0;
    const runOn = this.newestNamed ? this.newestNamed.tick + ((nowMs - this.newestNamed.atMs) / 1000) * hz : null;
    const newest = this.events.newest();
    const t = Math.max(this.clock.serverTick(nowMs) ?? -1, newest === null ? -1 : newest + 1, runOn === null ? -1 : Math.floor(runOn));
    if (t >= 0) {
      this.events.lostBefore(t + MARGIN_TICKS);
      this.pathCheck = t;
    }
    if (!this.clock.anchored) this.lostUnwelcomed = true;
  }

  /** A message published when the server was at `present` arrived: the first since a restored
   * link published at or past the estimate then shows the path whole again, and every tick
   * before `present` may have lost events. */
  private publishedAt(present: number): void {
    if (this.pathCheck !== null && present >= this.pathCheck) {
      this.pathCheck = null;
      this.events.lostBefore(present);
    }
  }

  /** The remote world's render tick at `nowMs`: the server's present less the delay. */
  renderTick(nowMs: number): number | null {
    const t = this.clock.serverTicks(nowMs);
    if (t === null || !this.remote) return null;
    return t - this.config.interpolationDelayS * this.remote.config.tickHz;
  }

  /** The remote world as it is to be drawn at `nowMs`. */
  drawRemote(nowMs: number): DrawnBody[] {
    const r = this.renderTick(nowMs);
    return r === null || !this.remote ? [] : this.remote.draw(r);
  }

  /** The own avatar as predicted at the tick an input made at `nowMs` would be stamped with,
   * corrections eased in; null before the server streamed its state. */
  drawAvatar(nowMs: number): Vec3 | null {
    const s = this.avatarState;
    const hz = this.clock.tickHz;
    const stamp = this.clock.serverTicks(nowMs);
    if (!s || !hz || stamp === null) return null;
    const tick = stamp + (this.config.ahead ? (this.clock.lead ?? 0) : 0);
    const p = this.predict(s, tick, hz);
    const decay = Math.exp((-CORRECTION_RATE_PER_S * Math.max(0, nowMs - this.correction.atMs)) / 1000);
    this.lastDrawn = { tick, position: p };
    return [p[0] + this.correction.offset[0] * decay, p[1] + this.correction.offset[1] * decay, p[2] + this.correction.offset[2] * decay];
  }

  private predict(s: { tick: number; position: Vec3; velocity: Vec3 }, tick: number, hz: number): Vec3 {
    const p: Vec3 = [...s.position];
    let v = s.velocity;
    let t = s.tick;
    for (const set of this.velocities) {
      if (set.tick <= s.tick) continue;
      if (set.tick >= tick) break;
      for (let k = 0; k < 3; k++) p[k]! += (v[k]! * (set.tick - t)) / hz;
      [t, v] = [set.tick, set.velocity];
    }
    for (let k = 0; k < 3; k++) p[k]! += (v[k]! * Math.max(0, tick - t)) / hz;
    return p;
  }

  /** A state of the own avatar at `tick`: the prediction restarts from it, and the jump it
   * makes in what is drawn is eased in rather than shown. */
  private reconcile(tick: number, a: AvatarState, nowMs: number): void {
    if (a.entity !== this.avatar) return;
    const before = this.lastDrawn;
    this.avatarState = { tick, position: [...a.position], velocity: [...a.velocity] };
    this.velocities = this.velocities.filter((v) => v.tick > tick);
    const hz = this.clock.tickHz;
    if (!before || !hz) return;
    const now = this.predict(this.avatarState, before.tick, hz);
    const decay = Math.exp((-CORRECTION_RATE_PER_S * Math.max(0, nowMs - this.correction.atMs)) / 1000);
    const off = [0, 1, 2].map((k) => before.position[k]! + this.correction.offset[k]! * decay - now[k]!) as Vec3;
    this.correction = Math.hypot(...off) > 2 ? { offset: [0, 0, 0], atMs: nowMs } : { offset: off, atMs: nowMs };
  }

  private observe(tick: number, nowMs: number): void {
    this.publishedAt(tick);
    if (this.clock.observe(tick, nowMs)) this.stats.clockResyncs++;
    const hz = this.clock.tickHz ?? 0;
    const n = this.newestNamed;
    if (!n || tick >= n.tick + ((nowMs - n.atMs) / 1000) * hz || nowMs - n.atMs > 10_000) this.newestNamed = { tick, atMs: nowMs };
  }

  private welcomed(w: Welcome, nowMs: number): void {
    this.stats.welcomes++;
    this.clock.anchor(w.tick, w.tick_hz, nowMs);
    if (this.lostUnwelcomed) {
      this.lostUnwelcomed = false;
      this.restoredAt(nowMs);
    }
    if (!this.remote || this.remote.config.tickHz !== w.tick_hz) {
      this.remote = new RemoteWorld({ ...remoteConfig(w.tick_hz), delayS: this.config.interpolationDelayS });
    }
    // Seqs below next_seq: the server accepted the one just below and answered or never heard
    // the others (answers lost with the old link). None is carried again, so the next ack's
    // accepted_before tells each accepted (ack_lost) or not (lost).
    this.outbox.resumeFrom(w.next_seq);
    this.resend = this.resend.filter((i) => !precedes(i.seq, w.next_seq));
    if (this.stats.welcomes > 1) {
      // Inputs at or above next_seq sent before this welcome may still be on their way, or their
      // answers held by a stalled path: no length of time tells. Order does: once an input made
      // after the welcome is acked (acks go out in order, each tick's after its rejects), every
      // one still unanswered and not carried since never reached the server.
      this.lostCheck = { welcomedMs: nowMs, nextSeq: w.next_seq };
    }
    if (this.status === "joining") {
      this.status = "syncing";
      this.syncStartedMs = nowMs;
    }
    this.welcome = w;
  }

  /** An input first sent at `sentMs` was acked: the check a second welcome left is settled when
   * that was after the welcome. */
  private ackedAfter(sentMs: number, nowMs: number): void {
    const c = this.lostCheck;
    if (!c || sentMs < c.welcomedMs) return;
    this.lostCheck = null;
    this.answerLost((seq, s) => !precedes(seq, c.nextSeq) && s.carriedMs < c.welcomedMs, nowMs);
    // Below next_seq and further back than the ack's bits reach (64 seqs): taken as the welcome
    // implies, accepted with the seq just below next_seq, acks lost.
    for (const [seq, sent] of this.outbox.takePending((q, s) => precedes(q, c.nextSeq) && s.carriedMs < c.welcomedMs)) {
      this.stats.inputsAcked++;
      this.stats.acksRecovered++;
      this.answered(seq, sent, { kind: "ack_lost" }, nowMs);
    }
  }

  /** An earlier input within an ack's bits that the server did not accept, carried by no
   * message since the acked one was made, never reached it (messages arrive in order). */
  private lostBefore(seq: number, bits: bigint, madeMs: number, nowMs: number): void {
    this.answerLost((s, sent) => {
      const back = (seq - s + 2 ** 32) % 2 ** 32;
      return precedes(s, seq) && back <= 64 && ((bits >> BigInt(back - 1)) & 1n) === 0n && sent.carriedMs < madeMs;
    }, nowMs);
  }

  private answerLost(lost: (seq: number, s: Sent) => boolean, nowMs: number): void {
    for (const [seq, sent] of this.outbox.takePending(lost)) {
      this.resend = this.resend.filter((i) => i.seq !== seq);
      this.stats.inputsLost++;
      this.answered(seq, sent, { kind: "lost" }, nowMs);
    }
  }

  private answered(seq: number, sent: Sent, outcome: Outcome, nowMs: number): void {
    if (sent.keepalive) return; // the session's own
    if (this.answers.length >= MAX_ANSWERS) this.answers.shift();
    this.answers.push({ seq, tick: sent.tick, sentMs: sent.atMs, roundTripMs: nowMs - sent.atMs, outcome });
  }

  private pushNews(n: EventNews): void {
    if (this.news.length >= MAX_NEWS) this.news.shift();
    this.news.push(n);
  }

  private startPlaying(): void {
    this.status = "playing";
    this.probe = null;
    const hz = this.clock.tickHz;
    if (!hz || this.samples.length === 0) return;
    const fastest = this.samples.reduce((a, b) => (b.rttMs < a.rttMs ? b : a));
    const slowest = Math.max(...this.samples.map((s) => s.rttMs));
    this.stats.syncRttMinMs = fastest.rttMs;
    this.stats.syncRttMaxMs = slowest;
    this.clock.anchor(fastest.tick, hz, fastest.atMs);
    this.clock.recommend(Math.ceil((slowest / 1000) * hz) + 1);
  }

  /** The page came back from the background (`visibilitychange`): timers were throttled, so
   * the clock is synced again before the next inputs are stamped. */
  resync(nowMs: number): void {
    if (this.status !== "playing" && this.status !== "syncing") return;
    this.status = "syncing";
    this.samples = [];
    this.probe = null;
    this.syncStartedMs = nowMs;
  }

  /** Numbers and stamps `actions` as the next input and queues it with the unanswered inputs
   * before it. Returns its seq. */
  input(actions: Action[], nowMs: number): number {
    return this.makeInput(actions, false, nowMs);
  }

  private makeInput(actions: Action[], keepalive: boolean, nowMs: number): number {
    if (this.status === "closed") throw new InputError("the world closed");
    if (actions.length > MAX_ACTIONS_PER_INPUT) throw new InputError(`${actions.length} actions: at most ${MAX_ACTIONS_PER_INPUT}`);
    const stamped = this.clock.stamp(this.config.ahead, nowMs);
    if (!stamped) throw new InputError("not joined yet");
    const seq = this.outbox.nextSeq();
    const input: ClientInput = { client: this.config.client, seq, tick: stamped.tick, actions };
    if (this.config.ahead) input.view_tick = stamped.view;
    const render = this.renderTick(nowMs);
    if (render !== null && actions.some((a) => a.type === "fire_ray")) input.aim_tick = Math.max(0, Math.floor(render));
    this.outbox.sent(seq, { atMs: nowMs, tick: stamped.tick, view: this.config.ahead ? stamped.view : null, carriedMs: nowMs, keepalive });
    this.lastInputMs = nowMs;
    if (keepalive) this.stats.keepalives++;
    for (const a of actions) {
      if (a.type === "set_velocity" && a.entity === this.avatar) {
        this.velocities = this.velocities.filter((v) => v.tick < stamped.tick);
        this.velocities.push({ tick: stamped.tick, velocity: [...a.velocity] });
      }
    }
    this.stats.inputsSent++;
    const oldest = this.welcome ? stamped.view - this.welcome.window_ticks : 0;
    let count = actions.length;
    const copies: ClientInput[] = [];
    for (const old of [...this.resend].reverse().slice(0, Math.min(this.config.redundancy, MAX_INPUTS_PER_MESSAGE - 1))) {
      if (old.tick < oldest || count + old.actions.length > MAX_ACTIONS_PER_INPUT) break;
      count += old.actions.length;
      copies.push(old);
    }
    for (const c of copies) this.outbox.carried(c.seq, nowMs);
    copies.reverse();
    this.push(copies.length === 0 ? { type: "input", ...input } : { type: "inputs", client: this.config.client, inputs: [...copies, input] });
    if (this.config.redundancy > 0) {
      this.resend.push(input);
      while (this.resend.length > this.config.redundancy) this.resend.shift();
    }
    return seq;
  }

  private push(m: ClientMessage): void {
    if (this.outgoing.length >= MAX_OUTGOING) {
      this.outgoing.shift();
      this.stats.outgoingDropped++;
    }
    this.outgoing.push(m);
  }

  /** A tick whose own confirmed batch was missed (a later one came while the view held events of
   * it): the transport asks for the batch the server kept (the gateway's `confirmed` request),
   * which comes as a `confirmed` message. Each tick is given once; one that did not come within
   * RECOVERY_WAIT_MS is taken as having no events for this client. */
  pollRecovery(): number | null {
    for (const [t, r] of this.recovery) {
      if (!r.asked) {
        r.asked = true;
        return t;
      }
    }
    return null;
  }

  /** The next message to send at `nowMs`: call until null each frame. */
  pollTransmit(nowMs: number): ClientMessage | null {
    for (const [t, r] of [...this.recovery]) {
      if (nowMs - r.sinceMs < RECOVERY_WAIT_MS) continue;
      this.recovery.delete(t);
      for (const f of this.events.giveUp(t)) this.pushNews({ kind: "confirmed", ...f });
    }
    if (this.status === "syncing") {
      const started = (this.syncStartedMs ??= nowMs);
      if (nowMs - started >= SYNC_TIMEOUT_MS) this.startPlaying();
      else if (!this.probe || nowMs - this.probe.atMs >= PROBE_TIMEOUT_MS) {
        const id = this.nextProbe;
        this.nextProbe = (this.nextProbe + 1) % 2 ** 32;
        this.probe = { id, atMs: nowMs };
        return { type: "ping", client: this.config.client, id };
      }
    }
    if (this.stats.stateFrames > 0 && this.remote?.needsFullFrame && (this.fullAskedMs === null || nowMs - this.fullAskedMs >= FULL_FRAME_EVERY_MS)) {
      this.fullAskedMs = nowMs;
      this.stats.fullFramesAsked++;
      return { type: "full_frame", client: this.config.client };
    }
    const idle = this.lastInputMs !== null && nowMs - this.lastInputMs >= KEEPALIVE_AFTER_MS;
    if (idle && this.status === "playing" && this.outbox.awaitsTheGames(KEEPALIVE_REACH)) this.makeInput([], true, nowMs);
    return this.outgoing.shift() ?? null;
  }

  /** Each input answered since the last call, in order. */
  takeAnswers(): Answer[] {
    return this.answers.splice(0);
  }

  /** What changed in the event view since the last call. */
  takeEventNews(): EventNews[] {
    return this.news.splice(0);
  }

  /** Ray results since the last call. */
  takeRayResults(): RayResult[] {
    return this.rays.splice(0);
  }
}
