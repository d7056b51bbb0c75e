// The remote world on a dead-reckoned stream (as the Rust client's test of the same name): a body
// flying straight is not carried again until something changes it, so its samples may be many
// frames apart. Up to the frame before the one that carried the change (when that frame held
// nothing back) it is drawn on its old path, where the server had it; the change is drawn after.

import { test } from "node:test";
import assert from "node:assert/strict";
import { RemoteWorld, remoteConfig } from "../src/remote.js";
import type { BodyMotion, StateFrame } from "../src/messages.js";

const frame = (n: number, tick: number, full: boolean, moved: BodyMotion[], deferred = 0): StateFrame => ({
  tick,
  frame: n,
  full,
  entered: full
    ? moved.map(([entity]) => ({ entity, class: "ball", owner: null, shape: "sphere" as const, half_extents_m: [0.5, 0.5, 0.5] as [number, number, number], offset_m: [0, 0, 0] as [number, number, number], fixed: false }))
    : [],
  moved,
  left: [],
  deferred,
  centre: null,
});

/** 6.4 m/s along x (0.1 m a tick); frames at ticks 4 and 8 do not carry it; by tick 12 it was
 * pushed along y (after tick 8 its paths are 0.4 m apart or more: no meeting). */
function pushed(deferred: number): RemoteWorld {
  const w = new RemoteWorld(remoteConfig(64));
  w.apply(frame(0, 0, true, [[1, [0, 0, 0], [6.4, 0, 0], false]]));
  w.apply(frame(1, 4, false, []));
  w.apply(frame(2, 8, false, [], deferred));
  w.apply(frame(3, 12, false, [[1, [1.2, 0.8, 0], [6.4, 6.4, 0], false]]));
  return w;
}

const near = (a: number, b: number) => Math.abs(a - b) < 1e-9;

test("a change is drawn after the last frame that vouched for the old path", () => {
  const w = pushed(0);
  for (const r of [1, 5, 8]) {
    const d = w.draw(r)[0]!;
    assert.ok(near(d.position[0], 0.1 * r) && d.position[1] === 0, `tick ${r}: ${d.position}`);
    assert.ok(d.steady, `tick ${r}: the stream vouched for it`);
  }
  // Between ticks 8 and 12, blended from the old path onto the new: half way at tick 10.
  const d = w.draw(10)[0]!;
  assert.ok(near(d.position[0], 1.0) && near(d.position[1], (0 + 0.8 - (6.4 * 2) / 64) / 2), `${d.position}`);
  assert.equal(d.steady, false);
});

test("after a frame that held bodies back, the change may have come any time after the old sample", () => {
  // The two paths cross at tick 4: taken for a bounce there.
  const d = pushed(1).draw(5)[0]!;
  assert.equal(d.steady, false);
  assert.ok(near(d.position[1], 0.1), `on the new path: ${d.position}`);
});
