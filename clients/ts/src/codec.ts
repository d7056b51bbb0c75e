// The wire encoding: MessagePack as the server writes it (PROTOCOL.md, "Encodings").
//
// JavaScript has one number type, and a MessagePack library writes 1.0 as the integer 1. The
// server's fields have exact types (f64 positions, f32 state, u32 ticks, u64 hashes), so messages
// are encoded by a schema that names each field's type: a float field is written as a float
// whatever its value, fields in the order the server writes them, absent optional fields left
// out where the server leaves them out. The result is byte for byte what the server's own encoder
// writes (test/examples.test.ts checks PROTOCOL.md's examples). Decoding is the npm package
// @msgpack/msgpack's, with u64 fields read as BigInt.

import { decode as msgpackDecode } from "@msgpack/msgpack";

/** A field's wire type. */
export type Kind =
  | "u" // an unsigned integer up to 2^53 (ticks, ids, seqs, counts)
  | "i" // a signed integer
  | "u64" // an unsigned 64-bit integer: a BigInt (or a safe integer) in, a BigInt out
  | "f64"
  | "f32"
  | "str"
  | "bool"
  | { vec: Kind } // an array (fixed-size arrays too: [f64; 3] is { vec: "f64" })
  | { opt: Kind } // nil when absent
  | { struct: Field[] } // a map of named fields, in this order
  | { tuple: Kind[] } // an array of fields of different types (BodyMotion)
  | { tagged: Record<string, Field[]> } // an internally tagged enum: `type` first, then the fields
  | { map: Kind }; // string keys in sorted order (GameState)

/** A named field. `skip`: left out when absent (the server's `skip_serializing_if`). */
export interface Field {
  name: string;
  kind: Kind;
  skip?: boolean;
}

/** Raised when a value does not fit its schema. */
export class EncodeError extends Error {}

const absent = (v: unknown): boolean => v === undefined || v === null;

/** A growing byte buffer with MessagePack's writers. */
class Writer {
  private buf = new Uint8Array(256);
  private view = new DataView(this.buf.buffer);
  len = 0;

  private room(n: number): void {
    if (this.len + n <= this.buf.length) return;
    let size = this.buf.length * 2;
    while (size < this.len + n) size *= 2;
    const next = new Uint8Array(size);
    next.set(this.buf.subarray(0, this.len));
    this.buf = next;
    this.view = new DataView(next.buffer);
  }

  byte(b: number): void {
    this.room(1);
    this.buf[this.len++] = b;
  }

  bytes(b: Uint8Array): void {
    this.room(b.length);
    this.buf.set(b, this.len);
    this.len += b.length;
  }

  be(n: number, size: 1 | 2 | 4): void {
    this.room(size);
    if (size === 1) this.view.setUint8(this.len, n);
    else if (size === 2) this.view.setUint16(this.len, n);
    else this.view.setUint32(this.len, n);
    this.len += size;
  }

  uint(n: number | bigint): void {
    const v = BigInt(n);
    if (v < 0n) throw new EncodeError(`${n} is not unsigned`);
    if (v < 128n) this.byte(Number(v));
    else if (v < 0x100n) (this.byte(0xcc), this.be(Number(v), 1));
    else if (v < 0x10000n) (this.byte(0xcd), this.be(Number(v), 2));
    else if (v < 0x100000000n) (this.byte(0xce), this.be(Number(v), 4));
    else if (v < 1n << 64n) {
      this.byte(0xcf);
      this.room(8);
      this.view.setBigUint64(this.len, v);
      this.len += 8;
    } else throw new EncodeError(`${n} does not fit 64 bits`);
  }

  int(n: number): void {
    if (!Number.isSafeInteger(n)) throw new EncodeError(`${n} is not an integer`);
    if (n >= 0) return this.uint(n);
    if (n >= -32) this.byte(n & 0xff);
    else if (n >= -128) (this.byte(0xd0), this.be(n & 0xff, 1));
    else if (n >= -32768) (this.byte(0xd1), this.be(n & 0xffff, 2));
    else if (n >= -2147483648) (this.byte(0xd2), this.be(n >>> 0, 4));
    else {
      this.byte(0xd3);
      this.room(8);
      this.view.setBigInt64(this.len, BigInt(n));
      this.len += 8;
    }
  }

  f64(n: number): void {
    this.byte(0xcb);
    this.room(8);
    this.view.setFloat64(this.len, n);
    this.len += 8;
  }

  f32(n: number): void {
    this.byte(0xca);
    this.room(4);
    this.view.setFloat32(this.len, n);
    this.len += 4;
  }

  str(s: string): void {
    const b = new TextEncoder().encode(s);
    if (b.length < 32) this.byte(0xa0 | b.length);
    else if (b.length < 0x100) (this.byte(0xd9), this.be(b.length, 1));
    else if (b.length < 0x10000) (this.byte(0xda), this.be(b.length, 2));
    else (this.byte(0xdb), this.be(b.length, 4));
    this.bytes(b);
  }

  arrayHeader(n: number): void {
    if (n < 16) this.byte(0x90 | n);
    else if (n < 0x10000) (this.byte(0xdc), this.be(n, 2));
    else (this.byte(0xdd), this.be(n, 4));
  }

  mapHeader(n: number): void {
    if (n < 16) this.byte(0x80 | n);
    else if (n < 0x10000) (this.byte(0xde), this.be(n, 2));
    else (this.byte(0xdf), this.be(n, 4));
  }

  done(): Uint8Array {
    return this.buf.slice(0, this.len);
  }
}

type Obj = Record<string, unknown>;

