// The session as a game meets it, with scripted server messages: join, time sync, inputs stamped
// ahead and answered, copies of unanswered inputs, acks recovered, inputs known lost after a
// second welcome, the event view, state streams drawn, the own avatar predicted and corrected
// without a jump, a gap answered by a full-frame request.

import { test } from "node:test";
import assert from "node:assert/strict";
import { RECOVERY_WAIT_MS, Session, sessionConfig, SYNC_PROBES } from "../src/session.js";
import { MAX_TICKS } from "../src/events.js";
import type { CollisionEvent, ServerMessage, StateFrame } from "../src/messages.js";

const ME = 7;
const AVATAR = 3;

const welcome = (tick: number, nextSeq: number): ServerMessage => ({
  type: "welcome",
  client: ME,
  avatar: AVATAR,
  tick,
  tick_hz: 64,
  window_ticks: 16,
  input_lead_ticks: 4,
  max_rewind_ticks: 16,
  next_seq: nextSeq,
  scene_hash: 0n,
});

/** A session welcomed at tick 100 (t = 0) and synced with pongs 50 ms after each ping. */
function playing(): Session {
  const s = new Session(sessionConfig(ME));
  s.receive(welcome(100, 1), 0);
  assert.equal(s.status, "syncing");
  let now = 0;
  for (let k = 0; k < SYNC_PROBES; k++) {
    const ping = s.pollTransmit(now);
    assert.equal(ping?.type, "ping");
    now += 50;
    s.receive({ type: "pong", client: ME, id: (ping as { id: number }).id, server_tick: 100 + Math.round((now / 1000) * 64) }, now);
  }
  assert.equal(s.status, "playing");
  return s;
}

const ack = (seq: number, acceptedBefore = 0n): ServerMessage => ({
  type: "ack",
  client: ME,
  seq,
  tick: 0,
  applied_tick: 0,
  server_tick: 117,
  margin_ticks: 2,
  lead_ticks: 5,
  accepted_before: acceptedBefore,
});

const walk = (x: number) => [{ type: "set_velocity" as const, entity: AVATAR, velocity: [x, 0, 0] as [number, number, number] }];

test("joining syncs the clock and takes the slowest round trip as the first lead", () => {
  const s = playing();
  assert.equal(s.stats.syncRttMaxMs, 50);
  assert.equal(s.clock.lead, Math.ceil(0.05 * 64) + 1);
  assert.equal(s.pollTransmit(250), null, "nothing more to send");
});

test("inputs are stamped ahead, sent with the unanswered before them, and answered by seq", () => {
  const s = playing();
  const a = s.input(walk(1), 260);
  const first = s.pollTransmit(260);
  assert.equal(first?.type, "input");
  const view = s.clock.serverTick(260)!;
  assert.deepEqual([(first as { seq: number }).seq, (first as { tick: number }).tick, (first as { view_tick: number }).view_tick], [a, view + 5, view]);
  const b = s.input(walk(2), 270);
  const second = s.pollTransmit(270);
  assert.equal(second?.type, "inputs", "the unanswered input goes again with the new one");
  assert.deepEqual((second as { inputs: { seq: number }[] }).inputs.map((i) => i.seq), [a, b]);
  // b's ack says a was accepted too (bit 0: b - 1).
  s.receive(ack(b, 1n), 300);
  const answers = s.takeAnswers();
  assert.deepEqual(answers.map((x) => [x.seq, x.outcome.kind]), [[b, "accepted"], [a, "ack_lost"]]);
  assert.equal(s.pendingInputs, 0);
  s.receive(ack(b), 310);
  assert.equal(s.stats.unmatchedAnswers, 1, "answered once");
});

