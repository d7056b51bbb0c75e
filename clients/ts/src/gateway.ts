// The session over the WebSocket gateway (PROTOCOL.md, "WebSocket binding"), in a browser or
// any runtime with a WHATWG WebSocket. The only I/O of the package.
//
// `Connection.open` sends the hello and resolves once the gateway is `ready`; `pump` hands the
// session what arrived and sends what it gives (call it every frame). A connection that breaks,
// or that the gateway closes for a reason worth retrying (no_server, unavailable, going_away,
// too_slow), is opened again with back-off and the same hello: back within the grace period the
// player keeps its avatar and its inputs' numbers (the welcome's next_seq), and inputs that never
// reached the server are answered lost. A page that was hidden (timers throttled) resyncs its
// clock when it is shown again.

import { encode as msgpackEncode } from "@msgpack/msgpack";
import { decodeServer, encodeClient, type GatewayNotice, type ServerMessage } from "./messages.js";
import type { Session } from "./session.js";

/** The hello: a users file entry, or a token from the game's backend. */
export type Hello =
  | { world: string; client: number; user: string; password: string; state?: boolean }
  | { token: string; world?: string; client?: number; state?: boolean };

/** Close codes that say: do not retry as is (PROTOCOL.md, "Close codes"). */
export const FINAL_CLOSES = new Set([4000, 4001, 4011, 4012, 4030, 1009]);

/** Why the connection ended for good. */
export class Closed extends Error {
  constructor(
    readonly code: number,
    readonly reason: string,
  ) {
    super(`closed ${code}: ${reason}`);
  }
}

export interface ConnectOptions {
  /** `ws://host:port/ws` or `wss://...`. */
  url: string;
  hello: Hello;
  /** Milliseconds to wait for `ready`. */
  readyTimeoutMs?: number;
  /** The longest back-off between reconnects. */
  maxBackoffMs?: number;
  /** The clock (default `performance.now()`). */
  now?: () => number;
  /** The WebSocket constructor (default the global one). */
  webSocket?: typeof WebSocket;
}

/** A connection to the gateway, reconnecting by itself. */
export class Connection {
  private ws: WebSocket | null = null;
  private inbox: { msg: ServerMessage | GatewayNotice; atMs: number }[] = [];
  private ended: Closed | null = null;
  private backoffMs = 250;
  private reconnectAt: number | null = null;
  private hiddenSince: number | null = null;
  /** Messages from the gateway that did not decode. */
  malformed = 0;
  /** Times the connection was opened again. */
  reconnects = 0;
  /** The `ready` notice of the current connection. */
  ready: Extract<GatewayNotice, { type: "ready" }> | null = null;
  /** Bytes received and sent. */
  bytesIn = 0;
  bytesOut = 0;

  private constructor(private readonly opts: Required<Omit<ConnectOptions, "hello">> & { hello: Hello }) {}

  /** Connects and waits for the gateway's `ready`. */
  static async open(options: ConnectOptions): Promise<Connection> {
    const opts = {
      readyTimeoutMs: 10_000,
      maxBackoffMs: 5_000,
      now: () => performance.now(),
      webSocket: globalThis.WebSocket,
      ...options,
    };
    const c = new Connection(opts);
    await c.connect();
    if (typeof document !== "undefined") {
      document.addEventListener("visibilitychange", () => {
        c.hiddenSince = document.hidden ? c.opts.now() : null;
        if (!document.hidden) c.shown = true;
      });
    }
    return c;
  }

  private shown = false;

