// The clock as the Rust client library's: the lead reached by dilation, a stalled server
// re-anchoring and late messages not, a future reject lowering the lead, small drift followed
// and jitter not.

import { test } from "node:test";
import assert from "node:assert/strict";
import { Clock, DILATION, RESYNC_TICKS } from "../src/clock.js";

const at = (tick: number, t0: number): Clock => {
  const c = new Clock();
  c.anchor(tick, 64, t0);
  return c;
};

test("the lead follows recommendations by time dilation", () => {
  const c = at(100, 0);
  assert.deepEqual(c.stamp(true, 0), { tick: 100, view: 100 }, "no lead before an ack");
  c.recommend(12);
  assert.deepEqual(c.stamp(true, 0), { tick: 112, view: 100 });
  c.recommend(2);
  assert.equal(c.stampRate(true), 1 - DILATION);
  assert.equal(c.stampRate(false), 1);
  assert.deepEqual(c.stamp(true, 1000), { tick: 164 + 6, view: 164 }, "12 - 6.4 rounds to 6");
  assert.deepEqual(c.stamp(true, 2000), { tick: 230, view: 228 });
  assert.deepEqual(c.stamp(false, 2000), { tick: 228, view: 228 });
  assert.equal(new Clock().stamp(true, 2000), null, "not before the welcome");
  assert.equal(c.stampRate(true), 1);
});

test("a stalled server re-anchors the clock and late messages do not", () => {
  const c = at(100, 0);
  assert.equal(c.serverTick(1000), 164);
  assert.equal(c.observe(164 - RESYNC_TICKS, 1000), false, "jitter within the bound");
  // The page stalled for 0.4 s: what queued arrives at once, then a timely message.
  for (const t of [138, 145, 152]) {
    assert.equal(c.observe(t, 1000), false, "a late message alone is no slip");
  }
  assert.equal(c.observe(163, 1001), false);
  assert.equal(c.serverTick(1001), 164, "the burst left the clock where it was");
  // The server lost 0.4 s to a stall: its batches name ticks 26 behind, and go on doing so.
  assert.equal(c.observe(144, 1100), false);
  assert.equal(c.observe(145, 1116), false, "a tick's time is not yet a slip");
  assert.equal(c.observe(146, 1132), true, "two ticks' time: followed");
  assert.equal(c.serverTick(1132), 146);
  assert.equal(c.serverTick(1632), 178);
  // A tick ahead of the clock re-anchors at once.
  assert.equal(c.observe(200, 1632), true);
  assert.equal(c.serverTick(1632), 200);
});

test("a future reject lowers the lead at once", () => {
  const c = at(100, 0);
  c.recommend(21);
  const s = c.stamp(true, 0)!;
  assert.deepEqual(s, { tick: 121, view: 100 });
  c.backOff(s.tick, s.view, 118, 8);
  assert.equal(c.stamp(true, 0)!.tick, 117, "lead 18 - 1");
  c.backOff(122, 101, 119, 8);
  assert.equal(c.stamp(true, 0)!.tick, 117);
  c.backOff(150, 130, 125, 8);
  assert.equal(c.stamp(true, 0)!.tick, 117, "a view past the server's present is its tick jumping back, not the lead");
});

test("a future reject far past lowers the lead when the view agrees with the server", () => {
  const c = at(806, 0);
  c.recommend(18);
  const s = c.stamp(true, 0)!;
  c.backOff(s.tick, s.view, 818, 8); // the server at 810 accepts up to 818: 6 too far
  assert.equal(c.stamp(true, 0)!.tick, 806 + 11);
});

test("small drift is followed and jitter is not", () => {
  const c = at(100, 0);
  for (let k = 0; k <= 64; k++) {
    const now = (k / 64) * 1000;
    const est = c.serverTick(now)!;
    assert.equal(c.observe(k % 2 === 0 ? est + 1 : est - 1, now), false);
  }
  assert.equal(c.serverTick(1000), 164, "jitter moved the clock");
  for (let k = 1; k <= 65; k++) {
    const now = 1000 + (k / 64) * 1000;
    const est = c.serverTick(now)!;
    assert.equal(c.observe(est - (k % 2 === 0 ? 3 : 2), now), false);
  }
  assert.equal(c.serverTick(1000 + (65 / 64) * 1000), 164 + 65 - 2, "moved back by the smallest lag");
});