test("an input the server never accepted is known lost: by a later ack, or after a second welcome", () => {
  const s = playing();
  const a = s.input(walk(1), 260);
  s.pollTransmit(260);
  const b = s.input(walk(2), 400); // a is carried again with b...
  s.pollTransmit(400);
  const c = s.input([], 500); // ...and with c: a later ack without a's bit only counts if nothing carried a after
  s.pollTransmit(500);
  s.receive(ack(c, 0b01n), 600); // b accepted, a not: a was carried with c, so not yet known lost
  assert.deepEqual(s.takeAnswers().map((x) => [x.seq, x.outcome.kind]), [[c, "accepted"], [b, "ack_lost"]]);
  assert.equal(s.pendingInputs, 1);
  // The connection drops and comes back: the server accepted nothing at or after a.
  s.receive(welcome(150, a), 700);
  const d = s.input([], 700);
  assert.equal(d, c + 1, "numbers go on");
  while (s.pollTransmit(700)) {}
  assert.equal(s.pollTransmit(3700)?.type, "input", "3 s of silence bring a keepalive");
  assert.equal(s.pendingInputs, 2, "no length of silence tells an input lost (a stalled path holds answers)");
  s.receive(ack(d), 3800);
  assert.deepEqual(s.takeAnswers().map((x) => [x.seq, x.outcome.kind]), [[d, "accepted"], [a, "lost"]]);
  assert.equal(s.stats.inputsLost, 1);
});

test("a game idle with inputs unanswered sends a keepalive each second, whose ack tells them lost", () => {
  const s = playing();
  const seqs = [s.input(walk(1), 260), s.input(walk(2), 260), s.input(walk(3), 260)];
  while (s.pollTransmit(260)) {}
  const keepalive = (now: number): number | null => {
    let made: number | null = null;
    for (let m = s.pollTransmit(now); m; m = s.pollTransmit(now)) {
      const newest = m.type === "input" ? m : m.type === "inputs" ? m.inputs[m.inputs.length - 1] : null;
      assert.ok(newest, `an input, not ${m.type}`);
      assert.deepEqual(newest.actions, [], "a keepalive has no actions");
      made = newest.seq;
    }
    return made;
  };
  assert.equal(keepalive(1160), null, "not yet overdue");
  const first = keepalive(1260);
  assert.ok(first !== null, "a keepalive after a second of silence");
  assert.equal(keepalive(1760), null, "one a second");
  const second = keepalive(2260);
  assert.ok(second !== null, "another while nothing is answered");
  assert.equal(s.stats.keepalives, 2);
  // The server heard the second input and the second keepalive only.
  s.receive(ack(second, 1n << BigInt(second - seqs[1]! - 1)), 2300);
  const answers = s.takeAnswers().map((x) => [x.seq, x.outcome.kind]).sort((x, y) => Number(x[0]) - Number(y[0]));
  assert.deepEqual(answers, [[seqs[0], "lost"], [seqs[1], "ack_lost"], [seqs[2], "lost"]], "the keepalives' answers are not the game's");
  assert.equal(s.stats.inputsLost, 3, "the first keepalive is lost too");
  assert.equal(keepalive(9000), null, "nothing of the game's awaits");
  assert.equal(s.pendingInputs, 0);
});

test("a server gone for good: keepalives stop where an ack could no longer tell", () => {
  const s = playing();
  s.input(walk(1), 260);
  while (s.pollTransmit(260)) {}
  let sent = 0;
  for (let k = 1; k <= 100; k++) while (s.pollTransmit(260 + k * 1000)) sent++;
  assert.equal(s.stats.keepalives, 64, "while the game's input is within 64 seqs of the next");
  assert.equal(sent, 64);
  assert.equal(s.pendingInputs, 1, "the game's input awaits still; the keepalives are not the game's");
});