  private connect(): Promise<void> {
    return new Promise((resolve, reject) => {
      const ws = new this.opts.webSocket(this.opts.url);
      ws.binaryType = "arraybuffer";
      this.ws = ws;
      this.ready = null;
      const timer = setTimeout(() => {
        ws.close();
        reject(new Closed(0, `no ready within ${this.opts.readyTimeoutMs} ms`));
      }, this.opts.readyTimeoutMs);
      ws.onopen = () => {
        const hello = { type: "hello", ...this.opts.hello };
        this.sendRaw(encodeRequest(hello));
      };
      ws.onmessage = (ev: MessageEvent) => {
        if (!(ev.data instanceof ArrayBuffer)) {
          this.malformed++;
          return;
        }
        this.bytesIn += ev.data.byteLength;
        let msg: ServerMessage | GatewayNotice;
        try {
          msg = decodeServer(new Uint8Array(ev.data));
        } catch {
          this.malformed++;
          return;
        }
        if (msg.type === "ready") {
          this.ready = msg as Extract<GatewayNotice, { type: "ready" }>;
          this.backoffMs = 250;
          clearTimeout(timer);
          resolve();
        }
        this.inbox.push({ msg, atMs: this.opts.now() });
      };
      ws.onclose = (ev: CloseEvent) => {
        clearTimeout(timer);
        if (this.ws !== ws) return;
        this.ws = null;
        if (FINAL_CLOSES.has(ev.code)) {
          this.ended = new Closed(ev.code, ev.reason);
          reject(this.ended);
          return;
        }
        // Retried with back-off (pump opens it again).
        this.reconnectAt = this.opts.now() + this.backoffMs;
        this.backoffMs = Math.min(this.backoffMs * 2, this.opts.maxBackoffMs);
        if (this.ready === null) reject(new Closed(ev.code, ev.reason));
      };
    });
  }

  private sendRaw(bytes: Uint8Array): void {
    if (this.ws?.readyState === 1) {
      this.ws.send(bytes);
      this.bytesOut += bytes.length;
    }
  }

  /** Why the connection ended for good, if it did. */
  get closed(): Closed | null {
    return this.ended;
  }

  /** Whether a WebSocket is open now. */
  get open(): boolean {
    return this.ws?.readyState === 1 && this.ready !== null;
  }

  /** Hands `session` what arrived, then sends what it gives. */
  pump(session: Session): void {
    const now = this.opts.now();
    if (this.shown) {
      this.shown = false;
      session.resync(now);
    }
    if (!this.ws && !this.ended && this.reconnectAt !== null && now >= this.reconnectAt) {
      this.reconnectAt = null;
      this.reconnects++;
      // A new connection's welcome resumes the session; a link that came back is a lost link.
      this.connect()
        .then(() => this.inbox.push({ msg: { type: "link_restored" }, atMs: this.opts.now() }))
        .catch(() => {});
    }
    for (const { msg, atMs } of this.inbox.splice(0)) {
      if (msg.type === "link_restored") session.linkRestored(atMs);
      else if (msg.type !== "ready") session.receive(msg as ServerMessage, atMs);
    }
    if (!this.open) return;
    for (let m = session.pollTransmit(now); m; m = session.pollTransmit(now)) this.sendRaw(encodeClient(m));
    for (let t = session.pollRecovery(); t !== null; t = session.pollRecovery()) this.sendRaw(encodeRequest({ type: "confirmed", tick: t }));
  }

  /** Asks the gateway for the world's scene (answered by a `scene` message). */
  askScene(): void {
    this.sendRaw(encodeRequest({ type: "scene" }));
  }

  /** Closes for good (the server keeps the avatar for its grace period). */
  close(): void {
    this.ended = new Closed(1000, "closed by the client");
    this.ws?.close(1000);
    this.ws = null;
  }

  /** Milliseconds the page has been hidden, if it is. */
  hiddenForMs(): number | null {
    return this.hiddenSince === null ? null : this.opts.now() - this.hiddenSince;
  }
}

/** The gateway's own requests (hello, scene, confirmed): plain MessagePack maps of strings, integers and
 * booleans, which any encoder writes as the gateway reads them. */
function encodeRequest(v: Record<string, unknown>): Uint8Array {
  return msgpackEncode(v);
}
