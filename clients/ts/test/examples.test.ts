// PROTOCOL.md's examples, read by this client: every MessagePack (hex) and JSON example decodes,
// and every example of a message this client writes or reads is encoded again byte for byte as
// the server's encoder wrote it (floats as floats, fields in the server's order). The log and
// scene examples are for servers and predicting clients: they decode, and are not re-encoded.

import { test } from "node:test";
import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { fileURLToPath } from "node:url";
import { encodeJsonWith, encodeWith, type Kind } from "../src/codec.js";
import { CLIENT_MESSAGE, SERVER_MESSAGE, decodeServer } from "../src/messages.js";

const doc = readFileSync(fileURLToPath(new URL("../../../../PROTOCOL.md", import.meta.url)), "utf8");
const blocks = (info: string): string[] =>
  doc
    .split("```" + info + "\n")
    .slice(1)
    .map((rest) => rest.split("```")[0] ?? "");

const variants = (kind: Kind): string[] => (typeof kind === "object" && "tagged" in kind ? Object.keys(kind.tagged) : []);
const CLIENT = variants(CLIENT_MESSAGE);
const SERVER = variants(SERVER_MESSAGE);
const NOT_OURS = ["log", "scene"];

const hex = (b: Uint8Array): string => Buffer.from(b).toString("hex");

test("every MessagePack example decodes and encodes again byte for byte", () => {
  const examples = blocks("hex");
  assert.ok(examples.length >= 4, "examples in PROTOCOL.md");
  const seen = new Set<string>();
  for (const block of examples) {
    const bytes = Uint8Array.from(Buffer.from(block.replace(/\s+/g, ""), "hex"));
    const msg = decodeServer(bytes) as { type: string };
    seen.add(msg.type);
    if (NOT_OURS.includes(msg.type)) continue;
    const kind = CLIENT.includes(msg.type) ? CLIENT_MESSAGE : SERVER_MESSAGE;
    assert.ok(CLIENT.includes(msg.type) || SERVER.includes(msg.type), `a schema for ${msg.type}`);
    assert.equal(hex(encodeWith(kind, msg)), hex(bytes), `${msg.type} re-encoded`);
  }
  for (const t of ["input", "ack", "events", "reject"]) assert.ok(seen.has(t), `an example of ${t}`);
});

test("every JSON example parses and encodes again character for character", () => {
  const examples = blocks("json");
  assert.ok(examples.length >= 10);
  const seen = new Set<string>();
  for (const block of examples) {
    const text = block.trim();
    const msg = JSON.parse(text) as { type: string };
    seen.add(msg.type);
    if (NOT_OURS.includes(msg.type)) continue;
    const kind = CLIENT.includes(msg.type) ? CLIENT_MESSAGE : SERVER_MESSAGE;
    assert.ok(CLIENT.includes(msg.type) || SERVER.includes(msg.type), `a schema for ${msg.type}`);
    assert.equal(encodeJsonWith(kind, msg), text, `${msg.type} re-encoded`);
  }
  for (const t of ["input", "inputs", "ping", "full_frame", "pong", "ack", "events", "reject", "state"]) {
    assert.ok(seen.has(t), `an example of ${t}`);
  }
});