test("inputs below a second welcome's next_seq are answered by the next ack, not forgotten", () => {
  const s = playing();
  const a = s.input(walk(1), 260);
  s.pollTransmit(260);
  const b = s.input(walk(2), 400);
  s.pollTransmit(400);
  // The connection drops with both answers: the server accepted b and refused a.
  s.receive(welcome(150, b + 1), 700);
  assert.deepEqual([s.takeAnswers().length, s.pendingInputs], [0, 2], "awaited, carried no more");
  const c = s.input([], 800);
  const sent = s.pollTransmit(800);
  assert.deepEqual(sent?.type === "inputs" ? sent.inputs.map((i) => i.seq) : [], [], "a and b are not carried");
  s.receive(ack(c, 0b01n), 900);
  assert.deepEqual(s.takeAnswers().map((x) => [x.seq, x.outcome.kind]), [[c, "accepted"], [b, "ack_lost"], [a, "lost"]]);
  assert.deepEqual([s.pendingInputs, s.stats.acksRecovered, s.stats.inputsLost], [0, 1, 1]);
});

const event = (tick: number, toi = 0.5): CollisionEvent => ({
  tick,
  toi,
  a: 1,
  b: 2,
  point: [0, 0, 0],
  normal: [1, 0, 0],
  depth_m: 0,
  closing_speed_mps: 1,
  phase: "begin",
  response: "bounce",
  status: "provisional",
});

test("the event view compares confirmed ticks, and leaves out those a lost link passed", () => {
  const s = playing();
  s.receive({ type: "events", tick: 110, revision: 0, events: [event(110)] }, 300);
  s.receive({ type: "confirmed", tick: 110, revision: 0, events: [event(110)] }, 310);
  s.receive({ type: "events", tick: 111, revision: 0, events: [event(111)] }, 320);
  s.receive({ type: "corrections", tick: 111, revision: 1, retracted: [], amended: [event(111, 0.25)], added: [] }, 330);
  s.receive({ type: "confirmed", tick: 111, revision: 1, events: [event(111, 0.25)] }, 340);
  s.receive({ type: "confirmed", tick: 112, revision: 0, events: [event(112)] }, 350);
  const confirmed = s.takeEventNews().filter((n) => n.kind === "confirmed");
  assert.deepEqual(confirmed.map((n) => n.kind === "confirmed" && [n.tick, n.matched]), [[110, true], [111, true], [112, false]]);
  s.linkRestored(400);
  s.receive({ type: "confirmed", tick: 113, revision: 0, events: [event(113)] }, 410);
  assert.equal(s.events.unverified, 1, "a tick the lost link passed is taken as it is");
  assert.equal(s.events.mismatched, 1);
});

test("after a restored link, the ticks before the server's present at its first message since are left uncompared", () => {
  const s = playing();
  s.linkRestored(400);
  // A second on, the first message since: a confirmed batch, published as tick 150 left the
  // window (at 166). The server's own link came back after the client's.
  s.receive({ type: "confirmed", tick: 150, revision: 0, events: [event(150)] }, 1400);
  s.receive({ type: "events", tick: 170, revision: 0, events: [event(170)] }, 1400);
  s.receive({ type: "confirmed", tick: 160, revision: 0, events: [event(160)] }, 1400);
  assert.deepEqual([s.events.mismatched, s.events.unverified], [0, 2]);
  s.receive({ type: "confirmed", tick: 170, revision: 0, events: [event(170)] }, 1410);
  assert.equal(s.events.matched, 1, "from then on ticks are compared");
});

test("a link restored before the welcome leaves the ticks before the welcome's present uncompared", () => {
  // A player back through the gateway: the server published on its keys while it was away, so
  // the gateway tells of a lost link before the welcome has come (on another key).
  const s = new Session(sessionConfig(ME));
  s.linkRestored(0);
  s.receive({ type: "confirmed", tick: 80, revision: 0, events: [event(80)] }, 0);
  s.receive({ type: "confirmed", tick: 84, revision: 0, events: [event(84)] }, 0);
  assert.deepEqual([s.events.mismatched, s.events.unverified], [0, 2]);
  s.receive(welcome(100, 1), 0);
  s.receive({ type: "events", tick: 105, revision: 0, events: [event(105)] }, 0);
  s.receive({ type: "events", tick: 140, revision: 0, events: [event(140)] }, 0);
  s.receive({ type: "confirmed", tick: 105, revision: 0, events: [event(105)] }, 0);
  assert.deepEqual([s.events.mismatched, s.events.unverified], [0, 3], "before the welcome's present");
  s.receive({ type: "confirmed", tick: 140, revision: 0, events: [event(140)] }, 0);
  assert.deepEqual([s.events.matched, s.events.mismatched], [1, 0], "published after the welcome: compared");
});

