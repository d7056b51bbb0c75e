// The TypeScript client against a live impact-server (under --users) and impact-gateway, both
// real processes over real sockets: join through the gateway with a password, sync, walk with
// inputs stamped ahead (each acked), draw the remote world from the state stream, predict the
// own avatar, and see confirmed ticks match the event view. Then the gateway is killed and
// started again on the same port: the client reconnects by itself, is welcomed back and plays on.
//
// Needs the debug binaries (`cargo build -p impact-server -p impact-gateway --bins`) in
// IMPACT_BIN_DIR (default: $CARGO_TARGET_DIR/debug, else the repository's target/debug); run with
// `npm run test:live` (.ci/run does).

import { test } from "node:test";
import assert from "node:assert/strict";
import { spawn, type ChildProcess } from "node:child_process";
import { mkdtempSync, writeFileSync, existsSync } from "node:fs";
import { createServer } from "node:net";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import WebSocket from "ws";
import { Connection, Session, sessionConfig, type Answer } from "../../src/index.js";

const repo = resolve(fileURLToPath(new URL("../../../../..", import.meta.url)));
const bins = process.env.IMPACT_BIN_DIR ?? join(process.env.CARGO_TARGET_DIR ?? join(repo, "target"), "debug");

const freePort = (): Promise<number> =>
  new Promise((ok) => {
    const s = createServer().listen(0, "127.0.0.1", () => {
      const port = (s.address() as { port: number }).port;
      s.close(() => ok(port));
    });
  });

/** Starts `bin` and resolves with the first stdout line matching `pattern`. */
function start(bin: string, args: string[], pattern: RegExp, procs: ChildProcess[]): Promise<RegExpMatchArray> {
  const path = join(bins, bin);
  assert.ok(existsSync(path), `${path}: build it first (cargo build -p impact-server -p impact-gateway --bins)`);
  const p = spawn(path, args, { stdio: ["ignore", "pipe", "pipe"], env: { ...process.env, RUST_BACKTRACE: "0" } });
  procs.push(p);
  let err = "";
  p.stderr!.on("data", (d: Buffer) => (err = (err + d.toString()).slice(-4000)));
  return new Promise((ok, fail) => {
    let out = "";
    const timer = setTimeout(() => fail(new Error(`${bin}: no ${pattern} within 30 s; stderr: ${err}`)), 30_000);
    p.stdout!.on("data", (d: Buffer) => {
      out += d.toString();
      const m = out.match(pattern);
      if (m) {
        clearTimeout(timer);
        ok(m);
      }
    });
    p.on("exit", (code) => fail(new Error(`${bin} exited ${code}: ${err}`)));
  });
}

const sleep = (ms: number) => new Promise((r) => setTimeout(r, ms));

/** Pumps the game every 10 ms until `done` says so or `ms` pass; walks when it can. */
async function play(conn: Connection, s: Session, ms: number, answers: Answer[], done: () => boolean): Promise<void> {
  const end = performance.now() + ms;
  let nextInput = 0;
  while (performance.now() < end && !done()) {
    const now = performance.now();
    conn.pump(s);
    if (s.status === "playing" && s.avatar !== null && now >= nextInput) {
      nextInput = now + 50;
      const vx = Math.sin(now / 500) * 3;
      s.input([{ type: "set_velocity", entity: s.avatar, velocity: [vx, 0, 0] }], now);
    }
    s.drawAvatar(now);
    answers.push(...s.takeAnswers());
    s.takeEventNews();
    await sleep(10);
  }
}

test("a TypeScript client plays through the gateway, and reconnects when the gateway restarts", async () => {
  const procs: ChildProcess[] = [];
  try {
    const dir = mkdtempSync(join(tmpdir(), "impact-ts-live-"));
    const users = join(dir, "users.toml");
    writeFileSync(
      users,
      '[[user]]\nname = "alice"\npassword = "alice-secret"\nclient = 1\n\n[[gateway]]\nname = "gw"\npassword = "gw-secret"\n',
    );
    const zport = await freePort();
    await start("impact-server", ["--scene", join(repo, "scenes/arena.toml"), "--listen", `tcp/127.0.0.1:${zport}`, "--users", users], /listening on/, procs);
    const wport = await freePort();
    const gwArgs = ["--connect", `tcp/127.0.0.1:${zport}`, "--users", users, "--as", "gw", "--listen", `127.0.0.1:${wport}`, "--report-s", "0"];
    await start("impact-gateway", gwArgs, /listening on http:\/\/(\S+) /, procs);

    const conn = await Connection.open({
      url: `ws://127.0.0.1:${wport}/ws`,
      hello: { world: "arena", client: 1, user: "alice", password: "alice-secret" },
      webSocket: WebSocket as unknown as typeof globalThis.WebSocket,
    });
    assert.equal(conn.ready?.client, 1);
    const s = new Session(sessionConfig(1));
    const answers: Answer[] = [];
    const accepted = () => answers.filter((a) => a.outcome.kind === "accepted").length;
    await play(conn, s, 15_000, answers, () => accepted() >= 20 && s.events.matched >= 1 && s.drawRemote(performance.now()).length > 0);
    assert.equal(s.status, "playing");
    assert.ok(accepted() >= 20, `inputs acked: ${accepted()} of ${answers.length} (${JSON.stringify(s.stats.rejects)})`);
    assert.ok(s.drawRemote(performance.now()).length > 0, "the remote world is drawn");
    assert.ok(s.drawAvatar(performance.now()) !== null, "the own avatar is predicted");
    // The server confirms the ticks with the player's events (the balls it walks into).
    assert.ok(s.events.matched >= 1 && s.events.mismatched === 0, `confirmed ticks: ${s.events.matched} matched, ${s.events.mismatched} differed`);

    // The gateway goes away and comes back on the same port.
    procs[1]!.kill("SIGKILL");
    await sleep(300);
    await start("impact-gateway", gwArgs, /listening on/, procs);
    const welcomes = s.stats.welcomes;
    const before = accepted();
    await play(conn, s, 20_000, answers, () => s.stats.welcomes > welcomes && accepted() >= before + 20);
    assert.ok(conn.reconnects >= 1, "reconnected");
    assert.ok(s.stats.welcomes > welcomes, "welcomed again");
    assert.ok(accepted() >= before + 20, `plays on: ${accepted() - before} more acked`);
    assert.equal(s.pendingInputs < 20, true, `answers kept coming: ${s.pendingInputs} awaited`);
    conn.close();
  } finally {
    for (const p of procs) p.kill("SIGKILL");
  }
});