function present(fields: Field[], o: Obj): Field[] {
  return fields.filter((f) => !(f.skip && absent(o[f.name])));
}

function writeValue(w: Writer, kind: Kind, v: unknown, at: string): void {
  if (typeof kind === "string") {
    switch (kind) {
      case "u":
        if (typeof v !== "number" || !Number.isSafeInteger(v) || v < 0) throw new EncodeError(`${at}: ${String(v)} is not a u32`);
        return w.uint(v);
      case "i":
        if (typeof v !== "number") throw new EncodeError(`${at}: ${String(v)} is not an integer`);
        return w.int(v);
      case "u64":
        if (typeof v !== "bigint" && typeof v !== "number") throw new EncodeError(`${at}: ${String(v)} is not a u64`);
        return w.uint(v);
      case "f64":
      case "f32":
        if (typeof v !== "number") throw new EncodeError(`${at}: ${String(v)} is not a number`);
        return kind === "f64" ? w.f64(v) : w.f32(v);
      case "str":
        if (typeof v !== "string") throw new EncodeError(`${at}: ${String(v)} is not a string`);
        return w.str(v);
      case "bool":
        if (typeof v !== "boolean") throw new EncodeError(`${at}: ${String(v)} is not a boolean`);
        return w.byte(v ? 0xc3 : 0xc2);
    }
  }
  if ("opt" in kind) return absent(v) ? w.byte(0xc0) : writeValue(w, kind.opt, v, at);
  if ("vec" in kind) {
    if (!Array.isArray(v)) throw new EncodeError(`${at}: not an array`);
    w.arrayHeader(v.length);
    v.forEach((x, i) => writeValue(w, kind.vec, x, `${at}[${i}]`));
    return;
  }
  if ("tuple" in kind) {
    if (!Array.isArray(v) || v.length !== kind.tuple.length) throw new EncodeError(`${at}: not a ${kind.tuple.length}-tuple`);
    w.arrayHeader(v.length);
    kind.tuple.forEach((k, i) => writeValue(w, k, v[i], `${at}[${i}]`));
    return;
  }
  if ("map" in kind) {
    const o = (v ?? {}) as Obj;
    const keys = Object.keys(o).sort();
    w.mapHeader(keys.length);
    for (const k of keys) (w.str(k), writeValue(w, kind.map, o[k], `${at}.${k}`));
    return;
  }
  if (typeof v !== "object" || v === null) throw new EncodeError(`${at}: not an object`);
  const o = v as Obj;
  if ("struct" in kind) return writeFields(w, kind.struct, o, at, undefined);
  const type = o["type"];
  const fields = typeof type === "string" ? kind.tagged[type] : undefined;
  if (!fields) throw new EncodeError(`${at}: unknown type ${String(type)}`);
  writeFields(w, fields, o, at, type as string);
}

function writeFields(w: Writer, fields: Field[], o: Obj, at: string, tag: string | undefined): void {
  const out = present(fields, o);
  w.mapHeader(out.length + (tag === undefined ? 0 : 1));
  if (tag !== undefined) (w.str("type"), w.str(tag));
  for (const f of out) {
    w.str(f.name);
    writeValue(w, f.kind, o[f.name], `${at}.${f.name}`);
  }
}

/** `value` as MessagePack, by `kind`. */
export function encodeWith(kind: Kind, value: unknown): Uint8Array {
  const w = new Writer();
  writeValue(w, kind, value, "message");
  return w.done();
}

/** A float as the server's JSON writes it: shortest round trip, integral values with ".0". */
function jsonFloat(n: number): string {
  if (!Number.isFinite(n)) throw new EncodeError(`${n} has no JSON form`);
  const s = String(n);
  return /[.eE]/.test(s) ? s : `${s}.0`;
}

function jsonValue(kind: Kind, v: unknown): string {
  if (typeof kind === "string") {
    switch (kind) {
      case "f64":
      case "f32":
        return jsonFloat(v as number);
      case "u64":
        return BigInt(v as bigint).toString();
      case "u":
      case "i":
      case "bool":
        return String(v);
      case "str":
        return JSON.stringify(v);
    }
  }
  if ("opt" in kind) return absent(v) ? "null" : jsonValue(kind.opt, v);
  if ("vec" in kind) return `[${(v as unknown[]).map((x) => jsonValue(kind.vec, x)).join(",")}]`;
  if ("tuple" in kind) return `[${kind.tuple.map((k, i) => jsonValue(k, (v as unknown[])[i])).join(",")}]`;
  if ("map" in kind) {
    const o = (v ?? {}) as Obj;
    return `{${Object.keys(o).sort().map((k) => `${JSON.stringify(k)}:${jsonValue(kind.map, o[k])}`).join(",")}}`;
  }
  const o = v as Obj;
  const tag = "tagged" in kind ? (o["type"] as string) : undefined;
  const fields = "struct" in kind ? kind.struct : kind.tagged[tag ?? ""];
  if (!fields) throw new EncodeError(`unknown type ${String(tag)}`);
  const parts = present(fields, o).map((f) => `${JSON.stringify(f.name)}:${jsonValue(f.kind, o[f.name])}`);
  if (tag !== undefined) parts.unshift(`"type":${JSON.stringify(tag)}`);
  return `{${parts.join(",")}}`;
}

/** `value` as the server's compact JSON, by `kind`. */
export function encodeJsonWith(kind: Kind, value: unknown): string {
  return jsonValue(kind, value);
}

/** MessagePack to a plain value: maps to objects, 64-bit integers to BigInt. */
export function decodeMsgpack(bytes: Uint8Array): unknown {
  return msgpackDecode(bytes, { useBigInt64: true });
}