test("a confirmation makes every earlier tick final, so a long match holds nothing", () => {
  const s = playing();
  s.receive({ type: "events", tick: 103, revision: 0, events: [event(103)] }, 300);
  s.receive({ type: "corrections", tick: 103, revision: 1, retracted: [event(103)], amended: [], added: [] }, 301);
  s.receive({ type: "events", tick: 104, revision: 0, events: [event(104)] }, 302);
  s.receive({ type: "events", tick: 105, revision: 0, events: [event(105)] }, 303);
  s.receive({ type: "events", tick: 107, revision: 0, events: [event(107)] }, 304);
  s.takeEventNews();
  // Tick 103's only event was retracted, so no batch of its own comes; 104's retraction was lost.
  s.receive({ type: "confirmed", tick: 105, revision: 0, events: [event(105)] }, 310);
  // 104 still held an event: in doubt, asked for once, then given up on.
  const finals = s.takeEventNews().map((n) => n.kind === "confirmed" && [n.tick, n.matched]);
  assert.deepEqual(finals, [[103, true], [105, true]]);
  assert.deepEqual([s.pollRecovery(), s.pollRecovery()], [104, null]);
  while (s.pollTransmit(310 + RECOVERY_WAIT_MS)) {}
  assert.deepEqual(s.takeEventNews().map((n) => n.kind === "confirmed" && [n.tick, n.matched]), [[104, false]]);
  assert.deepEqual([s.events.held, s.events.implied, s.events.newest()], [1, 2, 107]);
  for (let t = 108; t < 108 + 3 * MAX_TICKS; t++) {
    s.receive({ type: "events", tick: t, revision: 0, events: [event(t)] }, 400);
    s.receive({ type: "corrections", tick: t, revision: 1, retracted: [event(t)], amended: [], added: [] }, 400);
    if (t % 16 === 0) s.receive({ type: "confirmed", tick: t, revision: 0, events: [] }, 400);
    s.takeEventNews();
  }
  assert.ok(s.events.held <= 16, `${s.events.held} ticks held`);
  assert.deepEqual(s.events.doubtful(), [107], "tick 107's event was never confirmed");
  while (s.pollTransmit(400 + RECOVERY_WAIT_MS)) {}
  assert.deepEqual([s.events.forgotten, s.events.mismatched, s.events.doubtful().length], [0, 2, 0]);
});

test("a missed confirmed batch is asked for, and its late copy makes the tick final", () => {
  const s = playing();
  s.receive({ type: "events", tick: 104, revision: 0, events: [event(104)] }, 300);
  s.receive({ type: "confirmed", tick: 106, revision: 0, events: [] }, 310);
  assert.deepEqual(s.takeEventNews().filter((n) => n.kind === "confirmed").map((n) => n.kind === "confirmed" && n.tick), [106]);
  assert.equal(s.pollRecovery(), 104);
  s.receive({ type: "confirmed", tick: 104, revision: 0, events: [event(104)] }, 320);
  assert.deepEqual(s.takeEventNews().map((n) => n.kind === "confirmed" && [n.tick, n.matched]), [[104, true]]);
  while (s.pollTransmit(310 + RECOVERY_WAIT_MS)) {}
  assert.deepEqual([s.events.recovered, s.events.matched, s.events.mismatched, s.takeEventNews().length], [1, 2, 0, 0]);
});

