// Seqs numbered, matched once, bounded, and going on across the wrap, as the Rust client's.

import { test } from "node:test";
import assert from "node:assert/strict";
import { Outbox, acceptedBefore, precedes } from "../src/outbox.js";

const sent = (tick: number) => ({ atMs: 0, tick, view: null, carriedMs: 0 });
const MAX = 2 ** 32 - 1;

test("serial order holds across the wrap", () => {
  assert.ok(precedes(1, 2) && !precedes(2, 1) && !precedes(7, 7));
  assert.ok(precedes(MAX - 1, MAX) && precedes(MAX, 0) && precedes(MAX, 1) && precedes(MAX - 500, 500));
  assert.ok(!precedes(1, MAX) && !precedes(500, MAX - 500));
  assert.deepEqual(acceptedBefore(10, 0b101n), [9, 7]);
  assert.deepEqual(acceptedBefore(2, 0b11n), [1], "0 is never a seq");
  assert.deepEqual(acceptedBefore(1, 1n << 63n), [MAX - 62]);
});

test("inputs are numbered, matched once and bounded", () => {
  const o = new Outbox(3);
  const seqs = [0, 1, 2, 3, 4].map(() => o.nextSeq());
  assert.deepEqual(seqs, [1, 2, 3, 4, 5]);
  for (const s of seqs) o.sent(s, sent(s + 100));
  assert.deepEqual([o.size, o.forgotten], [3, 2]);
  assert.equal(o.answered(1), undefined, "forgotten");
  assert.equal(o.answered(4)?.tick, 104);
  assert.equal(o.answered(4), undefined, "answered once");
  assert.equal(o.size, 2);
});

test("numbers go on across the wrap", () => {
  const o = new Outbox(4);
  o.resumeFrom(MAX - 2);
  const seqs = [0, 1, 2, 3].map(() => o.nextSeq());
  assert.deepEqual(seqs, [MAX - 2, MAX - 1, MAX, 1]);
  for (const s of seqs) o.sent(s, sent(1));
  assert.ok(seqs.every((s) => o.awaits(s)));
  const lost = o.takePending(() => true).map(([s]) => s);
  assert.deepEqual(lost, seqs, "oldest first across the wrap");
  o.resumeFrom(5);
  assert.equal(o.nextSeq(), 5, "a welcome further on moves the numbers on");
});