const frame = (n: number, tick: number, full: boolean, x: number, vx: number, avatar?: [number, number]): StateFrame => ({
  tick,
  frame: n,
  full,
  entered: full
    ? [{ entity: 1, class: "ball", owner: null, shape: "sphere", half_extents_m: [0.5, 0.5, 0.5], offset_m: [0, 0, 0], fixed: false }]
    : [],
  moved: [[1, [x, 0, 0], [vx, 0, 0], false]],
  left: [],
  deferred: 0,
  centre: null,
  ...(avatar ? { avatar: { entity: AVATAR, position: [avatar[0], 0, 0], velocity: [avatar[1], 0, 0], asleep: false, still_ticks: 0, touching: [], class: null } } : {}),
});

test("state frames are drawn at the render tick, and a gap asks for a full frame", () => {
  const s = playing();
  s.receive({ type: "state", ...frame(0, 110, true, 0, 6.4) }, 300);
  s.receive({ type: "state", ...frame(1, 120, false, 1, 6.4) }, 310);
  const r = s.renderTick(310)!;
  const [ball] = s.drawRemote(310);
  assert.ok(ball && Math.abs(ball.position[0] - ((r - 110) * 6.4) / 64) < 1e-9, "on its path at the render tick");
  assert.equal(ball?.steady, true);
  s.receive({ type: "state", ...frame(5, 130, false, 2, 6.4) }, 320);
  assert.equal(s.remote?.needsFullFrame, true);
  assert.equal(s.pollTransmit(330)?.type, "full_frame");
  assert.equal(s.pollTransmit(340), null, "not again at once");
});

test("a stream numbered anew (back from a drop, a takeover) is not taken for repeats", () => {
  const s = playing();
  s.receive({ type: "state", ...frame(80, 110, true, 0, 0) }, 300);
  s.receive({ type: "state", ...frame(81, 113, false, 1, 0) }, 310);
  // Numbered from 0 again at newer ticks, its full frame lost: a gap, which asks for one.
  s.receive({ type: "state", ...frame(1, 150, false, 9, 0) }, 320);
  assert.equal(s.remote?.needsFullFrame, true);
  assert.equal(s.pollTransmit(330)?.type, "full_frame");
  s.receive({ type: "state", ...frame(2, 153, true, 5, 0) }, 340);
  assert.equal(s.remote?.needsFullFrame, false);
  // Its full frame first: applied at once; repeats are still repeats.
  assert.equal(s.remote?.apply({ ...frame(0, 200, true, 7, 0) }), "applied");
  assert.equal(s.remote?.apply({ ...frame(0, 200, true, 7, 0) }), "stale");
  assert.equal(s.remote?.apply({ ...frame(82, 116, true, 0, 0) }), "stale", "late, of the old numbering");
  assert.equal(s.remote?.apply({ ...frame(1, 190, false, 0, 0) }), "stale", "the next number, at an old tick");
  assert.equal(s.remote?.stats.fullFrames, 3);
});

test("the own avatar is predicted from its inputs and corrected without a jump", () => {
  const s = playing();
  s.receive({ type: "state", ...frame(0, 110, true, 0, 0, [0, 0]) }, 300);
  s.input(walk(6.4), 300);
  const p1 = s.drawAvatar(300 + 500)!;
  assert.ok(p1[0] > 2.5, `moving at 6.4 m/s: ${p1[0]}`);
  // The server had it 0.5 m behind the prediction: drawn where it was, then eased there.
  const tick = s.clock.serverTick(800)!;
  const predicted = ((tick + 5 - 110 - 5) * 6.4) / 64; // from the input's tick on
  s.receive({ type: "state", ...frame(1, tick, false, 0, 0, [predicted - 0.5, 6.4]) }, 800);
  const p2 = s.drawAvatar(800)!;
  assert.ok(Math.abs(p2[0] - p1[0]) < 1e-6, `no jump: ${p1[0]} -> ${p2[0]}`);
  const later = s.drawAvatar(1800)!;
  const truth = predicted - 0.5 + 6.4 * ((s.clock.serverTicks(1800)! + 5 - tick) / 64);
  assert.ok(Math.abs(later[0] - truth) < 1e-3, `converged: ${later[0]} vs ${truth}`);
});
